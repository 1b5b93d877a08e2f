"""Tests for swarm.scenarios.scenario: the YAML schema, one-line errors naming file, key and reason, the
resolved scenario round trip, reproducible initial poses and graphs.

``BAD_SCENARIOS`` is shared with tests/test_cli.py, which checks the same files through ``swarm run``.
"""

from __future__ import annotations

import copy
import itertools
import math
import re
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from swarm.core import graphs
from swarm.scenarios.scenario import (
    Scenario,
    ScenarioError,
    dump_scenario,
    load_scenario,
    parse_scenario,
)

PROJECT_ROOT = Path(__file__).resolve().parent.parent
THESIS_SCENARIOS = sorted((PROJECT_ROOT / "scenarios" / "thesis").glob("*.yaml"))

VALID = {
    "name": "test-valid",
    "robots": {
        "count": 3,
        "init": {"random": {"seed": 1, "x": [-2, 2], "y": [-2, 2], "min_separation": 0.4}},
    },
    "topology": {"kind": "cycle"},
    "robot": {"v_max": 0.5},
    "controller": {"kind": "local_consensus", "gain": 1.0},
    "sim": {"engine": "kinematic", "control_period": 0.05, "duration": 1.0},
    "success": {"metric": "max_pairwise", "threshold": 0.2},
}


def edited(*changes: tuple[str, object]) -> dict:
    """VALID with ``("a.b.c", value)`` changes applied (value None deletes the key)."""
    data = copy.deepcopy(VALID)
    for dotted, value in changes:
        *parents, last = dotted.split(".")
        node = data
        for part in parents:
            node = node.setdefault(part, {})
        if value is None:
            node.pop(last, None)
        else:
            node[last] = value
    return data


MATRIX_2X3 = {"kind": "matrix", "adjacency": [[0, 1, 0], [1, 0, 0]]}
ASYMMETRIC = {"kind": "matrix", "adjacency": [[0, 1, 0], [0, 0, 1], [0, 1, 0]]}

# (id, file content: a mapping to dump or raw text, key the error must name, reason it must give)
BAD_SCENARIOS = [
    ("unknown-top-level-key", edited(("colour", "red")), "colour", "unknown key"),
    ("unknown-nested-key", edited(("robot.wheelbase", 0.2)), "robot.wheelbase", "unknown key"),
    ("unknown-deep-key", edited(("robots.init.random.sed", 3)), "robots.init.random.sed", "unknown key"),
    ("wrong-type", edited(("robots.count", "six")), "robots.count", "valid integer"),
    ("wrong-type-nested", edited(("sim.control_period", "fast")), "sim.control_period", "valid number"),
    ("unknown-kind", edited(("topology.kind", "hexagon")), "topology.kind", "should be"),
    ("non-square-matrix", edited(("topology", MATRIX_2X3)), "topology.adjacency", "not square: 2x3"),
    ("asymmetric-matrix", edited(("topology", ASYMMETRIC)), "topology.adjacency", "not symmetric"),
    (
        "poses-count-mismatch",
        edited(("robots.init", {"poses": [[0, 0, 0], [1, 1, 0]]})),
        "robots.init.poses",
        "2 poses but robots.count is 3",
    ),
    (
        "matrix-count-mismatch",
        edited(("topology", {"kind": "matrix", "adjacency": [[0, 1], [1, 0]]})),
        "topology.adjacency",
        "2x2 but robots.count is 3",
    ),
    ("negative-duration", edited(("sim.duration", -1.0)), "sim.duration", "greater than 0"),
    ("zero-threshold", edited(("success.threshold", 0)), "success.threshold", "greater than 0"),
    (
        "missing-model-file",
        edited(("controller", {"kind": "gnn", "model": "models/no-such-model.npz"})),
        "controller.model",
        "model file not found: models/no-such-model.npz",
    ),
    ("random-without-p", edited(("topology", {"kind": "random", "seed": 2})), "topology", "needs 'p'"),
    ("disk-without-radius", edited(("topology", {"kind": "disk"})), "topology", "needs 'radius'"),
    ("missing-required-key", edited(("topology", None)), "topology", "required key is missing"),
    (
        "fault-robot-out-of-range",
        edited(("faults", [{"kind": "kill_agent", "at": 1, "robot": 7}])),
        "faults[0]",
        "robot 7 but robots.count is 3",
    ),
    (
        "impossible-placement",
        edited(("robots.init.random", {"seed": 0, "x": [0, 0.1], "y": [0, 0.1], "min_separation": 1.0})),
        "robots.init",
        "cannot place 3 robots",
    ),
    ("invalid-yaml", "name: [unclosed\nrobots: {count: 3}\n", "line", "invalid YAML"),
    ("not-a-mapping", "- just\n- a list\n", "top level", "must be a mapping"),
]


