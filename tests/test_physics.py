"""PyBullet robot against the unicycle model of swarm.core.robot (thesis 2.1).

Measured with the defaults (240 Hz, 10 solver iterations, 2 N traction limit = 0.08 N m):

- settling at construction: poses move < 0.1 mm and < 0.1 mrad;
- straight driving after a 1 s start-up: forward speed +0.17% (0.5 m/s) to +0.9% (0.1 m/s)
  of the command: a constant ~0.9 mm/s forward creep, a solver residual with 10 iterations
  that is also there at rest (0.2 mm/s with 30 iterations); lateral drift < 0.6 mm/s,
  heading drift < 0.6 mrad/s;
- constant arcs: yaw rate within 0.25% of ``(vR - vL) / (2 d)``;
- 10 s schedule at 20 Hz control (2.6 m of path): final axle-centre error vs exact unicycle
  integration 0.6-1.0 cm, heading error 6-11 mrad (the actuators' finite acceleration, which
  the unicycle model lacks, and the creep above);
- braking from 0.5 m/s: tilt < 0.03 deg (default limit), 1.4 deg with a friction-limited
  5 N m motor (the front anti-tip ball catches the robot);
- 8-robot pile-up: tilt < 0.25 deg, axle centres never closer than 2 x bumper radius.
"""

from __future__ import annotations

import numpy as np
import pytest

from sim_server.physics import LARGE_SWARM_PHYSICS_HZ, LARGE_SWARM_SOLVER_ITERATIONS, PhysicsWorld
from sim_server.urdf import packaged_urdf_path, render_urdf, write_urdf
from swarm.core.robot import (
    RobotParams,
    controlled_point,
    integrate_unicycle,
    point_velocity_to_wheels,
    saturate_wheels,
    unicycle_to_wheels,
    wrap_angle,
)

PARAMS = RobotParams()
CONTROL_DT_S = 0.05
SETTINGS = [(240.0, 10), (LARGE_SWARM_PHYSICS_HZ, LARGE_SWARM_SOLVER_ITERATIONS)]
"""(physics_hz, solver_iterations): the default and the large-swarm settings, both held to the model."""


def _heading(theta: float) -> np.ndarray:
    return np.array([np.cos(theta), np.sin(theta)])


def test_packaged_urdf_matches_default_rendering(tmp_path):
    assert packaged_urdf_path().read_text(encoding="utf-8") == render_urdf(RobotParams())
    out = write_urdf(tmp_path / "sub" / "r.urdf", RobotParams(wheel_radius_m=0.05))
    assert 'sphere radius="0.05"' in out.read_text(encoding="utf-8")


def test_initial_poses_are_axle_centres_and_settling_is_negligible():
    init = np.array([[0.3, -0.2, 0.7], [2.0, 2.0, -2.5], [-1.0, 0.5, 3.1]])
    with PhysicsWorld(PARAMS, init) as world:
        assert world.time_s == 0.0
        got = world.poses()
        np.testing.assert_allclose(got[:, :2], init[:, :2], atol=2e-4)
        np.testing.assert_allclose(wrap_angle(got[:, 2] - init[:, 2]), 0.0, atol=2e-4)
        np.testing.assert_allclose(world.axle_heights(), PARAMS.wheel_radius_m, atol=1e-4)
        assert world.step(0.05) == pytest.approx(0.05)
        assert world.time_s == pytest.approx(0.05)


@pytest.mark.parametrize("theta", [0.0, 0.9])
def test_straight_speed_matches_command(theta):
    """(a) Forward speed within 2% of the command after a start-up second; tiny lateral drift."""
    speeds = np.array([0.1, 0.3, 0.5])
    init = np.array([[0.0, 3.0 * k, theta] for k in range(len(speeds))])
    with PhysicsWorld(PARAMS, init) as world:
        world.set_wheel_speeds(np.repeat(speeds[:, None], 2, axis=1))
        world.step(1.0)
        start = world.poses()
        world.step(2.0)
        end = world.poses()
    h = _heading(theta)
    d = end[:, :2] - start[:, :2]
    forward = d @ h / 2.0
    lateral = (h[0] * d[:, 1] - h[1] * d[:, 0]) / 2.0
    np.testing.assert_allclose(forward, speeds, rtol=0.02)
    assert np.all(np.abs(lateral) < 0.002)  # m/s; measured < 6e-4
    assert np.all(np.abs(wrap_angle(end[:, 2] - start[:, 2])) < 0.01)  # rad in 2 s; measured < 1.2e-3


