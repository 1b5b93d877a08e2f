"""The wheel-speed saturation's forms held equal (issue 18 point 3): ``swarm.core.robot`` (wheels),
``swarm.sim.features.saturate_local_velocity`` (numpy, which the agents, the policies and, compiled, the
kernels call) and its torch twin ``swarm.learn.models.base.saturate`` (training), on adversarial
inputs. The oracle is the definition: both wheels ``v -+ d w`` scaled by one factor so that the larger
is ``v_max`` when it was above, the point's direction kept."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from swarm.core.robot import RobotParams, local_point_velocity_to_wheels
from swarm.learn.models.base import saturate
from swarm.sim.features import saturate_local_velocity

ROBOTS = [RobotParams(), RobotParams(v_max_mps=2.0, offset_m=0.01), RobotParams(v_max_mps=0.1, offset_m=0.3)]


def _inputs(robot: RobotParams) -> np.ndarray:
    rng = np.random.default_rng(0)
    ratio = robot.half_axle_m / robot.offset_m
    on_edge = []  # exactly on the diamond |ux| + (d / l) |uy| = v_max, and just outside it
    for share in (0.0, 0.25, 0.5, 1.0):
        ux = (1.0 - share) * robot.v_max_mps
        on_edge += [(ux, share * robot.v_max_mps / ratio), (-ux, -share * robot.v_max_mps / ratio)]
    rows = [
        *on_edge,
        *[(1.0000001 * a, 1.0000001 * b) for a, b in on_edge],
        (0.0, 0.0),
        (1e-300, -1e-300),
        (1e6, -1e6),
        (-1e-9, 3.0),
    ]
    return np.concatenate([np.array(rows), rng.normal(0.0, 3.0 * robot.v_max_mps, (500, 2))])


def _definition(u_local: np.ndarray, robot: RobotParams) -> np.ndarray:
    """Robot-frame point velocity of the saturated wheels, by the definition, one row at a time."""
    out = np.empty_like(u_local)
    for row, (ux, uy) in enumerate(u_local):
        v, w = ux, uy / robot.offset_m
        left, right = v - robot.half_axle_m * w, v + robot.half_axle_m * w
        larger = max(abs(left), abs(right))
        factor = 1.0 if larger <= robot.v_max_mps else robot.v_max_mps / larger
        out[row] = (v * factor, w * factor * robot.offset_m)
    return out


@pytest.mark.parametrize("robot", ROBOTS, ids=["default", "short_offset", "long_offset"])
def test_every_form_of_the_wheel_saturation_is_the_definition(robot):
    u_local = _inputs(robot)
    expected = _definition(u_local, robot)
    numpy_form = saturate_local_velocity(u_local, robot)
    torch_form = saturate(torch.as_tensor(u_local), robot).numpy()
    wheels = local_point_velocity_to_wheels(u_local, robot)
    v = 0.5 * (wheels[:, 0] + wheels[:, 1])
    w = (wheels[:, 1] - wheels[:, 0]) / (2 * robot.half_axle_m)
    wheel_form = np.stack([v, w * robot.offset_m], axis=-1)
    for form in (numpy_form, torch_form):
        np.testing.assert_allclose(form, expected, rtol=1e-12, atol=1e-300)
    # back from the wheels, v = (vL + vR) / 2 cancels: rounding of the wheel speeds' size, not more
    np.testing.assert_allclose(wheel_form, expected, rtol=1e-12, atol=1e-15 * robot.v_max_mps)
    assert (np.abs(wheels) <= robot.v_max_mps * (1 + 1e-12)).all()
