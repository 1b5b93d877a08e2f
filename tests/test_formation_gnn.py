"""The learned formation controller ``capt_gnn`` (``swarm.sim.formation_gnn``) and its training.

Oracles: hand-made poses (features, the gate), the definition of decentralization (a robot's first k
ticks do not depend on robots more than k hops away), the expert's closed form for the labels, and
files written by hand for the loader. The per-robot form against the batched one, every topology and
link fault: ``tests/test_contract.py`` (every controller kind)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from swarm.core import graphs
from swarm.core.robot import RobotParams
from swarm.core.tasks.formation import FormationSection
from swarm.learn.train import formation as train_formation
from swarm.sim.controller_kinds import ControllerArgs, batched_controller, onboard_controller
from swarm.sim.formation_gnn import (
    FEATURES,
    FormationGnnWeights,
    FormationPolicyError,
    local_command,
    steering_features,
)
from swarm.sim.kinematic import KinematicSim

ROOT = Path(__file__).resolve().parent.parent
ROBOT = RobotParams()


def _random_weights(seed: int) -> FormationGnnWeights:
    rng = np.random.default_rng(seed)
    shapes = [(len(FEATURES), 8), (8, 8), (8, 3)]
    return FormationGnnWeights(
        tuple(rng.normal(0, 1, shape) for shape in shapes),
        tuple(rng.normal(0, 1, shape[1]) for shape in shapes),
    )


def test_features_in_the_robot_frame_by_hand():
    # heading +y, slot 1 m in +x: in the robot's frame the slot is at (0, -1), i.e. to its right
    pose = np.array([2.0, 3.0, math.pi / 2])
    target = np.array([3.0, 3.0])
    features, gate = steering_features(pose, target, np.float64(0.25), np.float64(0.5), ROBOT, 0.05)
    np.testing.assert_allclose(features, [0.0, -1.0, 1.0, 0.25, 0.5], atol=1e-12)
    assert gate == 1.0
    # 1 cm away, under v_max T: the gate is the fraction of v_max T
    features, gate = steering_features(
        pose, pose[:2] + np.array([0.0, 0.01]), np.float64(1.0), np.float64(1.0), ROBOT, 0.05
    )
    assert gate == pytest.approx(0.01 / (ROBOT.v_max_mps * 0.05))


@pytest.mark.parametrize("seed", range(5))
def test_the_command_vanishes_on_the_slot_whatever_the_weights(seed):
    rng = np.random.default_rng(seed)
    poses = np.concatenate([rng.uniform(-500, 500, (20, 2)), rng.uniform(-4, 4, (20, 1))], -1)
    features, gate = steering_features(poses, poses[:, :2], rng.random(20), rng.random(20), ROBOT, 0.05)
    np.testing.assert_array_equal(local_command(_random_weights(seed), features, gate, ROBOT.v_max_mps), 0.0)


def test_a_policy_file_round_trips_and_bad_files_are_named(tmp_path: Path):
    weights = _random_weights(1)
    path = tmp_path / "policy.npz"
    weights.save(path)
    loaded = FormationGnnWeights.load(path.read_bytes())
    features = np.random.default_rng(2).normal(size=(7, len(FEATURES)))
    np.testing.assert_array_equal(loaded(features), weights(features))
    with pytest.raises(FormationPolicyError, match="capt_gnn"):
        FormationGnnWeights.load(ROOT / "models" / "gnn_default.npz")  # a rendezvous policy
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(FormationPolicyError, match="not a policy file"):
        FormationGnnWeights.load(tmp_path / "junk.npz")


def test_the_expert_label_is_capt_time_synchronized_in_the_robot_frame():
    # robot 0 faces its slot 1 m ahead, robot 1 (heading +y) its slot 2 m ahead, robot 2 has its slot
    # 1 m behind it: speeds v_max d / D = 0.25, 0.5 and 0.25 m/s, straight ahead (robot 2 in reverse)
    poses = np.array([[[0.0, 0.0, 0.0], [5.0, 0.0, math.pi / 2], [9.0, 9.0, 0.0]]])
    targets = np.array([[[1.0, 0.0], [5.0, 2.0], [8.0, 9.0]]])
    label = train_formation.expert_local(poses, targets, ROBOT, 0.05)
    np.testing.assert_allclose(label[0], [[0.25, 0.0], [0.5, 0.0], [-0.25, 0.0]], atol=1e-12)


def test_capt_gnn_robot_zero_ignores_robots_beyond_k_hops_for_k_ticks():
    """With the shipped policy: robot 0's message and pose through tick k do not depend on robots more
    than k hops away on a line; with them moved, its message differs at tick k + 1."""
    count, hops = 8, 3
    rng = np.random.default_rng(5)
    section = FormationSection(slots={"circle": {"radius_m": 1.5}})
    poses = np.concatenate([rng.uniform(-3, 3, (1, count, 2)), rng.uniform(-np.pi, np.pi, (1, count, 1))], -1)
    moved = poses.copy()
    moved[0, hops + 1 :, :2] += 5.0
    records = []
    for start in (poses, moved):
        args = ControllerArgs(robot=ROBOT, robot_count=count, task=section)
        sim = KinematicSim(
            ROBOT, batched_controller("capt_gnn", args), 0.05, start, adjacency=graphs.line(count)
        )
        messages, robot_poses = [], [sim.poses[0, 0].copy()]
        for _ in range(count + 1):
            sim.step()
            messages.append(sim.inbox[0, 0].copy())
            robot_poses.append(sim.poses[0, 0].copy())
        records.append((np.array(messages), np.array(robot_poses)))
    (messages, robot_poses), (moved_messages, moved_poses) = records
    np.testing.assert_array_equal(messages[: hops + 1], moved_messages[: hops + 1])
    np.testing.assert_array_equal(robot_poses[: hops + 2], moved_poses[: hops + 2])
    assert not np.array_equal(messages[hops + 1], moved_messages[hops + 1])


def test_the_shipped_policy_takes_every_slot_on_a_line_of_twelve():
    """Closed loop, the sweep's own cell rule: 8 starts of 12 robots on a line, every slot held 2 s, no
    conflicts (judged by ``swarm.core.tasks.formation.outcome`` from the axle positions)."""
    from swarm.core.tasks import formation
    from swarm.scenarios.task_sweep import TaskSweepConfig, run_chunk

    count = 12
    rng = np.random.default_rng(3)
    section = formation.sweep_section(count)
    poses = formation.sweep_starts(rng, 8, count)
    adjacency = np.broadcast_to(graphs.line(count), (8, count, count)).copy()
    config = TaskSweepConfig(task="formation", controllers=["capt_gnn"], duration_s=40.0)
    times, frames = run_chunk(config, section, "capt_gnn", poses, adjacency, 0.0, 0)
    for b in range(len(poses)):
        result = formation.outcome(times, frames[:, b], section, config.v_max_mps)
        assert result["converged"] and result["conflicts"] == 0, result
        assert result["ratio_to_lower_bound"] < 1.5, result


def test_onboard_capt_gnn_reads_a_policy_given_as_bytes(tmp_path: Path):
    weights = _random_weights(3)
    path = tmp_path / "policy.npz"
    weights.save(path)
    section = FormationSection(slots={"circle": {"radius_m": 1.0}})
    args = ControllerArgs(robot=ROBOT, robot_count=3, task=section, policy=path.read_bytes(), robot_id=1)
    controller = onboard_controller("capt_gnn", args)
    assert controller.weights.weights[0].shape == (len(FEATURES), 8)


@pytest.mark.slow
def test_training_smoke_writes_a_policy_the_controller_loads(tmp_path: Path):
    config = train_formation.make_config(
        "smoke", {"out": str(tmp_path / "run"), "progress": False, "eval_cells": [["line", 6]]}
    )
    path = train_formation.train(config)
    weights = FormationGnnWeights.load(path)
    assert weights.meta["config"]["counts"] == [4, 6]
    log = (tmp_path / "run" / "log.csv").read_text().splitlines()
    assert len(log) == 1 + config.iterations


@pytest.mark.runtime
def test_the_pybullet_runtime_runs_the_learned_formation_under_faults(tmp_path: Path):
    """``scenarios/tasks/formation-line-gnn-lossy.yaml``: 12 agent processes on a line, each running the
    shipped ``capt_gnn`` (numpy only), 20% packet loss and a dropped link: every slot taken (exit 0, no
    conflict), judged from the server's trajectory against the circle's slots written out here."""
    import json

    from swarm.cli import main

    scenario = ROOT / "scenarios" / "tasks" / "formation-line-gnn-lossy.yaml"
    out = tmp_path / "pb"
    code = main(["run", str(scenario), "--out", str(out), "--quiet"])
    metrics = json.loads((out / "metrics.json").read_text())
    assert code == 0, metrics.get("health")
    assert metrics["engine"] == "pybullet" and metrics["conflicts"] == 0
    assert metrics["faults"]["messages"]["lost_by_fault"] > 0
    final = json.loads((out / "trajectory.jsonl").read_text().splitlines()[-1])["poses"]
    slots = [(math.cos(2 * math.pi * k / 12), math.sin(2 * math.pi * k / 12)) for k in range(12)]
    nearest = [min(range(12), key=lambda k: math.dist(pose[:2], slots[k])) for pose in final]
    assert sorted(nearest) == list(range(12))
    assert max(math.dist(pose[:2], slots[k]) for pose, k in zip(final, nearest, strict=True)) <= 0.1
    for i in range(12):
        record = json.loads((out / "logs" / f"agent_{i}.json").read_text())
        assert record["controller"] == "capt_gnn" and record["heavy_modules"] == []
        assert record["neighbours"] == sorted({i - 1, i + 1} & set(range(12)))


@pytest.mark.parametrize(("speed", "factor"), [("full", 1.0), ("imitated", 0.3), ("imitated-above", 1.0)])
def test_the_polar_command_by_hand(speed, factor):
    """A one-layer MLP whose output is the constant (2, 0, c): direction straight ahead; the speed is
    v_max (``full``) or clip(c, 0, 1) of it (``imitated``), times the gate."""
    c = 1.7 if speed == "imitated-above" else 0.3
    weights = FormationGnnWeights(
        (np.zeros((len(FEATURES), 3)),), (np.array([2.0, 0.0, c]),), {"speed": speed.split("-")[0]}
    )
    features = np.array([[0.0, 1.0, 0.5, 0.2, 0.4], [1.0, 0.0, 1.0, 1.0, 1.0]])
    gate = features[:, 2]
    u = local_command(weights, features, gate, ROBOT.v_max_mps)
    np.testing.assert_allclose(u, [[ROBOT.v_max_mps * 0.5 * factor, 0.0], [ROBOT.v_max_mps * factor, 0.0]])
