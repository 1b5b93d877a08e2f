"""Differential-drive robot model (thesis section 2.1).

Every function works on arrays with any leading batch shape:
poses are ``(..., 3)`` as ``(x_m, y_m, theta_rad)``, planar vectors ``(..., 2)``,
wheel speeds ``(..., 2)`` as ``(left, right)`` linear speeds in m/s.

Frames: a world vector ``g`` seen from a robot with heading ``theta`` is
``R(theta)^T g``. (The thesis writes ``R(theta) g`` in eq. 3.2-3.3, which rotates
the wrong way; we use the transpose and test it.)
"""

from __future__ import annotations

import numpy as np
from pydantic import AliasChoices, BaseModel, ConfigDict, Field


class RobotParams(BaseModel):
    """Physical parameters of one robot. Defaults are BubbleRob-like."""

    model_config = ConfigDict(extra="forbid", frozen=True, populate_by_name=True)

    wheel_radius_m: float = Field(0.04, gt=0, validation_alias=AliasChoices("wheel_radius_m", "wheel_radius"))
    half_axle_m: float = Field(
        0.1,
        gt=0,
        validation_alias=AliasChoices("half_axle_m", "half_axle"),
        description="half the distance between the wheels (d in thesis eq. 2.4)",
    )
    offset_m: float = Field(
        0.05,
        gt=0,
        validation_alias=AliasChoices("offset_m", "offset_l", "l"),
        description="distance l of the controlled point ahead of the axle (thesis eq. 2.2)",
    )
    v_max_mps: float = Field(
        0.5,
        gt=0,
        validation_alias=AliasChoices("v_max_mps", "v_max"),
        description="wheel linear speed limit; the axle centre never moves faster",
    )
    body_radius_m: float = Field(
        0.12,
        gt=0,
        validation_alias=AliasChoices("body_radius_m", "body_radius"),
        description="radius of the robot's bumper (physics engine only)",
    )


