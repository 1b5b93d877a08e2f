"""DQN on the thesis's single-agent consensus env ``swarm/Consensus-v0`` (thesis 2.5.1, appendices C-D).

The thesis's DQN never trained: it used the network's output as the action and broke the batching.
This is Stable-Baselines3's DQN (experience replay, target network, epsilon-greedy, Huber loss): the
action is ``argmax_a Q(s, a)`` over the four point velocities, and minibatches are sampled from the
replay buffer. Robot 0 learns from its local ``[Mx, My, Phix, Phiy]`` while the others run local
consensus (``swarm.rl.consensus_env`` documents the reward and termination).

Reads top to bottom: hyperparameters, environment, logs (episode CSV, SB3 CSV and TensorBoard),
callbacks (tqdm progress, periodic greedy evaluation, checkpoints), training, final evaluation of the
greedy policy against a random policy and a hand-written one on held-out seeds, learning-curve plot.
Outputs in ``out``: ``model.zip``, ``checkpoints/``, ``monitor.csv`` (one row per training episode),
``progress.csv`` and ``events.out.tfevents.*`` (SB3 logger), ``eval_curve.csv``, ``eval.json``,
``learning_curve.png``.

Run: ``swarm train --algo dqn --out runs/dqn`` (``--config FILE``: YAML with any ``DQNConfig`` field,
``env:`` holding ``ConsensusConfig`` overrides).
"""

from __future__ import annotations

import csv
import json
import shlex
import sys
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import gymnasium
import numpy as np
import torch
from stable_baselines3 import DQN
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback, CallbackList, CheckpointCallback
from stable_baselines3.common.logger import configure
from stable_baselines3.common.monitor import Monitor

from swarm.learn.train import preset_with_overrides
from swarm.rl import ENV_ID
from swarm.rl.consensus_env import make_thesis_vector_env, thesis_config
from swarm.rl.vector_env import DISCRETE_ACTIONS
from swarm.sim.features import saturate_local_velocity


@dataclass(frozen=True)
class DQNConfig:
    out: str = "runs/dqn"
    seed: int = 0
    total_timesteps: int = 40_000
    env: dict = field(default_factory=dict)  # ConsensusConfig overrides of the thesis env (discrete actions)
    # DQN (Mnih et al. 2015 as in SB3); 50 steps of 0.2 s per episode at most
    learning_rate: float = 1e-3
    buffer_size: int = 40_000
    learning_starts: int = 1_000
    batch_size: int = 64
    gamma: float = 0.95
    train_freq: int = 2
    gradient_steps: int = 1
    target_update_interval: int = 500
    exploration_fraction: float = 0.25
    exploration_final_eps: float = 0.05
    net_arch: tuple[int, ...] = (64, 64)
    # evaluation: greedy policy on held-out seeds (eval_seed + episode)
    eval_every: int = 5_000
    eval_episodes_during: int = 100
    eval_episodes: int = 1_000
    eval_seed: int = 1_000_000
    transfer_episodes: int = 200  # per setting of TRANSFER (0: skip)
    checkpoint_every: int = 10_000
    threads: int = 1  # torch intra-op threads
    progress: bool = True


PRESETS: dict[str, DQNConfig] = {
    "default": DQNConfig(),
    # seconds: for tests and smoke runs
    "tiny": DQNConfig(
        total_timesteps=2_000,
        learning_starts=500,
        eval_every=1_000,
        eval_episodes_during=20,
        eval_episodes=50,
        transfer_episodes=0,
        checkpoint_every=1_000,
        progress=False,
    ),
}


# Settings the trained policy never saw (thesis appendix D: "generalize to more complex topologies").
TRANSFER: tuple[dict, ...] = (
    {"topology": "complete"},
    {"topology": "line"},
    {"topology": "star"},
    {"topology": "random"},
    {"robots": 4},
    {"robots": 10},
    {"others": "centralized"},
)


def make_config(preset: str = "default", overrides: dict | None = None) -> DQNConfig:
    config = preset_with_overrides("dqn", PRESETS, preset, overrides, tuple_fields=("net_arch",))
    thesis_config(**config.env)  # fail early on a bad environment option
    return config


# --- evaluation: B held-out episodes stepping together, one policy for all ----------------------------
Policy = Callable[[np.ndarray], np.ndarray]  # observations (B, 4) -> discrete actions (B,)


