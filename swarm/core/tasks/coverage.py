"""Coverage (``task: coverage``): N robots spread over a region in proportion to a density.

The region is a polygon and the density ``phi`` is uniform on it or a mixture of Gaussians, both public
(every robot knows them). The metric is the locational cost of Cortes, Martinez, Karatas and Bullo
(2004), on a fixed quadrature grid (:meth:`CoverageSection.quadrature`):

    H(p) = integral over the region of min_i |q - p_i|^2 phi(q) dq  ~  sum_g w_g min_i |q_g - p_i|^2,

with ``phi`` normalised to integrate to 1 over the region, so that H is a mean squared distance (m^2)
from a point drawn from the density to its nearest robot (:func:`locational_cost`). The robots' axles
are what is judged.

Reference (:func:`reference_cost`): the least H that centralized Lloyd reaches from
``reference_restarts`` k-means++ starts (seeded by ``reference_seed``), each iterated to a fixed point.
This is a *reference, not a bound*: Lloyd finds centroidal Voronoi configurations, which are local
minima of H, and a run may end below it (its ratio under 1). Success: ``H / H_ref <= 1 + tolerance``
from some time to the end of the run, held ``hold_s``.

Lloyd's map (:func:`lloyd_centroids`): every robot's target is the centroid of its Voronoi cell under
the density (the gradient of H is ``2 M_i (p_i - C_i)``, Cortes et al. eq. 5). A robot whose cell holds
no mass (every quadrature point is nearer another robot, or it is out of its cell radius) takes the
density's centroid as its target, which every robot knows, so that no robot is stranded.
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
from pydantic import Field, field_validator, model_validator

from swarm.core.initial_poses import random_poses
from swarm.core.tasks.registry import StrictSection, SweepCells, Task, register, settle_time

FRAMES_PER_CHUNK = 32
"""Frames of a trajectory whose costs are one matrix-vector product (:func:`locational_cost`). Part of
the result's bits: the product's rounding may depend on its shape, so this stays 32."""

FRAMES_PER_PASS = 4
"""Frames whose distances :func:`locational_cost` takes at once (its temporaries stay small); any value
gives the same bits."""

POINTS_PER_BLOCK = 64
"""Quadrature points per block of :func:`locational_cost`'s candidate robots; any value gives the same
bits."""


class Gaussian(StrictSection):
    """One component of the density: weight times the normal density of ``mean``, ``sigma_m``."""

    mean: tuple[float, float]
    sigma_m: float = Field(gt=0)
    weight: float = Field(1.0, gt=0)


def _default_region() -> list[tuple[float, float]]:
    return [(-2.0, -2.0), (2.0, -2.0), (2.0, 2.0), (-2.0, 2.0)]


class CoverageSection(StrictSection):
    """``task: {kind: coverage, region: [[x, y], ...], gaussians: [...], tolerance: 0.05}``."""

    kind: Literal["coverage"] = "coverage"
    region: list[tuple[float, float]] = Field(
        default_factory=_default_region, min_length=3, description="polygon vertices in order (m)"
    )
    gaussians: list[Gaussian] = Field(default_factory=list, description="the density; empty: uniform")
    grid_per_axis: int = Field(48, ge=8, le=400, description="quadrature cells along the longer side")
    tolerance: float = Field(0.05, gt=0, description="success: H <= (1 + tolerance) H_ref")
    hold_s: float = Field(2.0, ge=0, description="success must hold this long, to the end of the run")
    reference_restarts: int = Field(16, ge=1, le=256, description="Lloyd restarts of the reference")
    reference_seed: int = Field(0, ge=0)

    @field_validator("region")
    @classmethod
    def _region_has_area(cls, region: list[tuple[float, float]]) -> list[tuple[float, float]]:
        if polygon_area(np.asarray(region, dtype=np.float64)) <= 0.0:
            raise ValueError("the polygon has no area (give its vertices in order)")
        return region

    @model_validator(mode="after")
    def _quadrature_not_empty(self) -> CoverageSection:
        points, _ = quadrature(self)
        if len(points) == 0:
            raise ValueError("region: no quadrature point falls inside the polygon; raise grid_per_axis")
        return self

    def quadrature(self) -> tuple[np.ndarray, np.ndarray]:
        """``(G, 2)`` points and ``(G,)`` weights summing to 1 (:func:`quadrature`)."""
        return quadrature(self)


def polygon_area(vertices: np.ndarray) -> float:
    """The polygon's area (shoelace formula, absolute value)."""
    x, y = vertices[:, 0], vertices[:, 1]
    return 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))


