"""The layout's contract (docs/architecture.md), checked on the source itself: no import cycle
inside the package (imports inside functions count), stages never reach back up to the
pipeline or the CLI, one owner of the limits, one file per kinematics family."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

PKG = Path(__file__).resolve().parents[1] / "deltaslice"
STAGES = ("emit", "verify", "planning", "slicing", "kinematics", "mesh", "gcode", "samples", "toolpath", "machine")


def _modules() -> dict[str, Path]:
    out = {}
    for path in PKG.rglob("*.py"):
        rel = path.relative_to(PKG.parent).with_suffix("")
        parts = list(rel.parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


MODULES = _modules()


def _is_package(name: str) -> bool:
    return MODULES[name].name == "__init__.py"


def _imports(name: str) -> set[str]:
    """Every deltaslice module ``name`` imports, anywhere in the file (functions included)."""
    tree = ast.parse(MODULES[name].read_text())
    package = name if _is_package(name) else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            for alias in node.names:
                sub = f"{target}.{alias.name}"
                found.add(sub if sub in MODULES else target)
    return {m for m in found if m in MODULES and m != name}


GRAPH = {name: _imports(name) for name in MODULES}


def test_the_graph_is_read():
    assert "deltaslice.machine.limits" in GRAPH["deltaslice.planning.topp"] or "deltaslice.planning.pieces" in GRAPH[
        "deltaslice.planning.topp"]
    assert "deltaslice.pipeline" in GRAPH["deltaslice.cli"]  # imported inside functions


def test_no_import_cycle():
    state, stack, cycles = {}, [], []

    def visit(m):
        state[m] = 1
        stack.append(m)
        for n in sorted(GRAPH[m]):
            if state.get(n) == 1:
                cycles.append(stack[stack.index(n):] + [n])
            elif n not in state:
                visit(n)
        stack.pop()
        state[m] = 2

    for m in sorted(GRAPH):
        if m not in state:
            visit(m)
    assert not cycles, "import cycles: " + "; ".join(" -> ".join(c) for c in cycles)


@pytest.mark.parametrize("stage", STAGES)
def test_stages_never_reach_back_up(stage):
    mods = [m for m in GRAPH if m == f"deltaslice.{stage}" or m.startswith(f"deltaslice.{stage}.")]
    assert mods
    for m in mods:
        bad = GRAPH[m] & {"deltaslice.pipeline", "deltaslice.cli", "deltaslice.report"}
        assert not bad, f"{m} imports {bad}"


def test_only_the_pipeline_opens_outputs():
    """Stages write and read file objects; only the pipeline package creates output files."""
    for m, path in MODULES.items():
        if m == "deltaslice.pipeline" or m.startswith(("deltaslice.pipeline.", "deltaslice.kinematics.workspace")):
            continue
        text = path.read_text()
        assert "mkstemp" not in text and "os.replace" not in text, m
        assert not re.search(r"open\([^)]*['\"][wa]b?['\"]", text), f"{m} opens a file for writing"


def test_one_owner_of_the_limits():
    """Outside the machine package nobody assembles limits: no joint_array, no margin arithmetic
    (``limit * (1 + MARGIN)``: Limits.sampled_check owns the thresholds), no working-or-idle choice
    (``idle_velocity``: Limits.sampled_tool_velocity), no tool rate limits read from the tool's own fields."""
    for m, path in MODULES.items():
        if m.startswith("deltaslice.machine"):
            continue
        text = path.read_text()
        for pattern in (r"joint_array", r"limit_margin\s*[)*]", r"1(\.0)?\s*-\s*[\w.]*limit_margin", r"max_filament_speed",
                        r"max_filament_acceleration", r"\.is_laser", r"idle_velocity",
                        r"1(\.0)?\s*[+-]\s*(?:[A-Za-z_]\w*\.)*(?:\w*margin|\w*MARGIN|TOLERANCE|tolerance)\b"):
            assert not re.search(pattern, text), f"{m}: {pattern}"


def test_a_family_is_one_file():
    from deltaslice import kinematics

    files = {p.stem for p in (PKG / "kinematics").glob("*.py")} - {"__init__", "base", "workspace"}
    assert set(kinematics.FAMILIES) == files
    for name in kinematics.FAMILIES:
        module = kinematics.family(name)
        assert module.FAMILY == name
        assert callable(module.read_geometry) and issubclass(module.KINEMATICS, kinematics.Kinematics)
        assert module.KINEMATICS.geometry_class.__module__ == module.__name__
        assert len(module.KINEMATICS.joint_kinds) == module.KINEMATICS.n_joints