def write_case(directory: Path, content: dict | str) -> Path:
    path = directory / "scenario.yaml"
    path.write_text(content if isinstance(content, str) else yaml.safe_dump(content, sort_keys=False))
    return path


def check_one_line_error(message: str, path: Path, key: str, reason: str) -> None:
    assert "\n" not in message.strip(), message
    assert str(path) in message
    assert key in message
    assert reason in message


@pytest.mark.parametrize(
    ("content", "key", "reason"),
    [case[1:] for case in BAD_SCENARIOS],
    ids=[case[0] for case in BAD_SCENARIOS],
)
def test_bad_scenario_is_one_line_naming_file_key_and_reason(tmp_path, content, key, reason):
    path = write_case(tmp_path, content)
    with pytest.raises(ScenarioError) as error:
        load_scenario(path)
    check_one_line_error(str(error.value), path, key, reason)
    # no pydantic noise: no "For further information visit" links, "Value error," prefixes or model names
    assert not re.search(r"errors\.pydantic\.dev|Value error,|validation error for", str(error.value))


def test_errors_name_the_key_as_written():
    # the short aliases used in scenario files are what the error names
    with pytest.raises(ScenarioError, match=r"^f\.yaml: sim\.duration: "):
        parse_scenario(edited(("sim.duration", 0)), "f.yaml")
    with pytest.raises(ScenarioError, match=r"^f\.yaml: sim\.duration_s: "):
        parse_scenario(edited(("sim.duration", None), ("sim.duration_s", -2)), "f.yaml")


def test_missing_scenario_file(tmp_path):
    path = tmp_path / "nowhere" / "missing.yaml"
    with pytest.raises(ScenarioError) as error:
        load_scenario(path)
    check_one_line_error(str(error.value), path, str(path), "no such scenario file")


def test_random_graph_that_cannot_be_connected_is_bad_input(tmp_path):
    path = write_case(tmp_path, edited(("topology", {"kind": "random", "p": 0.0, "connected": True})))
    with pytest.raises(ScenarioError) as error:
        load_scenario(path)
    check_one_line_error(str(error.value), path, "topology", "no connected Erdos-Renyi graph")


def test_several_errors_are_all_named_on_one_line():
    with pytest.raises(ScenarioError) as error:
        parse_scenario(edited(("colour", "red"), ("robot.wheelbase", 1)), "f.yaml")
    message = str(error.value)
    assert "\n" not in message
    assert "colour: unknown key" in message and "robot.wheelbase: unknown key" in message, message
    assert "more)" not in message


def test_valid_scenario_and_defaults():
    scenario = parse_scenario(VALID)
    assert scenario.steps == 20  # 1.0 s / 0.05 s
    assert scenario.robot.v_max_mps == 0.5
    assert scenario.sim.mode == "lockstep"
    assert scenario.faults == []
    minimal = parse_scenario({"name": "m", "robots": {"count": 4}, "topology": {"kind": "line"}})
    assert minimal.success.metric == "max_pairwise"
    assert minimal.robots.init.random is not None


# ---------------------------------------------------------------- resolved scenario round trip


EXTRA_SCENARIOS = [
    edited(("robots.init", {"poses": [[0, 0, 0], [1, 0, 1.5], [0, 1, -3]]})),
    edited(("topology", {"kind": "disk", "radius": 1.5})),
    edited(("topology", {"kind": "matrix", "adjacency": [[0, 1, 0], [1, 0, 2], [0, 2, 0]]})),
    edited(("topology", {"kind": "random", "p": 0.4, "seed": 3, "connected": True})),
    edited(
        (
            "faults",
            [
                {"at": 5.0, "kind": "drop_link", "link": [0, 1]},
                {"kind": "packet_loss", "p": 0.2},
                {"at": 6.0, "kind": "kill_agent", "robot": 2},
            ],
        )
    ),
    edited(("controller", {"kind": "centralized", "gain": 2.5}), ("description", "x: y")),
]


