"""swarm.learn.data: expert samples from the batched simulator, with the policy's information timing."""

from __future__ import annotations

import numpy as np
import pytest

from swarm.core import graphs
from swarm.core.experts import complete_consensus_velocity
from swarm.core.initial_poses import random_poses
from swarm.core.robot import RobotParams, world_to_local
from swarm.learn.data import GRAPH_KINDS, ExpertRecorder, collect, collect_config, load_dataset
from swarm.sim.features import FeatureSpec, saturate_local_velocity
from swarm.sim.kinematic import KinematicSim

ROBOT = RobotParams()


def test_collect_mixes_graphs_and_sizes_and_round_trips(tmp_path):
    config = collect_config(samples=6000, sizes=(4, 7), hops=3, seed=3)
    dataset = collect(config, progress=False)
    assert len(dataset) == 6000
    assert dataset.features.shape == (6000, 3, 2) and dataset.features.dtype == np.float32
    assert dataset.labels.shape == (6000, 2) and dataset.labels.dtype == np.float32
    assert set(np.unique(dataset.robot_count)) == {4, 7}
    np.testing.assert_array_equal(np.bincount(dataset.graph, minlength=6), np.full(len(GRAPH_KINDS), 1000))
    # labels are what the robot can apply: inside the saturation diamond |ux| + (d/l)|uy| <= v_max
    ratio = ROBOT.half_axle_m / ROBOT.offset_m
    assert np.all(
        np.abs(dataset.labels[:, 0]) + ratio * np.abs(dataset.labels[:, 1]) <= ROBOT.v_max_mps + 1e-6
    )
    assert dataset.labels[:, 0].std() > 0.1  # the expert mostly runs at full speed
    loaded = load_dataset(dataset.save(tmp_path / "d.npz"))
    np.testing.assert_array_equal(loaded.features, dataset.features)
    assert loaded.spec == FeatureSpec(3) and loaded.metadata["labels"] == "centralized"
    assert loaded.metadata["config"]["seed"] == 3


def test_same_seed_same_data():
    config = collect_config(samples=1500, graphs=("random", "disk"), sizes=(5,), seed=7)
    first, second = collect(config, progress=False), collect(config, progress=False)
    np.testing.assert_array_equal(first.features, second.features)
    np.testing.assert_array_equal(first.labels, second.labels)


def test_thesis_preset():
    config = collect_config("thesis", samples=10)
    assert config.graphs == ("complete",) and config.sizes == (6,)
    assert config.spec == FeatureSpec(2, "m", "n_minus_1")
    with pytest.raises(ValueError, match="unknown"):
        collect_config(graphs=("tree",))
    with pytest.raises(ValueError, match="preset"):
        collect_config("nope")


@pytest.mark.parametrize("labels", ["centralized", "local_consensus"])
def test_recorder_labels_and_features(labels):
    """Each tick's label is the expert's velocity, saturated, in the robot frame; the features of
    tick 1 are M over the graph from the points of tick 0; robots that heard nobody are not recorded."""
    count = 5
    poses = random_poses(np.random.default_rng(8), 3, count)
    adjacency = graphs.line(count)
    recorder = ExpertRecorder(FeatureSpec(2), ROBOT, labels)
    sim = KinematicSim(ROBOT, recorder, 0.05, poses, adjacency)
    start_points = sim.points.copy()
    sim.step()
    assert recorder.recorded == []  # tick 0: nobody has heard anybody
    tick1_poses, tick1_points = sim.poses.copy(), sim.points.copy()
    sim.step()
    features, recorded_labels, ticks = recorder.take()
    assert np.all(ticks == 1) and len(features) == 3 * count
    if labels == "centralized":
        expert = complete_consensus_velocity(tick1_points, 1.0)
    else:
        expert = -(adjacency.sum(1)[:, None] * tick1_points - adjacency @ start_points)
    expected = saturate_local_velocity(world_to_local(expert, tick1_poses[..., 2]), ROBOT)
    np.testing.assert_allclose(recorded_labels, expected.reshape(-1, 2), atol=1e-6)
    m_world = (adjacency @ start_points) / adjacency.sum(1)[:, None] - tick1_points
    np.testing.assert_allclose(
        features[:, 0], world_to_local(m_world, tick1_poses[..., 2]).reshape(-1, 2), atol=1e-6
    )
