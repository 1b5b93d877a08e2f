"""Tests for swarm.core.robot: the differential-drive model of thesis section 2.1 (eq. 2.1-2.4) and the
robot frame of eq. 3.2-3.3 (with the transpose the thesis forgot).

Hand-computed cases write their arithmetic in comments; properties use hypothesis.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from swarm.core.robot import (
    RobotParams,
    controlled_point,
    integrate_unicycle,
    local_point_velocity_to_unicycle,
    local_point_velocity_to_wheels,
    point_velocity_to_unicycle,
    point_velocity_to_wheels,
    rotate,
    saturate_wheels,
    unicycle_to_wheels,
    wheel_angular_speeds,
    wheels_to_unicycle,
    world_to_local,
    wrap_angle,
)

TOL = 1e-12
finite = st.floats(-10.0, 10.0, allow_nan=False, allow_infinity=False)
angles = st.floats(-math.pi, math.pi, allow_nan=False)


def test_defaults_are_bubblerob_like_and_aliases_work():
    params = RobotParams()
    assert (params.wheel_radius_m, params.half_axle_m, params.offset_m, params.v_max_mps) == (
        0.04,
        0.1,
        0.05,
        0.5,
    )
    # scenario files use the short names
    short = RobotParams.model_validate({"v_max": 0.3, "half_axle": 0.2, "l": 0.1, "wheel_radius": 0.05})
    assert (short.v_max_mps, short.half_axle_m, short.offset_m, short.wheel_radius_m) == (0.3, 0.2, 0.1, 0.05)


# ---------------------------------------------------------------- wheel mapping (eq. 2.4)


def test_unicycle_to_wheels_by_hand():
    # d = 0.1 m, v = 0.3 m/s, w = 1 rad/s: vL = 0.3 - 0.1 * 1 = 0.2, vR = 0.3 + 0.1 * 1 = 0.4
    np.testing.assert_allclose(unicycle_to_wheels(np.array(0.3), np.array(1.0), 0.1), [0.2, 0.4], atol=TOL)
    # pure rotation v = 0, w = -2, d = 0.25: vL = 0 + 0.5 = 0.5, vR = -0.5
    np.testing.assert_allclose(unicycle_to_wheels(np.array(0.0), np.array(-2.0), 0.25), [0.5, -0.5], atol=TOL)


def test_wheels_to_unicycle_by_hand():
    # eq. 2.4: v = (vL + vR) / 2 = (0.2 + 0.4) / 2 = 0.3; w = (vR - vL) / (2 d) = 0.2 / 0.2 = 1
    v, w = wheels_to_unicycle(np.array([0.2, 0.4]), 0.1)
    assert v == pytest.approx(0.3, abs=TOL)
    assert w == pytest.approx(1.0, abs=TOL)
    # the thesis's matrix D = [[1/2, 1/2], [-1/(2d), 1/(2d)]] applied to (vL, vR) = (-0.1, 0.5), d = 0.2:
    # v = 0.2, w = (0.5 + 0.1) / 0.4 = 1.5
    d = 0.2
    matrix = np.array([[0.5, 0.5], [-1 / (2 * d), 1 / (2 * d)]])
    expected = matrix @ np.array([-0.1, 0.5])
    np.testing.assert_allclose(wheels_to_unicycle(np.array([-0.1, 0.5]), d), expected, atol=TOL)
    np.testing.assert_allclose(expected, [0.2, 1.5], atol=TOL)


def test_wheel_angular_speed_is_linear_over_radius():
    # 0.2 m/s on a 0.04 m wheel: 0.2 / 0.04 = 5 rad/s; -0.5 m/s: -12.5 rad/s
    np.testing.assert_allclose(wheel_angular_speeds(np.array([0.2, -0.5]), 0.04), [5.0, -12.5], atol=TOL)


# ---------------------------------------------------------------- point offset (eq. 2.2-2.3)


@pytest.mark.parametrize(
    ("theta", "u", "expected_v", "expected_w"),
    [
        # theta = 0: R^T = I, local u = (0.1, 0.02); v = 0.1, w = 0.02 / 0.05 = 0.4
        (0.0, (0.1, 0.02), 0.1, 0.4),
        # theta = pi/2: R^T = [[0, 1], [-1, 0]], local u = (0.02, -0.1); v = 0.02, w = -0.1 / 0.05 = -2
        (math.pi / 2, (0.1, 0.02), 0.02, -2.0),
        # theta = pi: R^T = -I, local u = (-0.1, -0.02); v = -0.1, w = -0.4
        (math.pi, (0.1, 0.02), -0.1, -0.4),
        # cos = 0.8, sin = 0.6, u = (1, 2): local = (0.8 + 1.2, -0.6 + 1.6) = (2, 1); v = 2, w = 1 / 0.05 = 20
        (math.atan2(0.6, 0.8), (1.0, 2.0), 2.0, 20.0),
    ],
)
def test_point_velocity_to_unicycle_by_hand(theta, u, expected_v, expected_w):
    v, w = point_velocity_to_unicycle(np.array(u), np.array(theta), 0.05)
    assert v == pytest.approx(expected_v, abs=1e-12)
    assert w == pytest.approx(expected_w, abs=1e-12)
    # eq. 2.2 forward: p' = R(theta) diag(1, l) [v, w] gives u back
    back = rotate(np.array([v, 0.05 * w]), np.array(theta))
    np.testing.assert_allclose(back, u, atol=1e-12)


def test_local_point_velocity_is_diag_inverse():
    # L(l)^-1 = diag(1, 1/l), l = 0.2: (0.3, -0.1) -> v = 0.3, w = -0.5
    v, w = local_point_velocity_to_unicycle(np.array([0.3, -0.1]), 0.2)
    assert (v, w) == (pytest.approx(0.3), pytest.approx(-0.5))


def test_point_velocity_to_wheels_by_hand():
    params = RobotParams(v_max_mps=10.0)
    # heading pi/2 and u = (0, 0.1) straight ahead: v = 0.1, w = 0 -> wheels (0.1, 0.1)
    np.testing.assert_allclose(
        point_velocity_to_wheels(np.array([0.0, 0.1]), np.array(math.pi / 2), params), [0.1, 0.1], atol=TOL
    )
    # heading 0 and u = (0, 0.01) to the left: v = 0, w = 0.01 / 0.05 = 0.2,
    # vL = -0.1 * 0.2 = -0.02, vR = +0.02
    np.testing.assert_allclose(
        point_velocity_to_wheels(np.array([0.0, 0.01]), np.array(0.0), params), [-0.02, 0.02], atol=TOL
    )
    # local variant: (0.1, 0.01) -> v = 0.1, w = 0.2 -> (0.08, 0.12)
    np.testing.assert_allclose(local_point_velocity_to_wheels(np.array([0.1, 0.01]), params), [0.08, 0.12])


# ---------------------------------------------------------------- frames (eq. 3.2-3.3, transposed)


def test_world_vector_along_heading_is_local_x():
    theta = 0.7
    speed = 2.5
    along = speed * np.array([math.cos(theta), math.sin(theta)])
    # R(theta)^T (|v| cos th, |v| sin th) = |v| (cos^2 + sin^2, -sin cos + cos sin) = (|v|, 0)
    np.testing.assert_allclose(world_to_local(along, np.array(theta)), [speed, 0.0], atol=TOL)
    # the world vector 90 degrees to the left of the heading is local +y
    left = np.array([-math.sin(theta), math.cos(theta)])
    np.testing.assert_allclose(world_to_local(left, np.array(theta)), [0.0, 1.0], atol=TOL)


def test_thesis_rotation_direction_is_fixed():
    # robot facing world +y (theta = pi/2): world +y is straight ahead (local +x), world +x is on its
    # right (local -y). The thesis's R(theta) g would give (-1, 0) for world +y: behind the robot.
    theta = np.array(math.pi / 2)
    np.testing.assert_allclose(world_to_local(np.array([0.0, 1.0]), theta), [1.0, 0.0], atol=TOL)
    np.testing.assert_allclose(world_to_local(np.array([1.0, 0.0]), theta), [0.0, -1.0], atol=TOL)
    # rotate is the inverse: local +x of a robot facing +y is world +y
    np.testing.assert_allclose(rotate(np.array([1.0, 0.0]), theta), [0.0, 1.0], atol=TOL)


@settings(max_examples=50, deadline=None)
@given(x=finite, y=finite, theta=angles)
def test_rotate_inverts_world_to_local(x, y, theta):
    g = np.array([x, y])
    np.testing.assert_allclose(rotate(world_to_local(g, np.array(theta)), np.array(theta)), g, atol=1e-9)
    assert np.linalg.norm(world_to_local(g, np.array(theta))) == pytest.approx(np.linalg.norm(g), abs=1e-9)


def test_batched_shapes():
    poses = np.zeros((4, 5, 3))
    u = np.ones((4, 5, 2))
    params = RobotParams()
    assert controlled_point(poses, 0.05).shape == (4, 5, 2)
    assert point_velocity_to_wheels(u, poses[..., 2], params).shape == (4, 5, 2)
    assert integrate_unicycle(poses, u, 0.1, 0.05).shape == (4, 5, 3)


# ---------------------------------------------------------------- saturation


def test_saturation_scales_both_wheels_by_one_factor():
    # (1.0, 0.5) with v_max 0.5: factor 0.5 / 1.0 = 0.5 -> (0.5, 0.25); ratio vL / vR = 2 kept
    np.testing.assert_allclose(saturate_wheels(np.array([1.0, 0.5]), 0.5), [0.5, 0.25], atol=TOL)
    # (-2.0, 1.0): largest |.| = 2, factor 0.25 -> (-0.5, 0.25); the larger wheel hits exactly -v_max
    saturated = saturate_wheels(np.array([-2.0, 1.0]), 0.5)
    np.testing.assert_allclose(saturated, [-0.5, 0.25], atol=TOL)
    assert abs(saturated[0]) == 0.5


def test_saturation_leaves_unsaturated_speeds_alone():
    for wheels in ([0.3, -0.2], [0.5, 0.5], [0.0, 0.0], [-0.49, 0.1]):
        np.testing.assert_array_equal(saturate_wheels(np.array(wheels), 0.5), wheels)


@settings(max_examples=100, deadline=None)
@given(ux=finite, uy=finite, theta=angles, v_max=st.floats(0.01, 5.0))
def test_saturation_bounds_speed_and_keeps_point_direction(ux, uy, theta, v_max):
    params = RobotParams(v_max_mps=v_max)
    u = np.array([ux, uy])
    wheels = point_velocity_to_wheels(u, np.array(theta), params)
    assert np.max(np.abs(wheels)) <= v_max * (1 + 1e-12)
    # velocity the controlled point actually gets (eq. 2.2) is a non-negative multiple of the wanted u
    v, w = wheels_to_unicycle(wheels, params.half_axle_m)
    actual = rotate(np.array([v, params.offset_m * w]), np.array(theta))
    norm_u = np.linalg.norm(u)
    cross = u[0] * actual[1] - u[1] * actual[0]
    assert abs(cross) <= 1e-9 * max(norm_u, 1.0) ** 2
    assert float(u @ actual) >= -1e-12
    assert np.linalg.norm(actual) <= norm_u * (1 + 1e-9) + 1e-12
    # and if u needs no saturation the point gets exactly u
    raw = unicycle_to_wheels(
        *point_velocity_to_unicycle(u, np.array(theta), params.offset_m), params.half_axle_m
    )
    if np.max(np.abs(raw)) <= v_max:
        np.testing.assert_allclose(actual, u, atol=1e-9)
    else:
        assert np.max(np.abs(wheels)) == pytest.approx(v_max, rel=1e-12)


@settings(max_examples=100, deadline=None)
@given(left=finite, right=finite, half_axle=st.floats(0.01, 1.0))
def test_wheels_unicycle_round_trip(left, right, half_axle):
    wheels = np.array([left, right])
    v, w = wheels_to_unicycle(wheels, half_axle)
    np.testing.assert_allclose(unicycle_to_wheels(v, w, half_axle), wheels, atol=1e-9)


# ---------------------------------------------------------------- unicycle integration (eq. 2.1)


def test_integrate_straight_line():
    # wheels (0.5, 0.5): v = 0.5, w = 0; 2 s along 45 degrees: 1 m, i.e. (sqrt(2)/2, sqrt(2)/2)
    pose = np.array([1.0, 2.0, math.pi / 4])
    new = integrate_unicycle(pose, np.array([0.5, 0.5]), 0.1, 2.0)
    half_root2 = math.sqrt(2) / 2
    np.testing.assert_allclose(new, [1.0 + half_root2, 2.0 + half_root2, math.pi / 4], atol=TOL)


def test_integrate_pure_rotation():
    # wheels (-0.1, 0.1), d = 0.1: v = 0, w = 0.2 / 0.2 = 1 rad/s; 0.5 s turns 0.5 rad in place
    new = integrate_unicycle(np.array([3.0, -1.0, 0.25]), np.array([-0.1, 0.1]), 0.1, 0.5)
    np.testing.assert_allclose(new, [3.0, -1.0, 0.75], atol=TOL)


def test_integrate_quarter_circle():
    # turning radius r = 1 m at w = pi/2 rad/s: v = r w = pi/2; with d = 0.1 the wheels are
    # vL = v - d w = 0.9 pi/2, vR = 1.1 pi/2. In 1 s from (0, 0, 0) the robot turns left around the
    # centre (0, 1) by a quarter: it ends at (1, 1) facing +y.
    w = math.pi / 2
    wheels = unicycle_to_wheels(np.array(w), np.array(w), 0.1)
    np.testing.assert_allclose(wheels, [0.9 * w, 1.1 * w], atol=TOL)
    new = integrate_unicycle(np.zeros(3), wheels, 0.1, 1.0)
    np.testing.assert_allclose(new, [1.0, 1.0, math.pi / 2], atol=TOL)
    # turning right (w < 0) from heading pi/2 at (1, 1), radius 1: centre (2, 1), ends at (2, 2) heading 0
    right = unicycle_to_wheels(np.array(w), np.array(-w), 0.1)
    np.testing.assert_allclose(integrate_unicycle(new, right, 0.1, 1.0), [2.0, 2.0, 0.0], atol=TOL)


def test_integrate_small_steps_agree_with_one_big_step():
    # constant wheels: the exact arc does not depend on how the time is split
    pose = np.array([0.3, -0.2, 2.9])
    wheels = np.array([0.12, 0.37])
    one = integrate_unicycle(pose, wheels, 0.1, 1.0)
    many = pose
    for _ in range(10):
        many = integrate_unicycle(many, wheels, 0.1, 0.1)
    np.testing.assert_allclose(many[:2], one[:2], atol=1e-12)
    assert wrap_angle(np.array(many[2] - one[2])) == pytest.approx(0.0, abs=1e-12)


def test_integrate_wraps_heading():
    # start at 3.0 rad, turn +0.5 rad: 3.5 rad wraps to 3.5 - 2 pi
    new = integrate_unicycle(np.array([0.0, 0.0, 3.0]), np.array([-0.05, 0.05]), 0.1, 1.0)
    assert new[2] == pytest.approx(3.5 - 2 * math.pi, abs=TOL)
    assert -math.pi <= new[2] < math.pi


def test_wrap_angle():
    np.testing.assert_allclose(
        wrap_angle(np.array([0.0, math.pi, -math.pi, 3 * math.pi / 2, -7.0])),
        [0.0, -math.pi, -math.pi, -math.pi / 2, -7.0 + 2 * math.pi],
        atol=TOL,
    )


def test_controlled_point_is_l_ahead():
    # pose (1, 2, pi/2), l = 0.05: p = (1 + 0.05 cos(pi/2), 2 + 0.05 sin(pi/2)) = (1, 2.05)
    np.testing.assert_allclose(
        controlled_point(np.array([1.0, 2.0, math.pi / 2]), 0.05), [1.0, 2.05], atol=TOL
    )
    # heading pi: the point is behind in world x: (1 - 0.3, 2)
    np.testing.assert_allclose(controlled_point(np.array([1.0, 2.0, math.pi]), 0.3), [0.7, 2.0], atol=TOL)


@settings(max_examples=50, deadline=None)
@given(x=finite, y=finite, theta=angles, ux=st.floats(-1, 1), uy=st.floats(-1, 1))
def test_controlled_point_moves_with_u_for_short_steps(x, y, theta, ux, uy):
    # eq. 2.2-2.3: over a very short step the controlled point moves by u dt (unsaturated)
    params = RobotParams(v_max_mps=1000.0)
    pose = np.array([x, y, theta])
    u = np.array([ux, uy])
    dt = 1e-6
    wheels = point_velocity_to_wheels(u, np.array(theta), params)
    moved = controlled_point(integrate_unicycle(pose, wheels, params.half_axle_m, dt), params.offset_m)
    velocity = (moved - controlled_point(pose, params.offset_m)) / dt
    np.testing.assert_allclose(velocity, u, atol=1e-3)


def test_wheel_speed_scale_one_formula_for_floats_arrays_and_numba():
    """The one saturation factor (``swarm.core.robot.wheel_speed_scale``), hand-checked: wheels
    (1, -0.25) m/s under v_max 0.5 scale by 0.5; under the limit by 1; at rest by 1. The float, array
    and compiled (``swarm.sim.kernels``) forms give the same bits."""
    from swarm.core.robot import largest_wheel_speed_local, wheel_speed_scale
    from swarm.sim import kernels

    assert wheel_speed_scale(1.0, 0.5) == 0.5
    assert wheel_speed_scale(0.3, 0.5) == 1.0
    assert wheel_speed_scale(0.0, 0.5) == 1.0
    rng = np.random.default_rng(9)
    largest = np.abs(rng.normal(size=2000)) * rng.uniform(0.0, 5.0, 2000)
    array = wheel_speed_scale(largest, 0.5)
    assert np.array_equal(array, [wheel_speed_scale(float(x), 0.5) for x in largest])
    assert np.array_equal(array, [kernels.wheel_speed_scale(float(x), 0.5) for x in largest])
    # |ux| + (d / l)|uy| is max(|v - d w|, |v + d w|) with v = ux, w = uy / l (eq. 2.3, 2.4)
    ux, uy = rng.normal(size=2000), rng.normal(size=2000)
    wheels = np.stack([ux - 0.1 * uy / 0.05, ux + 0.1 * uy / 0.05], axis=-1)
    np.testing.assert_allclose(
        largest_wheel_speed_local(ux, uy, 0.1, 0.05), np.abs(wheels).max(-1), rtol=1e-12
    )