def inside_polygon(points: np.ndarray, vertices: np.ndarray) -> np.ndarray:
    """``(G,)`` bool: is each point inside the polygon (even-odd rule: crossings of a ray to +x)."""
    x, y = points[:, 0:1], points[:, 1:2]
    x0, y0 = vertices[:, 0], vertices[:, 1]
    x1, y1 = np.roll(x0, -1), np.roll(y0, -1)
    straddles = (y0 > y) != (y1 > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        crossing_x = x0 + (y - y0) * (x1 - x0) / (y1 - y0)
    return (np.count_nonzero(straddles & (x < crossing_x), axis=1) % 2) == 1


def density(points: np.ndarray, gaussians: list[Gaussian]) -> np.ndarray:
    """``phi`` at the points, unnormalised: 1 (uniform) or ``sum_k w_k N(q; mean_k, sigma_k^2 I)``."""
    if not gaussians:
        return np.ones(len(points))
    value = np.zeros(len(points))
    for component in gaussians:
        squared = ((points - np.asarray(component.mean)) ** 2).sum(-1)
        variance = component.sigma_m**2
        value += component.weight * np.exp(-0.5 * squared / variance) / (2.0 * math.pi * variance)
    return value


_QUADRATURES: dict[str, tuple[np.ndarray, np.ndarray]] = {}


def quadrature(section: CoverageSection) -> tuple[np.ndarray, np.ndarray]:
    """The midpoint rule: square cells of side ``h = (longer side of the bounding box) / grid_per_axis``,
    the centres inside the polygon, each weighted ``phi(q) h^2`` and normalised to sum 1. Cached per
    section."""
    key = section.model_dump_json(include={"region", "gaussians", "grid_per_axis"})
    if key not in _QUADRATURES:
        vertices = np.asarray(section.region, dtype=np.float64)
        low, high = vertices.min(axis=0), vertices.max(axis=0)
        side_m = float((high - low).max()) / section.grid_per_axis
        xs = np.arange(low[0] + side_m / 2, high[0], side_m)
        ys = np.arange(low[1] + side_m / 2, high[1], side_m)
        grid = np.stack(np.meshgrid(xs, ys, indexing="xy"), axis=-1).reshape(-1, 2)
        points = grid[inside_polygon(grid, vertices)]
        weights = density(points, section.gaussians)
        total = weights.sum()
        weights = weights / total if total > 0 else weights
        points.setflags(write=False)
        weights.setflags(write=False)
        _QUADRATURES[key] = (points, weights)
    return _QUADRATURES[key]


def density_centroid(points: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """``(2,)`` the centre of mass of the density (where a robot with an empty cell heads)."""
    return weights @ points


def _point_blocks(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(members, low, high)``: the quadrature points cut into square-ish blocks of about
    ``POINTS_PER_BLOCK``, ``members (B, P)`` the indices of each nonempty block's points (a short block
    padded with its first point), ``low, high (B, 2)`` the corners of its points' bounding box."""
    side = max(1, round(math.sqrt(len(points) / POINTS_PER_BLOCK)))
    corner = points.min(axis=0)
    size = np.maximum((points.max(axis=0) - corner) / side, np.finfo(float).tiny)
    ij = np.minimum(((points - corner) / size).astype(np.int64), side - 1)
    block = ij[:, 1] * side + ij[:, 0]
    order = np.argsort(block, kind="stable")
    counts = np.bincount(block, minlength=side * side)
    counts = counts[counts > 0]
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    slot = np.minimum(np.arange(counts.max())[None, :], counts[:, None] - 1)  # (B, P): past the end, the last
    members = order[starts[:, None] + slot]
    return members, points[members].min(axis=1), points[members].max(axis=1)


def locational_cost(positions: np.ndarray, points: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """``H`` of each configuration ``(..., N, 2)`` (module docstring), in m^2; shape ``(...)``.

    ``sum_g w_g min_i ((x_g - x_i)^2 + (y_g - y_i)^2)``, the minimum over fewer robots. The points are
    cut into blocks (:func:`_point_blocks`); per block, a pivot robot (the nearest to the box's centre)
    and the candidates: the robots ``j`` with ``|c - p_j|^2 - |c - p_pivot|^2 <= 1e-9 S`` at some corner
    ``c`` of the block's box (``S`` the largest sum of the two over the corners). That difference is
    linear in ``c``, so a robot left out is farther than the pivot from every point of the box by more
    than ``1e-9 S``, a million times the rounding of the distances: as computed, too. Each distance of a
    candidate is the expression's, so each minimum is the one over every robot, bit for bit; each chunk
    of ``FRAMES_PER_CHUNK`` frames is then one matrix-vector product. At N = 100 on the sweep's grid a
    block has about 4 candidates, not 100 (``bench/results/coverage_cost.md``; ``tests/test_coverage.py``
    holds it to the plain expression, on ties and on robots apart by ulps). A non-finite position is
    every block's candidate, so it reaches the cost as in the expression."""
    positions = np.asarray(positions, dtype=np.float64)
    flat = positions.reshape(-1, *positions.shape[-2:])
    cost = np.empty(len(flat))
    if flat.shape[1] == 0 or len(points) == 0:  # no robot: every point infinitely far; no point: 0
        cost[:] = np.inf if len(points) else 0.0
        return cost.reshape(positions.shape[:-2])
    members, low, high = _point_blocks(points)
    member_x, member_y = points[members, 0], points[members, 1]  # (B, P)
    centre_x, centre_y = (
        0.5 * (low[None, :, 0:1] + high[None, :, 0:1]),
        0.5 * (low[None, :, 1:2] + high[None, :, 1:2]),
    )
    corners = [
        (low[None, :, 0:1], low[None, :, 1:2]),
        (low[None, :, 0:1], high[None, :, 1:2]),
        (high[None, :, 0:1], low[None, :, 1:2]),
        (high[None, :, 0:1], high[None, :, 1:2]),
    ]
    nearest_buffer = np.empty((min(len(flat), FRAMES_PER_CHUNK), len(points)))
    for start in range(0, len(flat), FRAMES_PER_CHUNK):
        chunk = flat[start : start + FRAMES_PER_CHUNK]
        nearest = nearest_buffer[: len(chunk)]
        for first in range(0, len(chunk), FRAMES_PER_PASS):
            part = chunk[first : first + FRAMES_PER_PASS]
            robot_x, robot_y = part[:, None, :, 0], part[:, None, :, 1]  # (F, 1, N) against blocks (1, B, 1)
            # the pivot: the robot nearest the block's centre; the candidates: whoever its bisector with
            # the pivot lets nearer at some corner (the pivot itself included, so no block is empty)
            pivot = ((centre_x - robot_x) ** 2 + (centre_y - robot_y) ** 2).argmin(axis=-1)  # (F, B)
            pivot_x = np.take_along_axis(robot_x[:, 0], pivot, -1)[..., None]
            pivot_y = np.take_along_axis(robot_y[:, 0], pivot, -1)[..., None]
            candidate = np.zeros(np.broadcast_shapes(robot_x.shape, centre_x.shape), dtype=bool)
            lead, scale = [], np.zeros(candidate.shape)
            for corner_x, corner_y in corners:
                theirs = (corner_x - robot_x) ** 2 + (corner_y - robot_y) ** 2
                pivots = (corner_x - pivot_x) ** 2 + (corner_y - pivot_y) ** 2
                with np.errstate(invalid="ignore"):  # inf - inf where robots are at infinity: candidates
                    lead.append(theirs - pivots)
                np.maximum(scale, theirs + pivots, out=scale)
            for difference in lead:
                candidate |= (difference <= 1e-9 * scale) | ~np.isfinite(difference)
            # one row per (frame, block, candidate), in (frame, block) groups that each hold the pivot
            frame, block, robot = np.nonzero(candidate)
            dx = member_x[block] - part[frame, robot, 0:1]  # (M, P): point minus robot, as the expression
            dy = member_y[block] - part[frame, robot, 1:2]
            np.multiply(dx, dx, out=dx)
            np.multiply(dy, dy, out=dy)
            np.add(dx, dy, out=dx)
            group = np.flatnonzero(np.diff(frame * len(members) + block, prepend=-1))
            block_nearest = np.minimum.reduceat(dx, group, axis=0)  # (F B, P)
            nearest[first : first + len(part)][:, members.ravel()] = block_nearest.reshape(len(part), -1)
        cost[start : start + len(chunk)] = nearest @ weights
    return cost.reshape(positions.shape[:-2])


def lloyd_centroids(positions: np.ndarray, points: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """``(N, 2)`` the centroid of each robot's Voronoi cell under the density (ties: the lowest robot
    index), the density's centroid for an empty cell: one step of Lloyd's map."""
    delta = points[:, None, :] - positions[None, :, :]
    owner = (delta * delta).sum(-1).argmin(axis=1)  # (G,)
    count = len(positions)
    mass = np.bincount(owner, weights, minlength=count)
    moment = np.stack([np.bincount(owner, weights * points[:, axis], minlength=count) for axis in (0, 1)], -1)
    fallback = density_centroid(points, weights)
    safe = np.where(mass > 0.0, mass, 1.0)[:, None]
    return np.where(mass[:, None] > 0.0, moment / safe, fallback)


def lloyd(
    positions: np.ndarray,
    points: np.ndarray,
    weights: np.ndarray,
    max_iterations: int = 2000,
    tolerance_m: float = 1e-10,
) -> np.ndarray:
    """Lloyd's algorithm from ``positions`` to a fixed point (largest move under ``tolerance_m``)."""
    current = np.asarray(positions, dtype=np.float64)
    for _ in range(max_iterations):
        following = lloyd_centroids(current, points, weights)
        moved = float(np.abs(following - current).max(initial=0.0))
        current = following
        if moved < tolerance_m:
            break
    return current


def kmeans_plus_plus(
    points: np.ndarray, weights: np.ndarray, count: int, rng: np.random.Generator
) -> np.ndarray:
    """``(count, 2)`` seeds drawn from the quadrature points by k-means++ (Arthur and Vassilvitskii 2007),
    with the density as the points' weights."""
    chosen = [int(rng.choice(len(points), p=weights))]
    nearest = ((points - points[chosen[0]]) ** 2).sum(-1)
    for _ in range(1, count):
        score = weights * nearest
        total = score.sum()
        index = int(rng.choice(len(points), p=score / total)) if total > 0 else int(rng.integers(len(points)))
        chosen.append(index)
        nearest = np.minimum(nearest, ((points - points[index]) ** 2).sum(-1))
    return points[chosen].astype(np.float64)


_REFERENCES: dict[tuple[str, int], tuple[float, np.ndarray]] = {}


def reference(section: CoverageSection, count: int) -> tuple[float, np.ndarray]:
    """``(H_ref, positions (N, 2))``: the best fixed point of centralized Lloyd over the section's
    restarts (module docstring: a reference, not a bound). Cached per section and N."""
    key = (section.model_dump_json(exclude={"tolerance", "hold_s"}), int(count))
    if key not in _REFERENCES:
        points, weights = section.quadrature()
        rng = np.random.default_rng(section.reference_seed)
        best_cost, best = math.inf, np.zeros((count, 2))
        for _ in range(section.reference_restarts):
            fixed = lloyd(kmeans_plus_plus(points, weights, count, rng), points, weights)
            cost = float(locational_cost(fixed, points, weights))
            if cost < best_cost:
                best_cost, best = cost, fixed
        _REFERENCES[key] = (best_cost, best)
    return _REFERENCES[key]


def reference_cost(section: CoverageSection, count: int) -> float:
    """``H_ref`` (m^2): the least locational cost centralized Lloyd reaches over the section's restarts
    (:func:`reference`). A reference, not a bound: Lloyd's fixed points are local minima of H."""
    return reference(section, count)[0]


def ratio_series(positions: np.ndarray, section: CoverageSection) -> np.ndarray:
    """``(T,)`` ``H / H_ref`` of each frame of ``positions (T, N, 2)``."""
    points, weights = section.quadrature()
    count = np.asarray(positions).shape[1]
    return locational_cost(positions, points, weights) / reference_cost(section, count)


REPORT_TIMES_S = (5.0, 10.0, 20.0, 40.0)
"""The times at which ``outcome`` reports ``H / H_ref`` (those within the run)."""


def outcome(times_s: np.ndarray, positions: np.ndarray, section: CoverageSection, v_max_mps: float) -> dict:
    """The task's results from the axle positions ``(T, N, 2)``: ``H / H_ref`` at the start, the end and
    the report times; success (``converged``: within ``1 + tolerance`` held ``hold_s`` to the end) and
    its time; the first time within it (held or not); H and H_ref in m^2."""
    positions = np.asarray(positions, dtype=np.float64)
    times_s = np.asarray(times_s, dtype=np.float64)
    h_ref = reference_cost(section, positions.shape[1])
    ratio = ratio_series(positions, section)
    within = ratio <= 1.0 + section.tolerance
    time_s = settle_time(times_s, within, section.hold_s)
    first = np.flatnonzero(within)
    return {
        "metric": "coverage_ratio",
        "unit": "",
        "threshold": 1.0 + section.tolerance,
        "converged": time_s is not None,
        "convergence_time_s": time_s,
        "hold_s": section.hold_s,
        "initial_metric": float(ratio[0]),
        "final_metric": float(ratio[-1]),
        "first_within_s": float(times_s[first[0]]) if len(first) else None,
        "ratio_at_s": {
            f"{t:g}": float(np.interp(t, times_s, ratio)) for t in REPORT_TIMES_S if t <= times_s[-1]
        },
        "coverage_cost_m2": float(ratio[-1] * h_ref),
        "reference_cost_m2": h_ref,
        "lower_bound_s": None,
        "ratio_to_lower_bound": None,
    }


def sweep_side_m(count: int) -> float:
    """The side of a sweep cell's square: 0.9 sqrt(N) m (about 0.8 m^2 a robot)."""
    return 0.9 * math.sqrt(count)


QUADRATURE_POINTS_PER_ROBOT = 100
"""How many quadrature points a sweep cell gives each robot (at least; :func:`sweep_grid_per_axis`).
Why: Lloyd's map on the grid is k-means on its points, and a cell of a few points has a fixed point
where a continuous cell would still move (moving the robot a little moves no point across its cell's
boundary). Measured (``bench/results/lloyd_quadrature.md``): from the one-corner starts at N = 100,
Lloyd at full speed stopped at 1.32-1.33 H_ref with 48 points a side (23 a robot) and ended at
1.05-1.06 with 100 a side."""


def sweep_grid_per_axis(count: int) -> int:
    """``max(48, ceil(sqrt(QUADRATURE_POINTS_PER_ROBOT N)))``: the section's default (48) up to N = 23,
    49 at 24, 71 at 50, 100 at 100."""
    default = CoverageSection.model_fields["grid_per_axis"].default
    return max(default, math.ceil(math.sqrt(QUADRATURE_POINTS_PER_ROBOT * count)))


def sweep_section(count: int) -> CoverageSection:
    """A sweep cell: the uniform density on a square of side :func:`sweep_side_m` centred at the origin
    (``bench/coverage_kinematic.py``'s uniform cells), on :func:`sweep_grid_per_axis` points a side."""
    half = sweep_side_m(count) / 2
    return CoverageSection(
        region=[(-half, -half), (half, -half), (half, half), (-half, half)],
        grid_per_axis=sweep_grid_per_axis(count),
    )


def sweep_starts(rng: np.random.Generator, number: int, count: int) -> np.ndarray:
    """Every robot in the square's lower-left quadrant, 0.3 m apart: a deployment from one corner."""
    half = sweep_side_m(count) / 2
    return random_poses(rng, number, count, (-half, 0.0), (-half, 0.0), 0.3)


COVERAGE = register(
    Task(
        name="coverage",
        summary="spread over a region by a density (least locational cost H)",
        section=CoverageSection,
        knows="its own pose, the public region and density, and what its heard neighbours sent last tick",
        experts=("lloyd",),
        baselines=("lloyd_local", "lloyd_flood", "lloyd_predict"),
        learned=("lloyd_gnn",),
        metric="coverage_ratio: H / H_ref, H the locational cost on the quadrature grid (m^2)",
        success="H <= (1 + tolerance) H_ref from some time to the end, held hold_s",
        bound="reference",
        bound_s=None,
        reference=reference_cost,
        series=ratio_series,
        reward="swarm.rl.coverage_v0:CoverageParallelEnv.step",
        plot="swarm.scenarios.task_report:coverage_pictures",
        outcome=outcome,
        sweep=SweepCells(
            section=sweep_section,
            starts=sweep_starts,
            duration_s=60.0,
            columns=(
                *(f"ratio_at_s.{t:g}" for t in REPORT_TIMES_S),
                "final_metric",
                "first_within_s",
            ),
            sample_every_ticks=5,
        ),
    )
)
