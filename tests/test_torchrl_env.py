"""The batched swarm as a TorchRL environment (swarm.rl.torchrl_env): TorchRL's own spec check, its
collector, partial resets, and the shaped return against its closed form; bench/ppo_torchrl.py's
training end to end on a tiny budget."""

from __future__ import annotations

import csv
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("torchrl", reason="torchrl is not installed (pip install -e .[torchrl])")

import torch
from tensordict.nn import TensorDictModule
from torchrl.collectors import Collector
from torchrl.envs.utils import RandomPolicy, check_env_specs

from swarm.core import metrics
from swarm.learn.train import ppo
from swarm.rl.torchrl_env import SwarmTorchRLEnv
from swarm.sim.policy import load_policy

ROOT = Path(__file__).resolve().parent.parent
# PPO fine-tunes the gated graph filter (the default before the flooding GNN), as `swarm train --algo ppo`.
DEFAULT_MODEL = ROOT / "models" / "gnn_graph_filter.npz"


def make_env(**overrides) -> SwarmTorchRLEnv:
    config = ppo.make_config("tiny", {"init_policy": str(DEFAULT_MODEL), **overrides})
    return SwarmTorchRLEnv(config, hops=8, feature_scale_m=load_policy(DEFAULT_MODEL).feature_scale_m)


def gnn_policy(env: SwarmTorchRLEnv) -> TensorDictModule:
    """The BC GNN's deterministic action, as ``swarm.sim.policy`` runs it."""
    robot = env.robot
    actor = ppo.Actor(ppo.load_gnn(env.config, robot), robot, 0.05, False, "velocity")
    return TensorDictModule(
        lambda features: actor.mean(features).detach(),
        in_keys=[("agents", "observation")],
        out_keys=[("agents", "action")],
    )


def test_env_passes_torchrl_check_env_specs():
    env = make_env()
    check_env_specs(env, seed=0)
    td = env.reset()
    mask = td.get(("agents", "mask"))
    counts = env.swarm.count
    assert torch.equal(mask, torch.arange(env.n_max)[None, :] < counts[:, None])
    # on an episode's first tick nobody has heard anybody (messages are a tick old)
    assert torch.count_nonzero(td.get(("agents", "observation"))) == 0


def test_collector_runs_a_few_batches():
    env = make_env(num_envs=3)
    collector = Collector(
        env, RandomPolicy(env.action_spec), frames_per_batch=3 * 8, total_frames=3 * 8 * 2,
        auto_register_policy_transforms=False,
    )  # fmt: skip
    batches = list(collector)
    collector.shutdown()
    assert len(batches) == 2
    for data in batches:
        assert data.batch_size == torch.Size([3, 8])
        assert data.get(("agents", "action")).shape == (3, 8, env.n_max, 2)
        assert torch.isfinite(data.get(("next", "reward"))).all()
        # the robots moved: the observation is no longer the first tick's zeros
        assert torch.count_nonzero(data.get(("next", "agents", "observation"))) > 0


@pytest.mark.slow
def test_shaped_return_is_minus_time_plus_the_start_potential():
    """gamma = 1: the shaping telescopes, so an episode's return is -T + D0 / (2 v_max), with D0 the
    start's diameter (numpy, from the poses the episode started from); auto partial resets start
    new episodes only in the swarms that ended."""
    env = make_env(num_envs=3, gamma=1.0, sizes=(4, 6), max_episode_s=60.0)
    policy = gnn_policy(env)
    v_max, dt = env.config.v_max_mps, env.config.control_period_s

    def start_diameters() -> np.ndarray:
        positions, counts = env.swarm.positions.double().numpy(), env.swarm.count.numpy()
        return np.array([float(metrics.max_pairwise(positions[b, : counts[b]])) for b in range(3)])

    td = env.reset()
    diameter0 = start_diameters()
    returns, ticks = np.zeros(3), np.zeros(3, dtype=int)
    checked = 0
    for _ in range(800):
        td = policy(td)
        before = env.swarm.positions.clone()
        td, td_next = env.step_and_maybe_reset(td)
        returns += td.get(("next", "reward"))[:, 0].double().numpy()
        ticks += 1
        done = td.get(("next", "done"))[:, 0].numpy()
        terminated = td.get(("next", "terminated"))[:, 0].numpy()
        for b in np.flatnonzero(done):
            assert terminated[b], "the GNN converges on these small graphs well within 60 s"
            np.testing.assert_allclose(returns[b], -ticks[b] * dt + diameter0[b] / (2 * v_max), atol=1e-4)
            checked += 1
        if done.any():
            fresh = start_diameters()
            # only the swarms that ended were redrawn
            moved = (env.swarm.positions - before).abs().amax(dim=(1, 2)).numpy()
            assert np.all(moved[~done] < v_max * dt + 1e-6)
            diameter0[done] = fresh[done]
            returns[done], ticks[done] = 0.0, 0
        td = td_next
    assert checked >= 6, f"only {checked} episodes ended"