def test_every_planner_returns_pieces(any_printer):
    from deltaslice.planning import Piece, plan
    from deltaslice.toolpath import Role, ToolpathBuilder

    p = any_printer
    z = p.slicing.first_layer_height
    b = ToolpathBuilder(start=(0.0, 0.0, z))
    tool = 0.5 if p.is_laser else 1.0
    for x, y in ((5, 0), (5, 5), (0, 5)):
        b.add((x, y, z), 20.0, 0.0 if p.is_laser else 0.2, tool, Role.PERIMETER if not p.is_laser else Role.LASER)
    b.add((0, 0, z), 50.0, 0.0, 0.0, Role.TRAVEL)
    tp = b.build()
    for planner in ("toppra", "trapezoid"):
        traj = plan(tp, p, planner=planner, workers=1)
        assert traj.pieces and all(isinstance(piece, Piece) for piece in traj.pieces)
        for a, c in zip(traj.pieces[:-1], traj.pieces[1:]):
            assert a.q_end is not None and c.q_start is not None
            assert abs(a.q_end - c.q_start).max() < 1e-6, (planner, a.kind, c.kind)


def test_the_module_table_lists_every_file():
    """docs/architecture.md's module table has one row per ``deltaslice/**/*.py``, no more, no less."""
    text = (PKG.parent / "docs" / "architecture.md").read_text()
    table = text.split("\n## Modules\n", 1)[1].split("\n## ", 1)[0]
    rows = re.findall(r"^\| `([^`]+)` \|", table, re.M)
    files = sorted(str(p.relative_to(PKG)) for p in PKG.rglob("*.py"))
    assert len(rows) == len(set(rows)), "a module has two rows"
    assert sorted(rows) == files, (f"missing rows: {sorted(set(files) - set(rows))}; "
                                   f"rows of no file: {sorted(set(rows) - set(files))}")


def test_one_table_of_file_suffixes():
    """File kinds by extension live in formats.py only: no other module keeps a tuple of suffixes."""
    table = re.compile(r"SUFFIXES\s*=|[(\[{]\s*['\"]\.[a-z0-9]+['\"]\s*,")
    for m, path in MODULES.items():
        if m == "deltaslice.formats":
            continue
        hit = table.search(path.read_text())
        assert not hit, f"{m}: a suffix table ({hit.group(0)!r}): use deltaslice/formats.py"


_FIRST_KERNEL_CALL = (  # the first call of a kernel (loads numba and the kernels), checked
    "from deltaslice.planning.blend import run_cumsum\n"
    "import numpy as np\n"
    "out = np.empty(4)\n"
    "run_cumsum(np.ones(3), np.array([0, 3]), out)\n"
    "assert out.tolist() == [0.0, 1.0, 2.0, 3.0], out\n"
)


def _in_a_fresh_interpreter(code: str, *argv: str) -> None:
    """Run ``code`` (which prints ``ok`` last) in a new Python process: imports counted from zero."""
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-c", code, *argv], capture_output=True, text=True, timeout=600)
    assert out.returncode == 0 and "ok" in out.stdout, out.stderr[-3000:]


def test_numba_loads_at_the_first_kernel_call_and_every_kernel_becomes_its_dispatcher():
    """deltaslice.jit: importing the package's modules imports no numba; the first kernel call
    does, and then every module holds numba's dispatcher where it held a stand-in (imported names
    too: runpath's run_cumsum, pieces' sample_kernel), so kernels calling kernels compile and Python
    calls go straight to numba. A kernel defined after that is a dispatcher at once. Copying,
    pickling or inspecting a stand-in does not load numba."""
    code = (
        "import sys, pkgutil, importlib\n"
        "import deltaslice\n"
        "from deltaslice import jit\n"
        "names = [m.name for m in pkgutil.walk_packages(deltaslice.__path__, 'deltaslice.')\n"
        "         if not m.name.endswith('__main__')]\n"
        "mods = [importlib.import_module(n) for n in names]\n"
        "assert 'numba' not in sys.modules, 'imported numba'\n"
        "stand_ins = [(m, k) for m in mods for k, v in vars(m).items() if type(v) is jit.Deferred]\n"
        "assert len(stand_ins) > 40, len(stand_ins)\n"
        "import copy, pickle, inspect\n"
        "from deltaslice.planning import blend\n"
        "k = blend.run_cumsum\n"
        "assert pickle.loads(pickle.dumps(k)) is k and type(copy.copy(k)) is jit.Deferred\n"
        "assert str(inspect.signature(k)) == '(values, offsets, out)' and inspect.getdoc(k)\n"
        "assert inspect.getsource(inspect.unwrap(k)).startswith('@njit')\n"
        "assert 'numba' not in sys.modules, 'inspecting a stand-in imported numba'\n"
        + _FIRST_KERNEL_CALL +
        "assert 'numba' in sys.modules and jit.loaded()\n"
        "from numba.extending import is_jitted\n"
        "left = [(m.__name__, k) for m, k in stand_ins if not is_jitted(vars(m)[k])]\n"
        "assert not left, left\n"
        "from deltaslice.planning import runpath, pieces, blend\n"
        "assert runpath.run_cumsum is blend.run_cumsum and pieces.sample_kernel is blend.sample_kernel\n"
        "@jit.njit(cache=False)\n"
        "def twice(x):\n"
        "    return 2 * x\n"
        "assert is_jitted(twice) and twice(2.0) == 4.0\n"
        "print('ok')\n"
    )
    _in_a_fresh_interpreter(code)