def evaluate(policy: Policy, env_overrides: dict, episodes: int, seed: int) -> dict:
    """Run the episodes of ``ConsensusEnv.reset(seed=seed + e)``, e < episodes; success: consensus in time."""
    venv = make_thesis_vector_env(episodes, autoreset=False, **env_overrides)
    obs, _ = venv.reset(seed=seed)
    done = np.zeros(episodes, dtype=bool)
    success = np.zeros(episodes, dtype=bool)
    returns = np.zeros(episodes)
    times = np.full(episodes, np.nan)
    for _ in range(venv.config.max_steps):
        obs, reward, terminated, truncated, info = venv.step(policy(obs[:, 0])[:, None])
        returns += np.where(done, 0.0, reward)
        finished = (terminated | truncated) & ~done
        success |= finished & terminated
        times[finished & terminated] = info["time_s"][finished & terminated]
        done |= finished
        if done.all():
            break
    return {
        "episodes": episodes,
        "success_rate": float(success.mean()),
        "mean_return": float(returns.mean()),
        "median_consensus_time_s": float(np.nanmedian(times)) if success.any() else None,
    }


def random_policy(seed: int) -> Policy:
    rng = np.random.default_rng(seed)
    return lambda obs: rng.integers(0, len(DISCRETE_ACTIONS), size=len(obs))


def toward_neighbours_policy(env_overrides: dict) -> Policy:
    """Hand-written reference: the action whose (saturated) velocity points most along M."""
    config = thesis_config(**env_overrides)
    velocities = saturate_local_velocity(config.v_max_mps * DISCRETE_ACTIONS, config.robot)
    return lambda obs: np.argmax(obs[:, :2] @ velocities.T, axis=1)


def greedy_policy(model: BaseAlgorithm) -> Policy:
    return lambda obs: model.predict(obs, deterministic=True)[0]


# --- callbacks ---------------------------------------------------------------------------------------
class ProgressBar(BaseCallback):
    """tqdm bar over environment steps with the last greedy success rate (SB3's own bar needs ``rich``)."""

    def __init__(self, total: int, evaluations: list[dict]):
        super().__init__()
        self.total, self.evaluations = total, evaluations

    def _on_training_start(self) -> None:
        from tqdm import tqdm

        self.bar = tqdm(total=self.total, unit="step", desc="dqn", dynamic_ncols=True)

    def _on_step(self) -> bool:
        self.bar.update(1)
        if self.evaluations and self.n_calls % 1000 == 0:
            self.bar.set_postfix(greedy_success=f"{self.evaluations[-1]['success_rate']:.2f}")
        return True

    def _on_training_end(self) -> None:
        self.bar.close()


class GreedyEvaluation(BaseCallback):
    """Every ``every`` steps: the greedy policy's success rate on fixed held-out episodes -> logs and CSV."""

    def __init__(self, config: DQNConfig, path: Path, rows: list[dict]):
        super().__init__()
        self.config, self.path, self.rows = config, path, rows

    def evaluate_now(self) -> None:
        config = self.config
        result = evaluate(
            greedy_policy(self.model), config.env, config.eval_episodes_during, config.eval_seed
        )
        row = {"timesteps": self.num_timesteps, **result}
        self.rows.append(row)
        self.logger.record("eval/success_rate", result["success_rate"])
        self.logger.record("eval/mean_return", result["mean_return"])
        with self.path.open("w", newline="") as file:
            writer = csv.DictWriter(file, fieldnames=list(row))
            writer.writeheader()
            writer.writerows(self.rows)

    def _on_training_start(self) -> None:
        self.evaluate_now()

    def _on_step(self) -> bool:
        if self.num_timesteps % self.config.eval_every == 0:
            self.evaluate_now()
        return True


