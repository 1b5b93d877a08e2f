"""Imitation of ``centralized_mec`` by the max-flooding GNN: behavioural cloning, then DAgger, over
whole episodes, with truncated backpropagation through time through the recurrent memory.

Reads top to bottom: hyperparameters, episodes (rollout + expert labels), the replay loss, the loop.

- An episode is a batch of random starts at one N <= 12, ``envs`` on each graph kind, run in
  ``KinematicSim`` for ``episode_ticks`` ticks. Each environment is driven for the WHOLE episode by
  the expert (``swarm.experts.centralized_mec_velocity``: full speed toward the minimum enclosing
  circle's centre of the current positions, with reversing) or by the current learner (DAgger: the
  expert's share of the environments is ``beta0 * beta_decay ** (i - 1)`` in iteration i >= 1;
  iteration 0 is pure behavioural cloning). What is recorded: every tick's poses, who heard whom
  (the engine's timing: last tick's graph, nobody at tick 0) and the expert's label at that state
  (its point velocity in the robot frame after the robot's saturation, ``swarm.data``'s convention).
- Replay: the torch model re-runs the episode from the recorded poses and links (its memory
  recurs through the ticks); in a random share of the environments (``loss_p``) each message is dropped
  independently, so the model also sees floods that lag. Loss: squared error of the saturated output
  against the label, over robots that heard someone, in units of v_max^2. Gradients flow through
  the memory for ``bptt_ticks`` ticks (the memory is detached between windows; one optimiser step
  per window).
- Every iteration's model is exported and checked in closed loop (median ratio to the lower bound
  over the ``eval_cells``); the best iterate is the result (``policy.npz``).

Seeded: numpy and torch generators from ``seed``, torch on ``threads`` threads (default 1). The same
command on the same machine gives the same weights; another machine (another BLAS, CPU, thread count
or torch version) may differ in the last bits and then drift, so we document the result, not the bits.

Run: ``swarm train --algo flood --out runs/flood`` (``models/README.md`` has the shipped command).
"""

from __future__ import annotations

import csv
import json
import logging
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch

from swarm import metrics
from swarm.experts import centralized_mec_velocity
from swarm.features import saturate_local_velocity
from swarm.initial_poses import box_for, random_poses
from swarm.kinematic import KinematicSim
from swarm.models.flood import FloodGNN
from swarm.policy import load_policy
from swarm.robot import RobotParams, world_to_local
from swarm.train import preset_with_overrides

log = logging.getLogger(__name__)

GRAPHS = ("complete", "cycle", "line", "star", "random", "disk")


@dataclass(frozen=True)
class FloodConfig:
    out: str = "runs/flood"
    seed: int = 0
    threads: int = 1
    # model (swarm.models.flood)
    directions: int = 12
    steer_hidden: tuple[int, ...] = (16, 16)
    newton_steps: int = 12
    tau_share: float = 0.003  # initial temperature / width of the target's soft minimax (learned)
    rho_cap_m: float = 0.5
    output_scale_mps: float = 2.0
    activation: str = "relu"
    # episodes
    graphs: tuple[str, ...] = GRAPHS
    sizes: tuple[int, ...] = (4, 6, 8, 10, 12)
    envs: int = 16  # environments per (graph, N) episode batch
    episode_ticks: int = 200
    v_max_mps: float = 0.5
    control_period_s: float = 0.05
    min_separation_m: float = 0.4
    reverse: bool = True  # the expert reverses (centralized_mec)
    loss_p: tuple[float, ...] = (0.0, 0.0, 0.3)  # per episode, drawn: message-drop probability in replay
    # DAgger
    iterations: int = 4  # after iteration 0 (behavioural cloning)
    beta0: float = 0.5
    beta_decay: float = 0.5
    # optimisation
    epochs: tuple[int, ...] = (40, 5)  # passes over all episodes: iteration 0, then every later one
    lr: float = 3e-3
    lr_decay: float = 0.7  # per iteration
    bptt_ticks: int = 40
    # closed-loop check of every iterate (starts per cell, time limit)
    eval_cells: tuple[tuple[str, int], ...] = (("line", 12), ("cycle", 12), ("random", 12), ("disk", 12))
    eval_starts: int = 32
    eval_max_s: float = 60.0
    progress: bool = False


PRESETS: dict[str, FloodConfig] = {"default": FloodConfig()}


def make_config(preset: str = "default", overrides: dict | None = None) -> FloodConfig:
    overrides = dict(overrides or {})
    if "eval_cells" in overrides:
        overrides["eval_cells"] = tuple(tuple(cell) for cell in overrides["eval_cells"])
    return preset_with_overrides(
        "flood",
        PRESETS,
        preset,
        overrides,
        tuple_fields=("steer_hidden", "graphs", "sizes", "loss_p", "epochs"),
    )


def build(config: FloodConfig) -> FloodGNN:
    return FloodGNN(
        config.directions,
        config.steer_hidden,
        config.newton_steps,
        config.tau_share,
        config.rho_cap_m,
        config.output_scale_mps,
        config.activation,
    )


