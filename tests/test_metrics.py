"""Tests for swarm.core.metrics: metrics, minimum enclosing circle, lower bound, convergence time."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from swarm.core.metrics import (
    METRICS,
    component_results,
    convergence_time,
    lower_bound_s,
    max_pairwise,
    minimum_enclosing_circle,
    spread,
    thesis_disk,
)

coordinates = st.floats(-10.0, 10.0, allow_nan=False, allow_infinity=False)


def swarms(min_robots: int = 1, max_robots: int = 12):
    return st.integers(min_robots, max_robots).flatmap(
        lambda n: arrays(np.float64, (n, 2), elements=coordinates)
    )


# ---------------------------------------------------------------- metrics, hand-computed


HAND_SWARM = np.array([[0.0, 0.0], [1.0, 2.0], [-3.0, 1.0], [2.0, -2.0]])


def test_thesis_disk_by_hand():
    # Robot 0 at the origin: (|1|+|2|) + (|-3|+|1|) + (|2|+|-2|) = 3 + 4 + 4 = 11.
    assert thesis_disk(HAND_SWARM) == pytest.approx(11.0)
    # The printed eq. 4.1, sum |(x1-xj)+(y1-yj)|, gives |-3| + |2| + |0| = 5: robot 3 cancels out.
    printed = np.sum(np.abs((HAND_SWARM[0, 0] - HAND_SWARM[:, 0]) + (HAND_SWARM[0, 1] - HAND_SWARM[:, 1])))
    assert printed == pytest.approx(5.0)
    # The centre is robot 0, so relabelling which robot is first changes the value:
    # centre (1, 2): (1+2) + (4+1) + (1+4) = 13.
    assert thesis_disk(HAND_SWARM[[1, 0, 2, 3]]) == pytest.approx(13.0)


def test_max_pairwise_and_spread_by_hand():
    # Farthest pair: (-3, 1) and (2, -2): sqrt(25 + 9).
    assert max_pairwise(HAND_SWARM) == pytest.approx(math.sqrt(34.0))
    # Centroid (0, 0.25); squared distances 0.0625, 4.0625, 9.5625, 9.0625; mean 5.6875.
    assert spread(HAND_SWARM) == pytest.approx(math.sqrt(5.6875))
    single = np.array([[3.0, 4.0]])
    assert max_pairwise(single) == 0.0 and spread(single) == 0.0 and thesis_disk(single) == 0.0


@pytest.mark.parametrize("name", sorted(METRICS))
def test_metrics_batched_equal_looped(name):
    metric = METRICS[name]
    positions = np.random.default_rng(1).normal(size=(5, 3, 7, 2))
    batched = metric(positions)
    assert batched.shape == (5, 3)
    looped = np.array([[metric(positions[a, b]) for b in range(3)] for a in range(5)])
    np.testing.assert_allclose(batched, looped, rtol=1e-12)


def test_metrics_registry():
    assert {"max_pairwise": max_pairwise, "spread": spread, "thesis_disk": thesis_disk} == METRICS


@settings(max_examples=60, deadline=None)
@given(
    positions=swarms(2),
    angle=st.floats(0.0, 2 * math.pi),
    shift=arrays(np.float64, (2,), elements=coordinates),
    data=st.data(),
)
def test_metrics_invariances(positions, angle, shift, data):
    n = len(positions)
    rotation = np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])
    moved = positions @ rotation.T + shift
    permutation = np.array(data.draw(st.permutations(range(n))))
    for metric in (max_pairwise, spread):
        reference = metric(positions)
        assert metric(moved) == pytest.approx(reference, rel=1e-9, abs=1e-9)
        assert metric(positions[permutation]) == pytest.approx(reference, rel=1e-9, abs=1e-9)
    _, radius = minimum_enclosing_circle(positions)
    assert minimum_enclosing_circle(moved)[1] == pytest.approx(radius, rel=1e-9, abs=1e-9)
    assert minimum_enclosing_circle(positions[permutation])[1] == pytest.approx(radius, rel=1e-9, abs=1e-9)
    # thesis_disk: L1 around robot 0; invariant under translation and relabelling robots 1..N-1 only.
    others = 1 + np.array(data.draw(st.permutations(range(n - 1))), dtype=int)
    reference = thesis_disk(positions)
    assert thesis_disk(positions + shift) == pytest.approx(reference, rel=1e-9, abs=1e-9)
    relabelled = positions[np.concatenate([[0], others])]
    assert thesis_disk(relabelled) == pytest.approx(reference, rel=1e-9, abs=1e-9)


# ---------------------------------------------------------------- minimum enclosing circle


def _assert_circle(points, center, radius, expected_center, expected_radius):
    np.testing.assert_allclose(center, expected_center, atol=1e-12)
    assert radius == pytest.approx(expected_radius, rel=1e-12)
    assert np.all(np.linalg.norm(np.asarray(points) - center, axis=1) <= radius + 1e-9)


@pytest.mark.parametrize(
    ("points", "expected_center", "expected_radius"),
    [
        ([[2.0, 3.0]], [2.0, 3.0], 0.0),
        ([[0.0, 0.0], [4.0, 0.0]], [2.0, 0.0], 2.0),
        ([[1.0, 1.0]] * 5, [1.0, 1.0], 0.0),
        # Right triangle (3-4-5): half the hypotenuse, centred at its midpoint.
        ([[0.0, 0.0], [3.0, 0.0], [0.0, 4.0]], [1.5, 2.0], 2.5),
        # Equilateral triangle of side 2: circumradius 2/sqrt(3), centred at the centroid.
        ([[0.0, 0.0], [2.0, 0.0], [1.0, math.sqrt(3.0)]], [1.0, math.sqrt(3.0) / 3], 2 / math.sqrt(3.0)),
        # Unit square corners: half the diagonal.
        ([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]], [0.5, 0.5], math.sqrt(2.0) / 2),
        # Obtuse triangle: the circle on the longest side, not the circumcircle (which has radius 6.5).
        ([[0.0, 0.0], [10.0, 0.0], [5.0, 1.0]], [5.0, 0.0], 5.0),
        # Collinear points with duplicates: the circle on the two extremes.
        ([[0.0, 0.0], [1.0, 1.0], [3.0, 3.0], [1.0, 1.0], [2.0, 2.0], [0.0, 0.0]], [1.5, 1.5], 1.5 * 2**0.5),
    ],
)
def test_mec_by_hand(points, expected_center, expected_radius):
    center, radius = minimum_enclosing_circle(np.array(points))
    assert center.shape == (2,)
    _assert_circle(points, center, radius, expected_center, expected_radius)


def _brute_force_mec_radius(points: np.ndarray) -> float:
    """Smallest circle over all pair-diameter circles and triple circumcircles that contains every point."""
    candidates = [(points[0], 0.0)]
    for a, b in itertools.combinations(points, 2):
        candidates.append(((a + b) / 2, np.linalg.norm(a - b) / 2))
    for a, b, c in itertools.combinations(points, 3):
        bx, by = b - a
        cx, cy = c - a
        det = 2 * (bx * cy - by * cx)
        if abs(det) < 1e-12:
            continue
        ux = (cy * (bx * bx + by * by) - by * (cx * cx + cy * cy)) / det
        uy = (bx * (cx * cx + cy * cy) - cx * (bx * bx + by * by)) / det
        candidates.append((a + np.array([ux, uy]), math.hypot(ux, uy)))
    return min(
        r
        for center, r in candidates
        if np.all(np.linalg.norm(points - center, axis=1) <= r * (1 + 1e-9) + 1e-9)
    )


@settings(max_examples=80, deadline=None)
@given(points=swarms(1, 12))
def test_mec_matches_brute_force(points):
    center, radius = minimum_enclosing_circle(points)
    assert np.all(np.linalg.norm(points - center, axis=1) <= radius + 1e-9)
    assert radius == pytest.approx(_brute_force_mec_radius(points), rel=1e-7, abs=1e-9)


@settings(max_examples=30, deadline=None)
@given(points=swarms(1, 8), copies=st.integers(2, 4))
def test_mec_with_duplicates(points, copies):
    repeated = np.tile(points, (copies, 1))
    center, radius = minimum_enclosing_circle(repeated)
    assert np.all(np.linalg.norm(repeated - center, axis=1) <= radius + 1e-9)
    assert radius == pytest.approx(minimum_enclosing_circle(points)[1], rel=1e-9, abs=1e-9)


def test_mec_reproducible():
    points = np.random.default_rng(3).normal(size=(1000, 2))
    center, radius = minimum_enclosing_circle(points)
    again_center, again_radius = minimum_enclosing_circle(points)
    np.testing.assert_array_equal(center, again_center)
    assert radius == again_radius
    assert np.all(np.linalg.norm(points - center, axis=1) <= radius + 1e-12)
    # The circle is at least as big as half the diameter and no bigger than diameter / sqrt(3) (Jung).
    assert max_pairwise(points) / 2 - 1e-12 <= radius <= max_pairwise(points) / math.sqrt(3) + 1e-12


def test_mec_rejects_bad_input():
    with pytest.raises(ValueError):
        minimum_enclosing_circle(np.zeros((0, 2)))
    with pytest.raises(ValueError):
        minimum_enclosing_circle(np.zeros((3, 3)))
    with pytest.raises(ValueError):
        minimum_enclosing_circle(np.array([[0.0, np.nan]]))


# ---------------------------------------------------------------- lower bound


def test_lower_bound_by_hand():
    # Two robots 10 m apart: R_mec = 5; threshold sqrt(3) m -> disk radius 1; (5 - 1) / 0.5 = 8 s.
    positions = np.array([[0.0, 0.0], [10.0, 0.0]])
    assert lower_bound_s(positions, math.sqrt(3.0), 0.5) == pytest.approx(8.0)


def test_lower_bound_zero_when_already_within_threshold():
    positions = np.array([[0.0, 0.0], [0.1, 0.0], [0.05, 0.05]])
    assert lower_bound_s(positions, 0.2, 0.5) == 0.0
    assert lower_bound_s(np.array([[1.0, 2.0]]), 0.0, 0.5) == 0.0


def test_lower_bound_equilateral_is_tight_at_jung_radius():
    # Equilateral triangle of side s has R_mec = s / sqrt(3): the bound is exactly 0 at threshold s.
    side_m = 2.0
    triangle = np.array([[0.0, 0.0], [side_m, 0.0], [side_m / 2, side_m * math.sqrt(3) / 2]])
    assert lower_bound_s(triangle, side_m, 1.0) == pytest.approx(0.0, abs=1e-12)
    assert lower_bound_s(triangle, side_m / 2, 1.0) == pytest.approx(side_m / (2 * math.sqrt(3)))


def test_lower_bound_rejects_bad_parameters():
    with pytest.raises(ValueError):
        lower_bound_s(np.zeros((2, 2)), 0.2, 0.0)
    with pytest.raises(ValueError):
        lower_bound_s(np.zeros((2, 2)), -0.2, 0.5)


# ---------------------------------------------------------------- convergence time


TIMES_S = np.arange(6) * 0.5  # 0.0, 0.5, ..., 2.5


def test_convergence_time_cases():
    assert convergence_time(TIMES_S, [5, 4, 3, 0.1, 0.1, 0.1], 0.2) == 1.5
    assert convergence_time(TIMES_S, [0.1] * 6, 0.2) == 0.0
    assert convergence_time(TIMES_S, [5, 4, 0.2, 0.2, 0.2, 0.2], 0.2) == 1.0  # equal to threshold counts
    assert math.isnan(convergence_time(TIMES_S, [5, 4, 3, 2, 1, 0.5], 0.2))  # never reached
    assert math.isnan(convergence_time(TIMES_S, [5, 0.1, 0.1, 0.1, 0.1, 0.3], 0.2))  # leaves at the end
    # Dips below, rises above, comes back: the time of the last entry below.
    assert convergence_time(TIMES_S, [5, 0.1, 0.1, 0.5, 0.1, 0.1], 0.2) == 2.0
    assert math.isnan(convergence_time(TIMES_S, [5, 0.1, np.nan, 0.1, 0.1, np.nan], 0.2))
    assert convergence_time(TIMES_S, [5, 0.1, np.nan, 0.1, 0.1, 0.1], 0.2) == 1.5
    assert isinstance(convergence_time(TIMES_S, [0.1] * 6, 0.2), float)


def test_convergence_time_rejects_mismatched_shapes():
    with pytest.raises(ValueError):
        convergence_time(TIMES_S, np.zeros(5), 0.2)


@settings(max_examples=40, deadline=None)
@given(
    values=arrays(
        np.float64,
        st.tuples(st.integers(1, 4), st.integers(1, 3), st.integers(1, 8)),
        elements=st.floats(0.0, 1.0),
    ),
    threshold=st.floats(0.0, 1.0),
)
def test_convergence_time_batched_equals_looped(values, threshold):
    times_s = np.cumsum(np.full(values.shape[-1], 0.1))
    batched = convergence_time(times_s, values, threshold)
    assert isinstance(batched, np.ndarray) and batched.shape == values.shape[:-1]
    for index in np.ndindex(values.shape[:-1]):
        series = values[index]
        looped = convergence_time(times_s, series, threshold)
        np.testing.assert_equal(batched[index], looped)
        below = series <= threshold
        if not below[-1]:
            assert math.isnan(looped)
        else:
            first = next(k for k in range(len(series)) if below[k:].all())
            assert looped == times_s[first]


# ---------------------------------------------------------------- per-component results


def test_component_results_two_groups_and_isolated_robot():
    times_s = np.array([0.0, 1.0, 2.0])
    # Robots 0, 1 meet at t = 1; robots 2, 3 stay 1 m apart; robot 4 is alone.
    positions = np.array(
        [
            [[0.0, 0.0], [2.0, 0.0], [5.0, 0.0], [6.0, 0.0], [9.0, 9.0]],
            [[1.0, 0.0], [1.1, 0.0], [5.0, 0.0], [6.0, 0.0], [9.0, 9.0]],
            [[1.0, 0.0], [1.0, 0.0], [5.0, 0.0], [6.0, 0.0], [9.0, 9.0]],
        ]
    )
    results = component_results(times_s, positions, [[0, 1], [2, 3], [4]], "max_pairwise", 0.2)
    assert results == [
        {"robots": [0, 1], "converged": True, "convergence_time_s": 1.0, "final_metric": 0.0},
        {"robots": [2, 3], "converged": False, "convergence_time_s": None, "final_metric": 1.0},
        {"robots": [4], "converged": True, "convergence_time_s": 0.0, "final_metric": 0.0},
    ]
    assert isinstance(results[0]["convergence_time_s"], float)
    assert isinstance(results[0]["final_metric"], float)


def test_component_results_rejects_unknown_metric():
    with pytest.raises(ValueError, match="unknown metric"):
        component_results(np.zeros(1), np.zeros((1, 2, 2)), [[0, 1]], "diameter", 0.2)


def test_enclosing_circle_of_a_tiny_swarm_far_from_the_origin():
    """Found by the invariance property above: two distinct points 1e-5 m apart (one repeated ten
    times) have radius 5e-6 m wherever they are; shifted 2 m, rounding once made a duplicate look
    outside its circle and the radius came out 1e-5."""
    points = np.full((11, 2), 1e-5)
    points[0] = [0.0, 1e-5]
    for shift in (0.0, 2.0, 1e3):
        assert minimum_enclosing_circle(points + shift)[1] == pytest.approx(5e-6, rel=1e-6)