# --- plot --------------------------------------------------------------------------------------------
def plot_learning_curve(out: Path, eval_rows: list[dict], baselines: dict[str, dict]) -> Path:
    """Training episode returns, then the greedy policy's success rate and return on held-out episodes."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    episodes = np.genfromtxt(out / "monitor.csv", delimiter=",", skip_header=2, usecols=(0, 1), ndmin=2)
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.4), dpi=90)
    if len(episodes):
        steps = np.cumsum(episodes[:, 1])
        window = max(1, min(50, len(episodes) // 10))
        smooth = np.convolve(episodes[:, 0], np.ones(window) / window, mode="valid")
        axes[0].plot(steps, episodes[:, 0], color="0.8", lw=0.5)
        axes[0].plot(steps[window - 1 :], smooth, color="C0", label=f"mean of {window}")
        axes[0].legend(loc="lower right")
    axes[0].set(xlabel="environment steps", ylabel="episode return (m s)", title="training (epsilon-greedy)")
    eval_steps = [row["timesteps"] for row in eval_rows]
    for axis, key, label in (
        (axes[1], "success_rate", "success rate"),
        (axes[2], "mean_return", "mean return"),
    ):
        axis.plot(eval_steps, [row[key] for row in eval_rows], "o-", color="C0", label="DQN greedy")
        for (name, result), color in zip(baselines.items(), ("C3", "C2"), strict=False):
            axis.axhline(result[key], ls="--", color=color, label=name)
        axis.set(xlabel="environment steps", ylabel=label, title=f"held-out episodes: {label}")
    axes[1].set_ylim(-0.02, 1.02)
    axes[2].set_ylim(bottom=min(result["mean_return"] for result in baselines.values()) * 1.1)
    axes[1].legend(loc="lower right", fontsize=8)
    for axis in axes:
        axis.grid(alpha=0.3)
    fig.tight_layout()
    path = out / "learning_curve.png"
    fig.savefig(path)
    plt.close(fig)
    return path


# --- training ----------------------------------------------------------------------------------------
def train(config: DQNConfig, command: str | None = None) -> Path:
    """Train, evaluate and plot; returns the path of the saved model (``model.zip``)."""
    command = command or shlex.join([Path(sys.argv[0]).name, *sys.argv[1:]])
    out = Path(config.out)
    out.mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(config.threads)

    env = Monitor(gymnasium.make(ENV_ID, **config.env), str(out), info_keywords=("is_success",))
    model = DQN(
        "MlpPolicy",
        env,
        learning_rate=config.learning_rate,
        buffer_size=config.buffer_size,
        learning_starts=config.learning_starts,
        batch_size=config.batch_size,
        gamma=config.gamma,
        train_freq=config.train_freq,
        gradient_steps=config.gradient_steps,
        target_update_interval=config.target_update_interval,
        exploration_fraction=config.exploration_fraction,
        exploration_final_eps=config.exploration_final_eps,
        policy_kwargs={"net_arch": list(config.net_arch)},
        seed=config.seed,
        device="cpu",
        verbose=0,
    )
    model.set_logger(configure(str(out), ["csv", "tensorboard"]))

    eval_rows: list[dict] = []
    callbacks = [
        GreedyEvaluation(config, out / "eval_curve.csv", eval_rows),
        CheckpointCallback(config.checkpoint_every, str(out / "checkpoints"), name_prefix="dqn"),
    ]
    if config.progress:
        callbacks.append(ProgressBar(config.total_timesteps, eval_rows))
    started = time.perf_counter()
    model.learn(config.total_timesteps, callback=CallbackList(callbacks))
    training_s = time.perf_counter() - started
    model_path = out / "model.zip"
    model.save(model_path)
    env.close()

    # final evaluation on held-out episodes: greedy DQN, random, and the hand-written reference
    def compare(env_overrides: dict, episodes: int) -> dict:
        policies = {
            "dqn_greedy": greedy_policy(model),
            "random": random_policy(config.seed),
            "toward_neighbours": toward_neighbours_policy(env_overrides),
        }
        return {
            name: evaluate(policy, env_overrides, episodes, config.eval_seed)
            for name, policy in policies.items()
        }

    results = compare(config.env, config.eval_episodes)
    transfer = {}
    if config.transfer_episodes:
        for setting in TRANSFER:
            label = ", ".join(f"{key}={value}" for key, value in setting.items())
            rows = compare({**config.env, **setting}, config.transfer_episodes)
            transfer[label] = {name: row["success_rate"] for name, row in rows.items()}
    summary = {
        "env_id": ENV_ID,
        "env": thesis_config(**config.env).to_dict(),
        "dqn": asdict(config),
        "training_time_s": round(training_s, 1),
        "torch_threads": config.threads,
        "eval_seeds": [config.eval_seed, config.eval_seed + config.eval_episodes - 1],
        "success": "max_pairwise <= threshold_m within time_limit_s (greedy policy, held-out seeds)",
        "results": results,
        "transfer_success_rates": transfer,
        "command": command,
    }
    (out / "eval.json").write_text(json.dumps(summary, indent=2) + "\n")
    plot_learning_curve(
        out,
        eval_rows,
        {"random": results["random"], "toward neighbours (hand-written)": results["toward_neighbours"]},
    )
    return model_path


def main(argv: list[str] | None = None) -> int:
    """``python -m swarm.rl.dqn [--preset P] [--config FILE] [--out DIR]`` (as ``swarm train --algo dqn``)."""
    import argparse

    import yaml

    parser = argparse.ArgumentParser(prog="python -m swarm.rl.dqn", description=__doc__.splitlines()[0])
    parser.add_argument("--preset", default="default", choices=sorted(PRESETS))
    parser.add_argument("--config", help="YAML file with DQNConfig fields")
    parser.add_argument("--out", help="output directory")
    args = parser.parse_args(argv)
    overrides = (yaml.safe_load(Path(args.config).read_text()) or {}) if args.config else {}
    if args.out:
        overrides["out"] = args.out
    config = make_config(args.preset, overrides)
    command = "python -m swarm.rl.dqn " + shlex.join(sys.argv[1:] if argv is None else argv)
    print(f"model: {train(config, command)}")
    print(json.dumps(json.loads((Path(config.out) / "eval.json").read_text())["results"], indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
