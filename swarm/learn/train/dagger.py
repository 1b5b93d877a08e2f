"""DAgger (Ross et al. 2011): the expert relabels the states the learner itself visits.

Reads top to bottom: hyperparameters, the beta-mixture driver, the loop. Iteration 0 is behavioural
cloning on expert-driven data (``data``, from ``swarm collect``) or a given ``init_policy``. Each
iteration i >= 1 then rolls out the mixture ``pi_i = beta_i expert + (1 - beta_i) learner`` (drawn per
environment and tick, ``beta_i = beta0 * beta_decay ** (i - 1)``) in the batched simulator with the
``swarm.learn.data`` recorder (same features, same saturated centralized labels), aggregates the samples
with all earlier ones, and refits with ``swarm.learn.train.bc`` (warm start from the last learner, a short
cosine schedule). Every iterate is checked in closed loop on a small grid of sparse graphs (median
convergence time summed over cells); the exported policy is the best iterate, as in the paper.

Outputs in ``out``: ``log.csv`` (iteration, beta, samples, validation loss, closed-loop medians),
``curve.png``, ``iter_<i>/`` (the bc run: checkpoints, log, policy), ``data.npz`` (aggregated) and
``policy.npz``. Run: ``swarm train --algo dagger --data data/bc.npz --out runs/dagger``.
"""

from __future__ import annotations

import csv
import json
import logging
import shutil
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from swarm.core.experts import complete_consensus_velocity
from swarm.core.robot import RobotParams, rotate, world_to_local
from swarm.learn.data import Dataset, collect, collect_config, load_dataset
from swarm.learn.train import bc, preset_with_overrides
from swarm.sim.features import saturate_local_velocity
from swarm.sim.policy import load_policy

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class DAggerConfig:
    out: str = "runs/dagger"
    seed: int = 0
    data: str = "data/bc.npz"  # expert-driven data of iteration 0 (swarm collect)
    init_policy: str | None = None  # iteration 0's learner; None: behavioural cloning on `data`
    iterations: int = 4
    beta0: float = 0.5  # expert share of the driving in iteration 1
    beta_decay: float = 0.5
    samples_per_iteration: int = 250_000
    collect: dict = field(default_factory=dict)  # learn.data.CollectConfig overrides (sizes, graphs, ...)
    bc: dict = field(default_factory=lambda: {"epochs": 4, "lr": 1e-3})  # BCConfig overrides, refits
    warm_start: bool = True
    # closed-loop check of every iterate: starts per cell, cells, time limit
    eval_seeds: int = 16
    eval_cells: tuple[tuple[str, int], ...] = (("cycle", 12), ("line", 12), ("cycle", 24), ("line", 24))
    eval_max_duration_s: float = 600.0
    progress: bool = True


PRESETS: dict[str, DAggerConfig] = {"default": DAggerConfig()}


def make_config(preset: str = "default", overrides: dict | None = None) -> DAggerConfig:
    overrides = dict(overrides or {})
    if "eval_cells" in overrides:
        overrides["eval_cells"] = [(str(t), int(n)) for t, n in overrides["eval_cells"]]
    config = preset_with_overrides("dagger", PRESETS, preset, overrides, tuple_fields=("eval_cells",))
    if not Path(config.data).is_file():
        raise ValueError(f"data: no such file {config.data} (make one with 'swarm collect')")
    if config.init_policy is not None and not Path(config.init_policy).is_file():
        raise ValueError(f"init_policy: no such file {config.init_policy}")
    return config


class MixtureDriver:
    """Moves each environment with the expert (probability ``beta``, drawn every tick) or the learner."""

    centralized = False

    def __init__(self, learner, robot: RobotParams, beta: float, rng: np.random.Generator, gain: float = 1.0):
        self.learner, self.robot, self.beta, self.rng, self.gain = learner, robot, beta, rng, gain
        self.message_dim = learner.message_dim

    def act(self, poses, points, inbox, heard):
        u_world, outbox = self.learner.act(poses, points, inbox, heard)
        expert = self.rng.random(len(poses)) < self.beta
        if expert.any():
            theta = poses[expert][..., 2]
            u_expert = complete_consensus_velocity(points[expert], self.gain)
            local = saturate_local_velocity(world_to_local(u_expert, theta), self.robot)
            u_world[expert] = rotate(local, theta)
        return u_world, outbox


def closed_loop(config: DAggerConfig, policy_path: Path) -> dict[str, float | None]:
    """Median convergence time of the policy per evaluation cell (``swarm.learn.train.evaluate``)."""
    from swarm.learn.train.evaluate import compare

    result = {}
    for topology, count in config.eval_cells:
        rows = compare(
            {"policy": lambda robot, n: load_policy(policy_path, robot, n)},
            [topology],
            [count],
            config.eval_seeds,
            max_duration_s=config.eval_max_duration_s,
        )
        result[f"{topology}{count}_median_s"] = rows[0]["median_time_s"]
    return result


