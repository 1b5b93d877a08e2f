"""Tests for swarm.core.graphs: topologies, validation, Laplacian, connectivity."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from swarm.core.graphs import (
    THESIS_WEAK_GRAPH,
    algebraic_connectivity,
    complete,
    connected_components,
    cycle,
    degrees,
    disk,
    erdos_renyi,
    is_connected,
    laplacian,
    line,
    star,
    validate_adjacency,
)


@pytest.mark.parametrize("builder", [complete, cycle, line, star])
@pytest.mark.parametrize("n", [1, 2, 3, 6, 11])
def test_builders_give_valid_float64_graphs(builder, n):
    adjacency = builder(n)
    assert adjacency.shape == (n, n) and adjacency.dtype == np.float64
    assert set(np.unique(adjacency)) <= {0.0, 1.0}
    np.testing.assert_array_equal(validate_adjacency(adjacency), adjacency)
    assert is_connected(adjacency)


def test_builder_edges():
    np.testing.assert_array_equal(degrees(complete(5)), [4] * 5)
    np.testing.assert_array_equal(degrees(cycle(5)), [2] * 5)
    np.testing.assert_array_equal(degrees(line(5)), [1, 2, 2, 2, 1])
    np.testing.assert_array_equal(degrees(star(5)), [4, 1, 1, 1, 1])
    assert cycle(5)[0, 4] == 1 and line(5)[0, 4] == 0
    # n < 3: no closing edge, the cycle is the line (= complete graph).
    np.testing.assert_array_equal(cycle(2), complete(2))
    np.testing.assert_array_equal(cycle(1), np.zeros((1, 1)))


def test_builders_reject_bad_counts():
    with pytest.raises(ValueError):
        complete(-1)
    with pytest.raises(ValueError):
        line(2.5)


def test_thesis_weak_graph_is_two_triangles_and_read_only():
    expected = np.array(
        [
            [0, 1, 1, 0, 0, 0],
            [1, 0, 1, 0, 0, 0],
            [1, 1, 0, 0, 0, 0],
            [0, 0, 0, 0, 1, 1],
            [0, 0, 0, 1, 0, 1],
            [0, 0, 0, 1, 1, 0],
        ],
        dtype=float,
    )
    np.testing.assert_array_equal(THESIS_WEAK_GRAPH, expected)
    with pytest.raises(ValueError):
        THESIS_WEAK_GRAPH[0, 3] = 1.0
    assert connected_components(THESIS_WEAK_GRAPH) == [[0, 1, 2], [3, 4, 5]]
    assert not is_connected(THESIS_WEAK_GRAPH)
    assert algebraic_connectivity(THESIS_WEAK_GRAPH) == 0.0


@pytest.mark.parametrize("n", [3, 4, 6, 10, 20])
def test_algebraic_connectivity_closed_forms(n):
    assert algebraic_connectivity(cycle(n)) == pytest.approx(2 - 2 * np.cos(2 * np.pi / n), abs=1e-10)
    assert algebraic_connectivity(line(n)) == pytest.approx(2 - 2 * np.cos(np.pi / n), abs=1e-10)
    assert algebraic_connectivity(complete(n)) == pytest.approx(n, abs=1e-10)
    assert algebraic_connectivity(star(n)) == pytest.approx(1.0, abs=1e-10)


def test_algebraic_connectivity_small_graphs():
    assert algebraic_connectivity(np.zeros((1, 1))) == 0.0
    assert algebraic_connectivity(complete(2)) == pytest.approx(2.0)
    assert algebraic_connectivity(np.zeros((3, 3))) == 0.0


def test_components_ordering_and_isolated_robots():
    adjacency = np.zeros((6, 6))
    for i, j in [(5, 1), (1, 3), (2, 4)]:
        adjacency[i, j] = adjacency[j, i] = 1.0
    assert connected_components(adjacency) == [[0], [1, 3, 5], [2, 4]]
    assert connected_components(np.zeros((0, 0))) == []
    assert is_connected(np.zeros((1, 1)))


def test_laplacian_and_degrees_batched():
    batch = np.stack([cycle(5), line(5), star(5)])
    lap = laplacian(batch)
    assert lap.shape == (3, 5, 5)
    np.testing.assert_allclose(lap.sum(axis=-1), 0.0)
    for item, adjacency in zip(lap, batch, strict=True):
        np.testing.assert_array_equal(item, np.diag(adjacency.sum(axis=1)) - adjacency)
    np.testing.assert_array_equal(degrees(batch), batch.sum(axis=-1))
    assert laplacian(batch.astype(np.float32)).dtype == np.float32


def test_erdos_renyi_reproducible_and_connected():
    a = erdos_renyi(12, 0.3, seed=7)
    np.testing.assert_array_equal(a, erdos_renyi(12, 0.3, seed=7))
    validate_adjacency(a)
    assert not np.array_equal(a, erdos_renyi(12, 0.3, seed=8))
    for seed in range(20):
        connected = erdos_renyi(10, 0.2, seed=seed, connected=True)
        assert is_connected(connected)
        np.testing.assert_array_equal(connected, erdos_renyi(10, 0.2, seed=seed, connected=True))
    np.testing.assert_array_equal(erdos_renyi(5, 1.0, seed=0), complete(5))
    np.testing.assert_array_equal(erdos_renyi(5, 0.0, seed=0), np.zeros((5, 5)))


def test_erdos_renyi_errors():
    with pytest.raises(ValueError, match="no connected Erdos-Renyi graph"):
        erdos_renyi(5, 0.0, seed=0, connected=True, max_tries=3)
    with pytest.raises(ValueError, match="probability"):
        erdos_renyi(5, 1.5, seed=0)


def test_disk_hand_example():
    positions = np.array([[0.0, 0.0], [1.0, 0.0], [3.0, 0.0], [1.0, 1.0]])
    expected = np.array([[0, 1, 0, 0], [1, 0, 0, 1], [0, 0, 0, 0], [0, 1, 0, 0]], dtype=float)
    np.testing.assert_array_equal(disk(positions, 1.0), expected)  # distance exactly 1 counts as a link
    assert disk(positions, 1.0).dtype == np.float64
    assert disk(positions.astype(np.float32), 1.0).dtype == np.float32


@pytest.mark.parametrize("shape", [(64, 100, 2), (1024, 6, 2), (3, 4, 7, 2)])
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_disk_batched_equals_per_item_and_symmetric(shape, dtype):
    positions = np.random.default_rng(0).uniform(-3, 3, size=shape).astype(dtype)
    adjacency = disk(positions, 1.5)
    assert adjacency.shape == shape[:-1] + shape[-2:-1] and adjacency.dtype == dtype
    np.testing.assert_array_equal(adjacency, np.swapaxes(adjacency, -1, -2))
    assert np.all(np.diagonal(adjacency, axis1=-2, axis2=-1) == 0)
    flat_positions = positions.reshape(-1, *shape[-2:])
    flat_adjacency = adjacency.reshape(-1, shape[-2], shape[-2])
    for index in range(0, len(flat_positions), max(1, len(flat_positions) // 16)):
        np.testing.assert_array_equal(flat_adjacency[index], disk(flat_positions[index], 1.5))


@pytest.mark.parametrize(
    ("matrix", "message"),
    [
        ([[0, 1, 1], [1, 0, 1], [1, 1, 0], [0, 0, 0]], "not square: 4x3"),
        ([[0, 1, 0, 0], [1, 0, 0, 0], [0, 0, 0, 0]], "not square: 3x4"),
        ([0, 1, 1], r"not 2-D: shape \(3,\)"),
        ([[0, 1], [1]], "not a numeric matrix"),
        ([[0, "a"], [1, 0]], "not a numeric matrix"),
        ([[0, np.nan], [np.nan, 0]], r"non-finite entry: A\[0\]\[1\]=nan"),
        ([[0, np.inf], [np.inf, 0]], r"non-finite entry: A\[0\]\[1\]=inf"),
        ([[0, -1], [-1, 0]], r"negative entry: A\[0\]\[1\]=-1"),
        ([[0, 1], [1, 2]], r"non-zero diagonal: A\[1\]\[1\]=2"),
        ([[0, 0, 1], [0, 0, 0], [0, 0, 0]], r"not symmetric: A\[0\]\[2\]=1 but A\[2\]\[0\]=0"),
        ([[0, 0.5], [0.25, 0]], r"not symmetric: A\[0\]\[1\]=0.5 but A\[1\]\[0\]=0.25"),
    ],
)
def test_validate_adjacency_errors(matrix, message):
    with pytest.raises(ValueError, match=message):
        validate_adjacency(matrix)


def test_validate_adjacency_accepts_lists_and_weights():
    result = validate_adjacency([[0, 0.5], [0.5, 0]])
    assert result.dtype == np.float64
    np.testing.assert_array_equal(result, [[0, 0.5], [0.5, 0]])
    original = complete(3)
    validate_adjacency(original)[0, 1] = 7.0
    assert original[0, 1] == 1.0  # returns a copy


@settings(max_examples=40, deadline=None)
@given(n=st.integers(2, 9), p=st.floats(0.0, 1.0), seed=st.integers(0, 2**32 - 1))
def test_components_partition_and_lambda2_agree(n, p, seed):
    adjacency = erdos_renyi(n, p, seed=seed)
    components = connected_components(adjacency)
    assert sorted(r for c in components for r in c) == list(range(n))
    for c in components:
        outside = np.setdiff1d(np.arange(n), c)
        assert not adjacency[np.ix_(c, outside)].any()
        assert is_connected(adjacency[np.ix_(c, c)])
    lam2 = algebraic_connectivity(adjacency)
    eig2 = np.linalg.eigvalsh(laplacian(adjacency))[1]
    assert (lam2 > 1e-9) == (len(components) == 1)
    assert (eig2 > 1e-9) == (len(components) == 1)
