"""The planning package's structure (issue 51; the size bar is tests/test_module_size.py's): no
branch on the tool's kind (the Tool object answers: takes_filament, takes_laser_power,
off_events), and no limit read from a printer (every limit comes from the PlanContext, built once
from ``printer.planned_limits()`` and ``printer.limits``)."""

from __future__ import annotations

import ast
import re
from pathlib import Path

PLANNING = Path(__file__).resolve().parents[1] / "deltaslice" / "planning"
MODULES = sorted(PLANNING.glob("*.py"))


def _source(path: Path) -> str:
    return path.read_text()


def test_the_planning_package_is_scanned():
    assert len(MODULES) >= 10 and (PLANNING / "context.py") in MODULES


def test_planning_never_compares_the_tools_kind():
    """No ``channel_kind`` nor ``is_laser`` in planning/: it asks the Tool what its channel does."""
    bad = [f"{p.name}:{i}" for p in MODULES for i, line in enumerate(_source(p).splitlines(), 1)
           if re.search(r"\bchannel_kind\b|\bis_laser\b", line)]
    assert not bad, f"the tool's kind compared in planning/: {bad}"


# a limit read on anything but a PlanContext: ``printer.limits``, ``p.limits.velocity``,
# ``printer.planned_limits()``, ``traj.printer.limits``
_RAW_LIMIT = re.compile(r"\b(?!ctx\b|self\b)\w+\.(limits\b|planned_limits\(\)|planned_actuators\(\))")


def _builders(source: str) -> set[int]:
    """Lines of the functions that build a PlanContext's parts from a printer (``torque_limits``,
    called by ``PlanContext.of``): the one place besides context.py allowed to read its limits."""
    lines = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.FunctionDef) and node.name in CONTEXT_BUILDERS:
            lines.update(range(node.lineno, node.end_lineno + 1))
    return lines


CONTEXT_BUILDERS = {"torque_limits"}


def test_planning_reads_no_limit_from_a_printer():
    """Every limit in planning/ comes from the PlanContext (context.py builds it, the one place that
    reads the printer's limits, with the builders it calls)."""
    bad = []
    for path in MODULES:
        if path.name == "context.py":
            continue
        source = _source(path)
        allowed = _builders(source)
        for i, line in enumerate(source.splitlines(), 1):
            code = line.split("#", 1)[0]
            if i in allowed:
                continue
            if _RAW_LIMIT.search(code) and not code.lstrip().startswith(('"', "'", "from ", "import ")):
                bad.append(f"{path.name}:{i}: {line.strip()}")
    assert not bad, "limits read from a printer in planning/ (use the PlanContext):\n" + "\n".join(bad)


def test_the_structure_checks_would_see_the_bugs_they_name():
    """The patterns match what they ban, and not the context's own fields."""
    assert _RAW_LIMIT.search("vmax = printer.limits.velocity")
    assert _RAW_LIMIT.search("lim = p.limits")
    assert _RAW_LIMIT.search("acc = printer.planned_limits().acceleration[-1]")
    assert not _RAW_LIMIT.search("acc = ctx.planned_limits.acceleration[-1]")
    assert not _RAW_LIMIT.search("names = ctx.machine_limits.names")
    assert re.search(r"\bchannel_kind\b", 'laser = printer.tool.channel_kind == "laser"')
    builder = "def torque_limits(printer):\n    return printer.planned_actuators()\ndef other(printer):\n    return 1\n"
    assert _builders(builder) == {1, 2}
