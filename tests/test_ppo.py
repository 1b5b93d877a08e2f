"""PPO fine-tuning of the GNN (swarm.learn.train.ppo): a short real training, reproducibility, the export,
the batched torch swarm against KinematicSim, the speed limit and decentralized execution."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest
import torch

from swarm.cli import main
from swarm.core import graphs
from swarm.core.initial_poses import box_for, random_poses
from swarm.core.robot import RobotParams, local_point_velocity_to_wheels
from swarm.learn.train import ppo
from swarm.sim.kinematic import KinematicSim
from swarm.sim.policy import load_policy

ROOT = Path(__file__).resolve().parent.parent
DEFAULT_MODEL = ROOT / "models" / "gnn_graph_filter.npz"  # the graph filter PPO fine-tunes


def tiny(out: Path, **overrides) -> ppo.PPOConfig:
    return ppo.make_config("tiny", {"out": str(out), "init_policy": str(DEFAULT_MODEL), **overrides})


def policy_arrays(path: Path) -> dict[str, np.ndarray]:
    with np.load(path, allow_pickle=False) as file:
        return {name: file[name] for name in file.files if name != "__metadata__"}


def read_csv(path: Path) -> list[dict]:
    with open(path, newline="") as file:
        return list(csv.DictReader(file))


def actor_for(model: Path = DEFAULT_MODEL, dtype=torch.float64, action_space: str = "velocity") -> ppo.Actor:
    robot = RobotParams()
    config = ppo.make_config("tiny", {"init_policy": str(model)})
    return ppo.Actor(ppo.load_gnn(config, robot), robot, 0.05, True, action_space).to(dtype)


@pytest.fixture(scope="module")
def two_runs(tmp_path_factory) -> tuple[Path, Path]:
    """Two tiny trainings with the same seed (the first also logs to TensorBoard)."""
    base = tmp_path_factory.mktemp("ppo")
    first = ppo.train(tiny(base / "a", tensorboard=True, lr=1e-3))
    second = ppo.train(tiny(base / "b", lr=1e-3))
    return first, second


@pytest.mark.slow
def test_short_training_runs_end_to_end(two_runs):
    first, _ = two_runs
    out = first.parent
    for name in ("log.csv", "eval.csv", "learning_curve.png", "config.json", "policy.npz"):
        assert (out / name).is_file(), name
    assert (out / "checkpoints" / "last.pt").is_file() and (out / "checkpoints" / "best.pt").is_file()
    assert list(out.glob("events.out.tfevents.*")), "no TensorBoard log"
    rows = read_csv(out / "log.csv")
    assert [int(row["update"]) for row in rows] == [1, 2]
    assert all(np.isfinite(float(row["value_loss"])) for row in rows)
    metadata = load_policy(first).metadata
    assert metadata["training"]["algo"] == "ppo"
    # the training moved the GNN's weights away from the BC start
    trained, start = policy_arrays(out / "policy.npz"), policy_arrays(DEFAULT_MODEL)
    final = torch.load(out / "checkpoints" / "last.pt", weights_only=False)["model"]
    assert any(not np.allclose(final[name].numpy(), start[name]) for name in start)
    assert set(trained) == set(start)


@pytest.mark.slow
def test_same_seed_same_training(two_runs):
    first, second = two_runs
    log_a = read_csv(first.parent / "log.csv")
    log_b = read_csv(second.parent / "log.csv")
    for row_a, row_b in zip(log_a, log_b, strict=True):
        for key in ("policy_loss", "value_loss", "approx_kl", "mean_reward", "policy_std"):
            assert row_a[key] == row_b[key], key
    last_a = torch.load(first.parent / "checkpoints" / "last.pt", weights_only=False)
    last_b = torch.load(second.parent / "checkpoints" / "last.pt", weights_only=False)
    for name, value in last_a["actor"].items():
        assert torch.equal(value, last_b["actor"][name]), name
    for name, value in policy_arrays(first).items():
        np.testing.assert_array_equal(value, policy_arrays(second)[name])


@pytest.mark.slow
def test_exported_policy_equals_torch_mean_action(two_runs):
    """``swarm.sim.policy`` (numpy) runs the PPO export exactly as the torch actor's deterministic action."""
    first, _ = two_runs
    actor = actor_for(first, dtype=torch.float32)
    policy = load_policy(first)
    rng = np.random.default_rng(0)
    features = rng.normal(scale=[[1.5, 1.5]] * 8, size=(500, 8, 2)) * rng.uniform(
        0.001, 1.0, size=(500, 1, 1)
    )
    with torch.no_grad():
        torch_mean = actor.mean(torch.as_tensor(features, dtype=torch.float32)).double().numpy()
    from swarm.sim.features import saturate_local_velocity

    numpy_mean = saturate_local_velocity(policy.forward(features), policy.robot)
    np.testing.assert_allclose(numpy_mean, torch_mean, atol=1e-5)


