"""The safety filter in the kinematic engine: sensing, the scenario key, contacts and clearance, and
bodies that never overlap over random rollouts of real controllers with obstacles."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from swarm.core import graphs
from swarm.core.initial_poses import random_poses
from swarm.core.obstacles import Capsules, ObstacleSpec
from swarm.core.robot import RobotParams
from swarm.core.safety import SafetyParams
from swarm.runtime.runner import run_scenario
from swarm.scenarios.safety_results import contact_results
from swarm.scenarios.scenario import ScenarioError, parse_scenario
from swarm.sim.controller_kinds import ControllerArgs, batched_controller
from swarm.sim.kinematic import KinematicSim
from swarm.sim.safety_filter import SafetyFilter
from swarm.sim.sensing import sense

ROBOT = RobotParams()
OBSTACLES = Capsules(
    [
        ObstacleSpec(kind="disc", centre=(0.5, 0.3), radius_m=0.3),
        ObstacleSpec(kind="wall", start=(-2.0, -1.2), end=(1.0, -1.2)),
    ]
)


def _sim(poses, kind="centralized_mec", safety=True, obstacles=OBSTACLES):
    count = poses.shape[1]
    controller = batched_controller(kind, ControllerArgs(robot=ROBOT, robot_count=count))
    layer = SafetyFilter(ROBOT, SafetyParams(), obstacles) if safety else None
    return KinematicSim(ROBOT, controller, 0.05, poses, adjacency=graphs.complete(count), safety=layer)


def _head_on():
    return np.array([[[-1.0, 0.0, 0.0], [1.0, 0.0, np.pi]]])


def test_head_on_collides_without_the_filter_and_not_with_it():
    for safety, collides in ((False, True), (True, False)):
        trajectory = _sim(_head_on(), "centralized", safety, Capsules()).rollout(200)
        result = contact_results(trajectory[:, 0], ROBOT.body_radius_m, Capsules())
        assert (result["contacts"]["robot_robot"] > 0) is collides, result
        assert (result["min_clearance_m"] < 0) is collides, result


def test_a_filter_with_nothing_near_changes_nothing():
    poses = np.array([[[-3.0, 0.0, 0.0], [3.0, 0.0, 1.0], [0.0, 3.0, -2.0]]])
    plain = _sim(poses.copy(), "local_consensus", False).rollout(20)
    sim = _sim(poses.copy(), "local_consensus", True, Capsules())
    filtered = sim.rollout(20)
    np.testing.assert_array_equal(plain, filtered)
    assert sim.safety is not None and sim.safety.counts == {"interventions": 0, "infeasible": 0}


def _clear_starts(seed, batch, count):
    rng = np.random.default_rng(seed)
    poses = random_poses(rng, 20 * batch, count, (-3.0, 3.0), (-3.0, 3.0), 0.5)
    clear = (OBSTACLES.surface_distance(poses[..., :2]) > 0.3).all(axis=(1, 2))
    return poses[clear][:batch]


@settings(max_examples=8)
@given(
    seed=st.integers(0, 2**32 - 1),
    count=st.integers(2, 16),
    kind=st.sampled_from(["centralized_mec", "local_consensus", "mec_flood", "gnn"]),
)
def test_bodies_never_overlap_over_random_rollouts(seed, count, kind):
    poses = _clear_starts(seed, 4, count)
    controller = batched_controller(kind, ControllerArgs(robot=ROBOT, robot_count=count, policy=_model()))
    layer = SafetyFilter(ROBOT, SafetyParams(), OBSTACLES)
    sim = KinematicSim(ROBOT, controller, 0.05, poses, disk_radius_m=1.5, safety=layer)
    trajectory = sim.rollout(300)
    for env in range(len(poses)):
        result = contact_results(trajectory[:, env], ROBOT.body_radius_m, OBSTACLES)
        assert result["contacts"]["ticks"] == 0 and result["min_clearance_m"] >= 0, result


def _model():
    from swarm.scenarios.scenario import default_model_path

    return default_model_path()


def test_sensing_sees_within_the_radius_only_and_is_seeded():
    poses = np.array([[[0.0, 0.0, np.pi / 2], [1.0, 0.0, 0.0], [5.0, 0.0, 0.0]]])
    points = poses[..., :2]
    readings = sense(poses, points, Capsules(), 1.5)
    assert readings.body_seen[0].tolist() == [
        [False, True, False],
        [True, False, False],
        [False, False, False],
    ]
    # robot 0 faces +y: robot 1, 1 m along +x, is on its right (bearing -pi/2), heading -pi/2 relative
    assert readings.body_range_m[0, 0, 1] == pytest.approx(1.0)
    assert readings.body_bearing_rad[0, 0, 1] == pytest.approx(-np.pi / 2)
    assert readings.body_heading_rad[0, 0, 1] == pytest.approx(-np.pi / 2)
    moved = poses.copy()
    moved[0, 2, :2] = [7.0, 3.0]  # outside everyone's radius: nobody's reading changes
    again = sense(moved, moved[..., :2], Capsules(), 1.5)
    for field in ("body_seen",):
        np.testing.assert_array_equal(getattr(readings, field), getattr(again, field))
    np.testing.assert_array_equal(readings.body_range_m[0, :2, :2], again.body_range_m[0, :2, :2])
    noisy = [sense(poses, points, OBSTACLES, 1.5, 0.02, 0.3, np.random.default_rng(4)) for _ in range(2)]
    np.testing.assert_array_equal(noisy[0].body_range_m, noisy[1].body_range_m)
    np.testing.assert_array_equal(noisy[0].obstacle_seen, noisy[1].obstacle_seen)


def test_obstacle_geometry():
    wall = Capsules([ObstacleSpec(kind="wall", start=(0.0, 0.0), end=(2.0, 0.0), thickness_m=0.2)])
    points = np.array([[1.0, 1.0], [-1.0, 0.0], [3.0, 1.0]])
    np.testing.assert_allclose(wall.surface_distance(points)[:, 0], [0.9, 0.9, np.sqrt(2) - 0.1])
    np.testing.assert_allclose(wall.nearest_surface(points)[0, 0], [1.0, 0.1])


SCENARIO = {
    "name": "head-on",
    "robots": {"count": 2, "init": {"poses": [[-1.0, 0.0, 0.0], [1.0, 0.0, 3.14159]]}},
    "topology": {"kind": "complete"},
    "controller": {"kind": "centralized"},
    "sim": {"engine": "kinematic", "duration_s": 8},
    "success": {"threshold": 0.6},
}


def test_scenario_key_and_metrics(tmp_path):
    plain = parse_scenario(SCENARIO)
    assert plain.safety is None and plain.obstacles == []
    safe = parse_scenario(
        {
            **SCENARIO,
            "safety": {"kind": "barrier"},
            "obstacles": [{"kind": "disc", "centre": [0.0, 2.0], "radius_m": 0.2}],
        }
    )
    for scenario, name in ((plain, "plain"), (safe, "safe")):
        run_scenario(scenario, tmp_path / name, progress=False)
    plain_metrics = json.loads((tmp_path / "plain" / "metrics.json").read_text())
    safe_metrics = json.loads((tmp_path / "safe" / "metrics.json").read_text())
    assert plain_metrics["contacts"]["robot_robot"] > 0 and plain_metrics["safety_filter"] is None
    assert safe_metrics["contacts"] == {"robot_robot": 0, "robot_obstacle": 0, "ticks": 0}
    assert safe_metrics["min_clearance_m"] >= 0
    assert safe_metrics["safety_filter"]["interventions"] > 0


@pytest.mark.parametrize(
    "safety,key",
    [
        ({"kind": "barrier", "sensing_radius_m": 0.3}, "safety.sensing_radius_m"),
        ({"kind": "barrier", "gain_per_s": 40}, "safety.gain_per_s"),
        ({"kind": "wall"}, "safety.kind"),
    ],
)
def test_bad_safety_keys_are_named(safety, key):
    with pytest.raises(ScenarioError, match=key.replace(".", r"\.")):
        parse_scenario({**SCENARIO, "safety": safety})


@pytest.mark.parametrize(
    ("engine", "given", "margin", "spacing"),
    [
        ("kinematic", {}, 0.03, None),  # pack_flood keeps its default spacing (2 (r + l) + 0.05)
        ("pybullet", {}, 0.05, 2 * (0.12 + 0.05) + 0.05 + 0.02),  # slots 2 cm wider than the barrier
        ("pybullet", {"margin_m": 0.03}, 0.03, None),  # a margin the scenario gives is kept
        ("kinematic", {"margin_m": 0.08}, 0.08, 2 * (0.12 + 0.05) + 0.08 + 0.02),
    ],
)
def test_the_default_margin_is_the_engines_and_pack_flood_slots_clear_it(engine, given, margin, spacing):
    """PyBullet's robots lag their commands: its default barrier margin is wider (docs/safety.md), and
    ``pack_flood``'s slots stay 2 cm wider than the barrier's distance."""
    robot = RobotParams()
    assert (robot.body_radius_m, robot.offset_m) == (0.12, 0.05)  # the numbers above
    data = {
        **SCENARIO,
        "controller": {"kind": "pack_flood"},
        "sim": {**SCENARIO.get("sim", {}), "engine": engine},
        "safety": {"kind": "barrier", **given},
    }
    scenario = parse_scenario(data)
    assert scenario.safety is not None and scenario.safety.margin_m == pytest.approx(margin)
    if spacing is None:
        assert scenario.controller.spacing_m is None
    else:
        assert scenario.controller.spacing_m == pytest.approx(spacing)
    plain = parse_scenario({**SCENARIO, "sim": {**SCENARIO.get("sim", {}), "engine": engine}})
    assert plain.safety is None and plain.controller.spacing_m is None


def test_bad_obstacle_is_named():
    with pytest.raises(ScenarioError, match="obstacles"):
        parse_scenario({**SCENARIO, "obstacles": [{"kind": "disc", "centre": [0, 0]}]})


def test_a_robot_sees_nothing_of_a_body_beyond_its_radius_and_its_k_hops():
    """Robot 0 of a line of 8 (2 m apart, sensing 1.5 m) keeps its poses for 7 ticks when robot 7, 7 hops
    away and out of everyone's sight but robot 6's, starts elsewhere; later the change reaches it (local
    consensus sends positions: a change moves one hop per two ticks, so robot 0 first moves differently
    at tick 14)."""
    count = 8
    poses = np.array([[[2.0 * i, 0.1 * i, 0.3 * i] for i in range(count)]])
    moved = poses.copy()
    moved[0, 7, :2] += [0.4, 0.3]

    def run(start):
        controller = batched_controller("local_consensus", ControllerArgs(robot=ROBOT, robot_count=count))
        layer = SafetyFilter(ROBOT, SafetyParams(), Capsules())
        sim = KinematicSim(ROBOT, controller, 0.05, start, adjacency=graphs.line(count), safety=layer)
        return sim.rollout(20)[:, 0]

    plain, perturbed = run(poses), run(moved)
    np.testing.assert_array_equal(plain[:8, 0], perturbed[:8, 0])
    assert np.any(plain[8:, 0] != perturbed[8:, 0])


def test_report_recomputes_contacts_and_keeps_the_filter_counts(tmp_path):
    from swarm.scenarios.results import report

    scenario = parse_scenario({**SCENARIO, "safety": {"kind": "barrier"}})
    run_scenario(scenario, tmp_path / "run", progress=False)
    written = json.loads((tmp_path / "run" / "metrics.json").read_text())
    lines = (tmp_path / "run" / "trajectory.jsonl").read_text().splitlines(keepends=True)
    collided = [json.loads(line) for line in lines]
    for line in collided[-3:]:  # the last ticks on top of each other: the report must see contacts
        line["poses"] = [[0.0, 0.0, 0.0], [0.1, 0.0, 0.0]]
    (tmp_path / "run" / "trajectory.jsonl").write_text("".join(json.dumps(line) + "\n" for line in collided))
    again = report(tmp_path / "run")
    assert again["contacts"] == {"robot_robot": 3, "robot_obstacle": 0, "ticks": 3}
    assert again["min_clearance_m"] == pytest.approx(0.1 - 2 * ROBOT.body_radius_m)
    assert again["safety_filter"] == written["safety_filter"]


def test_a_run_with_bodies_to_keep_apart_plots_their_clearance(tmp_path):
    """clearance.png for a run with the filter and an obstacle, none for the plain run; its curves are
    the gaps of the trajectory, computed here from the poses (bumper radius r, a disc of 0.2 m at
    (0, 2)), and their least is metrics.json's min_clearance_m."""
    from swarm.scenarios.results import read_trajectory

    safe = parse_scenario(
        {
            **SCENARIO,
            "safety": {"kind": "barrier"},
            "obstacles": [{"kind": "disc", "centre": [0.0, 2.0], "radius_m": 0.2}],
        }
    )
    run_scenario(safe, tmp_path / "safe", progress=False)
    run_scenario(parse_scenario(SCENARIO), tmp_path / "plain", progress=False)
    assert not (tmp_path / "plain" / "clearance.png").exists()
    assert (tmp_path / "safe" / "clearance.png").is_file()
    lines = {
        line["gid"]: line for line in json.loads((tmp_path / "safe" / "clearance.json").read_text())["lines"]
    }
    _, poses, _ = read_trajectory(tmp_path / "safe" / "trajectory.jsonl")
    r = ROBOT.body_radius_m
    centres = poses[..., :2]
    pair = np.linalg.norm(centres[:, :, None] - centres[:, None], axis=-1) + np.eye(centres.shape[1]) * 1e9
    np.testing.assert_allclose(lines["robot_robot"]["y"], pair.min(axis=(1, 2)) - 2 * r, atol=1e-6)
    disc = np.linalg.norm(centres - np.array([0.0, 2.0]), axis=-1) - 0.2 - r
    np.testing.assert_allclose(lines["robot_obstacle"]["y"], disc.min(axis=1), atol=1e-6)
    metrics = json.loads((tmp_path / "safe" / "metrics.json").read_text())
    least = min(min(lines["robot_robot"]["y"]), min(lines["robot_obstacle"]["y"]))
    assert least == pytest.approx(metrics["min_clearance_m"], abs=1e-6)


def test_a_run_on_another_engine_gets_that_engines_margin(tmp_path):
    """``swarm run FILE --engine pybullet`` of a kinematic file: the margin and pack_flood's spacing are
    chosen for PyBullet, unless the file gives them."""
    import argparse

    import yaml

    from swarm.cli import _load_with_overrides

    flags = argparse.Namespace(engine="pybullet", controller=None, model=None, duration=None)
    path = tmp_path / "s.yaml"
    data = {**SCENARIO, "controller": {"kind": "pack_flood"}, "safety": {"kind": "barrier"}}
    path.write_text(yaml.safe_dump(data))
    scenario = _load_with_overrides(path, flags)
    assert scenario.sim.engine == "pybullet" and scenario.safety is not None
    assert scenario.safety.margin_m == pytest.approx(0.05)
    assert scenario.controller.spacing_m == pytest.approx(2 * (0.12 + 0.05) + 0.05 + 0.02)
    path.write_text(yaml.safe_dump({**data, "safety": {"kind": "barrier", "margin_m": 0.03}}))
    scenario = _load_with_overrides(path, flags)
    assert scenario.safety is not None and scenario.safety.margin_m == pytest.approx(0.03)
    assert scenario.controller.spacing_m is None
