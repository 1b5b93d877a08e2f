"""The exit statuses are defined once (``swarm.core.exit_codes.ExitCode``): no module of the project
writes them as numbers. Read statically from the source (AST), like ``tests/test_import_cycles.py``:
an ``EXIT_...`` name bound to an integer literal, or ``sys.exit`` / ``os._exit`` of one, fails."""

from __future__ import annotations

import ast
from pathlib import Path

from swarm.core.exit_codes import ExitCode

ROOT = Path(__file__).resolve().parents[1]
DEFINITION = ROOT / "swarm" / "core" / "exit_codes.py"


def _literal_ints(node: ast.AST) -> bool:
    if isinstance(node, ast.Constant):
        return isinstance(node.value, int) and not isinstance(node.value, bool)
    if isinstance(node, ast.Tuple):
        return any(_literal_ints(element) for element in node.elts)
    return False


def _names(target: ast.AST) -> list[str]:
    if isinstance(target, ast.Name):
        return [target.id]
    if isinstance(target, ast.Tuple):
        return [name for element in target.elts for name in _names(element)]
    return []


def written_exit_codes(path: Path, root: Path = ROOT) -> list[str]:
    """``path:line what`` (relative to ``root``) for every exit status written as a number in ``path``."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Assign) and _literal_ints(node.value):
            names = [name for target in node.targets for name in _names(target) if name.startswith("EXIT_")]
            if names:
                found.append(f"{path.relative_to(root)}:{node.lineno} {', '.join(names)}")
        elif isinstance(node, ast.Call) and node.args and _literal_ints(node.args[0]):
            function = ast.unparse(node.func)
            if function in ("sys.exit", "os._exit", "exit", "SystemExit"):
                found.append(
                    f"{path.relative_to(root)}:{node.lineno} {function}({ast.unparse(node.args[0])})"
                )
    return found


def test_no_module_writes_an_exit_status_as_a_number():
    found = [
        hit
        for package in ("swarm", "sim_server", "robot_agent")
        for path in sorted((ROOT / package).rglob("*.py"))
        if path != DEFINITION
        for hit in written_exit_codes(path)
    ]
    assert found == []


def test_the_statuses_are_the_documented_ones():
    """README and docs: 0 success, 1 ran but did not succeed, 2 bad input, 130 interrupted."""
    assert [(code.name, int(code)) for code in ExitCode] == [
        ("SUCCESS", 0),
        ("NOT_MET", 1),
        ("BAD_INPUT", 2),
        ("INTERRUPTED", 130),
    ]


def test_the_scan_sees_a_status_written_by_hand(tmp_path):
    source = tmp_path / "probe.py"
    source.write_text("import sys\nEXIT_OK, EXIT_BAD = 0, 2\nsys.exit(1)\n")
    assert written_exit_codes(source, tmp_path) == ["probe.py:2 EXIT_OK, EXIT_BAD", "probe.py:3 sys.exit(1)"]