def test_torch_swarm_matches_kinematic_sim():
    """Same timing, features, saturation and unicycle step as KinematicSim running the exported file."""
    robot = RobotParams()
    actor = actor_for()
    rng = np.random.default_rng(3)
    count = 9
    poses = random_poses(rng, 2, count, box_for(count), box_for(count), 0.4)
    adjacency = np.stack([graphs.line(count), graphs.erdos_renyi(count, 0.4, 5, connected=True)])
    sim = KinematicSim(robot, load_policy(DEFAULT_MODEL, robot, count), 0.05, poses, adjacency)
    env = ppo.TorchSwarm(2, 12, 8, robot, 0.05, "cpu", torch.float64)  # padded to 12 robots
    env.load([0, 1], list(poses), list(adjacency), [1, 2])
    for _ in range(120):
        features, phi_world, points = env.observe()
        with torch.no_grad():
            env.step(actor.mean(features), phi_world, points)
        sim.step()
    np.testing.assert_allclose(env.positions[:, :count].numpy(), sim.poses[..., :2], atol=1e-9)
    assert np.all(env.positions[:, count:].numpy() == 0.0)
    diameter = np.linalg.norm(sim.poses[:, :, None, :2] - sim.poses[:, None, :, :2], axis=-1).max(axis=(1, 2))
    np.testing.assert_allclose(env.max_pairwise().numpy(), diameter, atol=1e-9)


@pytest.mark.parametrize("action_space", ["velocity", "hop_logits"])
def test_actions_respect_the_speed_limit(action_space):
    """Sampled actions (even with large noise) are saturated to the wheel-speed limit; no robot's axle
    moves faster than v_max."""
    robot = RobotParams()
    actor = actor_for(action_space=action_space)
    actor.log_std.data.fill_(np.log(2.0))  # 2 m/s (or 2 logits) of noise: far outside the limit
    count = 8
    poses = random_poses(np.random.default_rng(1), 4, count, box_for(count), box_for(count), 0.4)
    env = ppo.TorchSwarm(4, count, 8, robot, 0.05, "cpu", torch.float64)
    env.load(list(range(4)), list(poses), [graphs.cycle(count)] * 4, [0] * 4)
    generator = torch.Generator().manual_seed(0)
    for _ in range(40):
        features, phi_world, points = env.observe()
        with torch.no_grad():
            mean = actor.action_mean(features)
            noise = torch.randn(mean.shape, generator=generator, dtype=mean.dtype)
            applied = actor.apply(features, mean + actor.log_std.exp() * noise)
        wheels = local_point_velocity_to_wheels(applied.numpy(), robot)
        assert np.abs(wheels).max() <= robot.v_max_mps * (1 + 1e-9)
        before = env.positions.clone()
        env.step(applied, phi_world, points)
        step_m = (env.positions - before).norm(dim=-1)
        assert float(step_m.max()) <= robot.v_max_mps * 0.05 * (1 + 1e-9)


def test_decentralized_execution_k_hop_timing():
    """On a line of 10 robots, robot 0's actions at ticks 0..8 do not depend on robot 9 (9 hops away:
    its information needs 9 ticks to arrive); later they do (so the check can fail)."""
    robot = RobotParams()
    actor = actor_for()
    count = 10
    poses = random_poses(np.random.default_rng(2), 1, count, box_for(count), box_for(count), 0.4)[0]
    moved = poses.copy()
    moved[9] += [0.7, -0.5, 1.0]  # robot 9's start changes, nothing else
    env = ppo.TorchSwarm(2, count, 8, robot, 0.05, "cpu", torch.float64)
    env.load([0, 1], [poses, moved], [graphs.line(count)] * 2, [1, 1])
    actions = []
    for _ in range(30):
        features, phi_world, points = env.observe()
        with torch.no_grad():
            u = actor.mean(features)
        actions.append(u[:, 0].numpy().copy())  # robot 0 in both swarms
        env.step(u, phi_world, points)
    for tick in range(9):
        np.testing.assert_array_equal(actions[tick][0], actions[tick][1], err_msg=f"tick {tick}")
    assert any(not np.allclose(a[0], a[1]) for a in actions[9:]), "robot 0 never heard of robot 9"