# -- episodes ------------------------------------------------------------------------------------


def group_graph(
    graph: str, count: int, envs: int, rng: np.random.Generator
) -> tuple[np.ndarray | None, float | None]:
    from swarm import graphs
    from swarm.sweep import random_edge_probability

    if graph == "disk":
        return None, None
    if graph == "random":
        p = max(random_edge_probability(count), 0.4)
        return np.stack(
            [graphs.erdos_renyi(count, p, int(s), connected=True) for s in rng.integers(0, 2**31, envs)]
        ), None
    single = {"complete": graphs.complete, "cycle": graphs.cycle, "line": graphs.line, "star": graphs.star}
    return np.broadcast_to(single[graph](count), (envs, count, count)).copy(), None


class MixtureDriver:
    """Drives environment e with the expert where ``expert[e]``, else with the learner; the messages
    are always the learner's (it must see its own flood)."""

    centralized = False

    def __init__(self, learner, expert: np.ndarray, robot: RobotParams, config: FloodConfig):
        self.learner, self.expert, self.robot, self.config = learner, expert, robot, config
        self.message_dim = learner.message_dim

    def act(self, poses, points, inbox, heard):
        u_world, outbox = self.learner.act(poses, points, inbox, heard)
        for env in np.nonzero(self.expert)[0]:
            u_world[env] = expert_velocity(poses[env], self.robot, self.config)
        return u_world, outbox


def expert_velocity(poses: np.ndarray, robot: RobotParams, config: FloodConfig) -> np.ndarray:
    return centralized_mec_velocity(
        poses, robot.offset_m, robot.v_max_mps, config.control_period_s, config.reverse
    )


def run_group(
    config: FloodConfig, graph: str, count: int, learner, expert_share: float, rng: np.random.Generator
) -> dict:
    """Roll out one (graph, N) batch and label it: poses ``(T, B, N, 3)``, heard ``(T, B, N, N)``, labels."""
    robot = RobotParams(v_max_mps=config.v_max_mps)
    box = box_for(count)
    poses = random_poses(rng, config.envs, count, box, box, config.min_separation_m)
    adjacency, _ = group_graph(graph, count, config.envs, rng)
    radius = None
    if adjacency is None:
        from swarm.sweep import connecting_radius

        radius = connecting_radius(poses[..., :2])
    expert = rng.random(config.envs) < expert_share
    sim = KinematicSim(
        robot,
        MixtureDriver(learner, expert, robot, config),
        config.control_period_s,
        poses,
        adjacency,
        radius,
    )
    ticks = config.episode_ticks
    recorded = np.empty((ticks, config.envs, count, 3))
    heard = np.empty((ticks, config.envs, count, count), dtype=bool)
    labels = np.empty((ticks, config.envs, count, 2))
    for tick in range(ticks):
        recorded[tick] = sim.poses
        heard[tick] = sim._sent_over.dense > 0
        for env in range(config.envs):
            u_world = expert_velocity(sim.poses[env], robot, config)
            labels[tick, env] = saturate_local_velocity(world_to_local(u_world, sim.poses[env, :, 2]), robot)
        sim.step()
    return {"poses": recorded, "heard": heard, "labels": labels}


def run_episode(
    config: FloodConfig, count: int, learner, expert_share: float, rng: np.random.Generator
) -> dict:
    """One episode batch at N = ``count``: every graph kind's group side by side (``envs`` each),
    and per environment the message-drop probability of the replay (drawn from ``loss_p``)."""
    groups = [run_group(config, graph, count, learner, expert_share, rng) for graph in config.graphs]
    episode = {key: np.concatenate([group[key] for group in groups], axis=1) for key in groups[0]}
    episode["loss_p"] = rng.choice(np.asarray(config.loss_p, dtype=float), size=episode["poses"].shape[1])
    episode["count"] = count
    return episode


# -- the replay loss -----------------------------------------------------------------------------


def replay_loss(
    model: FloodGNN,
    episode: dict,
    robot: RobotParams,
    config: FloodConfig,
    generator: torch.Generator,
    optimizer: torch.optim.Optimizer | None = None,
) -> float:
    """Mean loss over the episode; with an optimizer, one step per ``bptt_ticks`` window."""
    poses = torch.as_tensor(episode["poses"], dtype=torch.float32)
    heard = torch.as_tensor(episode["heard"])
    labels = torch.as_tensor(episode["labels"], dtype=torch.float32) / robot.v_max_mps
    loss_p = torch.as_tensor(episode["loss_p"], dtype=torch.float32)[None, :, None, None]
    if bool((loss_p > 0).any()):
        heard = heard & (torch.rand(heard.shape, generator=generator) >= loss_p)
    memory, inbox = None, torch.zeros(*poses.shape[1:3], model.message_dim)
    total, counted = 0.0, 0
    window_loss, window_count = 0.0, 0
    for tick in range(poses.shape[0]):
        u_local, memory = model.step(poses[tick], memory, inbox, heard[tick])
        inbox = memory
        mask = heard[tick].any(dim=-1)
        if mask.any():
            error = (saturate(u_local, robot) / robot.v_max_mps - labels[tick])[mask]
            window_loss = window_loss + (error * error).sum(-1).sum()
            window_count += int(mask.sum())
        end = tick == poses.shape[0] - 1 or (tick + 1) % config.bptt_ticks == 0
        if end and window_count:
            loss = window_loss / window_count
            if optimizer is not None:
                optimizer.zero_grad()
                loss.backward()
                optimizer.step()
                memory, inbox = memory.detach(), inbox.detach()
            total += float(loss.detach()) * window_count
            counted += window_count
            window_loss, window_count = 0.0, 0
    return total / max(counted, 1)


