"""The learned coverage controller ``lloyd_gnn`` (``swarm.sim.coverage_gnn``) and its training.

Oracles: hand-made poses and tables (the features), the quadrature's cost recomputed here from the
raw positions (closed loop, the PyBullet run), and files written by hand for the loader.
Decentralization (a robot's first k ticks do not depend on robots more than k hops away):
``tests/test_coverage.py``, over every decentralized coverage kind. The per-robot form against the
batched one, every topology and link fault: ``tests/test_contract.py`` (every controller kind)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from swarm.core import tasks
from swarm.core.robot import RobotParams
from swarm.core.tasks import coverage
from swarm.learn.train import coverage as train_coverage
from swarm.sim.controller_kinds import ControllerArgs, onboard_controller
from swarm.sim.coverage_gnn import FEATURES, CoverageGnnWeights, coverage_features
from swarm.sim.formation_gnn import FormationGnnWeights
from swarm.sim.steering_mlp import PolicyFileError, local_command

ROOT = Path(__file__).resolve().parent.parent
ROBOT = RobotParams()
DT = 0.05


def _random_weights(seed: int) -> CoverageGnnWeights:
    rng = np.random.default_rng(seed)
    shapes = [(len(FEATURES), 8), (8, 8), (8, 3)]
    return CoverageGnnWeights(
        tuple(rng.normal(0, 1, shape) for shape in shapes),
        tuple(rng.normal(0, 1, shape[1]) for shape in shapes),
    )


def test_features_by_hand():
    """Robot 1 of 4 at (2, 3) heading +y. Its cell's centroid is 1 m in world +x: (0, -1) in its frame
    (to its right). It knows itself, robot 0 (age 3: 2 ticks old) and robot 3 (age 5: 4 ticks old), not
    robot 2: known 3/4, stale (2 + 4) / 2 / 4. Its cell holds 0.5 of the density: 0.5 N / 4 = 0.5. The
    density's centroid is 4 m in world -y, (-4, 0) in its frame, over the scale 8 m: (-0.5, 0)."""
    pose = np.array([2.0, 3.0, math.pi / 2])
    table = np.array([[3.0, 0.0, 0.0], [1.0, 2.0, 3.0], [0.0, 0.0, 0.0], [5.0, 1.0, 1.0]])
    own = np.array([False, True, False, False])
    centre = np.array([2.0, -1.0])  # 4 m in world -y: in the frame of a robot facing +y that is (-4, 0)
    features, gate = coverage_features(
        pose, np.array([3.0, 3.0]), table, own, np.float64(0.5), centre, 8.0, ROBOT, DT
    )
    np.testing.assert_allclose(features, [0.0, -1.0, 1.0, 0.75, 3.0 / 4, 0.5, -0.5, 0.0], atol=1e-12)
    assert gate == 1.0


def test_a_policy_file_round_trips_and_bad_files_are_named(tmp_path: Path):
    weights = _random_weights(1)
    path = tmp_path / "policy.npz"
    weights.save(path)
    loaded = CoverageGnnWeights.load(path.read_bytes())
    features = np.random.default_rng(2).normal(size=(7, len(FEATURES)))
    np.testing.assert_array_equal(loaded(features), weights(features))
    with pytest.raises(PolicyFileError, match="lloyd_gnn"):
        CoverageGnnWeights.load(ROOT / "models" / "formation" / "capt_gnn.npz")  # another task's
    with pytest.raises(PolicyFileError, match="capt_gnn"):
        FormationGnnWeights.load(path)

    class FloodCellWeights(CoverageGnnWeights):  # the file of lloyd_gnn before it took lloyd_predict's cell
        FORMAT = "coverage_gnn/1"

    FloodCellWeights(weights.weights, weights.biases).save(tmp_path / "v1.npz")
    with pytest.raises(PolicyFileError, match="coverage_gnn/1"):
        CoverageGnnWeights.load(tmp_path / "v1.npz")
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(PolicyFileError, match="not a policy file"):
        CoverageGnnWeights.load(tmp_path / "junk.npz")


@pytest.mark.parametrize("seed", range(3))
def test_the_command_vanishes_on_the_centroid_whatever_the_weights(seed):
    rng = np.random.default_rng(seed)
    poses = np.concatenate([rng.uniform(-500, 500, (20, 2)), rng.uniform(-4, 4, (20, 1))], -1)
    tables = np.concatenate([rng.integers(0, 4, (20, 5, 1)), rng.normal(size=(20, 5, 2))], -1)
    own = np.broadcast_to(np.eye(5, dtype=bool)[0], (20, 5))
    features, gate = coverage_features(
        poses, poses[:, :2], tables, own, rng.random(20), np.zeros(2), 4.0, ROBOT, DT
    )
    np.testing.assert_array_equal(local_command(_random_weights(seed), features, gate, ROBOT.v_max_mps), 0.0)


