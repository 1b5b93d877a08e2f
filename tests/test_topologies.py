"""The topology registry (``swarm.core.topologies``) is the one place a graph kind is defined: a kind
registered there is accepted by the scenario schema, sweeps, data collection and the RL
environment, and the built-in kinds build exactly the graphs of ``swarm.core.graphs``."""

from __future__ import annotations

import numpy as np
import pytest

from swarm.core import graphs, topologies
from swarm.learn.data import collect_config, episode_graphs
from swarm.rl.vector_env import ConsensusConfig, ConsensusVectorEnv
from swarm.scenarios.scenario import ScenarioError, parse_scenario
from swarm.scenarios.sweep import SweepConfig, cell_graphs


def scenario(topology: dict, count: int = 6):
    return parse_scenario({"name": "t", "robots": {"count": count}, "topology": topology})


def test_registration_order_is_the_seed_order_of_committed_results():
    # sweep cell seeds and dataset graph ids use these indices: reordering would change every result
    assert topologies.kinds(grid=True) == ("complete", "cycle", "line", "star", "random", "disk")
    assert topologies.kinds(default_grid=True) == ("complete", "cycle", "line", "star", "random")
    assert topologies.kinds() == (*topologies.kinds(grid=True), "matrix")
    assert [topologies.grid_index(kind) for kind in ("complete", "random", "disk")] == [0, 4, 5]


@pytest.mark.parametrize("kind", ["complete", "cycle", "line", "star"])
def test_deterministic_kinds_build_the_graphs_functions(kind):
    np.testing.assert_array_equal(topologies.build(kind, 7), getattr(graphs, kind)(7))
    np.testing.assert_array_equal(scenario({"kind": kind}, 7).adjacency(), getattr(graphs, kind)(7))


def test_random_and_proximity_kinds():
    params = topologies.Params(p=0.3, seed=5, connected=True)
    np.testing.assert_array_equal(topologies.build("random", 9, params), graphs.erdos_renyi(9, 0.3, 5, True))
    # no p: min(1, 1.5 ln N / N), worked by hand for N = 20: 1.5 * 2.9957 / 20 = 0.22468
    assert topologies.default_edge_probability(20) == pytest.approx(0.224680, abs=1e-6)
    assert topologies.default_edge_probability(2) == pytest.approx(0.519860, abs=1e-6)  # 1.5 * 0.693147 / 2
    assert topologies.build("disk", 5) is None
    with pytest.raises(ValueError, match="follows the positions"):
        topologies.get("disk").fixed(5)
    with pytest.raises(ValueError, match="unknown graph kind 'hexagon'"):
        topologies.get("hexagon")


def test_a_registered_kind_is_usable_everywhere(monkeypatch):
    def wheel(count: int, _params) -> np.ndarray:
        adjacency = graphs.cycle(count)
        adjacency[0, :] = adjacency[:, 0] = 1
        adjacency[0, 0] = 0
        return adjacency

    monkeypatch.setitem(topologies._REGISTRY, "wheel", topologies.Topology("wheel", wheel))
    expected = wheel(6, None)
    assert expected.sum() == 2 * (6 + 3)  # cycle of 6 (6 edges) plus hub edges to 2, 3, 4 (3 new)
    np.testing.assert_array_equal(scenario({"kind": "wheel"}).adjacency(), expected)  # the schema
    config = SweepConfig(topologies=["wheel"], seeds=3)
    config.check("test")  # sweep grid
    np.testing.assert_array_equal(cell_graphs(config, "wheel", 6, np.random.default_rng(0)), [expected] * 3)
    collect = collect_config(graphs=("wheel",), sizes=(6,))  # data
    adjacency, radius = episode_graphs("wheel", 6, 2, np.zeros((2, 6, 2)), collect, np.random.default_rng(0))
    assert radius is None and adjacency is not None
    np.testing.assert_array_equal(adjacency, [expected] * 2)
    env = ConsensusVectorEnv(1, ConsensusConfig(topology="wheel", robots=6))  # RL environment
    env.reset(seed=0)
    np.testing.assert_array_equal(env.adjacency()[0], expected)


def test_unknown_kinds_are_refused_with_the_registered_ones():
    with pytest.raises(ScenarioError, match=r"topology\.kind: Input should be 'complete', .* or 'matrix'"):
        scenario({"kind": "hexagon"})
    with pytest.raises(ScenarioError, match="unknown topology 'hexagon'"):
        SweepConfig(topologies=["hexagon"]).check("test")
    with pytest.raises(ScenarioError, match="topology: kind 'random' needs 'p'"):
        scenario({"kind": "random"})
