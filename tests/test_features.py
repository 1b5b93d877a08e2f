"""swarm.sim.features: the thesis's M and Phi (eq. 3.4-3.7, fixed) and their K-hop generalisation."""

from __future__ import annotations

import numpy as np
import pytest

from swarm.core import graphs
from swarm.core.robot import RobotParams, controlled_point, local_point_velocity_to_wheels, world_to_local
from swarm.sim.features import (
    FeatureSpec,
    batched_features,
    messages,
    robot_features,
    saturate_local_velocity,
)
from swarm.sim.kinematic import KinematicSim
from swarm.sim.links import Links
from swarm.sim.policy import FeatureController

ROBOT = RobotParams()


def _random_state(rng, batch, count, spec):
    poses = np.concatenate(
        [rng.uniform(-2, 2, (batch, count, 2)), rng.uniform(-np.pi, np.pi, (batch, count, 1))], -1
    )
    points = controlled_point(poses, ROBOT.offset_m)
    inbox = rng.normal(size=(batch, count, spec.message_dim))
    adjacency = np.stack([graphs.erdos_renyi(count, 0.5, int(s)) for s in rng.integers(0, 2**31, batch)])
    return poses, points, inbox, Links.from_dense(adjacency)


@pytest.mark.parametrize("normaliser", ["degree", "n_minus_1"])
@pytest.mark.parametrize("phi_source", ["m", "output"])
def test_batched_features_match_the_formulas(normaliser, phi_source):
    """M_i = (1/c_i) sum_j A_ij (p_j - p_i), Phi_i = (1/c_i) sum_j A_ij m_j, in R(theta_i)^T."""
    spec = FeatureSpec(2, phi_source, normaliser)
    rng = np.random.default_rng(1)
    poses, points, inbox, links = _random_state(rng, 3, 7, spec)
    features, _ = batched_features(poses, points, inbox, links, spec)
    adjacency = links.dense
    for b in range(3):
        for i in range(7):
            heard = np.flatnonzero(adjacency[b, i])
            c = len(heard) if normaliser == "degree" else 6
            m_world = sum((inbox[b, j, :2] - points[b, i] for j in heard), np.zeros(2)) / max(c, 1)
            phi_world = sum((inbox[b, j, 2:] for j in heard), np.zeros(2)) / max(c, 1)
            if len(heard) == 0:
                m_world = phi_world = np.zeros(2)
            theta = poses[b, i, 2]
            np.testing.assert_allclose(features[b, i, 0], world_to_local(m_world, theta), atol=1e-12)
            np.testing.assert_allclose(features[b, i, 1], world_to_local(phi_world, theta), atol=1e-12)


@pytest.mark.parametrize("spec", [FeatureSpec(1), FeatureSpec(4), FeatureSpec(2, "output", "n_minus_1")])
def test_per_robot_features_equal_batched(spec):
    rng = np.random.default_rng(2)
    poses, points, inbox, links = _random_state(rng, 2, 6, spec)
    features, phi = batched_features(poses, points, inbox, links, spec)
    for b in range(2):
        for i in range(6):
            heard = np.flatnonzero(links.dense[b, i])
            one, one_phi = robot_features(poses[b, i], points[b, i], inbox[b, heard], spec, robot_count=6)
            np.testing.assert_allclose(one, features[b, i], atol=1e-12)
            np.testing.assert_allclose(one_phi, phi[b, i], atol=1e-12)


def test_n_minus_1_needs_the_swarm_size():
    with pytest.raises(ValueError, match="robot_count"):
        robot_features(np.zeros(3), np.zeros(2), np.zeros((1, 4)), FeatureSpec(2, normaliser="n_minus_1"))


def test_bad_options_are_refused():
    with pytest.raises(ValueError):
        FeatureSpec(0)
    with pytest.raises(ValueError, match="hops = 2"):
        FeatureSpec(3, "output")
    with pytest.raises(ValueError):
        FeatureSpec(2, normaliser="n")


def test_saturation_is_the_robots_wheel_saturation():
    """Wheels of the saturated velocity = saturated wheels of the wished velocity; direction kept."""
    rng = np.random.default_rng(3)
    u_local = rng.normal(scale=1.5, size=(500, 2))
    saturated = saturate_local_velocity(u_local, ROBOT)
    np.testing.assert_allclose(
        local_point_velocity_to_wheels(saturated, ROBOT),
        local_point_velocity_to_wheels(u_local, ROBOT),
        atol=1e-12,
    )
    cross = u_local[:, 0] * saturated[:, 1] - u_local[:, 1] * saturated[:, 0]
    np.testing.assert_allclose(cross, 0.0, atol=1e-12)
    np.testing.assert_allclose(saturate_local_velocity(saturated, ROBOT), saturated, atol=1e-12)


class _Recorder(FeatureController):
    """Moves every robot with a fixed world velocity and records what it computes each tick."""

    def __init__(self, spec, velocities):
        super().__init__(spec, ROBOT)
        self.velocities = velocities
        self.seen = []

    def act(self, poses, points, inbox, heard):
        _, phi = batched_features(poses, points, inbox, heard, self.spec)
        self.seen.append((points.copy(), phi))
        return self.velocities, messages(points, phi, self.velocities, self.spec)


def test_hop_k_information_is_k_ticks_old():
    """In KinematicSim: M_i(k) uses neighbours' points of tick k-1, Phi_h(k) their Phi_(h-1) of tick k-1,
    and at tick 0 nobody has heard anybody (docs/design.md, "Information timing")."""
    spec = FeatureSpec(3)
    rng = np.random.default_rng(4)
    count = 5
    adjacency = graphs.line(count)
    poses = np.concatenate([rng.uniform(-2, 2, (1, count, 2)), rng.uniform(-3, 3, (1, count, 1))], -1)
    recorder = _Recorder(spec, rng.uniform(-0.2, 0.2, (1, count, 2)))
    sim = KinematicSim(ROBOT, recorder, 0.05, poses, adjacency)
    sim.rollout(6)
    assert np.all(recorder.seen[0][1] == 0.0)
    for k in range(1, 6):
        points_now, phi_now = recorder.seen[k]
        points_before, phi_before = recorder.seen[k - 1]
        for i in range(count):
            heard = np.flatnonzero(adjacency[i])
            np.testing.assert_allclose(
                phi_now[0, i, 0], points_before[0, heard].mean(0) - points_now[0, i], atol=1e-12
            )
            for h in range(1, 3):
                np.testing.assert_allclose(phi_now[0, i, h], phi_before[0, heard, h - 1].mean(0), atol=1e-12)
