"""The one enclosing circle (``swarm.core.mec.welzl_circle``) and its forms: compiled by numba for the
batched engine (``swarm.sim.mec_kernels``), shuffled and read out in numpy by
``swarm.core.metrics.minimum_enclosing_circle``. Oracle: the exact brute force of
``tests/circle_oracle.py`` (every 2- and 3-point circle, in rationals), on 10^4 adversarial swarms.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from circle_oracle import adversarial_swarm, exact_min_radius_squared, max_distance, random_tiny_swarm

from swarm.core import mec, metrics
from swarm.sim import mec_kernels

SWARMS = 10_000
EPS = 2.0**-52


def allowed_excess_m(points: np.ndarray, radius_m: float) -> float:
    """How much bigger than exact a float circle may be: a relative 1e-9, plus the rounding of a centre
    computed from coordinates of magnitude ``max |p|`` (a few ulps of it)."""
    return 1e-9 * radius_m + 64 * EPS * float(np.max(np.abs(points)))


def check_circle(points: np.ndarray, exact_radius_m: float, cx: float, cy: float, radius_m: float) -> None:
    true_max = max_distance(points, cx, cy)  # every point inside the circle returned, up to its rounding
    assert true_max <= radius_m * (1 + 4 * EPS), (points.tolist(), radius_m, true_max)
    # and the circle is the smallest: never below the exact one (up to the rounding of the readout) ...
    assert radius_m >= exact_radius_m * (1 - 4 * EPS), (points.tolist(), radius_m, exact_radius_m)
    # ... nor above it beyond rounding
    assert radius_m <= exact_radius_m + allowed_excess_m(points, exact_radius_m), (
        points.tolist(),
        radius_m,
        exact_radius_m,
    )


def swarms() -> list[np.ndarray]:
    rng = np.random.default_rng(18)
    adversarial = [adversarial_swarm(rng) for _ in range(SWARMS - 1000)]
    return adversarial + [random_tiny_swarm(rng) for _ in range(1000)]


@pytest.fixture(scope="module")
def swarms_and_exact_radii() -> list[tuple[np.ndarray, float]]:
    return [(points, math.sqrt(exact_min_radius_squared(points))) for points in swarms()]


def test_the_swarms_are_adversarial(swarms_and_exact_radii):
    """What the 10^4 swarms hold: all sizes 1..7, repeated points, tiny and far from the origin."""
    sizes = {len(points) for points, _ in swarms_and_exact_radii}
    assert set(range(1, 8)) <= sizes
    assert sum(len(np.unique(p, axis=0)) < len(p) for p, _ in swarms_and_exact_radii) > 2000
    assert sum(float(np.max(np.abs(p))) > 100 for p, _ in swarms_and_exact_radii) > 1000
    assert all(r <= 1e-4 for _, r in swarms_and_exact_radii)


def test_welzl_circle_is_the_exact_circle(swarms_and_exact_radii):
    for points, exact in swarms_and_exact_radii:
        cx, cy, radius = mec.welzl_circle(points[:, 0].tolist(), points[:, 1].tolist(), len(points))
        check_circle(points, exact, cx, cy, radius)


def test_compiled_circle_is_the_same_to_the_bit(swarms_and_exact_radii):
    """The batched engine's circle (numba, no fastmath) equals the agents' (Python floats)."""
    for points, _ in swarms_and_exact_radii:
        xs, ys = points[:, 0].copy(), points[:, 1].copy()
        compiled = mec_kernels.welzl_circle(xs, ys, len(points))
        assert compiled == mec.welzl_circle(xs.tolist(), ys.tolist(), len(points)), points.tolist()


def test_metrics_circle_is_the_exact_circle(swarms_and_exact_radii):
    for points, exact in swarms_and_exact_radii:
        centre, radius = metrics.minimum_enclosing_circle(points)
        check_circle(points, exact, float(centre[0]), float(centre[1]), radius)


def test_the_flood_regression_input_anywhere():
    """99bdc36's input (two points 1e-5 m apart, one repeated ten times) shifted far from the origin,
    in the order the flood hands its support points over: radius 5e-6 m everywhere."""
    points = np.full((11, 2), 1e-5)
    points[0] = [0.0, 1e-5]
    for shift in (0.0, 2.0, 1e3):
        moved = points + shift
        _, _, radius = mec_kernels.welzl_circle(moved[:, 0].copy(), moved[:, 1].copy(), len(moved))
        assert radius == pytest.approx(5e-6, rel=1e-6)