def aggregate(first: Dataset, second: Dataset) -> Dataset:
    columns = ("features", "labels", "robot_count", "graph", "tick")
    merged = {name: np.concatenate([getattr(first, name), getattr(second, name)]) for name in columns}
    return Dataset(**merged, metadata=first.metadata)


def plot_curve(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4), dpi=110)
    iterations = [row["iteration"] for row in rows]
    axes[0].plot(iterations, [row["val_loss"] for row in rows], marker="o")
    axes[0].set(xlabel="DAgger iteration", ylabel="validation MSE (aggregated data)", yscale="log")
    for key in rows[0]:
        if key.endswith("_median_s"):
            axes[1].plot(iterations, [row[key] or np.nan for row in rows], marker="o", label=key[:-9])
    axes[1].set(xlabel="DAgger iteration", ylabel="median convergence time (s)", yscale="log")
    axes[1].legend(fontsize=7)
    for ax in axes:
        ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def train(config: DAggerConfig) -> Path:
    """Run the DAgger loop; returns the exported policy file (the best iterate in closed loop)."""
    dataset = load_dataset(config.data)  # first: a bad file leaves no output folder behind
    out = Path(config.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "config.json").write_text(json.dumps(asdict(config), indent=2) + "\n")
    rng = np.random.default_rng(config.seed)
    collect_base = collect_config(**{**dataset.metadata["config"], **config.collect})
    collect_base = replace(collect_base, samples=config.samples_per_iteration)
    bc_base = {"seed": config.seed, "progress": config.progress, **config.bc}
    started = time.perf_counter()

    def fit(iteration: int, data_path: Path, init: Path | None) -> tuple[Path, float]:
        overrides = {**bc_base, "data": str(data_path), "out": str(out / f"iter_{iteration}")}
        if init is not None and config.warm_start:
            overrides["init_from"] = str(init)
        policy = bc.train(bc.make_config("default", overrides))
        return policy, float(load_policy(policy).metadata["training"]["best_val_loss"])

    if config.init_policy is not None:
        (out / "iter_0").mkdir(exist_ok=True)
        learner = Path(shutil.copy(config.init_policy, out / "iter_0" / "policy.npz"))
        training = load_policy(learner).metadata["training"]
        val_loss = float(training.get("best_val_loss", training.get("bc", {}).get("best_val_loss", np.nan)))
    else:
        learner, val_loss = fit(0, Path(config.data), None)
    rows: list[dict] = []
    best = (np.inf, learner)
    for iteration in range(config.iterations + 1):
        if iteration > 0:
            beta = config.beta0 * config.beta_decay ** (iteration - 1)

            def driver_for(count: int, learner=learner, beta=beta) -> MixtureDriver:
                robot = collect_base.robot
                return MixtureDriver(load_policy(learner, robot, count), robot, beta, rng, collect_base.gain)

            fresh = collect(replace(collect_base, seed=config.seed + iteration), driver_for, config.progress)
            dataset = aggregate(dataset, fresh)
            dataset.save(out / "data.npz")
            learner, val_loss = fit(iteration, out / "data.npz", learner)
        else:
            beta = 1.0
        row = {
            "iteration": iteration,
            "beta": beta,
            "samples": len(dataset),
            "val_loss": val_loss,
            **closed_loop(config, learner),
            "time_s": round(time.perf_counter() - started, 1),
        }
        rows.append(row)
        score = sum(
            value if value is not None else np.inf for key, value in row.items() if key.endswith("_median_s")
        )
        if score < best[0]:
            best = (score, learner)
        with open(out / "log.csv", "w", newline="") as file:
            writer = csv.DictWriter(file, fieldnames=list(row))
            writer.writeheader()
            writer.writerows(rows)
        if config.progress:
            log.info("dagger iteration %d: %s", iteration, row)
    plot_curve(rows, out / "curve.png")
    chosen = load_policy(best[1])
    metadata, arrays = chosen.metadata, {}
    with np.load(best[1], allow_pickle=False) as file:
        arrays = {name: file[name] for name in file.files if name != "__metadata__"}
    from swarm.sim.policy import save_policy

    training = {
        "algo": "dagger",
        "config": asdict(config),
        "chosen": str(best[1]),
        "log": rows,
        "bc": metadata.get("training", {}),
        "train_time_s": rows[-1]["time_s"],
    }
    extra = {
        key: value for key, value in metadata.items() if key not in ("format", "format_version", "training")
    }
    return save_policy(out / "policy.npz", {**extra, "training": training}, arrays)