def test_bad_config_is_one_line_error(tmp_path, capsys):
    with pytest.raises(ValueError, match="graphs: unknown graph kind 'ring'"):
        ppo.make_config("tiny", {"graphs": {"ring": 1.0}})
    with pytest.raises(ValueError, match="unknown ppo option 'learning_rate'"):
        ppo.make_config("tiny", {"learning_rate": 1.0})
    config = tmp_path / "bad.yaml"
    config.write_text("sizes: [1, 5]\n")
    # in-process: swarm.cli.main, what the console script calls
    assert main(["train", "--algo", "ppo", "--preset", "tiny", "--config", str(config)]) == 2
    stderr = capsys.readouterr().err
    assert "sizes" in stderr and len(stderr.strip().splitlines()) == 1, stderr


def test_stop_after_exports_the_last_iterate(tmp_path):
    """``stop_after`` ends the run at that update (the learning-rate schedule still spans ``updates``)
    and ``export: last`` ships that iterate."""
    policy = ppo.train(tiny(tmp_path, updates=5, stop_after=1, export="last", lr=1e-3))
    assert [row["update"] for row in read_csv(tmp_path / "log.csv")] == ["1"]
    assert float(read_csv(tmp_path / "log.csv")[0]["lr"]) == pytest.approx(1e-3)
    assert load_policy(policy).metadata["training"]["chosen_update"] == 1
    last = torch.load(tmp_path / "checkpoints" / "last.pt", weights_only=False)["model"]
    for name, value in policy_arrays(policy).items():
        np.testing.assert_array_equal(value, last[name].numpy())


def test_gae_by_hand():
    """gamma = lambda = 0.5 (gamma lambda = 0.25), T = 3, two swarms; every number below is worked by
    hand (dyadic, so exact in binary)."""
    t = lambda *rows: torch.tensor(rows, dtype=torch.float64)  # noqa: E731  (T, B)
    rewards, values = t([1, 1], [2, 1], [3, 1]), t([0.5, 2], [1, 2], [2, 2])
    next_value = torch.tensor([4.0, 10.0], dtype=torch.float64)  # swarm 1 was reset: 10 must not count
    terminated, truncated = t([0, 1], [0, 0], [0, 0]), t([0, 0], [0, 0], [0, 1])  # 1: ends at t=0 and t=2
    final = t([0, 0], [0, 0], [0, 8])  # value of the state swarm 1 timed out in
    # swarm 0 (no end): deltas 1 + .5*1 - .5 = 1, 2 + .5*2 - 1 = 2, 3 + .5*4 - 2 = 3;
    #   A2 = 3, A1 = 2 + .25*3 = 2.75, A0 = 1 + .25*2.75 = 1.6875; returns A + V = 2.1875, 3.75, 5
    # swarm 1, time-out as terminal: A2 = 1 - 2 = -1, A1 = (1 + .5*2 - 2) + .25*(-1) = -0.25,
    #   A0 = 1 - 2 = -1 (terminated: the recursion stops there)
    zeros = torch.zeros_like(final)
    advantages, returns = ppo.gae(rewards, values, next_value, terminated, truncated, zeros, 0.5, 0.5)
    assert advantages.tolist() == [[1.6875, -1.0], [2.75, -0.25], [3.0, -1.0]]
    assert returns.tolist() == [[2.1875, 1.0], [3.75, 1.75], [5.0, 1.0]]
    # bootstrapping the time-out from its state's value 8: A2 = 1 + .5*8 - 2 = 3, A1 = 0 + .25*3 = 0.75
    advantages, _ = ppo.gae(rewards, values, next_value, terminated, truncated, final, 0.5, 0.5)
    assert advantages[:, 1].tolist() == [-1.0, 0.75, 3.0]
    assert advantages[:, 0].tolist() == [1.6875, 2.75, 3.0]  # the other swarm is untouched


def test_shaped_reward_by_hand():
    """v_max 0.5 m/s: Phi = -diameter / (2 * 0.5) = -diameter (s); dt 0.05 s, gamma 0.5."""
    before = ppo.potential(torch.tensor([2.0, 2.0, 2.0]), 0.5)
    after = ppo.potential(torch.tensor([1.0, 1.0, 1.0]), 0.5)
    assert before.tolist() == [-2.0, -2.0, -2.0] and after.tolist() == [-1.0, -1.0, -1.0]
    terminated = torch.tensor([False, True, False])
    reward, used = ppo.shaped_reward(before, after, terminated, 0.05, 0.5, 1.0)
    # running: -0.05 + (0.5 * -1 - (-2)) = 1.45; terminal: Phi = 0, -0.05 + (0 + 2) = 1.95
    assert reward[:2].tolist() == pytest.approx([1.45, 1.95], abs=1e-6)
    assert used.tolist() == [-1.0, 0.0, -1.0]
    reward, _ = ppo.shaped_reward(before, after, terminated, 0.05, 0.5, 0.0)
    assert reward.tolist() == pytest.approx([-0.05] * 3)  # no shaping: 20 ticks return -1 s, minus the time
