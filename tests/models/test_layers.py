"""Layering of ``models/``: it imports nothing of the layers above it, and has no import cycle."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

MODELS = Path(__file__).resolve().parents[2] / "models"
FORBIDDEN = ("blackboard", "knowledge_sources")


def _is_type_checking(node: ast.If) -> bool:
    test = node.test
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def imports(path: Path, *, typing_only: bool = True) -> list[tuple[int, str]]:
    """``(line, module)`` of every import in ``path``: module level, inside functions, and (with
    ``typing_only``) under ``if TYPE_CHECKING:``; also ``importlib.import_module("...")`` and
    ``__import__("...")`` calls with a literal name."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    found: list[tuple[int, str]] = []

    def visit(node: ast.AST) -> None:
        if isinstance(node, ast.If) and _is_type_checking(node) and not typing_only:
            for child in node.orelse:
                visit(child)
            return
        if isinstance(node, ast.Import):
            found.extend((node.lineno, alias.name) for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:  # relative: resolve against the models package
                base = "models" + ("." + node.module if node.module else "")
                found.append((node.lineno, base))
            elif node.module:
                found.append((node.lineno, node.module))
                found.extend((node.lineno, f"{node.module}.{a.name}") for a in node.names)
        elif isinstance(node, ast.Call):
            fn = node.func
            name = fn.attr if isinstance(fn, ast.Attribute) else getattr(fn, "id", None)
            if name in ("import_module", "__import__") and node.args and isinstance(node.args[0], ast.Constant):
                if isinstance(node.args[0].value, str):
                    found.append((node.lineno, node.args[0].value))
        for child in ast.iter_child_nodes(node):
            visit(child)

    visit(tree)
    return found


FILES = sorted(MODELS.rglob("*.py"))


def test_the_walk_sees_every_kind_of_import(tmp_path):
    probe = tmp_path / "probe.py"
    probe.write_text(
        "import blackboard.errors\n"
        "from knowledge_sources import levels\n"
        "from typing import TYPE_CHECKING\n"
        "if TYPE_CHECKING:\n    from blackboard.hypothesis import Hypothesis\n"
        "def f():\n    import importlib\n    return importlib.import_module('knowledge_sources.cli')\n"
    )
    modules = {m for _, m in imports(probe)}
    assert {"blackboard.errors", "knowledge_sources", "blackboard.hypothesis", "knowledge_sources.cli"} <= modules


@pytest.mark.parametrize("path", FILES, ids=[p.name for p in FILES])
def test_models_import_nothing_of_blackboard_or_knowledge_sources(path):
    bad = [(line, m) for line, m in imports(path) if m.split(".")[0] in FORBIDDEN]
    assert not bad, f"{path.name} imports " + ", ".join(f"{m} (line {line})" for line, m in bad)


def test_models_have_no_import_cycle():
    names = {p.stem: p for p in FILES if p.stem != "__init__"}
    graph = {
        name: {m.split(".")[1] for _, m in imports(path, typing_only=False) if m.startswith("models.")} & set(names)
        for name, path in names.items()
    }
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(node: str) -> None:
        state[node] = 1
        stack.append(node)
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                cycle = stack[stack.index(nxt) :] + [nxt]
                pytest.fail("import cycle in models/: " + " -> ".join(cycle))
            if nxt not in state:
                visit(nxt)
        stack.pop()
        state[node] = 2

    for name in sorted(graph):
        if name not in state:
            visit(name)
