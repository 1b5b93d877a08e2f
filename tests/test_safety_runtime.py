"""The safety filter in the PyBullet runtime: each robot's sensor reading on its own key, the filter in
its agent (the kinematic engine's arithmetic), static obstacles as PyBullet bodies, and contacts counted
from PyBullet's contact points."""

from __future__ import annotations

import json

import numpy as np
import pytest

from sim_server.physics import PhysicsWorld
from swarm.core.obstacles import Capsules, ObstacleSpec
from swarm.core.robot import RobotParams, controlled_point
from swarm.core.safety import SafetyParams, filter_reading
from swarm.runtime import wire
from swarm.sim.safety_filter import SafetyFilter
from swarm.sim.sensing import robot_reading, sense

ROBOT = RobotParams()


def test_a_sensing_reading_travels_and_a_malformed_one_is_refused():
    bodies = np.array([[0.5, -0.3, 1.2], [1.4, 3.1, -3.0]])
    obstacles = np.array([[0.9, 0.1]])
    decoded = wire.decode_sensing(wire.encode_sensing(17, bodies, obstacles))
    assert decoded is not None and decoded.tick == 17
    np.testing.assert_array_equal(decoded.bodies, bodies)
    np.testing.assert_array_equal(decoded.obstacles, obstacles)
    empty = wire.decode_sensing(wire.encode_sensing(0, np.zeros((0, 3)), np.zeros((0, 2))))
    assert empty is not None and empty.bodies.shape == (0, 3) and empty.obstacles.shape == (0, 2)
    for bad_bodies, bad_obstacles in (
        (np.array([[np.nan, 0.0, 0.0]]), obstacles),
        (np.array([[-0.1, 0.0, 0.0]]), obstacles),  # a negative range
        (bodies, np.array([[0.5, 1e3]])),  # a bearing beyond any angle
        (bodies[:, :2], obstacles),  # rows of two where three belong
    ):
        assert wire.decode_sensing(wire.encode_sensing(3, bad_bodies, bad_obstacles)) is None
    assert wire.decode_sensing(b"\x00garbage") is None
    assert wire.decode_sensing(wire.encode_pose(1, 0.0, (0.0, 0.0, 0.0))) is None


@pytest.mark.parametrize("case", ["far-from-origin", "ties-on-a-grid", "tiny-swarm", "crowd-with-walls"])
def test_each_agents_filter_equals_the_kinematic_engines(case):
    """The twin: the sim server's per-robot reading (``robot_reading``) filtered by the agent's numpy
    ``filter_reading`` gives, robot by robot and bit for bit, the batched numba filter of
    ``KinematicSim``, on commands that push the robots into each other and the obstacles."""
    rng = np.random.default_rng(len(case))
    obstacles = Capsules()
    if case == "far-from-origin":
        poses = np.c_[1e4 + rng.uniform(0, 1.2, (6, 2)), rng.uniform(-np.pi, np.pi, 6)]
    elif case == "ties-on-a-grid":
        grid = np.array([(0.45 * i, 0.45 * j) for i in range(3) for j in range(3)])
        poses = np.c_[grid, np.zeros(9)]
    elif case == "tiny-swarm":
        poses = np.array([[0.0, 0.0, 0.0], [0.5, 0.0, np.pi]])
    else:
        poses = np.c_[rng.uniform(-1.5, 1.5, (12, 2)), rng.uniform(-np.pi, np.pi, 12)]
        obstacles = Capsules(
            [
                ObstacleSpec(kind="disc", centre=(0.2, 0.1), radius_m=0.25),
                ObstacleSpec(kind="wall", start=(-2.0, -1.0), end=(2.0, -1.2), thickness_m=0.1),
            ]
        )
    params = SafetyParams()
    u_world = -0.8 * (poses[:, :2] - poses[:, :2].mean(axis=0))  # everyone at the centre
    u_world += rng.normal(0.0, 0.2, u_world.shape)
    batched = SafetyFilter(ROBOT, params, obstacles)
    points = controlled_point(poses[None], ROBOT.offset_m)
    expected = batched.apply(poses[None], points, u_world[None])[0]
    assert batched.counts["interventions"] > 0  # the case exercises the barriers
    readings = sense(poses[None], points, obstacles, params.sensing_radius_m)
    for i in range(len(poses)):
        bodies, walls = robot_reading(readings, i)
        sent = wire.decode_sensing(wire.encode_sensing(0, bodies, walls))  # what crosses the wire
        assert sent is not None
        safe, status = filter_reading(u_world[i], poses[i, 2], sent.bodies, sent.obstacles, ROBOT, params)
        assert status == batched.last_status[0, i]
        if status == 2:  # infeasible: the engine brakes; the agent sends zero wheel speeds
            continue
        np.testing.assert_array_equal(safe, expected[i])