def test_lloyd_gnn_steers_from_lloyd_predicts_cell():
    """The learned kind's cell is ``lloyd_predict``'s, horizon included: fed the same tables (made up
    here, entries up to 12 ticks old with far targets, where the horizon matters), both compute the
    same centroids and send the same 5-float entries; ``lloyd_flood``'s centroids differ."""
    from swarm.sim.coverage_controllers import LloydFlood, LloydGnn, LloydPredict
    from swarm.sim.links import Links

    rng = np.random.default_rng(4)
    count, batch = 6, 3
    section = coverage.sweep_section(count)
    poses = np.concatenate([rng.uniform(0, 2, (batch, count, 2)), rng.uniform(-3, 3, (batch, count, 1))], -1)
    tables = np.concatenate(
        [rng.integers(1, 13, (batch, count, count, 1)), rng.uniform(0, 2, (batch, count, count, 4))], -1
    )
    inbox = tables.reshape(batch, count, 5 * count)
    heard = Links.from_dense(np.zeros((batch, count, count)))  # nothing heard: the tables are memory
    learned = LloydGnn(ROBOT, DT, section, count, _random_weights(5))
    predict = LloydPredict(ROBOT, DT, section, count)
    sent_learned = learned.act(poses, poses[..., :2], inbox, heard)[1]
    sent_predict = predict.act(poses, poses[..., :2], inbox, heard)[1]
    np.testing.assert_array_equal(learned._targets, predict._targets)
    np.testing.assert_array_equal(sent_learned, sent_predict)
    flood = LloydFlood(ROBOT, DT, section, count)
    flood.act(poses, poses[..., :2], tables[..., :3].reshape(batch, count, 3 * count), heard)
    assert not np.allclose(flood._targets, predict._targets)


def _section():
    return tasks.parse_section({"kind": "coverage", "grid_per_axis": 24})


def test_the_shipped_policy_covers_a_cycle_of_twelve():
    """Closed loop on the sweep's cells: 8 corner starts of 12 robots on a cycle reach and hold
    H <= 1.05 H_ref within 30 s, H recomputed here from the axle positions on the quadrature."""
    from swarm.scenarios.task_sweep import TaskSweepConfig, cell_starts, run_chunk

    count = 12
    section = coverage.sweep_section(count)
    config = TaskSweepConfig(task="coverage", controllers=["lloyd_gnn"], seeds=8, seed=7, duration_s=30.0)
    poses, adjacency = cell_starts(config, "cycle", count)
    times, frames = run_chunk(config, section, "lloyd_gnn", poses, adjacency, 0.0, 0)
    points, weights = section.quadrature()
    h_ref = coverage.reference_cost(section, count)
    for b in range(len(poses)):
        final = frames[-1, b]
        cost = float(((points[:, None, :] - final[None]) ** 2).sum(-1).min(axis=1) @ weights)
        assert cost <= 1.05 * h_ref, (b, cost / h_ref)
        assert coverage.outcome(times, frames[:, b], section, config.v_max_mps)["converged"]


def test_onboard_lloyd_gnn_reads_a_policy_given_as_bytes(tmp_path: Path):
    weights = _random_weights(3)
    path = tmp_path / "policy.npz"
    weights.save(path)
    args = ControllerArgs(robot=ROBOT, robot_count=3, task=_section(), policy=path.read_bytes(), robot_id=1)
    controller = onboard_controller("lloyd_gnn", args)
    assert controller.policy.weights[0].shape == (len(FEATURES), 8)


@pytest.mark.slow
def test_training_smoke_writes_a_policy_the_controller_loads(tmp_path: Path):
    config = train_coverage.make_config(
        "smoke", {"out": str(tmp_path / "run"), "progress": False, "eval_cells": [["line", 6]]}
    )
    path = train_coverage.train(config)
    weights = CoverageGnnWeights.load(path)
    assert weights.meta["config"]["counts"] == [4, 6]
    log = (tmp_path / "run" / "log.csv").read_text().splitlines()
    assert len(log) == 1 + config.iterations