@pytest.mark.parametrize(
    "source", [*THESIS_SCENARIOS, *EXTRA_SCENARIOS], ids=lambda s: getattr(s, "stem", None)
)
def test_resolved_scenario_round_trips(tmp_path, source):
    scenario = load_scenario(source) if isinstance(source, Path) else parse_scenario(source)
    text = dump_scenario(scenario)
    again = parse_scenario(yaml.safe_load(text))
    assert again == scenario
    assert dump_scenario(again) == text
    # and through a file: what a results directory's scenario.yaml holds loads back the same
    resolved = tmp_path / "resolved.yaml"
    resolved.write_text(text)
    assert load_scenario(resolved) == scenario
    np.testing.assert_array_equal(load_scenario(resolved).initial_poses(), scenario.initial_poses())


def test_thesis_scenarios_are_there():
    names = {path.stem for path in THESIS_SCENARIOS}
    topologies = ["complete", "cycle", "line", "random", "weak"]
    controllers = ["centralized", "local_consensus"]
    assert names >= {f"{t}-{c}" for t, c in itertools.product(topologies, controllers)}


def test_weak_scenarios_are_the_two_triangles():
    for path in THESIS_SCENARIOS:
        if path.stem.startswith("weak-"):
            np.testing.assert_array_equal(load_scenario(path).adjacency(), graphs.THESIS_WEAK_GRAPH)
            assert not graphs.is_connected(load_scenario(path).adjacency())


ALL_SCENARIOS = sorted((PROJECT_ROOT / "scenarios").rglob("*.yaml"))


@pytest.mark.parametrize("path", ALL_SCENARIOS, ids=lambda path: path.relative_to(PROJECT_ROOT).as_posix())
def test_every_scenario_file_loads(path):
    load_scenario(path)  # raises ScenarioError, naming the key, for a bad one


# ---------------------------------------------------------------- initial poses and graphs


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**31),
    count=st.integers(1, 12),
    min_separation=st.floats(0.0, 0.8),
    box=st.tuples(st.floats(-3, -1), st.floats(1, 3)),
)
def test_initial_poses_reproducible_and_separated(seed, count, min_separation, box):
    # keep to placements that random sequential placement always completes (density far below jamming)
    assume(min_separation <= (box[1] - box[0]) / (2 * math.sqrt(count)))

    def scenario(seed: int) -> Scenario:
        init = {"random": {"seed": seed, "x": list(box), "y": list(box), "min_separation": min_separation}}
        return parse_scenario(edited(("robots", {"count": count, "init": init})))

    poses = scenario(seed).initial_poses()
    assert poses.shape == (count, 3)
    np.testing.assert_array_equal(scenario(seed).initial_poses(), poses)
    assert np.all((poses[:, :2] >= box[0]) & (poses[:, :2] <= box[1]))
    assert np.all((poses[:, 2] >= -math.pi) & (poses[:, 2] <= math.pi))
    if count > 1:
        gaps = np.linalg.norm(poses[:, None, :2] - poses[None, :, :2], axis=-1)[np.triu_indices(count, 1)]
        assert gaps.min() >= min_separation
    assert not np.array_equal(scenario(seed + 1).initial_poses(), poses)


def test_explicit_poses_are_used_as_given():
    poses = [[0, 0, 0], [1, 0, 1.5], [0, 1, -3]]
    scenario = parse_scenario(edited(("robots.init", {"poses": poses})))
    np.testing.assert_array_equal(scenario.initial_poses(), poses)


def test_adjacency_per_topology():
    def adjacency(topology: dict, count: int = 5):
        return parse_scenario(edited(("robots", {"count": count}), ("topology", topology))).adjacency()

    np.testing.assert_array_equal(adjacency({"kind": "complete"}), graphs.complete(5))
    np.testing.assert_array_equal(adjacency({"kind": "cycle"}), graphs.cycle(5))
    np.testing.assert_array_equal(adjacency({"kind": "line"}), graphs.line(5))
    np.testing.assert_array_equal(adjacency({"kind": "star"}), graphs.star(5))
    assert adjacency({"kind": "disk", "radius": 1.0}) is None
    random = {"kind": "random", "p": 0.3, "seed": 4, "connected": True}
    np.testing.assert_array_equal(adjacency(random, 8), adjacency(random, 8))
    assert graphs.is_connected(adjacency(random, 8))
    np.testing.assert_array_equal(adjacency(random, 8), graphs.erdos_renyi(8, 0.3, 4, connected=True))