def test_torchrl_gae_and_loss_equal_the_loop_equations():
    """On one collected batch, TorchRL's GAE equals the loop's recursion (no truncation in the batch)
    and ClipPPOLoss's actor gradient equals the loop's clipped surrogate over the robots that exist
    (per robot ratio, team advantage normalized over the minibatch; up to n vs n - 1 in its std)."""
    sys.path.insert(0, str(ROOT / "bench"))
    from ppo_torchrl import build_mappo, team_to_agents

    torch.manual_seed(0)
    env = make_env(num_envs=4, sizes=(4, 6), init_std=0.1)
    config, robot = env.config, env.robot
    actor = ppo.Actor(ppo.load_gnn(config, robot), robot, config.init_std, True, "velocity")
    critic = ppo.Critic(8, 16, env.scale_m)
    policy, loss = build_mappo(config, actor, critic, env.n_max)
    B, T = 4, 200
    collector = Collector(
        env, policy, frames_per_batch=B * T, total_frames=B * T, auto_register_policy_transforms=False
    )
    data = next(iter(collector))
    collector.shutdown()
    assert not data.get(("next", "truncated")).any()
    assert data.get(("next", "terminated")).sum() >= 2, "too few episodes ended to test the done handling"
    team_to_agents(data)
    with torch.no_grad():
        loss.value_estimator(data)
        value = critic(
            data.get(("agents", "critic_robots")), data.get(("agents", "mask")), data["critic_summary"]
        )
        last_value = critic(
            data.get(("next", "agents", "critic_robots"))[:, -1],
            data.get(("next", "agents", "mask"))[:, -1],
            data["next", "critic_summary"][:, -1],
        )
    # the loop's GAE: delta_t = r_t + gamma V(s_t+1) (1 - done_t) - V(s_t),
    # A_t = delta_t + gamma lambda (1 - done_t) A_t+1
    reward, done = data["next", "reward"][..., 0], data["next", "done"][..., 0].float()
    advantage, running = torch.zeros(B, T), torch.zeros(B)
    for t in reversed(range(T)):
        following = last_value if t == T - 1 else value[:, t + 1]
        alive = 1.0 - done[:, t]
        delta = reward[:, t] + config.gamma * following * alive - value[:, t]
        running = delta + config.gamma * config.gae_lambda * alive * running
        advantage[:, t] = running
    torchrl_advantage = data["advantage"]
    assert torch.allclose(
        torchrl_advantage, advantage[..., None, None].expand_as(torchrl_advantage), atol=1e-5
    )
    # the actor gradient of one minibatch (the whole batch)
    flat = data.reshape(-1)
    actor.zero_grad()
    loss(flat)["loss_objective"].backward()
    torchrl_grad = [p.grad.clone() for p in actor.parameters()]
    actor.zero_grad()
    adv = flat["advantage"][:, 0, 0]
    adv = (adv - adv.mean()) / (adv.std() + 1e-8)
    valid = flat.get(("agents", "mask"))
    logp = (
        actor.distribution(flat.get(("agents", "observation"))[valid])
        .log_prob(flat.get(("agents", "action"))[valid])
        .sum(-1)
    )
    ratio = (logp - flat.get(("agents", "sample_log_prob"))[valid]).exp()
    robot_adv = adv[:, None].expand_as(valid)[valid]
    clip = config.clip
    torch.max(-robot_adv * ratio, -robot_adv * ratio.clamp(1 - clip, 1 + clip)).mean().backward()
    for mine, theirs in zip(torchrl_grad, (p.grad for p in actor.parameters()), strict=True):
        assert torch.allclose(mine, theirs, rtol=5e-3, atol=1e-7)


@pytest.mark.slow
def test_bench_training_runs_end_to_end(tmp_path):
    """bench/ppo_torchrl.py train: TorchRL's collector, GAE and ClipPPOLoss for two updates."""
    config = tmp_path / "tiny.yaml"
    config.write_text(
        f"init_policy: {DEFAULT_MODEL}\nnum_envs: 4\nrollout_steps: 16\nupdates: 2\nsizes: [4, 8]\n"
        "epochs: 2\nminibatches: 2\ncritic_warmup_updates: 0\neval_every: 2\neval_cells: [[cycle, 6]]\n"
        "eval_starts: 4\neval_max_s: 20.0\nlr: 1.0e-3\n"
    )
    out = tmp_path / "run"
    result = subprocess.run(
        [sys.executable, str(ROOT / "bench" / "ppo_torchrl.py"), "train", "--config", str(config),
         "--out", str(out), "--quiet"],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert result.returncode == 0, result.stderr[-2000:]
    with open(out / "log.csv", newline="") as file:
        rows = list(csv.DictReader(file))
    assert [int(row["update"]) for row in rows] == [1, 2]
    assert all(float(row["approx_kl"]) > 0 for row in rows), "the policy was updated"
    policy = load_policy(out / "policy.npz")
    assert policy.metadata["training"]["trainer"] == "torchrl"
    start = np.load(DEFAULT_MODEL)
    trained = np.load(out / "policy.npz")
    assert any(not np.allclose(trained[name], start[name]) for name in start.files if name != "__metadata__")


@pytest.mark.slow
def test_bench_training_refuses_a_missing_config(tmp_path):
    result = subprocess.run(
        [sys.executable, str(ROOT / "bench" / "ppo_torchrl.py"), "train", "--config",
         str(tmp_path / "no.yaml")],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert result.returncode == 2 and "no.yaml" in result.stderr
