"""Consensus metrics, convergence time and the physical lower bound (docs/design.md, "Metrics").

Positions are axle centres in metres, shape ``(..., N, 2)``; every metric is batched over the leading
dimensions and returns shape ``(...)``.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from swarm.core.mec import welzl_circle
from swarm.core.packing import packing_limit_m


def _check_positions(positions: np.ndarray) -> np.ndarray:
    positions = np.asarray(positions, dtype=np.float64)
    if positions.ndim < 2 or positions.shape[-1] != 2 or positions.shape[-2] < 1:
        raise ValueError(f"positions must have shape (..., N, 2) with N >= 1, got {positions.shape}")
    return positions


def max_pairwise(positions: np.ndarray) -> np.ndarray:
    """Largest distance between two robots, in metres (the default success metric)."""
    positions = _check_positions(positions)
    diff = positions[..., :, None, :] - positions[..., None, :, :]
    return np.sqrt(np.max(np.sum(diff * diff, axis=-1), axis=(-2, -1)))


def spread(positions: np.ndarray) -> np.ndarray:
    """RMS distance of the robots to their centroid, in metres."""
    positions = _check_positions(positions)
    offsets = positions - positions.mean(axis=-2, keepdims=True)
    return np.sqrt(np.mean(np.sum(offsets * offsets, axis=-1), axis=-1))


def thesis_disk(positions: np.ndarray) -> np.ndarray:
    """The thesis's "global disk distance" as its code computed it: ``sum_j |x_0 - x_j| + |y_0 - y_j|``.

    Robot 0 (the thesis's robot 1) is the centre, so the value depends on the labelling. The printed formula,
    eq. 4.1 ``d = sum_j |(x_1 - x_j) + (y_1 - y_j)|``, adds the signed offsets before the absolute value and
    can cancel: a robot at ``(x_1 + 1, y_1 - 1)`` contributes 0. Kept only to compare with the thesis's
    figures; use ``max_pairwise`` (docs/design.md, "What the thesis got wrong").
    """
    positions = _check_positions(positions)
    return np.sum(np.abs(positions[..., :1, :] - positions), axis=(-2, -1))


METRICS: dict[str, Callable[[np.ndarray], np.ndarray]] = {
    "max_pairwise": max_pairwise,
    "spread": spread,
    "thesis_disk": thesis_disk,
}


def minimum_enclosing_circle(points: np.ndarray) -> tuple[np.ndarray, float]:
    """Exact smallest circle containing every point: ``(center (2,), radius)``.

    ``swarm.core.mec.welzl_circle`` (the one implementation of the circle and its inside tolerance,
    which the MEC controllers run too) on a fixed-seed shuffle of the points, so results are
    reproducible and expected O(N). Handles N = 1, 2, duplicates and collinear points. The returned
    radius is the largest distance from the centre to a point, so every point is inside up to rounding.
    """
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 2 or len(points) < 1:
        raise ValueError(f"points must have shape (N, 2) with N >= 1, got {points.shape}")
    if not np.all(np.isfinite(points)):
        raise ValueError("points must be finite")
    shuffled = points[np.random.default_rng(0).permutation(len(points))]
    cx, cy, _ = welzl_circle(shuffled[:, 0].tolist(), shuffled[:, 1].tolist(), len(points))
    center = np.array([cx, cy])
    radius = float(np.sqrt(np.max(np.sum((points - center) ** 2, axis=1))))
    return center, radius


def lower_bound_s(initial_positions: np.ndarray, threshold_m: float, v_max_mps: float) -> float:
    """Lower bound on the time any controller needs to bring every pairwise distance to ``threshold_m``.

    ``max(0, R_mec - threshold / sqrt(3)) / v_max``. Why: when every pairwise distance is at most
    ``threshold`` the swarm has that diameter, so by Jung's theorem it lies in a disk of radius
    ``r = threshold / sqrt(3)``, centre ``c``. Axle centres move no faster than the wheel-speed limit
    ``v_max``, so after time ``t`` every initial position is within ``r + v_max t`` of ``c``; that disk
    encloses the initial swarm, hence ``R_mec <= r + v_max t`` (docs/design.md, "Metrics").
    """
    if v_max_mps <= 0:
        raise ValueError(f"v_max_mps must be positive, got {v_max_mps}")
    if threshold_m < 0:
        raise ValueError(f"threshold_m must be non-negative, got {threshold_m}")
    _, radius_m = minimum_enclosing_circle(initial_positions)
    return max(0.0, radius_m - threshold_m / math.sqrt(3.0)) / v_max_mps


def min_gathered_max_pairwise_m(count: int, body_radius_m: float) -> float:
    """The smallest ``max_pairwise`` (m) that ``count`` round bodies of radius ``body_radius_m`` can
    reach: their centres stay ``2 r`` apart, so it is the packing limit of ``swarm.core.packing`` for a
    spacing of ``2 r``: exact for ``count <= 8`` (``packing.MIN_DIAMETER_UNIT``), a lower bound above
    (``packing_lower_bound_m``). A threshold below it can never be met with bodies (PyBullet)."""
    if count < 1 or body_radius_m < 0:
        raise ValueError(f"need count >= 1 and body_radius_m >= 0, got {count}, {body_radius_m}")
    return packing_limit_m(count, 2.0 * body_radius_m)[0]


def convergence_time(times_s: np.ndarray, values: np.ndarray, threshold: float) -> float | np.ndarray:
    """First time from which ``values <= threshold`` holds until the end; NaN if the final value is above.

    ``times_s`` ``(T,)``, ``values`` ``(..., T)`` -> float for 1-D values, else an array of shape ``(...)``.
    NaN values count as above the threshold.
    """
    times_s = np.asarray(times_s, dtype=np.float64)
    values = np.asarray(values, dtype=np.float64)
    if times_s.ndim != 1 or len(times_s) < 1 or values.ndim < 1 or values.shape[-1] != len(times_s):
        raise ValueError(
            f"need times_s (T,) with T >= 1 and values (..., T); got {times_s.shape} and {values.shape}"
        )
    above = ~(values <= threshold)
    n_steps = len(times_s)
    last_above = np.where(above.any(axis=-1), n_steps - 1 - np.argmax(above[..., ::-1], axis=-1), -1)
    start = last_above + 1
    result = np.where(start < n_steps, times_s[np.minimum(start, n_steps - 1)], np.nan)
    return float(result) if values.ndim == 1 else result


def component_results(
    times_s: np.ndarray, positions: np.ndarray, components: list[list[int]], metric: str, threshold: float
) -> list[dict]:
    """Per-component consensus results for a (possibly disconnected) graph (docs/design.md, "Results").

    ``positions`` ``(T, N, 2)``. Each entry: ``{"robots", "converged", "convergence_time_s", "final_metric"}``
    with ``convergence_time_s`` None when not converged. The metric is computed on the component's robots only
    (for ``thesis_disk`` its centre is the component's first robot). A single robot is converged at
    ``times_s[0]`` with metric 0.
    """
    if metric not in METRICS:
        raise ValueError(f"unknown metric {metric!r}; choose one of {sorted(METRICS)}")
    positions = np.asarray(positions, dtype=np.float64)
    if positions.ndim != 3 or positions.shape[-1] != 2:
        raise ValueError(f"positions must have shape (T, N, 2), got {positions.shape}")
    times_s = np.asarray(times_s, dtype=np.float64)
    results = []
    for component in components:
        robots = [int(r) for r in component]
        if len(robots) == 1:
            time_s, final_metric = float(times_s[0]), 0.0
        else:
            values = METRICS[metric](positions[:, robots, :])
            time_s, final_metric = float(convergence_time(times_s, values, threshold)), float(values[-1])
        converged = not math.isnan(time_s)
        results.append(
            {
                "robots": robots,
                "converged": converged,
                "convergence_time_s": time_s if converged else None,
                "final_metric": final_metric,
            }
        )
    return results
