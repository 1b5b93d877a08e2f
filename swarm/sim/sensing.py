"""What each robot's sensors see in the kinematic engine (batched): every other body and every obstacle
within the sensing radius, as range and bearing in the robot's own frame, optionally noisy and with
dropouts, from a seeded generator. Independent of the communication graph.

* A body j: the range and bearing of its centre (axle) from robot i's centre, and its heading relative
  to robot i's (what a marker-tracking sensor reports), seen when the centres are within the radius.
* An obstacle: the range and bearing, from robot i's centre, of the obstacle's surface point nearest
  robot i's controlled point (what a range scan determines), seen when that point is within the radius.

Noise: the range gets ``N(0, noise_m^2)``, the bearing ``N(0, (noise_m / range)^2)`` (a lateral error of
``noise_m``); dropout: each reading is missing with probability ``dropout`` at each tick.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from swarm.core.obstacles import Capsules
from swarm.core.robot import wrap_angle


class Readings(NamedTuple):
    """``(B, N, N)`` for bodies (j seen by i at ``[b, i, j]``; never itself), ``(B, N, K)`` for obstacles."""

    body_range_m: np.ndarray
    body_bearing_rad: np.ndarray
    body_heading_rad: np.ndarray
    body_seen: np.ndarray
    obstacle_range_m: np.ndarray
    obstacle_bearing_rad: np.ndarray
    obstacle_seen: np.ndarray


def _polar(vectors: np.ndarray, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Range and robot-frame bearing of world ``vectors (B, N, M, 2)`` seen at headings ``theta (B, N)``."""
    distance = np.hypot(vectors[..., 0], vectors[..., 1])
    bearing = wrap_angle(np.arctan2(vectors[..., 1], vectors[..., 0]) - theta[..., None])
    return distance, bearing


def sense(
    poses: np.ndarray,
    points: np.ndarray,
    obstacles: Capsules,
    sensing_radius_m: float,
    noise_m: float = 0.0,
    dropout: float = 0.0,
    rng: np.random.Generator | None = None,
) -> Readings:
    """The readings of every robot of ``poses (B, N, 3)`` (controlled points ``points (B, N, 2)``)."""
    centres, theta = poses[..., :2], poses[..., 2]
    count = poses.shape[1]
    body_range, body_bearing = _polar(centres[:, None, :, :] - centres[:, :, None, :], theta)
    body_heading = wrap_angle(theta[:, None, :] - theta[:, :, None])
    body_seen = (body_range <= sensing_radius_m) & ~np.eye(count, dtype=bool)[None]
    if len(obstacles):
        surface = obstacles.nearest_surface(points)  # (B, N, K, 2)
        obstacle_range, obstacle_bearing = _polar(surface - centres[:, :, None, :], theta)
    else:
        obstacle_range = obstacle_bearing = np.zeros((*theta.shape, 0))
    obstacle_seen = obstacle_range <= sensing_radius_m
    if noise_m > 0 or dropout > 0:
        if rng is None:
            raise ValueError("noisy or dropping sensing needs a seeded generator")
        body_range, body_bearing = _noisy(rng, body_range, body_bearing, noise_m)
        obstacle_range, obstacle_bearing = _noisy(rng, obstacle_range, obstacle_bearing, noise_m)
        if dropout > 0:
            body_seen = body_seen & (rng.random(body_seen.shape) >= dropout)
            obstacle_seen = obstacle_seen & (rng.random(obstacle_seen.shape) >= dropout)
    return Readings(
        body_range, body_bearing, body_heading, body_seen, obstacle_range, obstacle_bearing, obstacle_seen
    )


def _noisy(rng: np.random.Generator, distance: np.ndarray, bearing: np.ndarray, noise_m: float):
    if noise_m == 0:
        return distance, bearing
    noisy_distance = np.maximum(distance + rng.normal(0.0, noise_m, distance.shape), 0.0)
    noisy_bearing = bearing + rng.normal(0.0, 1.0, bearing.shape) * noise_m / np.maximum(distance, 1e-6)
    return noisy_distance, wrap_angle(noisy_bearing)


def robot_reading(readings: Readings, robot: int, environment: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """What robot ``robot`` of ``environment`` sees, as the sim server sends it (``wire.Sensing``):
    ``(M, 3)`` range, bearing and relative heading of each body seen, in robot order, and ``(K, 2)``
    range and bearing of each obstacle seen, in obstacle order."""
    seen = readings.body_seen[environment, robot]
    bodies = np.stack(
        [
            readings.body_range_m[environment, robot][seen],
            readings.body_bearing_rad[environment, robot][seen],
            readings.body_heading_rad[environment, robot][seen],
        ],
        axis=-1,
    )
    walls = readings.obstacle_seen[environment, robot]
    obstacles = np.stack(
        [
            readings.obstacle_range_m[environment, robot][walls],
            readings.obstacle_bearing_rad[environment, robot][walls],
        ],
        axis=-1,
    )
    return bodies.reshape(-1, 3), obstacles.reshape(-1, 2)
