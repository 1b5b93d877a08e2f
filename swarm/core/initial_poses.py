"""Random initial poses: every robot uniform in a box, heading uniform, a minimum separation."""

from __future__ import annotations

import math

import numpy as np


def random_poses(
    rng: np.random.Generator,
    batch: int,
    count: int,
    x_range_m: tuple[float, float] = (-2.0, 2.0),
    y_range_m: tuple[float, float] = (-2.0, 2.0),
    min_separation_m: float = 0.4,
    theta_range_rad: tuple[float, float] = (-math.pi, math.pi),
    max_tries: int = 10_000,
) -> np.ndarray:
    """``(batch, count, 3)`` poses; robots are placed one at a time, redrawing any that land
    closer than ``min_separation_m`` to one already placed (all environments at once)."""
    positions = np.empty((batch, count, 2))
    low = np.array([x_range_m[0], y_range_m[0]])
    high = np.array([x_range_m[1], y_range_m[1]])
    for robot in range(count):
        pending = np.arange(batch)
        for _ in range(max_tries):
            candidates = rng.uniform(low, high, size=(len(pending), 2))
            if robot == 0 or min_separation_m == 0:
                positions[pending, robot] = candidates
                break
            gaps = np.linalg.norm(positions[pending, :robot] - candidates[:, None, :], axis=-1).min(axis=-1)
            accepted = gaps >= min_separation_m
            positions[pending[accepted], robot] = candidates[accepted]
            pending = pending[~accepted]
            if len(pending) == 0:
                break
        else:
            raise ValueError(
                f"cannot place {count} robots {min_separation_m} m apart in x {list(x_range_m)},"
                f" y {list(y_range_m)}: make the box larger or the separation smaller"
            )
    theta = rng.uniform(theta_range_rad[0], theta_range_rad[1], size=(batch, count, 1))
    return np.concatenate([positions, theta], axis=-1)


def box_for(count: int, area_per_robot_m2: float = 16.0 / 6.0) -> tuple[float, float]:
    """A square box ``[-h, h]`` whose area grows with the swarm: 4 m x 4 m for the thesis's 6 robots."""
    half_width = 0.5 * math.sqrt(area_per_robot_m2 * max(count, 6))
    return (-half_width, half_width)