def test_arcs_yaw_rate_matches_unicycle():
    """(b) Constant (v, w): yaw rate within 2% of the unicycle model."""
    vw = np.array([[0.3, 1.0], [0.2, -2.0], [0.0, 3.0], [0.4, 0.5], [-0.2, 1.5]])
    wheels = unicycle_to_wheels(vw[:, 0], vw[:, 1], PARAMS.half_axle_m)
    assert np.all(np.abs(wheels) <= PARAMS.v_max_mps + 1e-12)
    init = np.array([[3.0 * k, 0.0, 0.3 * k] for k in range(len(vw))])
    with PhysicsWorld(PARAMS, init) as world:
        world.set_wheel_speeds(wheels)
        world.step(1.0)
        prev = world.poses()[:, 2]
        turned = np.zeros(len(vw))
        for _ in range(20):  # unwrap over 2 s
            world.step(0.1)
            now = world.poses()[:, 2]
            turned += wrap_angle(now - prev)
            prev = now
    np.testing.assert_allclose(turned / 2.0, vw[:, 1], rtol=0.02)


def _schedule(k: int) -> np.ndarray:
    """Wheel-speed schedule (left, right) m/s at control tick k: 1 s ramps from and to rest, then
    speed and turn rate vary (speed 0.1-0.5 m/s, turn rate up to 1.5 rad/s, wheel limit active)."""
    t = k * CONTROL_DT_S
    envelope = np.clip(min(t, 10.0 - t), 0.0, 1.0)
    v = envelope * (0.3 + 0.2 * np.sin(2 * np.pi * 0.3 * t))
    w = envelope * 1.5 * np.sin(2 * np.pi * 0.21 * t + 0.5)
    return saturate_wheels(unicycle_to_wheels(v, w, PARAMS.half_axle_m), PARAMS.v_max_mps)


@pytest.mark.parametrize(("physics_hz", "solver_iterations"), SETTINGS)
def test_schedule_tracks_unicycle_integration(physics_hz, solver_iterations):
    """(c) 10 s at 20 Hz control: final pose close to exact unicycle integration.

    Measured: 0.6-1.0 cm and 6-11 mrad after 10 s, 2.6 m of path (40 Hz / 30 iterations: 0.1-0.3 cm,
    2-6 mrad); asserted: 3 cm and 0.03 rad.
    """
    init = np.array([[0.5, -0.3, 0.0], [5.0, 5.0, 2.4]])
    with PhysicsWorld(PARAMS, init, physics_hz, solver_iterations) as world:
        ref = world.poses()
        for k in range(round(10.0 / CONTROL_DT_S)):
            wheels = np.tile(_schedule(k), (len(init), 1))
            world.set_wheel_speeds(wheels)
            world.step(CONTROL_DT_S)
            ref = integrate_unicycle(ref, wheels, PARAMS.half_axle_m, CONTROL_DT_S)
        final = world.poses()
    assert world.time_s == pytest.approx(10.0)
    position_error = np.hypot(*(final[:, :2] - ref[:, :2]).T)
    heading_error = np.abs(wrap_angle(final[:, 2] - ref[:, 2]))
    assert np.all(position_error < 0.03), position_error
    assert np.all(heading_error < 0.03), heading_error


