"""Imitation of ``centralized_mec`` by the max-flooding GNN: behavioural cloning, then DAgger, over
whole episodes, with backpropagation through time through the recurrent max-memory.

Reads top to bottom: hyperparameters, episodes (rollout + expert labels), the replay, the loop.

- An episode is a batch of random starts at one N <= 12, ``envs`` on each graph kind, run in
  ``KinematicSim`` for ``episode_ticks`` ticks. Each environment is driven for the WHOLE episode by
  the expert (``swarm.core.experts.centralized_mec_velocity``: full speed toward the minimum enclosing
  circle's centre of the current positions, with reversing) or by the current learner (DAgger: the
  expert's share of the environments is ``beta0 * beta_decay ** (i - 1)`` in iteration i >= 1;
  iteration 0 is pure behavioural cloning). What is recorded: every tick's poses, who heard whom
  (the engine's timing: last tick's graph, nobody at tick 0) and the expert's label at that state
  (its point velocity in the robot frame after the robot's saturation, ``swarm.learn.data``'s convention).
- Replay: the memory recurrence re-runs over the recorded poses and links with the current
  projections (numpy, every ``argmax_every`` epochs); in a random share of the environments
  (``loss_p``) each message is dropped independently, so the model also learns from floods that lag.
  It records, for every memory entry, the position whose projection the entry holds (its arg-max
  over robots and past ticks). A max passes its gradient to its arg-max, so writing the memory as
  ``<arg-max position, w_q>`` gives exactly the gradient of backpropagation through time through
  the whole episode (no truncation needed) while the ticks train as independent rows: minibatches
  of (tick, environment, robot) rows where the robot heard someone, Adam. Loss: squared error of
  the saturated output against the label, in units of v_max^2.
- Every iteration's model is exported and checked in closed loop (median ratio to the lower bound
  over the ``eval_cells``); the best iterate is the result (``policy.npz``).
- Steering stage (``steering_steps`` > 0): then only the steering MLP is fitted, by Adam with a
  cosine-annealed rate, to the expert's own steering law on random (pose, target) pairs
  (:func:`steering_rows`); the flood and the target are left as they are. The imitation rows teach
  the steering through targets that are not the expert's (the flooded extent lags the current one),
  which leaves it slower than the expert near its target and in sharp turns; the stage removes that.
  With ``init`` (a ``gnn_flood`` policy file) and ``imitation: false`` it is a fine-tuning of that
  file's steering alone.

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
from typing import Any

import numpy as np
import torch

from swarm.core import metrics
from swarm.core.experts import centralized_mec_velocity
from swarm.core.initial_poses import box_for, random_poses
from swarm.core.robot import RobotParams, world_to_local
from swarm.learn.models.base import linears
from swarm.learn.models.flood import FloodGNN
from swarm.learn.train import preset_with_overrides
from swarm.sim.features import saturate_local_velocity
from swarm.sim.kinematic import KinematicSim
from swarm.sim.policy import FloodPolicy, load_policy

log = logging.getLogger(__name__)

GRAPHS = ("complete", "cycle", "line", "star", "random", "disk")


@dataclass(frozen=True)
class FloodConfig:
    out: str = "runs/flood"
    seed: int = 0
    threads: int = 1
    # model (swarm.learn.models.flood)
    directions: int = 12
    steer_hidden: tuple[int, ...] = (16, 16)
    newton_steps: int = 12
    tau_share: float = 0.003  # initial temperature / width of the target's soft minimax (learned)
    rho_cap_m: float = 0.5  # metric steering only
    output_scale_mps: float = 2.0  # metric steering only
    activation: str = "relu"
    # "scaled": the steering in units of v_max T and v_max (every robot scale); "metric": metres and m/s
    # of this config (the files up to gnn_flood.npz). A steering stage from an `init` of the other form
    # refits the init's steering MLP in this form.
    steering: str = "scaled"
    # episodes
    graphs: tuple[str, ...] = GRAPHS
    sizes: tuple[int, ...] = (4, 6, 8, 10, 12)
    envs: int = 16  # environments per (graph, N) episode batch
    episode_ticks: int = 160
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
    batch_size: int = 2048  # (tick, environment, robot) rows per Adam step
    argmax_every: int = 2  # epochs between replays of the memory arg-maxes for the current projections
    steering_rows: int = 512  # per Adam step: rows of the expert's steering law on random targets
    steering_weight: float = 1.0
    # closed-loop check of every iterate (starts per cell, time limit)
    eval_cells: tuple[tuple[str, int], ...] = (("line", 12), ("cycle", 12), ("random", 12), ("disk", 12))
    eval_starts: int = 32
    eval_max_s: float = 60.0
    # start, imitation, steering stage
    init: str | None = None  # a gnn_flood policy file to start from (its architecture is used)
    imitation: bool = True  # behavioural cloning + DAgger (off: the steering stage only)
    steering_steps: int = 0  # then: Adam steps of the steering MLP alone on the expert's steering law
    steering_batch: int = 4096  # rows per step
    steering_lr: float = 1e-3  # cosine-annealed to 0 over the steps
    progress: bool = False


PRESETS: dict[str, FloodConfig] = {"default": FloodConfig()}


def make_config(preset: str = "default", overrides: dict | None = None) -> FloodConfig:
    overrides = dict(overrides or {})
    if "eval_cells" in overrides:
        overrides["eval_cells"] = tuple(tuple(cell) for cell in overrides["eval_cells"])
    config = preset_with_overrides(
        "flood",
        PRESETS,
        preset,
        overrides,
        tuple_fields=("steer_hidden", "graphs", "sizes", "loss_p", "epochs"),
    )
    if config.init is not None:
        from swarm.sim.policy import PolicyFormatError

        if not Path(config.init).is_file():
            raise ValueError(f"init: {config.init}: no such policy file")
        try:
            kind = load_policy(config.init).kind
        except (PolicyFormatError, OSError, KeyError) as error:
            raise ValueError(f"init: {config.init}: not a policy file ({error})") from None
        if kind != FloodGNN.kind:
            raise ValueError(f"init: {config.init}: a {kind!r} policy, expected {FloodGNN.kind!r}")
    if not config.imitation and not config.steering_steps:
        raise ValueError("imitation: false needs steering_steps > 0 (nothing would be trained)")
    return config


def from_policy_file(
    path: str | Path, v_max_mps: float = 0.5, control_period_s: float = 0.05, steering: str | None = None
) -> FloodGNN:
    """The torch model of a ``gnn_flood`` policy file, with its weights (float32, as stored), training
    at ``v_max_mps`` and ``control_period_s``; ``steering``: switch to that steering form (the weights
    stay, their meaning changes: only a steering stage should follow)."""
    from swarm.learn.models.flood import build_flood

    policy = load_policy(path)
    if not isinstance(policy, FloodPolicy):
        raise ValueError(f"{path}: a {policy.kind!r} policy, expected {FloodGNN.kind!r}")
    model_section = dict(policy.model)
    if steering is not None:
        model_section["steering"] = steering
    model = build_flood(
        {"model": model_section, "output_scale_mps": policy.output_scale_mps}, v_max_mps, control_period_s
    )
    model.load_state_dict(
        {name: torch.as_tensor(np.asarray(value)) for name, value in policy._arrays.items()}
    )
    return model


def build(config: FloodConfig) -> FloodGNN:
    if config.init is not None:
        model = from_policy_file(config.init, config.v_max_mps, config.control_period_s)
        if model.steering != config.steering:  # a new steering form: a fresh MLP of `steer_hidden`
            model = from_policy_file(config.init, config.v_max_mps, config.control_period_s, config.steering)
            model.steer_hidden = [int(width) for width in config.steer_hidden]
            model.steer = linears([3, *model.steer_hidden, 2])
        return model
    return FloodGNN(
        config.directions,
        config.steer_hidden,
        config.newton_steps,
        config.tau_share,
        config.rho_cap_m,
        config.output_scale_mps,
        config.activation,
        config.steering,
        config.v_max_mps,
        config.control_period_s,
    )


# -- episodes ------------------------------------------------------------------------------------


def group_graph(
    graph: str, count: int, envs: int, rng: np.random.Generator
) -> tuple[np.ndarray | None, float | None]:
    from swarm.core import graphs
    from swarm.scenarios.sweep import random_edge_probability

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
    return centralized_mec_velocity(poses, robot.v_max_mps, config.control_period_s, config.reverse)


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
        from swarm.scenarios.sweep import connecting_radius

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
    episode: dict[str, Any] = {
        key: np.concatenate([group[key] for group in groups], axis=1) for key in groups[0]
    }
    episode["loss_p"] = rng.choice(np.asarray(config.loss_p, dtype=float), size=episode["poses"].shape[1])
    episode["count"] = count
    return episode


# -- the replay: memory arg-maxes, then supervised minibatches ---------------------------------------


def argmax_positions(episode: dict, projections: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Replay the memory recurrence with numpy for the current projections ``(P, 2)`` and return, for
    every tick, robot and memory entry, the position whose projection the entry holds:
    ``(T, B, N, 2P, 2)`` float32. Messages are dropped with each environment's ``loss_p``.

    ``h_q = <argmax position, w_q>`` with ``w = [W, -W]``: the memory as a function of the learned
    projections, whose gradient is exactly backpropagation through time through the max (a max
    routes its gradient to its arg-max), without unrolling the ticks."""
    poses, heard = episode["poses"], episode["heard"]
    ticks, batch, count = poses.shape[:3]
    signed = np.concatenate([projections, -projections], axis=0)  # (2P, 2)
    drop = episode["loss_p"][None, :, None, None]
    kept = heard & (rng.random(heard.shape) >= drop)
    out = np.empty((ticks, batch, count, len(signed), 2), dtype=np.float32)
    values: np.ndarray | None = None
    positions: np.ndarray | None = None
    rows = np.arange(batch)[:, None, None]
    for tick in range(ticks):
        axle = poses[tick, :, :, :2]
        own = axle @ signed.T  # (B, N, 2P)
        own_positions = np.broadcast_to(axle[:, :, None, :], (*own.shape, 2))
        if values is None:
            new_values, new_positions = own, own_positions.copy()
        else:
            assert positions is not None
            take = own > values
            new_values = np.where(take, own, values)
            new_positions = np.where(take[..., None], own_positions, positions)
            masked = np.where(kept[tick][..., None], values[:, None, :, :], -np.inf)  # (B, N, N, 2P)
            best = masked.argmax(axis=2)  # (B, N, 2P)
            best_values = np.take_along_axis(masked, best[:, :, None, :], axis=2)[:, :, 0]
            take = best_values > new_values
            new_values = np.where(take, best_values, new_values)
            neighbour_positions = positions[rows, best, np.arange(len(signed))[None, None, :]]
            new_positions = np.where(take[..., None], neighbour_positions, new_positions)
        values, positions = new_values, new_positions
        out[tick] = positions
    return out