def rotate(vectors: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """``R(theta) v``: local (robot-frame) vectors to world vectors."""
    c, s = np.cos(theta), np.sin(theta)
    x, y = vectors[..., 0], vectors[..., 1]
    return np.stack([c * x - s * y, s * x + c * y], axis=-1)


def world_to_local(vectors: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """``R(theta)^T g``: world vectors in the frame of a robot with heading theta (eq. 3.2-3.3, fixed)."""
    c, s = np.cos(theta), np.sin(theta)
    x, y = vectors[..., 0], vectors[..., 1]
    return np.stack([c * x + s * y, -s * x + c * y], axis=-1)


def controlled_point(poses: np.ndarray, offset_m: float) -> np.ndarray:
    """Point p at distance l ahead of the axle centre (thesis Fig. 2.2)."""
    theta = poses[..., 2]
    return np.stack(
        [poses[..., 0] + offset_m * np.cos(theta), poses[..., 1] + offset_m * np.sin(theta)], axis=-1
    )


def local_point_velocity_to_unicycle(u_local: np.ndarray, offset_m: float) -> tuple[np.ndarray, np.ndarray]:
    """``[v, w] = L(l)^-1 u_local`` with ``L = diag(1, l)`` (thesis eq. 2.3, u already in the robot frame)."""
    return u_local[..., 0], u_local[..., 1] / offset_m


def point_velocity_to_unicycle(
    u_world: np.ndarray, theta: np.ndarray, offset_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """``[v, w] = L(l)^-1 R(theta)^T u`` (thesis eq. 2.3)."""
    return local_point_velocity_to_unicycle(world_to_local(u_world, theta), offset_m)


def unicycle_to_wheels(v: np.ndarray, w: np.ndarray, half_axle_m: float) -> np.ndarray:
    """Wheel linear speeds ``vL = v - d w``, ``vR = v + d w`` (inverse of thesis eq. 2.4)."""
    return np.stack([v - half_axle_m * w, v + half_axle_m * w], axis=-1)


def wheels_to_unicycle(wheels: np.ndarray, half_axle_m: float) -> tuple[np.ndarray, np.ndarray]:
    """``v = (vL + vR) / 2``, ``w = (vR - vL) / (2 d)`` (thesis eq. 2.4)."""
    left, right = wheels[..., 0], wheels[..., 1]
    return 0.5 * (left + right), (right - left) / (2.0 * half_axle_m)


def wheel_speed_scale(largest_mps, v_max_mps: float):
    """The one factor of the wheel-speed saturation: ``min(1, v_max / max(largest, 1e-12))``, where
    ``largest = max(|vL|, |vR|)`` (m/s). Both wheels (or ``v`` and ``w``, or the point velocity) are
    multiplied by it, which keeps the ratio ``v / w``: the robot turns on the same arc, only slower,
    and the controlled point keeps its direction. One form for floats, numpy arrays and numba
    kernels (``np.minimum``, ``np.maximum``: an ``@njit`` kernel may call it once compiled)."""
    return np.minimum(1.0, v_max_mps / np.maximum(largest_mps, 1e-12))


def largest_wheel_speed_local(ux_mps, uy_mps, half_axle_m: float, offset_m: float):
    """``max(|vL|, |vR|) = |v| + d |w|`` of a robot-frame point velocity ``(ux, uy)``: with ``v = ux``,
    ``w = uy / l`` (eq. 2.3) and ``v -+ d w`` (eq. 2.4), ``|ux| + (d / l) |uy|`` (a diamond). Floats,
    arrays or numba, like :func:`wheel_speed_scale`."""
    return np.abs(ux_mps) + half_axle_m / offset_m * np.abs(uy_mps)


def saturate_wheels(wheels: np.ndarray, v_max_mps: float) -> np.ndarray:
    """Both wheels scaled by :func:`wheel_speed_scale` so that ``max(|vL|, |vR|) <= v_max``."""
    return wheels * wheel_speed_scale(np.max(np.abs(wheels), axis=-1, keepdims=True), v_max_mps)


def point_velocity_to_wheels(u_world: np.ndarray, theta: np.ndarray, params: RobotParams) -> np.ndarray:
    """Desired world velocity of the controlled point to saturated wheel linear speeds (m/s)."""
    v, w = point_velocity_to_unicycle(u_world, theta, params.offset_m)
    return saturate_wheels(unicycle_to_wheels(v, w, params.half_axle_m), params.v_max_mps)


def local_point_velocity_to_wheels(u_local: np.ndarray, params: RobotParams) -> np.ndarray:
    """Desired robot-frame velocity of the controlled point to saturated wheel linear speeds (m/s)."""
    v, w = local_point_velocity_to_unicycle(u_local, params.offset_m)
    return saturate_wheels(unicycle_to_wheels(v, w, params.half_axle_m), params.v_max_mps)


def wheel_angular_speeds(wheels: np.ndarray, wheel_radius_m: float) -> np.ndarray:
    """Wheel angular speeds in rad/s from wheel linear speeds in m/s."""
    return wheels / wheel_radius_m


def wrap_angle(theta: np.ndarray) -> np.ndarray:
    """Angles to [-pi, pi)."""
    return (theta + np.pi) % (2.0 * np.pi) - np.pi


def integrate_unicycle(poses: np.ndarray, wheels: np.ndarray, half_axle_m: float, dt_s: float) -> np.ndarray:
    """Exact integration of thesis eq. 2.1 over ``dt_s`` with constant wheel speeds.

    The axle centre moves along an arc of length ``v dt``; its chord has
    length ``v dt sinc(w dt / 2)`` and points along the mid-step heading.
    """
    v, w = wheels_to_unicycle(wheels, half_axle_m)
    half_turn = 0.5 * w * dt_s
    mid_heading = poses[..., 2] + half_turn
    chord = v * dt_s * np.sinc(half_turn / np.pi)
    return np.stack(
        [
            poses[..., 0] + chord * np.cos(mid_heading),
            poses[..., 1] + chord * np.sin(mid_heading),
            wrap_angle(poses[..., 2] + 2.0 * half_turn),
        ],
        axis=-1,
    )