_NUMBA_INTERNALS = ("numba.core", "numba.np", "numba.cpython", "numba.misc", "numba.parfors", "numba.stencils")


def _imported_names(tree: ast.AST):
    """Every absolute module an import names (``from a.b import c`` gives ``a.b`` and ``a.b.c``)."""
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            yield from (alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
            yield node.module
            yield from (f"{node.module}.{alias.name}" for alias in node.names)


def test_no_private_module_of_a_dependency():
    """The package uses its dependencies' public API only: none of numba's internals (``numba.core``
    and the rest change between releases), no llvmlite, no module with a leading underscore
    (``numpy._core``, ``scipy._lib``)."""
    for m, path in MODULES.items():
        text = path.read_text()
        for name in _imported_names(ast.parse(text)):
            if name.startswith("deltaslice"):
                continue
            top = name.split(".")[0]
            assert top != "llvmlite", f"{m} imports {name}"
            assert not any(part.startswith("_") for part in name.split(".")[1:]), f"{m} imports {name}"
            assert not (name + ".").startswith(tuple(p + "." for p in _NUMBA_INTERNALS)), f"{m} imports {name}"
        assert not re.search(r"\bnumba\.core\b", text), f"{m} names numba.core"


def test_slicing_a_mesh_imports_neither_scipy_spatial_nor_sparse(tmp_path):
    """Slicing a thin wall (its gap fill takes the Voronoi path, the fit check the hull) imports no
    scipy.spatial or scipy.sparse: importing them cost every compile 0.3-0.5 s before the slicing
    workers could fork (numba's own scipy.linalg comes after, while they slice)."""
    code = (
        "import sys\n"
        "import numpy as np\n"
        "from deltaslice import load_printer\n"
        "from deltaslice.pipeline import load_toolpath\n"
        "from deltaslice.toolpath import Role\n"
        "v = np.array([[i * 20, j * 1.3, k * 2.0] for i in (0, 1) for j in (0, 1) for k in (0, 1)]) - [10, 0.65, 0]\n"
        "f = [(0, 1, 3), (0, 3, 2), (4, 6, 7), (4, 7, 5), (0, 4, 5), (0, 5, 1), (2, 3, 7), (2, 7, 6), (0, 2, 6),\n"
        "     (0, 6, 4), (1, 5, 7), (1, 7, 3)]\n"
        "path = sys.argv[1]\n"
        "with open(path, 'w') as out:\n"
        "    out.write('solid wall\\n')\n"
        "    for t in f:\n"
        "        out.write('facet normal 0 0 0\\nouter loop\\n')\n"
        "        out.write(''.join(f'vertex {x} {y} {z}\\n' for x, y, z in v[list(t)]))\n"
        "        out.write('endloop\\nendfacet\\n')\n"
        "    out.write('endsolid wall\\n')\n"
        "tp = load_toolpath(path, load_printer('delta_etitc'), workers=1)\n"
        "assert (tp.role == Role.GAP_FILL).sum() > 0, 'no gap fill'\n"
        "bad = sorted(m for m in sys.modules if m.startswith(('scipy.spatial', 'scipy.sparse')))\n"
        "assert not bad, bad\n"
        "print('ok')\n"
    )
    _in_a_fresh_interpreter(code, str(tmp_path / "wall.stl"))


def test_the_planner_loads_no_linear_programming_until_a_jerk_limited_run():
    """The planner's modules (which a compile loads while its slicing workers slice) import neither
    scipy.optimize nor scipy.sparse: only the jerk limits' linear programs use them, and importing
    them at the top of planning/jerk.py cost every compile 1-2 CPU-s, jerk limits on or not."""
    code = (
        "import sys\n"
        "import deltaslice.planning, deltaslice.planning.jerk, deltaslice.planning.travel\n"
        "bad = sorted(m for m in sys.modules if m.startswith(('scipy.optimize', 'scipy.sparse')))\n"
        "assert not bad, bad\n"
        "print('ok')\n"
    )
    _in_a_fresh_interpreter(code)
