"""The numba safety filter (swarm.sim.safety_kernel) equals the numpy form (swarm.core.safety) robot by
robot, on adversarial inputs: bodies far away and very near, exact ties, a single robot, no
constraints, many constraints, overlapping bodies (infeasible), zero rows."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from swarm.core import safety
from swarm.core.robot import RobotParams
from swarm.sim import kernels, safety_kernel

ROBOT = RobotParams()
PARAMS = safety.SafetyParams()


def _numpy_rows(u, bodies, body_seen, obstacles, obstacle_seen, robot=ROBOT, params=PARAMS):
    out = np.empty_like(u)
    status = np.empty(len(u), dtype=np.int8)
    for r in range(len(u)):
        out[r], status[r] = safety.filter_command(
            u[r], bodies[r][body_seen[r]], obstacles[r][obstacle_seen[r]], robot, params
        )
    return out, status


def _assert_twins(u, bodies, body_seen, obstacles, obstacle_seen, robot=ROBOT, params=PARAMS):
    expected, expected_status = _numpy_rows(u, bodies, body_seen, obstacles, obstacle_seen, robot, params)
    got, status = safety_kernel.filter_local(u, bodies, body_seen, obstacles, obstacle_seen, robot, params)
    np.testing.assert_array_equal(status, expected_status)
    np.testing.assert_array_equal(got, expected)  # same arithmetic in the same order: the same bits


def _random_rows(rng, rows, bodies, obstacles, scale):
    u = rng.normal(0, 0.6, (rows, 2))
    b = rng.normal(0, scale, (rows, bodies, 2))
    o = rng.normal(0, scale, (rows, obstacles, 2))
    return u, b, rng.random((rows, bodies)) < 0.7, o, rng.random((rows, obstacles)) < 0.7


@settings(max_examples=60)
@given(
    seed=st.integers(0, 2**32 - 1),
    rows=st.integers(1, 6),
    bodies=st.integers(0, 12),
    obstacles=st.integers(0, 4),
    scale=st.sampled_from([0.2, 0.4, 1.0, 1e3]),
)
def test_kernel_equals_numpy_on_random_rows(seed, rows, bodies, obstacles, scale):
    _assert_twins(*_random_rows(np.random.default_rng(seed), rows, bodies, obstacles, scale))


def test_kernel_equals_numpy_on_adversarial_rows():
    distance = safety.body_distance_m(ROBOT, PARAMS)
    cases = []
    # ties: two bodies mirrored about the command's axis, at and inside the barrier
    for gap in (distance, 0.9 * distance, 1.1 * distance):
        cases.append(([0.5, 0.0], [[gap, 0.2], [gap, -0.2]], [[gap, 0.0]]))
    # a body exactly ahead at h = 0, a body on top of us (zero row), overlap (h < 0) from every side
    cases.append(([0.5, 0.0], [[distance, 0.0]], []))
    cases.append(([0.5, 0.1], [[0.0, 0.0]], []))
    ring = [
        [0.5 * distance * np.cos(a), 0.5 * distance * np.sin(a)] for a in np.linspace(0, 2 * np.pi, 9)[:-1]
    ]
    cases.append(([0.3, 0.0], ring, []))
    # far: huge relative positions, and tiny ones
    cases.append(([0.5, -0.2], [[1e6, 3.0], [-1e6, 1e6]], [[4e5, -1.0]]))
    cases.append(([1e-12, 1e-12], [[distance + 1e-12, 0.0]], []))
    # many constraints: 60 bodies on a circle just outside the barrier
    many = [[1.001 * distance * np.cos(a), 1.001 * distance * np.sin(a)] for a in np.linspace(0, 6.2, 60)]
    cases.append(([0.4, 0.4], many, [[0.5, 0.0], [0.0, -0.5]]))
    width_b = max(len(c[1]) for c in cases)
    width_o = max(len(c[2]) for c in cases)
    u = np.array([c[0] for c in cases], dtype=float)
    bodies = np.zeros((len(cases), width_b, 2))
    body_seen = np.zeros((len(cases), width_b), dtype=bool)
    obstacles = np.zeros((len(cases), width_o, 2))
    obstacle_seen = np.zeros((len(cases), width_o), dtype=bool)
    for r, (_, b, o) in enumerate(cases):
        bodies[r, : len(b)], body_seen[r, : len(b)] = b, True
        obstacles[r, : len(o)], obstacle_seen[r, : len(o)] = (o if o else np.zeros((0, 2))), True
    _assert_twins(u, bodies, body_seen, obstacles, obstacle_seen)
    _, status = safety_kernel.filter_local(u, bodies, body_seen, obstacles, obstacle_seen, ROBOT, PARAMS)
    assert {int(s) for s in status} == {safety.UNCHANGED, safety.CHANGED, safety.INFEASIBLE}


@pytest.mark.parametrize("robot", [RobotParams(), RobotParams(half_axle_m=0.3, offset_m=0.02, v_max_mps=2.0)])
def test_kernel_equals_numpy_other_robots_and_threads(robot, monkeypatch):
    rng = np.random.default_rng(7)
    params = safety.SafetyParams(gain_per_s=5.0, margin_m=0.0)
    rows = _random_rows(rng, 300, 8, 3, 0.5)
    _assert_twins(*rows, robot=robot, params=params)
    monkeypatch.setattr(kernels, "PARALLEL_MIN_ROBOTS", 0)  # the threaded variant, same bits
    _assert_twins(*rows, robot=robot, params=params)
