"""Experts: consensus (thesis eq. 3.1) and the minimum-enclosing-circle expert.

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


def drive_toward_velocity(
    poses: np.ndarray,
    targets: np.ndarray,
    v_max_mps: float,
    control_period_s: float,
    reverse: bool = True,
    backward: np.ndarray | bool | None = None,
    step_fraction: float = 1.0,
) -> np.ndarray:
    """Full-speed drive of a robot's AXLE toward a target, forward or (``reverse``) backward.

    poses ``(..., 3)``, targets ``(..., 2)`` world positions. The axle ``x`` is what success judges
    (``swarm.core.metrics``), so the command is ``u = (c - x) min(v_max / |c - x|, 1 / T)``: full
    speed, or the whole way in one control period ``T`` when closer than ``v_max T``, applied to the
    leading point ``x + l h`` (eq. 2.2), or, when ``reverse`` and the target is behind the axle
    (``<c - x, h> < 0``), to the point ``x - l h`` the backward unicycle leads with. Either way the
    axle moves with ``v = <u, h>``, so ``d|x - c|^2 / dt = -2 k <x - c, h>^2 <= 0`` while the
    heading turns toward (away from, in reverse) the target: the axles gather on the target,
    whatever the offset ``l`` (a law on the point ``x + l h`` would leave them ``l`` from it). A
    robot already on its target gets ``u = 0``.

    Returns the world velocity of the FORWARD controlled point that gives the same ``(v, w)`` as
    this command (eq. 2.3 with offset ``-l`` equals eq. 2.3 with ``+l`` on the command reflected
    across the heading axis, ``2 <u, h> h - u``), so every engine's point-velocity path and wheel
    saturation (``swarm.core.robot``) apply unchanged.

    ``backward`` (bool, broadcast to ``poses[..., 0]``), when given, chooses the law per robot instead
    of ``reverse``: the backward one where True, wherever the target is (the backward unicycle is the
    forward one with its heading turned by pi, so the same argument holds), and the robot arrives
    with its heading pointing back along its way in.

    ``step_fraction`` ``f`` in (0, 1] damps the last stretch: ``u = (c - x) min(v_max / |c - x|, f / T)``,
    a fraction ``f`` of the way in one period when closer than ``v_max T / f`` (1: the whole way).
    """
    poses = np.asarray(poses, dtype=np.float64)
    targets = np.asarray(targets, dtype=np.float64)
    heading = np.stack([np.cos(poses[..., 2]), np.sin(poses[..., 2])], axis=-1)
    delta = targets - poses[..., :2]
    if backward is None:
        behind = (delta * heading).sum(axis=-1) < 0.0
        law = behind if reverse else np.zeros_like(behind)
    else:
        law = np.broadcast_to(np.asarray(backward, dtype=bool), poses.shape[:-1])
    distance = np.sqrt((delta * delta).sum(axis=-1))
    scale = np.where(
        distance > 0.0,
        np.minimum(v_max_mps / np.where(distance > 0.0, distance, 1.0), step_fraction / control_period_s),
        0.0,
    )
    u = delta * scale[..., None]
    along = (u * heading).sum(axis=-1, keepdims=True)
    return np.where(law[..., None], 2.0 * along * heading - u, u)


def centralized_mec_velocity(
    poses: np.ndarray,
    v_max_mps: float,
    control_period_s: float,
    reverse: bool = True,
) -> np.ndarray:
    """The time-optimal centralized expert (``centralized_mec``) for one swarm: every robot drives its
    axle at full speed toward the centre of the exact minimum enclosing circle of the
    CURRENT axle positions (``swarm.core.metrics.minimum_enclosing_circle``), with reversing
    (:func:`drive_toward_velocity`). poses ``(N, 3)`` -> world velocities ``(N, 2)`` of the forward
    controlled points. The MEC centre is the point the lower bound of ``swarm.core.metrics.lower_bound_s``
    measures against: every robot heads straight for it.
    """
    from swarm.core.metrics import minimum_enclosing_circle

    poses = np.asarray(poses, dtype=np.float64)
    centre, _ = minimum_enclosing_circle(poses[:, :2])
    targets = np.broadcast_to(centre, poses[:, :2].shape)
    return drive_toward_velocity(poses, targets, v_max_mps, control_period_s, reverse)
