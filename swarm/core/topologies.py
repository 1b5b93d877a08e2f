"""The registry of communication-graph kinds: the one place that defines a topology.

Each :class:`Topology` says what a kind is called, which scenario keys it needs, how to build its
adjacency, and where it may be used. Every consumer reads this registry: the scenario schema
(``swarm.scenarios.scenario.TopologySpec`` accepts exactly the registered kinds and checks their required
keys), ``swarm sweep`` and ``swarm evaluate`` (their grids and cell seeds), ``swarm collect``
(``swarm.learn.data``), the RL environments (``swarm.rl``) and PPO training (``swarm.learn.train.ppo``).
Adding a kind is one :func:`register` call here (docs/design.md, "Extending").

The order of registration is part of the results: a sweep cell's seed and a dataset's ``graph``
column use the index of the kind among :func:`kinds` ``(grid=True)``, so new kinds go at the end.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from swarm.core import graphs


class GraphParams(Protocol):
    """What a builder may read: the parameters of ``swarm.scenarios.scenario.TopologySpec`` (or
    :class:`Params`)."""

    @property
    def p(self) -> float | None: ...
    @property
    def seed(self) -> int: ...
    @property
    def connected(self) -> bool: ...
    @property
    def radius_m(self) -> float | None: ...
    @property
    def adjacency(self) -> Sequence[Sequence[float]] | None: ...


@dataclass(frozen=True)
class Params:
    """Graph parameters outside a scenario file (sweeps, data collection, training)."""

    p: float | None = None
    seed: int = 0
    connected: bool = False
    radius_m: float | None = None
    adjacency: Sequence[Sequence[float]] | None = None


Builder = Callable[[int, GraphParams], np.ndarray]
"""``(robot_count, params) -> (N, N)`` symmetric adjacency with zero diagonal."""


@dataclass(frozen=True)
class Topology:
    """One graph kind.

    ``requires``: (attribute, scenario key) pairs a scenario of this kind must give. ``random``: a
    fresh graph per start, drawn from ``params.seed`` (sweeps, data and training draw one seed per
    start). ``proximity``: no fixed graph; it is recomputed from the positions every tick
    (``graphs.disk`` with ``radius_m``), so ``build`` is never called. ``grid``: a sweep, evaluation
    or data cell can be of this kind (it needs nothing but N); ``default_grid``: in their default
    grid.
    """

    kind: str
    build: Builder | None
    requires: tuple[tuple[str, str], ...] = ()
    random: bool = False
    proximity: bool = False
    grid: bool = True
    default_grid: bool = True

    def fixed(self, count: int, params: GraphParams | None = None) -> np.ndarray:
        """``(N, N)`` adjacency; ValueError for a proximity graph (it has none)."""
        if self.build is None:
            raise ValueError(f"a {self.kind!r} graph follows the positions; it has no fixed adjacency")
        return self.build(count, params if params is not None else Params())


_REGISTRY: dict[str, Topology] = {}


def register(topology: Topology) -> Topology:
    if topology.kind in _REGISTRY:
        raise ValueError(f"topology kind {topology.kind!r} is already registered")
    if (topology.build is None) != topology.proximity:
        raise ValueError(f"topology {topology.kind!r}: a builder exactly when it is not a proximity graph")
    _REGISTRY[topology.kind] = topology
    return topology


def get(kind: str) -> Topology:
    """The registered kind; ValueError naming the known ones otherwise."""
    try:
        return _REGISTRY[kind]
    except KeyError:
        raise ValueError(f"unknown graph kind {kind!r}; choose from {list(_REGISTRY)}") from None


def kinds(*, grid: bool = False, default_grid: bool = False, fixed: bool = False) -> tuple[str, ...]:
    """Registered kinds in registration order; ``grid``: only those a grid cell can be,
    ``default_grid``: only those of the default grids, ``fixed``: no proximity graphs."""
    return tuple(
        kind
        for kind, topology in _REGISTRY.items()
        if (topology.grid or not grid)
        and (topology.default_grid or not default_grid)
        and not (fixed and topology.proximity)
    )


def grid_index(kind: str) -> int:
    """Index of a grid kind among ``kinds(grid=True)`` (seeds of sweep cells, dataset graph ids)."""
    return kinds(grid=True).index(kind)


def build(kind: str, count: int, params: GraphParams | None = None) -> np.ndarray | None:
    """``(N, N)`` adjacency of a fixed kind; None for a proximity graph."""
    topology = get(kind)
    return None if topology.proximity else topology.fixed(count, params)


def draw(kind: str, count: int, rng: np.random.Generator, p: float | None = None) -> np.ndarray | None:
    """One start's graph for sweeps-like uses: a random kind draws its seed from ``rng`` (connected,
    edge probability ``p`` or :func:`default_edge_probability`); a deterministic kind draws nothing."""
    topology = get(kind)
    seed = int(rng.integers(2**31)) if topology.random else 0
    return build(kind, count, Params(p=p, seed=seed, connected=True))


def default_edge_probability(count: int) -> float:
    """Edge probability of a random graph when none is given: ``min(1, 1.5 ln N / N)``, above the
    connectivity threshold ``ln N / N`` of G(N, p)."""
    return min(1.0, 1.5 * math.log(count) / count)


def _random(count: int, params: GraphParams) -> np.ndarray:
    p = params.p if params.p is not None else default_edge_probability(count)
    return graphs.erdos_renyi(count, p, params.seed, connected=params.connected)


def _matrix(count: int, params: GraphParams) -> np.ndarray:
    if params.adjacency is None:
        raise ValueError("kind 'matrix' needs 'adjacency'")
    return graphs.validate_adjacency(params.adjacency)


register(Topology("complete", lambda count, _: graphs.complete(count)))
register(Topology("cycle", lambda count, _: graphs.cycle(count)))
register(Topology("line", lambda count, _: graphs.line(count)))
register(Topology("star", lambda count, _: graphs.star(count)))
register(Topology("random", _random, requires=(("p", "p"),), random=True))
register(Topology("disk", None, requires=(("radius_m", "radius"),), proximity=True, default_grid=False))
register(Topology("matrix", _matrix, requires=(("adjacency", "adjacency"),), grid=False, default_grid=False))
