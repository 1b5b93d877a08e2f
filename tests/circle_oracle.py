"""An exact oracle for the smallest enclosing circle, and adversarial swarms to hold it against.

The oracle knows nothing of Welzl's algorithm: the smallest enclosing circle of a finite set is the
smallest of the circles through two points (as a diameter) or three (circumscribed) that contains
every point, so it tries them all, in exact rational arithmetic on the float coordinates as given
(``fractions.Fraction`` is exact on every float). O(n^4): for small swarms only.

The swarms are what broke the floating-point circle: tiny (1e-6..1e-4 m across), far from the origin
(up to 1e3 m), with repeated points, collinear points, points on a lattice or on one circle (ties),
of 1 to ``max_count`` points.
"""

from __future__ import annotations

import math
from fractions import Fraction
from itertools import combinations

import numpy as np

KINDS = ("uniform", "duplicates", "collinear", "lattice", "cocircular")


def exact_min_radius_squared(points: np.ndarray) -> Fraction:
    """The exact squared radius of the smallest circle containing ``points`` ``(n, 2)``."""
    pts = [(Fraction(float(x)), Fraction(float(y))) for x, y in points]
    distinct = list(dict.fromkeys(pts))
    if len(distinct) == 1:
        return Fraction(0)
    candidates: list[tuple[Fraction, Fraction, Fraction]] = []  # (r^2, cx, cy)
    for (ax, ay), (bx, by) in combinations(distinct, 2):
        cx, cy = (ax + bx) / 2, (ay + by) / 2
        candidates.append(((ax - cx) ** 2 + (ay - cy) ** 2, cx, cy))
    for (ax, ay), (bx, by), (qx, qy) in combinations(distinct, 3):
        ux, uy, vx, vy = bx - ax, by - ay, qx - ax, qy - ay
        det = 2 * (ux * vy - uy * vx)
        if det == 0:  # collinear: a pair's circle covers them
            continue
        u2, v2 = ux * ux + uy * uy, vx * vx + vy * vy
        ox, oy = (vy * u2 - uy * v2) / det, (ux * v2 - vx * u2) / det
        candidates.append((ox * ox + oy * oy, ax + ox, ay + oy))
    for r2, cx, cy in sorted(candidates, key=lambda c: c[0]):
        if all((x - cx) ** 2 + (y - cy) ** 2 <= r2 for x, y in distinct):
            return r2
    raise AssertionError("no candidate circle contains every point")  # cannot happen


def max_distance(points: np.ndarray, cx: float, cy: float) -> float:
    """Largest distance from ``(cx, cy)`` to a point, exactly rounded once (the true distance)."""
    fx, fy = Fraction(cx), Fraction(cy)
    d2 = max((Fraction(float(x)) - fx) ** 2 + (Fraction(float(y)) - fy) ** 2 for x, y in points)
    return math.sqrt(d2)


def adversarial_swarm(rng: np.random.Generator, max_count: int = 7) -> np.ndarray:
    """One swarm ``(n, 2)``, ``1 <= n <= max_count``: a kind of :data:`KINDS`, 1e-6..1e-4 m across,
    centred within 1e3 m of the origin (a third of them on an axis or at the origin itself)."""
    count = int(rng.integers(1, max_count + 1))
    kind = KINDS[int(rng.integers(len(KINDS)))]
    extent = 10.0 ** rng.uniform(-6, -4)
    if kind == "uniform":
        local = rng.uniform(-0.5, 0.5, (count, 2)) * extent
    elif kind == "duplicates":
        distinct = rng.uniform(-0.5, 0.5, (int(rng.integers(1, 4)), 2)) * extent
        local = distinct[rng.integers(len(distinct), size=count)]
    elif kind == "collinear":
        angle = rng.choice([0.0, math.pi / 2, math.pi / 4, rng.uniform(0, math.pi)])
        along = rng.uniform(-0.5, 0.5, count) * extent
        local = np.stack([along * math.cos(angle), along * math.sin(angle)], axis=1)
    elif kind == "lattice":
        local = rng.integers(-2, 3, (count, 2)) * (extent / 4)
    else:
        angles = rng.integers(0, 8, count) * (math.pi / 4) + rng.choice([0.0, rng.uniform(0, math.pi)])
        local = 0.5 * extent * np.stack([np.cos(angles), np.sin(angles)], axis=1)
    where = rng.integers(3)
    centre = 10.0 ** rng.uniform(-3, 3) * rng.choice([-1.0, 1.0], 2)
    if where == 1:
        centre[int(rng.integers(2))] = 0.0
    elif where == 2 and rng.uniform() < 0.3:
        centre[:] = 0.0
    return centre + local


def random_tiny_swarm(rng: np.random.Generator, directions: int = 16) -> np.ndarray:
    """The measurement of issue 18, as ``mec_flood`` sees a swarm: 2..16 robots uniform in a 10 um square
    centred uniformly within 10 m of the origin, given by their ``directions`` support points (the robot
    of largest ``<p, d_m>`` per direction ``d_m``: repeated points, in the flood's order)."""
    count = int(rng.integers(2, 17))
    robots = rng.uniform(-10.0, 10.0, 2) + rng.uniform(0.0, 1e-5, (count, 2))
    angles = 2 * np.pi * np.arange(directions) / directions
    return robots[np.argmax(robots @ np.stack([np.cos(angles), np.sin(angles)]), axis=0)]
