"""Consensus experts (thesis eq. 3.1).

``u_i = -K sum_j A_ij (p_i - p_j)`` where ``p`` is each robot's controlled point.
On the complete graph it is the ``centralized`` expert (everyone's information);
on the scenario's own graph it is classical ``local_consensus``.
"""

from __future__ import annotations

import numpy as np


def consensus_velocity(points: np.ndarray, adjacency: np.ndarray, gain: float) -> np.ndarray:
    """Thesis eq. 3.1 for every robot at once: ``-K (D p - A p)`` = ``-K L p``.

    points: ``(..., N, 2)`` world positions; adjacency: ``(..., N, N)``.
    Returns world velocities ``(..., N, 2)`` of the controlled points.
    """
    degree = adjacency.sum(axis=-1)[..., None]
    return -gain * (degree * points - adjacency @ points)


def complete_consensus_velocity(
    points: np.ndarray, gain: float, alive: np.ndarray | None = None
) -> np.ndarray:
    """Eq. 3.1 on the complete graph over the ``alive`` robots, in O(N): ``-K (n p_i - sum_j p_j)``."""
    if alive is None:
        count = points.shape[-2]
        total = points.sum(axis=-2, keepdims=True)
        return -gain * (count * points - total)
    weight = alive[..., None].astype(points.dtype)
    count = weight.sum(axis=-2, keepdims=True)
    total = (points * weight).sum(axis=-2, keepdims=True)
    return -gain * (count * points - total) * weight


def neighbour_consensus_velocity(
    own_point: np.ndarray, neighbour_points: np.ndarray, gain: float
) -> np.ndarray:
    """Eq. 3.1 for one robot from the points its neighbours reported: ``-K sum_j (p_i - p_j)``.

    own_point ``(2,)``, neighbour_points ``(m, 2)`` (m may be 0: the robot holds still).
    """
    neighbour_points = np.asarray(neighbour_points, dtype=float).reshape(-1, 2)
    return -gain * (len(neighbour_points) * np.asarray(own_point, dtype=float) - neighbour_points.sum(axis=0))