def saturate(u_local: torch.Tensor, robot: RobotParams) -> torch.Tensor:
    from swarm.learn.models.base import saturate as torch_saturate

    return torch_saturate(u_local, robot)


def rows_of(episodes: list[dict], model: FloodGNN, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Every (tick, environment, robot) where the robot heard someone, over all episodes."""
    projections = model.projections.detach().double().numpy()
    parts: dict[str, list] = {"positions": [], "poses": [], "labels": []}
    for episode in episodes:
        positions = argmax_positions(episode, projections, rng)
        heard_any = episode["heard"].any(axis=-1)
        parts["positions"].append(positions[heard_any])
        parts["poses"].append(episode["poses"][heard_any].astype(np.float32))
        parts["labels"].append(episode["labels"][heard_any].astype(np.float32))
    return {key: np.concatenate(value) for key, value in parts.items()}


def batch_loss(model: FloodGNN, positions, poses, labels, robot: RobotParams) -> torch.Tensor:
    signed = torch.cat([model.projections, -model.projections], dim=0)
    memory = (positions * signed).sum(-1)  # (R, 2P)
    u_local = model.steer_local(poses, model.target(memory))
    error = saturate(u_local, robot) / robot.v_max_mps - labels / robot.v_max_mps
    return (error * error).sum(-1).mean()


def steering_rows(count: int, robot: RobotParams, config: FloodConfig, rng: np.random.Generator) -> tuple:
    """The expert's own steering law on random (pose, target) pairs: ``centralized_mec`` applies
    ``swarm.core.experts.drive_toward_velocity`` toward the MEC centre, so these are its labels for any
    target (distances log-uniform from 1 cm to 5 m, every relative bearing; for scaled steering from
    10^-3 to 10^2 times v_max T, the whole range the law has a shape in). Episodes visit turning
    states only in their first ticks; these rows keep the turning well represented."""
    from swarm.core.experts import drive_toward_velocity

    poses = np.concatenate([np.zeros((count, 2)), rng.uniform(-np.pi, np.pi, (count, 1))], axis=-1)
    if config.steering == "scaled":
        unit_m = robot.v_max_mps * config.control_period_s
        distance = unit_m * np.exp(rng.uniform(np.log(1e-3), np.log(1e2), count))
    else:
        distance = np.exp(rng.uniform(np.log(0.01), np.log(5.0), count))
    bearing = rng.uniform(-np.pi, np.pi, count)
    targets = np.stack([distance * np.cos(bearing), distance * np.sin(bearing)], axis=-1)
    u_world = drive_toward_velocity(poses, targets, robot.v_max_mps, config.control_period_s)
    labels = saturate_local_velocity(world_to_local(u_world, poses[:, 2]), robot)
    return tuple(torch.as_tensor(a, dtype=torch.float32) for a in (poses, targets, labels))


def fit_epoch(
    model: FloodGNN, data: dict, robot: RobotParams, config: FloodConfig, optimizer, generator, rng
) -> float:
    order = torch.randperm(len(data["labels"]), generator=generator)
    tensors = {key: torch.as_tensor(value) for key, value in data.items()}
    total = 0.0
    for start in range(0, len(order), config.batch_size):
        chosen = order[start : start + config.batch_size]
        loss = batch_loss(
            model, tensors["positions"][chosen], tensors["poses"][chosen], tensors["labels"][chosen], robot
        )
        if config.steering_rows:
            poses, targets, labels = steering_rows(config.steering_rows, robot, config, rng)
            error = (saturate(model.steer_local(poses, targets), robot) - labels) / robot.v_max_mps
            loss = loss + config.steering_weight * (error * error).sum(-1).mean()
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        total += float(loss.detach()) * len(chosen)
    return total / len(order)


def fit_steering(model: FloodGNN, robot: RobotParams, config: FloodConfig, rng: np.random.Generator) -> float:
    """The steering stage: ``steering_steps`` Adam steps of the steering MLP alone on fresh rows of
    the expert's steering law (:func:`steering_rows`); returns the last step's loss (v_max^2 units)."""
    optimizer = torch.optim.Adam(model.steer.parameters(), lr=config.steering_lr)
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, config.steering_steps)
    loss = torch.zeros(())
    for step in range(config.steering_steps):
        poses, targets, labels = steering_rows(config.steering_batch, robot, config, rng)
        error = (saturate(model.steer_local(poses, targets), robot) - labels) / robot.v_max_mps
        loss = (error * error).sum(-1).mean()
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        schedule.step()
        if config.progress and step % 500 == 0:
            log.info("steering step %d loss %.5f", step, float(loss.detach()))
    return float(loss.detach())


# -- closed-loop check ---------------------------------------------------------------------------


def closed_loop(policy_path: Path, config: FloodConfig) -> dict[str, float]:
    """Median ratio to the lower bound (failures count as the time limit) per eval cell."""
    from swarm.scenarios.sweep import SweepConfig, cell_starts, converge_batch

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
    robot = RobotParams(v_max_mps=config.v_max_mps)
    rows: list[dict] = []
    started = time.perf_counter()
    chosen = imitate(config, robot, rng, rows, started) if config.imitation else build(config)
    if config.steering_steps:
        loss = fit_steering(chosen, robot, config, rng)
        policy_path = chosen.export(out / "steering" / "policy.npz", robot)
        rows.append(
            {
                "iteration": "steering",
                "loss": loss,
                **check_row(policy_path, config),
                "elapsed_s": round(time.perf_counter() - started, 1),
            }
        )
        write_log(out, rows, config)
    training = {"algo": "flood", "config": asdict(config), "log": rows}
    if config.imitation:
        training["best_iteration"] = min(
            (row for row in rows if row["iteration"] != "steering"),
            key=lambda row: row["closed_loop_mean_ratio"],
        )["iteration"]
    return chosen.export(out / "policy.npz", robot, training)


def check_row(policy_path: Path, config: FloodConfig) -> dict:
    check = closed_loop(policy_path, config)
    return {"closed_loop_mean_ratio": float(np.mean(list(check.values()))), **check}


def write_log(out: Path, rows: list[dict], config: FloodConfig) -> None:
    if config.progress:
        log.info("%s", json.dumps(rows[-1]))
    fields = list(dict.fromkeys(key for row in rows for key in row))
    with open(out / "log.csv", "w", newline="") as file:
        writer = csv.DictWriter(file, fieldnames=fields)
        writer.writeheader()
        writer.writerows(rows)


def imitate(
    config: FloodConfig, robot: RobotParams, rng: np.random.Generator, rows: list[dict], started: float
) -> FloodGNN:
    """Behavioural cloning, then DAgger (module docstring); the best iterate, by the closed-loop check."""
    out = Path(config.out)
    generator = torch.Generator().manual_seed(config.seed)
    model = build(config)
    episodes: list[dict] = []
    best: tuple[float, int] = (np.inf, 0)
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
            if epoch % config.argmax_every == 0:  # the arg-maxes follow the learned projections
                data = rows_of(episodes, model, rng)
            loss = fit_epoch(model, data, robot, config, optimizer, generator, rng)
            elapsed = time.perf_counter() - started
            if config.progress:
                log.info("iteration %d epoch %d loss %.5f (%.0f s)", iteration, epoch, loss, elapsed)
        policy_path = out / f"iter_{iteration}" / "policy.npz"
        torch.save(
            {"model": model.state_dict(), "model_config": model.config()},
            out / f"iter_{iteration}" / "checkpoint.pt",
        )
        model.export(policy_path, robot, {"algo": "flood", "iteration": iteration, "config": asdict(config)})
        check = check_row(policy_path, config)
        rows.append(
            {
                "iteration": iteration,
                "expert_share": share,
                "episodes": len(episodes),
                "loss": loss,
                **check,
                "elapsed_s": round(time.perf_counter() - started, 1),
            }
        )
        write_log(out, rows, config)
        if check["closed_loop_mean_ratio"] < best[0]:
            best = (check["closed_loop_mean_ratio"], iteration)
    chosen = build(config)
    chosen.load_state_dict(torch.load(out / f"iter_{best[1]}" / "checkpoint.pt", weights_only=False)["model"])
    return chosen
