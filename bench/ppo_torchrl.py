"""PPO side by side: TorchRL's multi-agent PPO (MAPPO) against the hand-written loop of ``swarm train
--algo ppo``, on the same environment, policy, critic, hyperparameters and budget.

``train``: TorchRL trains the task of ``swarm.learn.train.ppo`` through ``swarm.rl.torchrl_env`` (the same
batched torch swarm, episodes, GNN features and shaped team reward), with TorchRL's parts only:
``Collector`` (64 swarms x 64 ticks per batch), ``GAE`` (gamma, lambda of the config; bootstraps
truncated episodes, which the hand-written loop counts as done), ``ClipPPOLoss`` (per-robot ratio,
padding slots masked through ``loss_mask_key``, advantage normalized per minibatch), a replay buffer
sampling minibatches without replacement. MAPPO: decentralized actor, centralized critic, one set of
parameters shared by all robots. Policy: the GNN of ``models/gnn_graph_filter.npz`` as the mean of
TorchRL's ``IndependentNormal`` with the learned state-free std (``swarm.learn.train.ppo.Actor``);
critic: ``swarm.learn.train.ppo.Critic``, its swarm value given to every robot. Adam with the loop's two
learning rates and linear schedule, per-network gradient clipping, the critic-only warm-up updates.
Writes ``log.csv``, ``eval.csv`` (the loop's deterministic evaluation, ``swarm.learn.train.ppo.evaluate``),
``config.json`` and ``policy.npz`` (the last iterate, the loop's exporter) into ``--out``.

``compare``: both runs' ``policy.npz`` (and the BC model they started from, and local consensus with
its gain tuned per graph) from the first ``--starts`` starts of ``swarm sweep`` per graph at N = 20,
as ``bench/eval_ppo.py`` evaluates (kinematic engine, v_max 0.5 m/s, 0.05 s, max_pairwise <= 0.2 m
held 5 s); writes ``comparison.md``, ``.json`` and ``learning_curves.png`` into ``--out`` (default
``runs/bench/``; ``--update-results``: ``docs/results/rl/ppo/torchrl/``).

    nice -n 10 swarm train --algo ppo --config docs/results/rl/ppo/torchrl/ours.yaml --out runs/ppo-ours
    nice -n 10 python bench/ppo_torchrl.py train --out runs/ppo-torchrl   # the same ours.yaml by default
    python bench/ppo_torchrl.py compare runs/ppo-ours runs/ppo-torchrl --starts 200 --update-results
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import sys
import time
import warnings
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np
import torch
import yaml
from torch import nn

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _output import add_output_arguments, output_dir, progress

ROOT = Path(__file__).resolve().parent.parent
OUT_DIR = ROOT / "docs" / "results" / "rl" / "ppo" / "torchrl"
AGENTS = "agents"


class _Loc(nn.Module):
    """The actor's Gaussian parameters for TorchRL: ``loc = sat(GNN(x))``, ``scale = exp(log_std)``."""

    def __init__(self, actor):
        super().__init__()
        # the actor's parameters, registered here; the actor itself is kept unregistered because its
        # ``apply(features, action)`` shadows ``nn.Module.apply``, which TorchRL's collector calls
        self.gnn, self.log_std = actor.gnn, actor.log_std
        object.__setattr__(self, "_actor", actor)

    def forward(self, features: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        loc = self._actor.action_mean(features)
        return loc, self.log_std.exp().expand_as(loc)


class _TeamValue(nn.Module):
    """The centralized critic's swarm value, given to every robot slot ``(..., N, 1)`` (MAPPO)."""

    def __init__(self, critic, n_max: int):
        super().__init__()
        self.critic, self.n_max = critic, n_max

    def forward(self, robots: torch.Tensor, mask: torch.Tensor, summary: torch.Tensor) -> torch.Tensor:
        value = self.critic(robots, mask, summary)
        return value[..., None, None].expand(*value.shape, self.n_max, 1)


def build_mappo(config, actor, critic, n_max: int):
    """TorchRL's pieces around the loop's networks: the stochastic policy (``IndependentNormal``
    around ``sat(GNN(x))``), the critic as a ``ValueOperator`` and ``ClipPPOLoss`` with GAE, keyed
    for the ``"agents"`` group and masked to the robots that exist. Returns ``(policy, loss)``."""
    from tensordict.nn import TensorDictModule
    from torchrl.modules import IndependentNormal, ProbabilisticActor, ValueOperator
    from torchrl.objectives import ClipPPOLoss, ValueEstimators

    policy = ProbabilisticActor(
        TensorDictModule(
            _Loc(actor), in_keys=[(AGENTS, "observation")], out_keys=[(AGENTS, "loc"), (AGENTS, "scale")]
        ),
        in_keys=[(AGENTS, "loc"), (AGENTS, "scale")],
        out_keys=[(AGENTS, "action")],
        distribution_class=IndependentNormal,
        return_log_prob=True,
        log_prob_key=(AGENTS, "sample_log_prob"),
    )
    value = ValueOperator(
        _TeamValue(critic, n_max),
        in_keys=[(AGENTS, "critic_robots"), (AGENTS, "mask"), "critic_summary"],
        out_keys=[(AGENTS, "state_value")],
    )
    loss = ClipPPOLoss(
        actor_network=policy,
        critic_network=value,
        clip_epsilon=config.clip,
        entropy_bonus=config.entropy_coef > 0,
        entropy_coeff=config.entropy_coef if config.entropy_coef > 0 else None,
        critic_coeff=config.value_coef * 0.5,  # TorchRL's "l2" is (v - R)^2; the loop's 0.5 (v - R)^2
        loss_critic_type="l2",
        normalize_advantage=True,
        clip_value=config.clip if config.clip_value else None,
        functional=False,
    )
    loss.set_keys(
        reward=(AGENTS, "reward"),
        action=(AGENTS, "action"),
        sample_log_prob=(AGENTS, "sample_log_prob"),
        value=(AGENTS, "state_value"),
        done=(AGENTS, "done"),
        terminated=(AGENTS, "terminated"),
    )
    loss.loss_mask_key = (AGENTS, "mask")
    # one team advantage per swarm, normalized over the minibatch's robots (not per robot slot)
    warnings.filterwarnings("ignore", message="You requested advantage normalization")
    loss.make_value_estimator(ValueEstimators.GAE, gamma=config.gamma, lmbda=config.gae_lambda)
    return policy, loss


def team_to_agents(data) -> None:
    """The team reward, done and terminated for every robot slot (TorchRL's multi-agent layout)."""
    shape = (*data.get(("next", AGENTS, "mask")).shape, 1)
    for key in ("reward", "done", "terminated"):
        data.set(("next", AGENTS, key), data.get(("next", key)).unsqueeze(-2).expand(shape))


def load_config(path: str | None, overrides: dict):
    from swarm.learn.train import ppo

    data = yaml.safe_load(Path(path).read_text()) or {} if path else {}
    data.update(overrides)
    return ppo.make_config("default", data)


def train(args: argparse.Namespace) -> Path:
    """TorchRL MAPPO on ``swarm.rl.torchrl_env``; returns the exported policy file."""
    from torchrl.collectors import Collector
    from torchrl.data import LazyTensorStorage, ReplayBuffer
    from torchrl.data.replay_buffers.samplers import SamplerWithoutReplacement
    from torchrl.envs.utils import ExplorationType, set_exploration_type
    from tqdm import tqdm

    from swarm.core.robot import RobotParams
    from swarm.learn.train import ppo
    from swarm.rl.torchrl_env import SwarmTorchRLEnv

    overrides = {"out": args.out, "progress": False, "tensorboard": False}
    if args.seed is not None:
        overrides["seed"] = args.seed
    config = load_config(args.config, overrides)
    B, T = config.num_envs, config.rollout_steps
    frames_per_update = B * T
    if args.frames is not None:
        config = replace(config, stop_after=max(1, args.frames // frames_per_update))
    if args.budget_s is not None:
        config = replace(config, time_limit_s=args.budget_s)
    stop_after = config.stop_after or config.updates
    out = Path(config.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "config.json").write_text(json.dumps({**asdict(config), "trainer": "torchrl"}, indent=2) + "\n")
    torch.manual_seed(config.seed)
    torch.set_num_threads(config.threads)
    robot = RobotParams(v_max_mps=config.v_max_mps)

    gnn = ppo.load_gnn(config, robot)
    hops, scale_m = gnn.spec.hops, gnn.feature_scale_m
    actor = ppo.Actor(gnn, robot, config.init_std, config.learn_std, "velocity")
    critic = ppo.Critic(hops, config.critic_hidden, scale_m)
    env = SwarmTorchRLEnv(config, hops, scale_m)
    n_max = env.n_max

    policy, loss = build_mappo(config, actor, critic, n_max)

    actor_params = [p for p in actor.parameters() if p.requires_grad]
    optimizer = torch.optim.Adam(
        [{"params": actor_params, "lr": config.lr}, {"params": critic.parameters(), "lr": config.critic_lr}],
        eps=1e-5,
    )
    base_lrs = [config.lr, config.critic_lr]
    collector = Collector(
        env,
        policy,
        frames_per_batch=frames_per_update,
        total_frames=frames_per_update * stop_after,
        device="cpu",
        auto_register_policy_transforms=False,  # the policy is feed-forward: no InitTracker
    )
    buffer = ReplayBuffer(
        storage=LazyTensorStorage(frames_per_update),
        sampler=SamplerWithoutReplacement(),
        batch_size=frames_per_update // config.minibatches,
    )

    log_rows: list[dict] = []
    eval_rows: list[dict] = []
    episode_return = torch.zeros(B, dtype=torch.float64)
    episode_ticks = torch.zeros(B, dtype=torch.long)
    started, cpu_started = time.perf_counter(), time.process_time()
    env_steps = 0

    def run_eval(update: int) -> None:
        with set_exploration_type(ExplorationType.DETERMINISTIC):
            row = {
                "update": update,
                "env_steps": env_steps,
                **ppo.evaluate(actor, config, robot, "cpu", torch.float32),
            }
        row["score"] = ppo.eval_score(row)
        row["time_s"] = round(time.perf_counter() - started, 2)
        eval_rows.append(row)
        ppo.write_csv(out / "eval.csv", eval_rows)

    run_eval(0)
    bar = None if args.quiet else tqdm(total=stop_after, unit="update", desc="torchrl ppo")
    for update, data in enumerate(collector, start=1):
        for group, base in zip(optimizer.param_groups, base_lrs, strict=True):
            group["lr"] = base * (1.0 - (update - 1) / config.updates)
        env_steps += B * T
        # episodes that ended in this batch (data is [B, T])
        reward = data.get(("next", "reward"))[..., 0].to(torch.float64)
        done = data.get(("next", "done"))[..., 0]
        truncated = int(data.get(("next", "truncated")).sum())
        times, returns = [], []
        for t in range(T):
            episode_return += reward[:, t]
            episode_ticks += 1
            ended = done[:, t].nonzero().flatten()
            if len(ended):
                returns.extend(episode_return[ended].tolist())
                times.extend((episode_ticks[ended] * config.control_period_s).tolist())
                episode_return[ended] = 0.0
                episode_ticks[ended] = 0
        team_to_agents(data)
        with torch.no_grad():
            loss.value_estimator(data)
        buffer.extend(data.reshape(-1))
        train_policy = update > config.critic_warmup_updates
        stats: dict[str, list[float]] = {
            "policy_loss": [],
            "value_loss": [],
            "approx_kl": [],
            "clip_fraction": [],
        }
        for _ in range(config.epochs):
            for _ in range(config.minibatches):
                batch = buffer.sample()
                values = loss(batch)
                total = values["loss_critic"]
                if train_policy:
                    total = total + values["loss_objective"]
                    if "loss_entropy" in values:
                        total = total + values["loss_entropy"]
                    stats["policy_loss"].append(float(values["loss_objective"].detach()))
                    stats["approx_kl"].append(float(values["kl_approx"]))
                    stats["clip_fraction"].append(float(values["clip_fraction"]))
                stats["value_loss"].append(float(values["loss_critic"].detach()) / 0.5)
                optimizer.zero_grad(set_to_none=True)
                total.backward()
                nn.utils.clip_grad_norm_(actor_params, config.max_grad_norm)
                nn.utils.clip_grad_norm_(critic.parameters(), config.max_grad_norm)
                optimizer.step()
        row = {
            "update": update,
            "env_steps": env_steps,
            "episodes": len(returns),
            "truncated": truncated,
            "episode_time_s": float(np.mean(times)) if times else math.nan,
            "episode_return": float(np.mean(returns)) if returns else math.nan,
            "mean_reward": float(reward.mean()),
            "policy_loss": float(np.mean(stats["policy_loss"])) if stats["policy_loss"] else 0.0,
            "value_loss": float(np.mean(stats["value_loss"])),
            "approx_kl": float(np.mean(stats["approx_kl"])) if stats["approx_kl"] else 0.0,
            "clip_fraction": float(np.mean(stats["clip_fraction"])) if stats["clip_fraction"] else 0.0,
            "policy_std": float(actor.log_std.detach().exp().mean()),
            "lr": optimizer.param_groups[0]["lr"],
            "time_s": round(time.perf_counter() - started, 2),
            "cpu_s": round(time.process_time() - cpu_started, 2),
        }
        log_rows.append(row)
        ppo.write_csv(out / "log.csv", log_rows)
        out_of_time = config.time_limit_s is not None and time.perf_counter() - started > config.time_limit_s
        last = update >= stop_after or out_of_time
        if update % config.eval_every == 0 or last:
            run_eval(update)
        if bar is not None:
            bar.update()
            bar.set_postfix_str(
                f"ep {row['episode_time_s']:.1f}s kl {row['approx_kl']:.1e} eval "
                + " ".join(
                    f"{k[:-9]}={v:.2f}" for k, v in eval_rows[-1].items() if k.endswith("_median_s") and v
                )
            )
        if last:
            break
    collector.shutdown()
    if bar is not None:
        bar.close()
    training = {
        "algo": "ppo",
        "trainer": "torchrl",
        "config": asdict(config),
        "chosen_update": log_rows[-1]["update"],
        "eval": eval_rows,
        "train_time_s": round(time.perf_counter() - started, 1),
        "init_policy": config.init_policy,
    }
    return gnn.export(out / "policy.npz", robot, training)


# -- compare ------------------------------------------------------------------------------------------

TOPOLOGIES = ("cycle", "line", "random", "complete")


def read_csv(path: Path) -> list[dict]:
    with open(path, newline="") as file:
        return [{k: _number(v) for k, v in row.items()} for row in csv.DictReader(file)]


def _number(text: str):
    try:
        return float(text)
    except ValueError:
        return None if text == "" else text


def evaluate_policies(
    models: dict[str, str], starts: int, count: int, max_duration_s: float, args: argparse.Namespace
) -> list[dict]:
    """Every controller from the same ``swarm sweep`` starts as ``bench/eval_ppo.py``, per graph."""
    from eval_ppo import tuned_gains
    from tune_consensus_gain import OUT_DIR as TUNED_DIR
    from tune_consensus_gain import sweep_config

    from swarm.core import metrics
    from swarm.core.robot import RobotParams
    from swarm.scenarios.sweep import cell_starts, converge_batch
    from swarm.sim.controllers import LocalConsensus
    from swarm.sim.kinematic import KinematicSim
    from swarm.sim.policy import load_policy

    robot = RobotParams(v_max_mps=0.5)
    config = sweep_config(starts, 0.2, 0.5, 0.05)
    gains = tuned_gains(TUNED_DIR / "tuned_lc.json")
    rows = []
    for topology in progress(TOPOLOGIES, args, desc="graphs", unit="graph"):
        gain = gains[(topology, count)]
        factories = {name: (lambda n, p=path: load_policy(p, robot, n)) for name, path in models.items()}
        factories["local_consensus_tuned"] = lambda n, g=gain: LocalConsensus(robot, g)
        poses, adjacency, _ = cell_starts(config, topology, count)
        lower = np.array([metrics.lower_bound_s(p[:, :2], 0.2, robot.v_max_mps) for p in poses])
        # the undiscounted shaped return of a start is -t - Phi(s_0) = -t + D0 / (2 v_max)
        start_potential = metrics.max_pairwise(poses[..., :2]) / (2 * robot.v_max_mps)
        times = {}
        for name, factory in factories.items():
            sim = KinematicSim(robot, factory(count), 0.05, poses, adjacency)
            times[name] = converge_batch(sim, 0.2, max_duration_s, 5.0)
            print(f"{topology} N={count} {name}: median {np.nanmedian(times[name]):.2f} s", flush=True)
        reference = times["local_consensus_tuned"]
        for name, values in times.items():
            ok = ~np.isnan(values)
            median = float(np.median(values[ok])) if ok.any() else None
            rows.append(
                {
                    "topology": topology,
                    "robots": count,
                    "controller": name,
                    "tuned_gain_per_s": gain,
                    "starts": len(values),
                    "success_rate": float(ok.mean()),
                    "median_time_s": median,
                    "ratio_of_medians_to_tuned_lc": None
                    if median is None
                    else median / float(np.nanmedian(reference)),
                    "median_ratio_to_lower_bound": float(np.median(values[ok] / lower[ok]))
                    if ok.any()
                    else None,
                    "mean_return_s": float(np.mean(start_potential - values)) if ok.all() else None,
                }
            )
    return rows


def run_summary(run: Path) -> dict:
    """Wall time, swarm ticks and the training return at the end of a run (mean of its last 5 updates)."""
    log = read_csv(run / "log.csv")
    last = [row["episode_return"] for row in log[-5:] if row["episode_return"] is not None]
    last = [value for value in last if not math.isnan(value)]
    return {
        "run": str(run),
        "updates": int(log[-1]["update"]),
        "swarm_ticks": int(log[-1]["env_steps"]),
        "train_wall_s": float(log[-1]["time_s"]),
        "wall_s_per_update": float(log[-1]["time_s"]) / int(log[-1]["update"]),
        "final_training_return": float(np.mean(last)) if last else None,
        "final_training_episode_time_s": float(np.nanmean([row["episode_time_s"] for row in log[-5:]])),
    }


def _smooth(values: list[float], width: int = 5) -> np.ndarray:
    """Running mean over the last ``width`` updates (NaN updates skipped)."""
    values = np.asarray(values, dtype=float)
    out = np.full_like(values, np.nan)
    for i in range(len(values)):
        window = values[max(0, i - width + 1) : i + 1]
        if np.isfinite(window).any():
            out[i] = np.nanmean(window)
    return out


def plot(runs: dict[str, Path], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 2, figsize=(13, 8), dpi=110)
    colors = {"hand-written": "tab:blue", "torchrl": "tab:orange"}
    for name, run in runs.items():
        log, evals = read_csv(run / "log.csv"), read_csv(run / "eval.csv")
        color = colors.get(name)
        wall = [row["time_s"] for row in log]
        ticks = [row["env_steps"] for row in log]
        returns = [row["episode_return"] for row in log]
        for ax, x in ((axes[0, 0], wall), (axes[0, 1], ticks)):
            ax.plot(x, returns, color=color, alpha=0.25)
            ax.plot(x, _smooth(returns), color=color, label=f"{name} (mean of 5 updates)")
        # the wall time at the end of the update whose iterate was evaluated (update 0: the start)
        at = {row["update"]: row["time_s"] for row in log}
        eval_wall = [at.get(row["update"], 0.0) for row in evals]
        eval_ticks = [row["env_steps"] for row in evals]
        for ax, x in ((axes[1, 0], eval_wall), (axes[1, 1], eval_ticks)):
            for cell, style in (("cycle20", "-"), ("line20", "--")):
                values = [row[f"{cell}_median_s"] for row in evals]
                ax.plot(x, values, style, marker="o", ms=3, color=color, label=f"{name} {cell}")
    for ax, xlabel in ((axes[0, 0], "wall time (s)"), (axes[0, 1], "swarm ticks")):
        ax.set(
            xlabel=xlabel, ylabel="shaped return per training episode", title=f"training return vs {xlabel}"
        )
    for ax, xlabel in ((axes[1, 0], "wall time (s)"), (axes[1, 1], "swarm ticks")):
        ax.set(
            xlabel=xlabel,
            ylabel="median convergence time (s)",
            title="deterministic policy, 32 fixed starts, N = 20",
        )
    for ax in axes.flat:
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def compare(args: argparse.Namespace) -> None:
    runs = {"hand-written": Path(args.ours), "torchrl": Path(args.torchrl)}
    for run in runs.values():
        for name in ("log.csv", "eval.csv", "policy.npz"):
            if not (run / name).is_file():
                print(f"{run / name}: missing (train the run first)", file=sys.stderr)
                raise SystemExit(2)
    models = {"ppo_hand_written": str(runs["hand-written"] / "policy.npz")}
    models["ppo_torchrl"] = str(runs["torchrl"] / "policy.npz")
    models["bc_start"] = args.bc
    rows = evaluate_policies(models, args.starts, 20, args.max_duration, args)
    summaries = {name: run_summary(run) for name, run in runs.items()}
    out = output_dir(args, OUT_DIR)
    plot(runs, out / "learning_curves.png")
    (out / "comparison.json").write_text(
        json.dumps(
            {"settings": {k: str(v) for k, v in vars(args).items()}, "runs": summaries, "evaluation": rows},
            indent=2,
        )
        + "\n"
    )
    lines = [
        "| trainer | updates | swarm ticks | wall (s) | s / update | final training return "
        "| final episode (s) |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, s in summaries.items():
        lines.append(
            f"| {name} | {s['updates']} | {s['swarm_ticks']:,} | {s['train_wall_s']:.0f} | "
            f"{s['wall_s_per_update']:.2f} | {s['final_training_return']:.3f} | "
            f"{s['final_training_episode_time_s']:.2f} |"
        )
    lines += [
        "",
        "| graph | controller | success | median t (s) | t / tuned LC | t / LB | return (s) |",
        "|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        lines.append(
            f"| {row['topology']} | {row['controller']} | {row['success_rate']:.1%} | "
            f"{row['median_time_s']:.2f} | {row['ratio_of_medians_to_tuned_lc']:.3f} | "
            f"{row['median_ratio_to_lower_bound']:.3f} | {row['mean_return_s']:.2f} |"
        )
    header = [
        "# PPO side by side: the hand-written loop and TorchRL's MAPPO",
        "",
        f"Command: `python bench/ppo_torchrl.py compare {args.ours} {args.torchrl} --starts {args.starts}"
        + (" --update-results" if args.update_results else f" --out {args.out}")
        + "`. "
        f"Runs: `{args.ours}` (`swarm train --algo ppo`), `{args.torchrl}` (`bench/ppo_torchrl.py train`). "
        f"Evaluation: the first {args.starts} starts of `swarm sweep` per graph (seed 0) at N = 20, "
        "kinematic engine, v_max 0.5 m/s, 0.05 s, max_pairwise <= 0.2 m held 5 s (as `bench/eval_ppo.py`); "
        "tuned LC: local consensus with its gain tuned per graph (`tuned_lc.json`); t / tuned LC: ratio "
        "of medians; "
        "t / LB: median per-start ratio to the lower bound. Final training return: mean shaped return of "
        "the episodes that ended in the last 5 updates. Return (s): the deterministic policy's undiscounted "
        "shaped return, -t + max_pairwise(start) / (2 v_max), mean over the starts.",
        "",
    ]
    (out / "comparison.md").write_text("\n".join(header + lines) + "\n")
    print("\n".join(lines))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser(
        "train", help="train TorchRL's MAPPO on the swarm (same config as swarm train --algo ppo)"
    )
    p.add_argument(
        "--config", default=str(OUT_DIR / "ours.yaml"), help="a swarm train --algo ppo YAML config"
    )
    p.add_argument("--out", default="runs/ppo-torchrl", help="run directory (log.csv, eval.csv, policy.npz)")
    p.add_argument("--seed", type=int, default=None, help="overrides the config's seed")
    p.add_argument("--frames", type=int, default=None, help="swarm ticks to train (overrides stop_after)")
    p.add_argument("--budget-s", type=float, default=None, help="also stop after this wall time (s)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    c = sub.add_parser("compare", help="evaluate both runs' policies and write the comparison")
    c.add_argument("ours", help="run directory of swarm train --algo ppo")
    c.add_argument("torchrl", help="run directory of bench/ppo_torchrl.py train")
    c.add_argument("--bc", default="models/gnn_graph_filter.npz", help="the policy both started from")
    c.add_argument("--starts", type=int, default=200, help="first starts of swarm sweep per graph")
    c.add_argument("--max-duration", type=float, default=3000.0)
    add_output_arguments(c, committed=OUT_DIR)
    args = parser.parse_args(argv)
    if args.command == "train":
        if args.config and not Path(args.config).is_file():
            print(f"{args.config}: no such config file", file=sys.stderr)
            return 2
        try:
            path = train(args)
        except ValueError as error:
            print(f"{args.config}: {error}", file=sys.stderr)
            return 2
        print(f"policy: {path}")
    else:
        compare(args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