def saturate(u_local: torch.Tensor, robot: RobotParams) -> torch.Tensor:
    from swarm.models.base import saturate as torch_saturate

    return torch_saturate(u_local, robot)


# -- closed-loop check ---------------------------------------------------------------------------


def closed_loop(policy_path: Path, config: FloodConfig) -> dict[str, float]:
    """Median ratio to the lower bound (failures count as the time limit) per eval cell."""
    from swarm.sweep import SweepConfig, cell_starts, converge_batch

    sweep = SweepConfig(seeds=config.eval_starts, seed=12345)
    robot = RobotParams(v_max_mps=config.v_max_mps)
    result = {}
    for graph, count in config.eval_cells:
        poses, adjacency, radius = cell_starts(sweep, graph, count)
        sim = KinematicSim(
            robot, load_policy(policy_path, robot, count), config.control_period_s, poses, adjacency, radius
        )
        times = converge_batch(sim, sweep.threshold_m, config.eval_max_s, sweep.hold_s)
        lower = np.array(
            [metrics.lower_bound_s(p[:, :2], sweep.threshold_m, config.v_max_mps) for p in poses]
        )
        times = np.where(np.isnan(times), config.eval_max_s, times)
        result[f"{graph}_{count}"] = float(np.median(times[lower > 0] / lower[lower > 0]))
    return result


# -- the loop ------------------------------------------------------------------------------------


def train(config: FloodConfig) -> Path:
    out = Path(config.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "config.json").write_text(json.dumps(asdict(config), indent=2) + "\n")
    torch.manual_seed(config.seed)
    torch.set_num_threads(config.threads)
    rng = np.random.default_rng(config.seed)
    generator = torch.Generator().manual_seed(config.seed)
    robot = RobotParams(v_max_mps=config.v_max_mps)
    model = build(config)
    episodes: list[dict] = []
    rows, best = [], (np.inf, None)
    started = time.perf_counter()
    for iteration in range(config.iterations + 1):
        share = 1.0 if iteration == 0 else config.beta0 * config.beta_decay ** (iteration - 1)
        learner_path = out / f"iter_{iteration}" / "learner.npz"
        model.export(learner_path, robot)
        learner = load_policy(learner_path, robot)
        for count in config.sizes:
            episodes.append(run_episode(config, count, learner, share, rng))
        optimizer = torch.optim.Adam(model.parameters(), lr=config.lr * config.lr_decay**iteration)
        epochs = config.epochs[0] if iteration == 0 else config.epochs[-1]
        for epoch in range(epochs):
            order = rng.permutation(len(episodes))
            loss = float(
                np.mean([replay_loss(model, episodes[e], robot, config, generator, optimizer) for e in order])
            )
            log.info(
                "iteration %d epoch %d loss %.5f (%.0f s)",
                iteration,
                epoch,
                loss,
                time.perf_counter() - started,
            )
            if config.progress:
                print(
                    f"iteration {iteration} epoch {epoch} loss {loss:.5f} "
                    f"({time.perf_counter() - started:.0f} s)",
                    flush=True,
                )
        policy_path = out / f"iter_{iteration}" / "policy.npz"
        torch.save(
            {"model": model.state_dict(), "model_config": model.config()},
            out / f"iter_{iteration}" / "checkpoint.pt",
        )
        model.export(policy_path, robot, {"algo": "flood", "iteration": iteration, "config": asdict(config)})
        check = closed_loop(policy_path, config)
        score = float(np.mean(list(check.values())))
        row = {
            "iteration": iteration,
            "expert_share": share,
            "episodes": len(episodes),
            "loss": loss,
            "closed_loop_mean_ratio": score,
            **check,
            "elapsed_s": round(time.perf_counter() - started, 1),
        }
        rows.append(row)
        if config.progress:
            print(json.dumps(row), flush=True)
        with open(out / "log.csv", "w", newline="") as file:
            writer = csv.DictWriter(file, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)
        if score < best[0]:
            best = (score, iteration)
    chosen = build(config)
    chosen.load_state_dict(torch.load(out / f"iter_{best[1]}" / "checkpoint.pt", weights_only=False)["model"])
    training = {"algo": "flood", "best_iteration": best[1], "config": asdict(config), "log": rows}
    return chosen.export(out / "policy.npz", robot, training)