def test_pybullet_counts_the_contacts_of_a_scripted_head_on_collision():
    """Two robots 1.2 m apart driven straight at each other at 0.3 m/s, no filter: their bumpers (0.12 m
    radius) meet after (1.2 - 0.24) / 0.6 = 1.6 s. Checked against the geometry of the poses at each
    tick: no contact while the bumpers are 1 cm apart or more, a contact at every tick that ends with
    them pressed together (within 3 mm: pushing, the bodies pitch and their rims touch first). A third
    robot drives into a wall and touches it only; two more rest 8 mm apart and never count as touching."""
    wall = ObstacleSpec(kind="wall", start=(-1.0, -1.0), end=(1.0, -1.0), thickness_m=0.1)
    side = 2 * ROBOT.body_radius_m + 0.008  # robots 3 and 4 rest side by side, bumpers 8 mm apart
    poses = np.array(
        [
            [-0.6, 0.0, 0.0],
            [0.6, 0.0, np.pi],
            [0.0, -0.6, -np.pi / 2],
            [2.0, 1.0, 0.0],
            [2.0, 1.0 + side, 0.0],
        ]
    )
    wheels = np.array([[0.3, 0.3]] * 3 + [[0.0, 0.0]] * 2)
    gaps, walls, robot_pairs, wall_pairs = [], [], [], []
    with PhysicsWorld(ROBOT, poses, obstacles=(wall.capsule(),), count_contacts=True) as world:
        for _ in range(80):
            before = world.poses()
            world.set_wheel_speeds(wheels)
            world.step(0.05)
            after = world.poses()
            robots, touching = world.take_contacts()
            robot_pairs.append(robots)
            wall_pairs.append(touching)
            gap = [np.linalg.norm(p[0, :2] - p[1, :2]) - 2 * ROBOT.body_radius_m for p in (before, after)]
            gaps.append(gap)
            walls.append([p[2, 1] + 0.95 - ROBOT.body_radius_m for p in (before, after)])  # surface at -0.95
    gaps_m, walls_m = np.array(gaps), np.array(walls)
    apart = np.all(gaps_m >= 0.01, axis=1)
    pressed = gaps_m[:, 1] <= 0.003  # pushing, the bodies pitch a little: their rims touch first
    assert apart.sum() >= 25 and pressed.sum() >= 25  # both phases happen
    assert all(not robot_pairs[k] for k in np.flatnonzero(apart))
    assert all(robot_pairs[k] == {(0, 1)} for k in np.flatnonzero(pressed))
    assert not any((3, 4) in pairs for pairs in robot_pairs)  # near is not touching
    wall_apart = np.all(walls_m >= 0.01, axis=1)
    wall_pressed = walls_m[:, 1] <= 0.003
    assert wall_apart.sum() >= 10 and wall_pressed.sum() >= 10
    assert all(not wall_pairs[k] for k in np.flatnonzero(wall_apart))
    assert all(wall_pairs[k] == {(2, 0)} for k in np.flatnonzero(wall_pressed))
    assert all(pair[0] == 2 for pairs in wall_pairs for pair in pairs)


