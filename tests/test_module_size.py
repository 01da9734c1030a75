"""Issue 51's bar on the whole package: modules of at most 800 lines, functions of at most 100,
and no branch on the tool's kind outside deltaslice/machine/ (the Tool object answers what a stage
asks of it). tests/test_structure.py adds planning/'s own rules."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PKG = Path(__file__).resolve().parents[1] / "deltaslice"
MAX_MODULE_LINES = 800
MAX_FUNCTION_LINES = 100
KIND_NAMES = {"channel_kind", "tool_kind"}


def _sources(*skipped: str) -> list[Path]:
    """The package's Python files outside the sub-packages ``skipped``."""
    return sorted(p for p in PKG.rglob("*.py") if p.relative_to(PKG).parts[0] not in skipped)


def _long_functions(tree: ast.AST) -> list[tuple[str, int, int]]:
    """(name, first line, lines) of every function or method longer than MAX_FUNCTION_LINES."""
    return [(node.name, node.lineno, node.end_lineno - node.lineno + 1) for node in ast.walk(tree)
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef))
            and node.end_lineno - node.lineno + 1 > MAX_FUNCTION_LINES]


def _is_kind(node: ast.AST) -> bool:
    """``x.channel_kind``, ``h.tool_kind``, ``tool_kind``, or ``<...tool...>.kind``."""
    if isinstance(node, ast.Name):
        return node.id in KIND_NAMES
    if isinstance(node, ast.Attribute):
        return node.attr in KIND_NAMES or (node.attr == "kind" and "tool" in ast.unparse(node.value).lower())
    return False


def _is_text(node: ast.AST) -> bool:
    if isinstance(node, (ast.Tuple, ast.List, ast.Set)):
        return bool(node.elts) and all(_is_text(e) for e in node.elts)
    return isinstance(node, ast.Constant) and isinstance(node.value, str)


def _kind_comparisons(source: str) -> list[int]:
    """Lines comparing a tool's kind with a name (``==``, ``!=``, ``in``; a match on it too)."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Compare):
            operands = [node.left, *node.comparators]
            if any(_is_kind(o) for o in operands) and any(_is_text(o) for o in operands):
                found.append(node.lineno)
        elif isinstance(node, ast.Match) and _is_kind(node.subject):
            found.append(node.lineno)
    return found


def test_the_checks_see_what_they_look_for():
    assert _kind_comparisons('if printer.tool.channel_kind == "laser":\n    pass\n') == [1]
    assert _kind_comparisons('x = 1 if h.tool_kind != "laser" else 2\n') == [1]
    assert _kind_comparisons('if tool.kind in ("laser", "engraver"):\n    pass\n') == [1]
    assert _kind_comparisons('match tool_kind:\n    case "laser":\n        pass\n') == [1]
    # naming the kind in a message is fine; so is a joint's kind
    assert _kind_comparisons('raise ValueError(f"a {tool.channel_kind} cannot")\nok = joint.kind == "revolute"\n') == []
    body = "\n".join(f"    x = {i}" for i in range(MAX_FUNCTION_LINES))
    assert [f[0] for f in _long_functions(ast.parse(f"def f():\n{body}\n"))] == ["f"]
    assert not _long_functions(ast.parse(f"def f():\n{body[: body.rindex(chr(10))]}\n"))


@pytest.mark.parametrize("path", _sources(), ids=lambda p: str(p.relative_to(PKG)))
def test_modules_and_functions_are_short(path):
    text = path.read_text()
    lines = text.count("\n")
    assert lines <= MAX_MODULE_LINES, f"{path.relative_to(PKG)}: {lines} lines (at most {MAX_MODULE_LINES})"
    long = _long_functions(ast.parse(text))
    assert not long, f"{path.relative_to(PKG)}: functions over {MAX_FUNCTION_LINES} lines (name, line, lines): {long}"


@pytest.mark.parametrize("path", _sources("machine"), ids=lambda p: str(p.relative_to(PKG)))
def test_no_branch_on_the_tools_kind_outside_the_machine(path):
    lines = _kind_comparisons(path.read_text())
    assert not lines, (f"{path.relative_to(PKG)}: lines {lines} compare a tool's kind with a name: ask the Tool "
                       "object (deltaslice/machine/tool.py) instead")
