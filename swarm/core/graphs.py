"""Communication graphs: topologies, validation, Laplacian, connectivity.

An adjacency matrix ``A`` is a float array of shape ``(N, N)`` (or ``(..., N, N)`` where a function says it
is batched): symmetric, zero diagonal, non-negative; ``A[i, j] > 0`` means robots i and j hear each other.
The builders return 0/1 float64 arrays.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


def _check_count(n: int) -> int:
    if isinstance(n, bool) or int(n) != n or n < 0:
        raise ValueError(f"robot count must be a non-negative integer, got {n!r}")
    return int(n)


def complete(n: int) -> np.ndarray:
    """Every robot talks to every other robot (the thesis's "fully connected" graph)."""
    n = _check_count(n)
    return np.ones((n, n)) - np.eye(n)


def line(n: int) -> np.ndarray:
    """Path graph ``0 - 1 - ... - (n-1)``."""
    n = _check_count(n)
    adjacency = np.zeros((n, n))
    idx = np.arange(n - 1)
    adjacency[idx, idx + 1] = 1.0
    adjacency[idx + 1, idx] = 1.0
    return adjacency


def cycle(n: int) -> np.ndarray:
    """Ring ``0 - 1 - ... - (n-1) - 0``.

    A cycle needs ``n >= 3``; for ``n < 3`` the closing edge would duplicate an existing one (n = 2) or be a
    self-loop (n = 1), so this returns ``line(n)`` (which equals ``complete(n)`` there).
    """
    adjacency = line(n)
    if len(adjacency) >= 3:
        adjacency[0, -1] = adjacency[-1, 0] = 1.0
    return adjacency


def star(n: int) -> np.ndarray:
    """Robot 0 is the hub, linked to every other robot; no other links."""
    n = _check_count(n)
    adjacency = np.zeros((n, n))
    adjacency[0, 1:] = 1.0
    adjacency[1:, 0] = 1.0
    return adjacency


def erdos_renyi(
    n: int, p: float, seed: int | None, connected: bool = False, max_tries: int = 10_000
) -> np.ndarray:
    """G(n, p): each of the n(n-1)/2 links present independently with probability ``p``.

    Reproducible from ``seed`` (a numpy ``default_rng`` seed). With ``connected=True`` the graph is resampled
    from the same generator until it is connected; ``ValueError`` after ``max_tries`` failures.
    """
    n = _check_count(n)
    if not 0.0 <= p <= 1.0:
        raise ValueError(f"link probability p must be in [0, 1], got {p}")
    if max_tries < 1:
        raise ValueError(f"max_tries must be >= 1, got {max_tries}")
    rng = np.random.default_rng(seed)
    rows, cols = np.triu_indices(n, k=1)
    for _ in range(max_tries if connected else 1):
        adjacency = np.zeros((n, n))
        present = rng.random(rows.size) < p
        adjacency[rows[present], cols[present]] = 1.0
        adjacency += adjacency.T
        if not connected or is_connected(adjacency):
            return adjacency
    raise ValueError(
        f"no connected Erdos-Renyi graph with n={n}, p={p} in {max_tries} tries (seed={seed}); raise p"
    )


def disk(positions: np.ndarray, radius_m: float) -> np.ndarray:
    """Proximity graph: a link when two robots are at most ``radius_m`` apart.

    ``positions`` ``(..., N, 2)`` -> adjacency ``(..., N, N)``, batched over leading dimensions. Compares
    squared distances (no square root). float32 in, float32 out; anything else gives float64.
    """
    positions = np.asarray(positions)
    if positions.ndim < 2 or positions.shape[-1] != 2:
        raise ValueError(f"positions must have shape (..., N, 2), got {positions.shape}")
    dtype = np.float32 if positions.dtype == np.float32 else np.float64
    positions = positions.astype(dtype, copy=False)
    xs, ys = np.ascontiguousarray(positions[..., 0]), np.ascontiguousarray(positions[..., 1])
    squared_m2 = xs[..., :, None] - xs[..., None, :]
    squared_m2 *= squared_m2
    dy_m = ys[..., :, None] - ys[..., None, :]
    dy_m *= dy_m
    squared_m2 += dy_m
    adjacency = (squared_m2 <= dtype(radius_m) ** 2).astype(dtype)
    n = positions.shape[-2]
    adjacency[..., np.arange(n), np.arange(n)] = 0.0
    return adjacency


def _read_only(array: np.ndarray) -> np.ndarray:
    array.flags.writeable = False
    return array


THESIS_WEAK_GRAPH: np.ndarray = _read_only(np.kron(np.eye(2), np.ones((3, 3)) - np.eye(3)))
"""The thesis's "random weak graph" (section 4.2.6): two disjoint triangles {0, 1, 2} and {3, 4, 5}.

It is disconnected, so global consensus is impossible on it (docs/design.md, "What the thesis got wrong");
report per-component consensus instead.
"""


def validate_adjacency(matrix: np.ndarray | Sequence[Sequence[float]]) -> np.ndarray:
    """Check an ``(N, N)`` adjacency matrix and return it as a new float64 array.

    Weighted non-negative entries are allowed. Symmetry is checked exactly. Raises ``ValueError`` with a
    short reason: not numeric, not 2-D, not square, non-finite, negative, non-zero diagonal, not symmetric.
    """
    try:
        adjacency = np.array(matrix, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"not a numeric matrix: {exc}") from None
    if adjacency.ndim != 2:
        raise ValueError(f"not 2-D: shape {adjacency.shape}")
    rows, cols = adjacency.shape
    if rows != cols:
        raise ValueError(f"not square: {rows}x{cols}")

    def first(mask: np.ndarray) -> tuple[int, int] | None:
        hits = np.argwhere(mask)
        return (int(hits[0][0]), int(hits[0][1])) if len(hits) else None

    if (bad := first(~np.isfinite(adjacency))) is not None:
        raise ValueError(f"non-finite entry: A[{bad[0]}][{bad[1]}]={adjacency[bad]:g}")
    if (bad := first(adjacency < 0)) is not None:
        raise ValueError(f"negative entry: A[{bad[0]}][{bad[1]}]={adjacency[bad]:g}")
    diagonal = np.diagonal(adjacency)
    if np.any(diagonal != 0):
        i = int(np.flatnonzero(diagonal)[0])
        raise ValueError(f"non-zero diagonal: A[{i}][{i}]={diagonal[i]:g}")
    if (bad := first(adjacency != adjacency.T)) is not None:
        i, j = bad
        forward, backward = adjacency[i, j], adjacency[j, i]
        raise ValueError(f"not symmetric: A[{i}][{j}]={forward:g} but A[{j}][{i}]={backward:g}")
    return adjacency


def degrees(adjacency: np.ndarray) -> np.ndarray:
    """Weighted degree ``d_i = sum_j A_ij``, batched: ``(..., N, N)`` -> ``(..., N)``."""
    return np.asarray(adjacency).sum(axis=-1)


def laplacian(adjacency: np.ndarray) -> np.ndarray:
    """Graph Laplacian ``L = D - A``, batched over leading dimensions."""
    adjacency = np.asarray(adjacency)
    lap = -adjacency.astype(np.result_type(adjacency.dtype, np.float32), copy=True)
    n = adjacency.shape[-1]
    lap[..., np.arange(n), np.arange(n)] += degrees(adjacency)
    return lap


def connected_components(adjacency: np.ndarray) -> list[list[int]]:
    """Connected components of one ``(N, N)`` graph (validated first).

    Each component is sorted; components are ordered by their smallest member.
    """
    linked = validate_adjacency(adjacency) > 0
    n = len(linked)
    component_of = np.full(n, -1)
    components: list[list[int]] = []
    for root in range(n):
        if component_of[root] >= 0:
            continue
        component_of[root] = len(components)
        frontier = [root]
        members = [root]
        while frontier:
            new = np.flatnonzero(linked[frontier].any(axis=0) & (component_of < 0))
            component_of[new] = len(components)
            frontier = new.tolist()
            members.extend(frontier)
        components.append(sorted(members))
    return components


def is_connected(adjacency: np.ndarray) -> bool:
    """True when every robot can reach every other one (a graph with 0 or 1 robots counts as connected)."""
    return len(connected_components(adjacency)) <= 1


def algebraic_connectivity(adjacency: np.ndarray) -> float:
    """lambda_2, the second-smallest Laplacian eigenvalue (Fiedler value); 0 when disconnected or N < 2.

    Linear consensus converges like ``exp(-lambda_2 t)`` (docs/design.md, "Metrics and the lower bound").
    """
    validated = validate_adjacency(adjacency)
    if len(validated) < 2 or not is_connected(validated):
        return 0.0
    return float(max(np.linalg.eigvalsh(laplacian(validated))[1], 0.0))