@pytest.mark.runtime
def test_the_pybullet_runtime_runs_the_learned_coverage_under_faults(tmp_path: Path):
    """``scenarios/tasks/coverage-cycle-gnn-lossy.yaml``: 12 agent processes on a cycle, each running the
    shipped ``lloyd_gnn`` (numpy only), 20% packet loss and a dropped link: the exit status is 0 exactly
    when H / H_ref, computed here from the sim server's last poses, is within 1.05; each agent heard only
    its graph neighbours."""
    from swarm.cli import main

    path = ROOT / "scenarios" / "tasks" / "coverage-cycle-gnn-lossy.yaml"
    out = tmp_path / "pb"
    code = main(["run", str(path), "--out", str(out), "--quiet"])
    metrics = json.loads((out / "metrics.json").read_text())
    final = np.array(
        [pose[:2] for pose in json.loads((out / "trajectory.jsonl").read_text().splitlines()[-1])["poses"]]
    )
    points, weights = tasks.parse_section(yaml.safe_load(path.read_text())["task"]).quadrature()
    ratio = (
        float(((points[:, None, :] - final[None]) ** 2).sum(-1).min(axis=1) @ weights)
        / metrics["reference_cost_m2"]
    )
    assert code == (0 if ratio <= 1.05 else 1), (ratio, metrics.get("health"))
    assert ratio <= 1.05  # the shipped policy covers it (lloyd_flood does: tests/test_coverage.py)
    assert metrics["engine"] == "pybullet" and metrics["faults"]["messages"]["lost_by_fault"] > 0
    for i in range(12):
        record = json.loads((out / "logs" / f"agent_{i}.json").read_text())
        assert record["controller"] == "lloyd_gnn" and record["heavy_modules"] == []
        assert record["neighbours"] == sorted({(i - 1) % 12, (i + 1) % 12})


def test_training_episodes_take_packet_loss_when_asked():
    """``packet_losses``: an episode under 50% loss records staler tables (the ``stale`` feature, the
    mean age of what the robots know) than the same episode without loss; the default draws nothing
    more from the generator, so the default training is unchanged (the shipped file retrains bit for
    bit, models/README.md)."""
    base = train_coverage.make_config("smoke", {"progress": False, "episode_s": 1.0})
    lossy = train_coverage.make_config("smoke", {"progress": False, "episode_s": 1.0, "packet_losses": [0.5]})
    assert lossy.packet_losses == (0.5,)
    weights = _random_weights(6)
    stale = FEATURES.index("stale")
    rows = {}
    for name, config in (("none", base), ("lossy", lossy)):
        rng = np.random.default_rng(9)
        features, _ = train_coverage.episode(config, weights, 1.0, "line", 6, rng)
        rows[name] = features[:, stale].mean()
    assert rows["lossy"] > rows["none"]


def test_the_velocity_weighted_fit_is_the_squared_velocity_error():
    """``direction_weight: velocity``: with the command at its fixed speed ``v = gate`` (units of v_max)
    in the direction ``(a, b)``, the weighted ``1 - cos`` times the weights' sum is half the squared
    velocity error ``sum |u - u*|^2`` less what no direction can remove, ``sum (v - |u*|)^2``: the
    oracle here is the velocity vectors themselves. A row at its fixed point (a millimetre's label)
    moves the weighted loss by almost nothing and the unweighted one by a whole ``1 - cos``."""
    torch = pytest.importorskip("torch")
    from swarm.learn.train.steering import polar_loss

    rng = np.random.default_rng(4)
    rows = 64
    features = np.zeros((rows, len(FEATURES)))
    features[:, 2] = rng.uniform(0.05, 1.0, rows)  # the gate, min(rho_n, 1)
    output = rng.normal(0, 1, (rows, 3))
    labels = rng.normal(0, 0.5, (rows, 2))
    speed = features[:, 2]
    direction = output[:, :2] / np.linalg.norm(output[:, :2], axis=1, keepdims=True)
    u = speed[:, None] * direction
    excess = np.sum((u - labels) ** 2) - np.sum((speed - np.linalg.norm(labels, axis=1)) ** 2)
    weights = speed * np.linalg.norm(labels, axis=1)

    def loss(out: np.ndarray, lab: np.ndarray, feat: np.ndarray, weighted: bool) -> float:
        tensors = (torch.tensor(feat), torch.tensor(out), torch.tensor(lab))
        return float(polar_loss(*tensors, imitate_speed=False, weighted=weighted))

    assert math.isclose(loss(output, labels, features, True) * weights.sum(), excess / 2, rel_tol=1e-9)
    # one row more, at its fixed point and pointing the wrong way
    still_out = np.vstack([output, [-1.0, 0.0, 0.0]])
    still_labels = np.vstack([labels, [1e-4, 0.0]])
    still_features = np.vstack([features, features[:1]])
    changes = [
        loss(still_out, still_labels, still_features, weighted) - loss(output, labels, features, weighted)
        for weighted in (True, False)
    ]
    assert abs(changes[0]) < 1e-4 < changes[1]


def test_a_bad_direction_weight_is_refused_by_name():
    with pytest.raises(ValueError, match=r"direction_weight.*'speed'.*equal, velocity"):
        train_coverage.make_config("default", {"direction_weight": "speed"})
