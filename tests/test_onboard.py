"""Tests for swarm.sim.onboard: the per-robot controller an agent runs computes what the batched
controller of the kinematic engine computes for that robot, and the agent's imports stay light."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from swarm.core import graphs
from swarm.core.robot import RobotParams, controlled_point, point_velocity_to_wheels
from swarm.sim.controller_kinds import robot_controller
from swarm.sim.controllers import LocalConsensus
from swarm.sim.links import Links
from swarm.sim.onboard import OnboardLocalConsensus, wheels_one


@pytest.mark.parametrize("adjacency", [graphs.cycle(6), graphs.line(5), graphs.THESIS_WEAK_GRAPH * 0.5])
def test_onboard_local_consensus_matches_the_batched_controller(adjacency):
    rng = np.random.default_rng(4)
    robot = RobotParams()
    count = len(adjacency)
    poses = np.column_stack([rng.uniform(-2, 2, (count, 2)), rng.uniform(-np.pi, np.pi, count)])
    last_points = controlled_point(poses + rng.normal(0, 0.05, poses.shape), robot.offset_m)
    batched = LocalConsensus(robot, gain=0.7)
    u_batched, out_batched = batched.act(
        poses[None],
        controlled_point(poses, robot.offset_m)[None],
        last_points[None],
        Links.from_dense(adjacency[None]),
    )
    onboard = OnboardLocalConsensus(robot, gain=0.7)
    for i in range(count):
        heard = np.flatnonzero(adjacency[i])
        u, message = onboard.act_one(poses[i], last_points[heard], adjacency[i, heard])
        np.testing.assert_allclose(u, u_batched[0, i], rtol=0, atol=1e-12)
        np.testing.assert_allclose(message, out_batched[0, i], rtol=0, atol=1e-12)


def test_wheels_one_is_point_velocity_to_wheels_in_plain_floats():
    rng = np.random.default_rng(2)
    robot = RobotParams(v_max_mps=0.3)
    for _ in range(2000):
        u_world, theta = rng.normal(0, 1, 2) * rng.choice([1e-6, 0.1, 10.0]), rng.uniform(-4, 4)
        expected = point_velocity_to_wheels(u_world, theta, robot)
        np.testing.assert_allclose(wheels_one(u_world, theta, robot), expected, rtol=1e-14, atol=1e-15)
    assert wheels_one(np.zeros(2), 0.3, robot) == (0.0, 0.0)


def test_a_robot_that_heard_nobody_holds_still():
    u, message = OnboardLocalConsensus(RobotParams()).act_one(np.array([1.0, 2.0, 0.0]), np.zeros((0, 2)))
    assert np.all(u == 0.0)
    np.testing.assert_allclose(message, [1.05, 2.0])


def test_controller_factory_refuses_what_does_not_run_on_board():
    robot = RobotParams()
    assert isinstance(robot_controller("local_consensus", robot, 2.0), OnboardLocalConsensus)
    with pytest.raises(ValueError, match="central process"):
        robot_controller("centralized", robot)
    with pytest.raises(ValueError, match="needs a policy file"):
        robot_controller("gnn", robot)
    with pytest.raises(ValueError, match="unknown controller"):
        robot_controller("telepathy", robot)


def test_agent_modules_import_no_torch_pybullet_or_numba():
    code = (
        "import sys, robot_agent.agent, robot_agent.central, robot_agent.__main__, swarm.sim.policy;"
        "print(sorted(m for m in ('torch', 'pybullet', 'numba') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"
