"""No import cycle in the project's packages (docs/design.md, "Architecture").

The graph is read statically from the source (AST): every ``import x`` and ``from x import y``, at
module level, inside functions and under ``TYPE_CHECKING`` alike, resolved to the project module it
names (``from swarm import graphs`` is an edge to ``swarm.core.graphs``; a package's ``__init__`` is a
module of its own). Imports also go one way between the top-level packages: ``swarm`` never
imports ``sim_server`` or ``robot_agent``.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("swarm", "sim_server", "robot_agent")


def project_modules(root: Path = ROOT) -> dict[str, Path]:
    """Dotted module name -> source file, for every module of ``PACKAGES`` under ``root``."""
    modules = {}
    for package in PACKAGES:
        for path in sorted((root / package).rglob("*.py")):
            parts = list(path.relative_to(root).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            modules[".".join(parts)] = path
    return modules


def _resolve(name: str, modules: dict[str, Path]) -> str | None:
    """The longest project module that ``name`` (a module or a name inside one) lies in."""
    while name and name not in modules:
        name = name.rpartition(".")[0]
    return name or None


def import_graph(modules: dict[str, Path]) -> dict[str, set[str]]:
    """Module -> the project modules it imports anywhere in its source."""
    graph: dict[str, set[str]] = {}
    for module, path in modules.items():
        package = module.split(".") if path.name == "__init__.py" else module.split(".")[:-1]
        targets: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom):
                if node.level:  # relative: from . import x, from ..a import b
                    base = package[: len(package) - node.level + 1]
                    source = ".".join([*base, *([node.module] if node.module else [])])
                else:
                    source = node.module or ""
                names = [f"{source}.{alias.name}" for alias in node.names] or [source]
            else:
                continue
            for name in names:
                target = _resolve(name, modules)
                if target is not None and target != module:
                    targets.add(target)
        graph[module] = targets
    return graph


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One import cycle as ``[a, b, ..., a]``, or None (iterative depth-first search)."""
    state = dict.fromkeys(graph, 0)  # 0 unseen, 1 on the current path, 2 done
    for start in sorted(graph):
        if state[start]:
            continue
        path = [start]
        stack = [iter(sorted(graph[start]))]
        state[start] = 1
        while stack:
            child = next(stack[-1], None)
            if child is None:
                state[path.pop()] = 2
                stack.pop()
            elif state.get(child, 2) == 1:
                return [*path[path.index(child) :], child]
            elif state.get(child, 2) == 0:
                state[child] = 1
                path.append(child)
                stack.append(iter(sorted(graph[child])))
    return None


def test_the_project_has_no_import_cycle():
    graph = import_graph(project_modules())
    assert len(graph) > 40  # every module was found
    # edges are found (results draws its pictures)
    assert "swarm.scenarios.report" in graph["swarm.scenarios.results"]
    cycle = find_cycle(graph)
    assert cycle is None, "import cycle: " + " -> ".join(cycle or [])


def test_swarm_never_imports_the_processes():
    graph = import_graph(project_modules())
    for module, targets in graph.items():
        if module.split(".")[0] == "swarm":
            wrong = sorted(t for t in targets if t.split(".")[0] != "swarm")
            assert not wrong, f"{module} imports {wrong}"


@pytest.mark.parametrize(
    ("sources", "cycle"),
    [
        ({"a": "import swarm.b\n", "b": "def f():\n    from swarm import a\n"}, True),  # function-level
        ({"a": "from swarm.b import x\n", "b": "from . import c\n", "c": "import swarm.a as z\n"}, True),
        (
            {
                "a": "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from swarm.b import B\n",
                "b": "from swarm import a\n",
            },
            True,
        ),
        ({"a": "import swarm.b\n", "b": "import numpy\nfrom swarm import c\n", "c": "import os\n"}, False),
    ],
)
def test_the_walker_finds_cycles_of_every_import_form(tmp_path, sources, cycle):
    package = tmp_path / "swarm"
    package.mkdir()
    (package / "__init__.py").write_text("")
    for name, text in sources.items():
        (package / f"{name}.py").write_text(text)
    found = find_cycle(import_graph(project_modules(tmp_path)))
    assert (found is not None) == cycle, found
