"""The safety QP (swarm.core.safety): its exact solution against a brute-force grid, the feasibility of
what it returns, and the barriers staying non-negative over random rollouts."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from swarm.core import safety
from swarm.core.robot import RobotParams

ROBOT = RobotParams()
PARAMS = safety.SafetyParams()


def _grid_optimum(u_ref, normals, bounds, half_width, step):
    """The feasible grid point nearest u_ref (None when none is feasible), by looking at every one."""
    axis = np.arange(-half_width, half_width + step / 2, step)
    gx, gy = np.meshgrid(axis, axis, indexing="ij")
    points = np.stack([gx.ravel(), gy.ravel()], axis=1)
    ok = np.all(points @ normals.T <= bounds + 1e-12, axis=1)
    if not ok.any():
        return None
    points = points[ok]
    cost = np.sum((points - u_ref) ** 2, axis=1)
    return points[np.argmin(cost)]


def _kkt_holds(u, u_ref, normals, bounds) -> bool:
    """``u`` is the minimiser of |u - u_ref|^2 over the polygon iff ``u_ref - u = sum_k lambda_k a_k``
    with ``lambda >= 0`` over the constraints active at ``u`` (checked over every subset, by lstsq)."""
    from itertools import combinations

    slack = normals @ u - bounds
    active = np.nonzero(slack > -1e-7 * np.linalg.norm(normals, axis=1))[0]
    gradient = u_ref - u
    if np.linalg.norm(gradient) < 1e-9:
        return True
    for size in (1, 2):
        for subset in combinations(active, size):
            rows = normals[list(subset)]
            weights, *_ = np.linalg.lstsq(rows.T, gradient, rcond=None)
            if np.all(weights >= -1e-9) and np.linalg.norm(rows.T @ weights - gradient) < 1e-7:
                return True
    return False


def _case(seed: int, count: int):
    rng = np.random.default_rng(seed)
    normals = rng.normal(size=(count, 2))
    bounds = rng.normal(0.3, 0.5, size=count)
    u_ref = rng.normal(0, 1.0, size=2)
    return u_ref, normals, bounds


@settings(max_examples=150)
@given(seed=st.integers(0, 2**32 - 1), count=st.integers(1, 7))
@example(seed=10299, count=3)  # a thin wedge at the optimum: the grid's nearest feasible point is far
def test_exact_solution_matches_a_brute_force_grid(seed, count):
    u_ref, normals, bounds = _case(seed, count)
    box_normals = np.array([[1.0, 0], [-1, 0], [0, 1], [0, -1]])  # keep the problem bounded: |u| <= 2
    normals = np.concatenate([normals, box_normals])
    bounds = np.concatenate([bounds, np.full(4, 2.0)])
    u, status = safety.solve_qp(u_ref, normals, bounds)
    step = 0.01
    best = _grid_optimum(u_ref, normals, bounds, 2.0, step)
    if status == safety.INFEASIBLE:
        assert best is None, f"the grid found a feasible point {best}"
        np.testing.assert_array_equal(u, 0.0)
        return
    scale = np.linalg.norm(normals, axis=1)
    assert np.all(normals @ u - bounds <= 1e-8 * scale), "the answer breaks a constraint"
    cost = np.sum((u - u_ref) ** 2)
    if best is not None:  # no feasible point on the grid: a sliver thinner than a grid step
        best_cost = np.sum((best - u_ref) ** 2)
        assert cost <= best_cost + 1e-12, (cost, best_cost)
    assert _kkt_holds(u, u_ref, normals, bounds), "not a KKT point: not the minimiser"
    if status == safety.UNCHANGED:
        np.testing.assert_array_equal(u, u_ref)


def test_infeasible_brakes_and_is_flagged():
    # u_x >= 1 and u_x <= -1 together: nothing is feasible
    u, status = safety.solve_qp(
        np.array([0.3, 0.1]), np.array([[-1.0, 0.0], [1.0, 0.0]]), np.array([-1.0, -1.0])
    )
    assert status == safety.INFEASIBLE
    np.testing.assert_array_equal(u, 0.0)
    # a zero row with a negative bound is infeasible, with a non-negative one it is dropped
    assert safety.solve_qp(np.ones(2), np.zeros((1, 2)), np.array([-1.0]))[1] == safety.INFEASIBLE
    u, status = safety.solve_qp(np.ones(2), np.zeros((1, 2)), np.array([0.0]))
    assert status == safety.UNCHANGED and np.all(u == 1.0)


def test_nothing_to_avoid_changes_nothing_but_saturation():
    u = np.array([2.0, 0.3])
    out, status = safety.filter_command(u, np.zeros((0, 2)), np.zeros((0, 2)), ROBOT, PARAMS)
    assert status == safety.UNCHANGED
    np.testing.assert_allclose(out, u * ROBOT.v_max_mps / (2.0 + 2 * 0.3))
    far = np.array([[5.0, 0.0]])  # a body far ahead: its barrier is inactive
    out2, status2 = safety.filter_command(u, far, np.zeros((0, 2)), ROBOT, PARAMS)
    assert status2 == safety.UNCHANGED
    np.testing.assert_array_equal(out, out2)


def test_head_on_body_stops_the_approach():
    distance = safety.body_distance_m(ROBOT, PARAMS)
    ahead = np.array([[distance, 0.0]])  # exactly at the barrier: h = 0, may not approach at all
    out, status = safety.filter_command(np.array([0.5, 0.0]), ahead, np.zeros((0, 2)), ROBOT, PARAMS)
    assert status == safety.CHANGED
    assert out[0] <= 1e-9


def _single_integrator_rollout(seed: int, count: int, obstacles: int, steps: int, dt: float):
    """Robots as points moving by exactly u dt (heading 0: the robot frame is the world frame), every one
    filtering toward a common goal; returns the smallest barrier value met (bodies, obstacles)."""
    rng = np.random.default_rng(seed)
    distance = safety.body_distance_m(ROBOT, PARAMS)
    rho = safety.obstacle_distance_m(ROBOT, PARAMS)
    points = []
    while len(points) < count:  # random starts with every barrier non-negative
        p = rng.uniform(-2.0, 2.0, 2)
        if all(np.linalg.norm(p - q) >= distance for q in points):
            points.append(p)
    points = np.array(points)
    centres = rng.uniform(-1.5, 1.5, (obstacles, 2))
    radii = rng.uniform(0.05, 0.3, obstacles)
    keep = [
        all(np.linalg.norm(p - c) - r >= rho for p in points) for c, r in zip(centres, radii, strict=True)
    ]
    centres, radii = centres[keep], radii[keep]
    goal = rng.uniform(-0.5, 0.5, 2)
    smallest = np.inf
    for _ in range(steps):
        commands = np.empty_like(points)
        for i in range(count):
            bodies = np.delete(points, i, axis=0) - points[i]
            towards = centres - points[i]
            gap = np.linalg.norm(towards, axis=1, keepdims=True)
            surface = towards * (1.0 - radii[:, None] / gap)  # nearest surface point, relative
            commands[i], _ = safety.filter_command(2.0 * (goal - points[i]), bodies, surface, ROBOT, PARAMS)
        points = points + dt * commands
        pair = points[:, None] - points[None]
        h = np.sum(pair**2, axis=-1) - distance**2
        np.fill_diagonal(h, np.inf)
        gap = np.linalg.norm(points[:, None] - centres[None], axis=-1) - radii[None]
        smallest = min(smallest, h.min(), (gap**2 - rho**2).min(initial=np.inf))
    return smallest


@settings(max_examples=25)
@given(seed=st.integers(0, 2**32 - 1), count=st.integers(2, 9), obstacles=st.integers(0, 3))
def test_barriers_stay_non_negative_over_random_rollouts(seed, count, obstacles):
    dt = 1.0 / PARAMS.gain_per_s  # gamma dt = 1: the edge of the discrete-time argument
    assert safety.gain_is_exact(PARAMS, dt)
    assert _single_integrator_rollout(seed, count, obstacles, 40, dt) >= -1e-9


def test_readings_to_points():
    # a body 1 m straight ahead, facing back at us: its controlled point is l nearer, ours l ahead
    point = safety.readings_to_points(np.array([1.0]), np.array([0.0]), np.array([np.pi]), 0.05)
    np.testing.assert_allclose(point, [[1.0 - 0.05 - 0.05, 0.0]], atol=1e-15)
    obstacle = safety.readings_to_points(np.array([1.0]), np.array([np.pi / 2]), None, 0.05)
    np.testing.assert_allclose(obstacle, [[-0.05, 1.0]], atol=1e-15)


@pytest.mark.parametrize("dt,exact", [(0.05, True), (0.2, False)])
def test_gain_is_exact(dt, exact):
    assert safety.gain_is_exact(PARAMS, dt) is exact
