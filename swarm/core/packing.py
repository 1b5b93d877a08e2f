"""How tightly N bodies can gather: a hexagonal packing to aim at, and a lower bound on any packing.

A swarm of bodies that must keep ``D`` apart (centre to centre) cannot gather to a point; the smallest
``max_pairwise`` it can reach is the *packing limit* ``W*(N) D``: the least diameter of N points in the
plane with every pair at least ``D`` apart. This module gives both sides of it:

* :func:`hex_packing` (above it): the N points of the triangular lattice of spacing ``D`` nearest a
  centre, for the centre on a lattice point, a triangle's centroid or an edge's midpoint, or a ring
  (a regular N-gon of side ``D``, or a regular (N-1)-gon around one point at its centre, circumradius at
  least ``D``), whichever set has the least diameter; returned centred on its own minimum enclosing
  circle. Its diameter is what a controller aiming at it can reach.
* :func:`packing_lower_bound_m` (below it): points at mutual distance >= 1 in a convex set K number at
  most ``2 A(K) / sqrt(3) + P(K) / 2 + 1`` (Groemer 1960, Oler 1961). The convex hull of N such points
  of diameter W has area at most ``pi W^2 / 4`` (the isodiametric inequality) and perimeter at most
  ``pi W`` (Rosenthal-Szasz), so ``N <= (pi / (2 sqrt 3)) W^2 + (pi / 2) W + 1``: W is at least the
  positive root, and at least 1 for N >= 2.

For small N the optimum is known and lies between the two (N = 6: ``W* = 2 sin 72 deg = 1.902``, the
pentagon around a centre found here, the lattice's best 2.0, the bound 1.64).
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

from swarm.core.mec import welzl_circle

MIN_DIAMETER_UNIT = {
    1: 0.0,
    2: 1.0,
    3: 1.0,
    4: math.sqrt(2.0),  # a square
    5: (1 + math.sqrt(5.0)) / 2,  # a regular pentagon (its diagonal)
    6: 2 * math.sin(2 * math.pi / 5),  # a pentagon of unit circumradius and its centre
    7: 2.0,  # a hexagon and its centre
    8: 1 / (2 * math.sin(math.pi / 14)),  # a heptagon and its centre
}
"""The packing limit ``W*(n)`` of points at mutual distance >= 1, known exactly for small ``n``
(Bateman and Erdos 1951; Bezdek and Fodor 1999)."""

_LATTICE_OFFSETS = ((0.0, 0.0), (0.5, math.sqrt(3.0) / 6.0), (0.5, 0.0))
"""Centres tried, in lattice units: a lattice point, the centroid of a triangle, an edge's midpoint."""


def diameter(points: np.ndarray) -> float:
    """Largest distance between two of ``points (N, 2)`` (0 for fewer than two)."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    if len(points) < 2:
        return 0.0
    gaps = points[:, None, :] - points[None, :, :]
    return float(np.sqrt((gaps * gaps).sum(-1)).max())


def _rings(count: int) -> list[np.ndarray]:
    """A regular ``count``-gon of side 1, and a regular ``count - 1``-gon of circumradius
    ``max(1, 1 / (2 sin(pi / (count - 1))))`` around a point at its centre."""
    rings = []
    for corners, centre in ((count, False), (count - 1, True)):
        if corners < 3:
            continue
        radius = 1.0 / (2.0 * math.sin(math.pi / corners))
        if centre:
            radius = max(1.0, radius)
        angles = 2.0 * math.pi * np.arange(corners) / corners
        ring = np.stack([radius * np.cos(angles), radius * np.sin(angles)], axis=-1)
        rings.append(np.vstack([np.zeros((1, 2)), ring]) if centre else ring)
    return rings


@lru_cache(maxsize=64)
def _unit_hex(count: int) -> tuple[tuple[float, float], ...]:
    reach = math.isqrt(count) + 3
    i, j = np.meshgrid(np.arange(-reach, reach + 1), np.arange(-reach, reach + 1), indexing="ij")
    lattice = np.stack([i + 0.5 * j, (math.sqrt(3.0) / 2.0) * j], axis=-1).reshape(-1, 2).astype(np.float64)
    best: np.ndarray | None = None
    for offset in _LATTICE_OFFSETS:
        shifted = lattice - np.asarray(offset)
        radius = np.round(np.hypot(shifted[:, 0], shifted[:, 1]), 9)
        angle = np.round(np.arctan2(shifted[:, 1], shifted[:, 0]), 9)
        chosen = shifted[np.lexsort((angle, radius))[:count]]  # nearest first, ties by angle
        if best is None or diameter(chosen) < diameter(best) - 1e-9:
            best = chosen
    for ring in _rings(count):
        if best is None or diameter(ring) < diameter(best) - 1e-9:
            best = ring
    assert best is not None
    cx, cy, _ = welzl_circle(best[:, 0].tolist(), best[:, 1].tolist(), count)
    return tuple((float(x - cx), float(y - cy)) for x, y in best)


def hex_packing(count: int, spacing_m: float) -> np.ndarray:
    """``(count, 2)``: the hexagonal set of the module docstring, spacing ``spacing_m``, centred on its
    minimum enclosing circle's centre (the origin)."""
    if count < 1:
        raise ValueError(f"count must be >= 1, got {count}")
    if not spacing_m > 0:
        raise ValueError(f"spacing_m must be > 0, got {spacing_m}")
    return np.array(_unit_hex(int(count)), dtype=np.float64).reshape(-1, 2) * float(spacing_m)


def packing_limit_m(count: int, spacing_m: float) -> tuple[float, float]:
    """``(low, high)`` around the packing limit of ``count`` points ``spacing_m`` apart: both the exact
    value for ``count <= 8`` (``MIN_DIAMETER_UNIT``); above, :func:`packing_lower_bound_m` and the
    diameter of :func:`hex_packing`."""
    if count in MIN_DIAMETER_UNIT:
        exact = MIN_DIAMETER_UNIT[count] * float(spacing_m)
        return exact, exact
    return packing_lower_bound_m(count, spacing_m), diameter(hex_packing(count, spacing_m))


def packing_lower_bound_m(count: int, spacing_m: float) -> float:
    """A lower bound on the packing limit: the least ``max_pairwise`` of ``count`` points at least
    ``spacing_m`` apart (module docstring: the root of ``(pi / (2 sqrt 3)) W^2 + (pi / 2) W + 1 - N``)."""
    if count < 2:
        return 0.0
    a, b, c = math.pi / (2.0 * math.sqrt(3.0)), math.pi / 2.0, 1.0 - count
    root = (-b + math.sqrt(b * b - 4.0 * a * c)) / (2.0 * a)
    return max(1.0, root) * float(spacing_m)