@pytest.mark.parametrize("force_limit_nm", [None, 5.0])
def test_upright_under_hard_braking(force_limit_nm):
    """(d) Full speed forward/backward, then zero (or reversed) command: the robot stays upright."""
    with PhysicsWorld(PARAMS, np.array([[0.0, 0.0, 0.4]]), wheel_force_limit_nm=force_limit_nm) as world:
        worst = 0.0
        for drive, brake in [(0.5, 0.0), (-0.5, 0.0), (0.5, -0.5), (-0.5, 0.5)]:
            world.set_wheel_speeds(np.full((1, 2), drive))
            world.step(1.0)
            world.set_wheel_speeds(np.full((1, 2), brake))
            for _ in range(60):
                world.step(1.0 / world.physics_hz)
                worst = max(worst, float(world.tilt_rad()[0]))
        assert worst < np.radians(3.0), np.degrees(worst)
        np.testing.assert_allclose(world.axle_heights(), PARAMS.wheel_radius_m, atol=1e-3)


@pytest.mark.parametrize(("physics_hz", "solver_iterations"), SETTINGS)
def test_pile_up_at_origin_no_flips_no_overlap(physics_hz, solver_iterations):
    """(e) 8 robots all heading for the origin at full speed: no flips, bumpers barely overlap."""
    n = 8
    angles = np.arange(n) * 2 * np.pi / n + 0.1
    init = np.stack([1.2 * np.cos(angles), 1.2 * np.sin(angles), angles + np.pi], axis=1)
    min_gap = np.inf
    with PhysicsWorld(PARAMS, init, physics_hz, solver_iterations) as world:
        worst_tilt = 0.0
        for _ in range(round(6.0 / CONTROL_DT_S)):
            poses = world.poses()
            u = -2.0 * controlled_point(poses, PARAMS.offset_m)  # every robot drives its point to 0
            world.set_wheel_speeds(point_velocity_to_wheels(u, poses[:, 2], PARAMS))
            world.step(CONTROL_DT_S)
            worst_tilt = max(worst_tilt, float(world.tilt_rad().max()))
            p = world.poses()[:, :2]
            dist = np.hypot(*(p[:, None, :] - p[None, :, :]).transpose(2, 0, 1))
            min_gap = min(min_gap, float(dist[~np.eye(n, dtype=bool)].min()))
        np.testing.assert_allclose(world.axle_heights(), PARAMS.wheel_radius_m, atol=2e-3)
        final = world.poses()[:, :2]
    assert worst_tilt < np.radians(5.0), np.degrees(worst_tilt)
    assert min_gap > 2 * PARAMS.body_radius_m - 0.004, min_gap
    # They did pile up: all within a small disk (8 bumpers of 0.12 m fit in ~0.28 m radius).
    assert np.max(np.hypot(*final.T)) < 0.45


def test_two_worlds_are_bit_identical():
    """(f) Same inputs, two worlds stepped alternately in one process: bit-identical poses."""
    rng = np.random.default_rng(7)
    init = np.column_stack([rng.uniform(-0.6, 0.6, (6, 2)), rng.uniform(-np.pi, np.pi, 6)])
    with PhysicsWorld(PARAMS, init) as a, PhysicsWorld(PARAMS, init) as b:
        assert a.client_id != b.client_id
        for _ in range(40):
            wheels = rng.uniform(-0.5, 0.5, (6, 2))
            a.set_wheel_speeds(wheels)
            b.set_wheel_speeds(wheels)
            a.step(CONTROL_DT_S)
            b.step(CONTROL_DT_S)
            assert np.array_equal(a.poses(), b.poses())
        a.stop_robot(2)
        b.stop_robot(2)
        a.step(0.5)
        b.step(0.5)
        assert np.array_equal(a.poses(), b.poses())
        assert np.all(a.wheel_speeds[2] == 0.0)


def test_bad_inputs_rejected():
    with pytest.raises(ValueError):
        PhysicsWorld(PARAMS, np.zeros((2, 2)))
    with PhysicsWorld(PARAMS, np.zeros((1, 3))) as world:
        with pytest.raises(ValueError):
            world.set_wheel_speeds(np.zeros((2, 2)))
        with pytest.raises(ValueError):
            world.set_wheel_speeds(np.array([[np.nan, 0.0]]))
        with pytest.raises(IndexError):
            world.stop_robot(1)
    world.close()  # idempotent
