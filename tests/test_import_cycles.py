"""No import cycle in the project's packages, and imports that go one way between its layers
(docs/design.md, "Architecture").

The graph is read statically from the source (AST): every ``import x`` and ``from x import y``, at
module level, inside functions and under ``TYPE_CHECKING`` alike, resolved to the project module it
names (``from swarm.core import graphs`` is an edge to ``swarm.core.graphs``; a package's
``__init__`` is a module of its own). Between the top-level packages: ``swarm`` never imports
``sim_server`` or ``robot_agent``. Inside ``swarm`` (``LAYERS``): the command line imports the
runtime and learning, which import the scenarios, which import the simulators, which import the
math; never the other way, and the runtime and learning never import each other.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("swarm", "sim_server", "robot_agent")

# Each package's layer, bottom first; a module may import its own layer and the layers below it.
# ``swarm`` itself (its ``__init__``: the version) is the floor; any other module directly under
# ``swarm`` belongs to no layer, so a new flat module fails the test.
LAYERS: dict[str, tuple[int, str]] = {
    "swarm": (0, "root"),
    "swarm.core": (1, "math"),
    "swarm.sim": (2, "simulators"),
    "swarm.scenarios": (3, "scenarios"),
    "swarm.learn": (4, "learning"),
    "swarm.rl": (4, "learning"),
    "swarm.runtime": (4, "runtime"),
    "swarm.cli": (5, "command line"),
    "sim_server": (5, "processes"),
    "robot_agent": (5, "processes"),
}
# Below a layer but still not allowed: the processes never import learning (torch) or the command line.
FORBIDDEN = {("processes", "learning")}


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
    # edges are found (results draws its pictures by the task, the task's pictures use the report's)
    assert "swarm.scenarios.task_report" in graph["swarm.scenarios.results"]
    assert "swarm.scenarios.report" in graph["swarm.scenarios.task_report"]
    cycle = find_cycle(graph)
    assert cycle is None, "import cycle: " + " -> ".join(cycle or [])


def test_swarm_never_imports_the_processes():
    graph = import_graph(project_modules())
    for module, targets in graph.items():
        if module.split(".")[0] == "swarm":
            wrong = sorted(t for t in targets if t.split(".")[0] != "swarm")
            assert not wrong, f"{module} imports {wrong}"


def layer_of(module: str) -> tuple[int, str] | None:
    """``LAYERS`` of the longest package that ``module`` lies in; None for a module in none."""
    name = module
    while name not in LAYERS:
        name = name.rpartition(".")[0]
        if not name:
            return None
    if LAYERS[name][1] == "root" and module != name:
        return None  # a flat module under swarm/
    return LAYERS[name]


def layer_violations(graph: dict[str, set[str]]) -> list[str]:
    """Every module outside the layers and every import that goes up, sideways or is forbidden."""
    wrong = []
    for module, targets in sorted(graph.items()):
        layer = layer_of(module)
        if layer is None:
            wrong.append(f"{module} is in no layer (put it in a sub-package of LAYERS)")
            continue
        for target in sorted(targets):
            other = layer_of(target)
            if other is None or other[1] == layer[1]:
                continue  # reported as a module of its own, or the same layer
            if other[0] >= layer[0] or (layer[1], other[1]) in FORBIDDEN:
                wrong.append(f"{module} ({layer[1]}) imports {target} ({other[1]})")
    return wrong


def test_imports_go_one_way_between_the_layers():
    graph = import_graph(project_modules())
    assert {layer_of(module) for module in graph} == set(LAYERS.values())  # every layer has modules
    assert not layer_violations(graph), "\n".join(layer_violations(graph))


@pytest.mark.parametrize(
    ("sources", "wrong"),
    [
        ({"sim/a": "from swarm.core import b\n", "core/b": "import numpy\n"}, []),  # down: fine
        ({"core/b": "def f():\n    from swarm.sim import a\n", "sim/a": ""}, ["swarm.core.b"]),  # up
        ({"learn/a": "from swarm.runtime import b\n", "runtime/b": ""}, ["swarm.learn.a"]),  # sideways
        ({"rl/a": "from swarm.learn import b\n", "learn/b": ""}, []),  # one layer, two packages
        ({"flat": "from swarm.core import b\n", "core/b": ""}, ["swarm.flat"]),  # in no layer
        ({"cli": "from swarm.learn import b\n", "learn/b": "from swarm import cli\n"}, ["swarm.learn.b"]),
    ],
)
def test_the_layer_check_finds_imports_that_go_up_or_sideways(tmp_path, sources, wrong):
    for name, text in sources.items():
        path = tmp_path / "swarm" / f"{name}.py"
        path.parent.mkdir(parents=True, exist_ok=True)
        for folder in [path.parent, *path.parent.parents][: len(Path(name).parts)]:
            (folder / "__init__.py").touch()
        path.write_text(text)
    found = layer_violations(import_graph(project_modules(tmp_path)))
    assert [line.split()[0] for line in found] == wrong, found


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