HEAD_ON = {
    "name": "head-on",
    "robots": {"count": 3, "init": {"poses": [[-0.7, 0.0, 0.0], [0.7, 0.0, 3.14159], [0.0, 1.2, -1.5708]]}},
    "topology": {"kind": "complete"},
    "controller": {"kind": "mec_flood"},
    "sim": {"engine": "pybullet", "duration_s": 4.0, "mode": "lockstep"},
    "obstacles": [{"kind": "disc", "centre": [0.0, 0.6], "radius_m": 0.15}],
    "success": {"metric": "max_pairwise", "threshold": 1.0},
}


@pytest.mark.runtime
def test_the_pybullet_runtime_filters_in_each_agent_and_counts_contacts(tmp_path):
    """Three robots gathered by mec_flood, two head-on and one across a disc obstacle. Without the filter
    PyBullet reports bumper contacts (and the trajectory shows the bumpers pressed together); with it, 0
    contact ticks and a positive clearance, from each agent's own reading on its own key (the agents'
    records: subscriptions and readings, none missing)."""
    import yaml

    from swarm.cli import main

    runs = {}
    for name, extra in (("plain", {}), ("filtered", {"safety": {"kind": "barrier"}})):
        path = tmp_path / f"{name}.yaml"
        path.write_text(yaml.safe_dump({**HEAD_ON, **extra}))
        assert main(["run", str(path), "--out", str(tmp_path / name), "--quiet"]) == 0
        runs[name] = json.loads((tmp_path / name / "metrics.json").read_text())
    plain, filtered = runs["plain"], runs["filtered"]
    assert plain["contacts"]["robot_robot"] > 0 and plain["min_clearance_m"] < 0.002
    assert plain["safety_filter"] is None
    assert filtered["contacts"] == {"robot_robot": 0, "robot_obstacle": 0, "ticks": 0}
    assert filtered["min_clearance_m"] > 0
    counts = filtered["safety_filter"]
    assert counts["interventions"] > 0 and counts["infeasible"] == counts["missing"] == 0
    assert counts["unauthenticated"] == counts["invalid"] == 0
    keys = wire.Keys(json.loads((tmp_path / "filtered" / "logs" / "agent_0.json").read_text())["run"])
    for i in range(3):
        record = json.loads((tmp_path / "filtered" / "logs" / f"agent_{i}.json").read_text())
        assert keys.sense(i) in record["subscriptions"]
        assert not any(keys.sense(j) in record["subscriptions"] for j in range(3) if j != i)
        assert record["safety_filter"]["received"] == record["ticks"]


@pytest.mark.runtime
def test_a_central_controller_filters_each_robot_with_its_own_reading(tmp_path):
    """centralized_mec (one process for every robot) with the filter: each robot's command filtered
    with that robot's reading, heard on robot/*/sense; no contact, where without it the two head-on
    robots press together (the plain run of the test above, same start)."""
    import yaml

    from swarm.cli import main

    path = tmp_path / "central.yaml"
    path.write_text(
        yaml.safe_dump({**HEAD_ON, "controller": {"kind": "centralized_mec"}, "safety": {"kind": "barrier"}})
    )
    assert main(["run", str(path), "--out", str(tmp_path / "out"), "--quiet"]) == 0
    metrics = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert metrics["contacts"] == {"robot_robot": 0, "robot_obstacle": 0, "ticks": 0}
    assert metrics["min_clearance_m"] > 0
    counts = metrics["safety_filter"]
    assert counts["interventions"] > 0 and counts["missing"] == counts["infeasible"] == 0
    record = json.loads((tmp_path / "out" / "logs" / "central.json").read_text())
    assert record["safety_filter"]["received"] == 3 * record["ticks"]
