"""Imitation of the formation expert ``capt`` by ``capt_gnn`` (``swarm.sim.formation_gnn``): DAgger.

Reads top to bottom: hyperparameters, episodes (rollout + expert labels), the closed-loop check, the
loop (the fit and the DAgger loop are ``swarm.learn.train.steering``'s, shared with ``lloyd_gnn``).

- An episode is a batch of starts at every N of ``counts`` (all <= 12) on every graph of ``graphs``
  (``sweep_starts`` and ``sweep_section`` of ``swarm.core.tasks.formation``, the sweep's cells), run in
  ``KinematicSim`` for at most ``episode_s`` (an environment stops being recorded once every slot has
  held its robot ``settle_s``). Every tick each robot runs ``capt_gnn``'s flood and provisional CAPT
  slot (fixed, not learned) and its features (eq. (1) there) are recorded with the expert's label: the
  point velocity, in the robot's frame (before the wheels saturate, as the GNN's output), that ``capt``
  would command at that state (the CAPT assignment of the episode's starts, every robot at ``v_max d_i / D``
  of the current distances, reversing as ``drive_toward_velocity`` does).
- Who drives: iteration 0 the expert everywhere (behavioural cloning); iteration i >= 1 the expert in a
  share ``beta_decay ** i`` of the environments and the current learner in the others (DAgger: the
  learner's own states, with the expert's labels).
- The fit: every row recorded so far, minibatches of ``batch_rows``, Adam for ``steps`` per iteration;
  loss, in eq. (1)'s polar form: the squared error of the speed ``clip(c, 0, 1)`` against the label's
  (its length over ``v_max min(rho_n, 1)``, at most 1) plus ``1 - cos`` of the angle between the
  direction ``(a, b)`` and the label's (rows with a label of length 0: speed only). Fitting the
  Cartesian command instead averages commands toward slots the robot cannot know yet into shorter
  ones: measured 3-5% slower than ``capt_flood`` at N <= 12 (``docs/tasks.md``).
- Every iteration's weights are checked in closed loop on ``eval_cells`` (median time over the lower
  bound); the best iterate is the result (``policy.npz``).

Seeded: numpy and torch from ``seed``, torch on one thread: the same command on the same machine gives
the same weights.

Run: ``swarm train --algo formation --out runs/formation`` (``models/README.md``: the shipped file).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from swarm.core import graphs, topologies
from swarm.core.robot import RobotParams, world_to_local
from swarm.core.tasks import formation
from swarm.learn.train import preset_with_overrides
from swarm.learn.train.steering import dagger
from swarm.sim.formation_controllers import CaptGnn, capt_velocity
from swarm.sim.formation_gnn import FEATURES, FormationGnnWeights
from swarm.sim.kinematic import KinematicSim


# ------------------------------------------------------------------------------------ hyperparameters
@dataclass(frozen=True)
class FormationConfig:
    out: str = "runs/formation"
    seed: int = 0
    counts: tuple[int, ...] = (4, 6, 8, 10, 12)  # every N trained on (the issue: N <= 12)
    graphs: tuple[str, ...] = ("complete", "cycle", "line", "random", "disk")
    envs: int = 12  # starts per (N, graph) and iteration
    iterations: int = 5
    beta_decay: float = 0.5  # the expert's share of the environments in iteration i >= 1
    episode_s: float = 15.0
    settle_s: float = 0.5
    disk_radius_m: float = 3.0
    v_max_mps: float = 0.5
    control_period_s: float = 0.05
    hidden: int = 32
    learning_rate: float = 3e-3
    steps: int = 6000  # Adam steps per iteration
    batch_rows: int = 2048
    eval_cells: tuple[tuple[str, int], ...] = (("line", 12), ("cycle", 12), ("disk", 12), ("complete", 8))
    eval_starts: int = 8
    speed: str = "full"  # "full": eq. (1) at v_max, the direction learned; "imitated": the expert's speed too
    progress: bool = True


PRESETS: dict[str, FormationConfig] = {
    "default": FormationConfig(),
    "smoke": FormationConfig(counts=(4, 6), envs=2, iterations=2, steps=50, eval_starts=2, episode_s=8.0),
}


def make_config(preset: str = "default", overrides: dict | None = None) -> FormationConfig:
    overrides = dict(overrides or {})
    if "eval_cells" in overrides:
        overrides["eval_cells"] = tuple(tuple(cell) for cell in overrides["eval_cells"])
    return preset_with_overrides("formation", PRESETS, preset, overrides, ("counts", "graphs"))


# ------------------------------------------------------------------------------------ episodes
def _sim(config: FormationConfig, controller, topology: str, poses: np.ndarray, rng) -> KinematicSim:
    robot = RobotParams(v_max_mps=config.v_max_mps)
    if topologies.get(topology).proximity:
        return KinematicSim(
            robot, controller, config.control_period_s, poses, disk_radius_m=config.disk_radius_m
        )
    return KinematicSim(
        robot,
        controller,
        config.control_period_s,
        poses,
        adjacency=fixed_graphs(topology, poses.shape[1], len(poses), rng),
    )


def fixed_graphs(topology: str, count: int, number: int, rng) -> np.ndarray:
    """``(number, N, N)``: one graph per start of a fixed (not proximity) topology kind."""
    drawn = [topologies.draw(topology, count, rng) for _ in range(number)]
    return np.stack([graph for graph in drawn if graph is not None])


def starts(config: FormationConfig, topology: str, count: int, number: int, rng) -> np.ndarray:
    """``(number, N, 3)`` sweep starts; on a disk graph only those it connects."""
    if not topologies.get(topology).proximity:
        return formation.sweep_starts(rng, number, count)
    chosen: list[np.ndarray] = []
    while len(chosen) < number:
        for pose in formation.sweep_starts(rng, number, count):
            if graphs.is_connected(graphs.disk(pose[:, :2], config.disk_radius_m)):
                chosen.append(pose)
    return np.stack(chosen[:number])


def expert_targets(section, poses: np.ndarray) -> np.ndarray:
    """``(B, N, 2)``: the slot ``capt`` assigns each robot from the starts."""
    slots = section.slot_positions(poses.shape[1])
    out = []
    for pose in poses:
        placed = formation.placed_slots(section, pose[:, :2], slots)
        out.append(placed[formation.capt_assignment(pose[:, :2], placed)])
    return np.stack(out)


def expert_local(poses: np.ndarray, targets: np.ndarray, robot: RobotParams, period_s: float) -> np.ndarray:
    """``capt``'s command at ``poses``, robot frame, before the wheels saturate (the label)."""
    return world_to_local(capt_velocity(poses, targets, robot.v_max_mps, period_s), poses[..., 2])


def episode(
    config: FormationConfig, weights: FormationGnnWeights, beta: float, topology: str, count: int, rng
):
    """Rows ``(features (R, 5), labels (R, 2))`` of one batch of starts (module docstring)."""
    robot = RobotParams(v_max_mps=config.v_max_mps)
    section = formation.sweep_section(count)
    poses = starts(config, topology, count, config.envs, rng)
    learner = CaptGnn(robot, config.control_period_s, section, count, weights)
    sim = _sim(config, learner, topology, poses, rng)
    targets = expert_targets(section, poses)
    expert_drives = rng.random(len(poses)) < beta
    slots = section.slot_positions(count)
    settle_ticks = round(config.settle_s / config.control_period_s)
    held_for = np.zeros(len(poses), dtype=int)
    features, labels = [], []
    for _ in range(round(config.episode_s / config.control_period_s)):
        recording = held_for < settle_ticks
        if not recording.any():
            break
        u_world = sim.act()
        expert_world = capt_velocity(sim.poses, targets, robot.v_max_mps, config.control_period_s)
        label = world_to_local(expert_world, sim.poses[..., 2])  # expert_local, computed once
        assert learner.last_features is not None
        features.append(learner.last_features[recording].reshape(-1, len(FEATURES)))
        labels.append(label[recording].reshape(-1, 2))
        sim.move(np.where(expert_drives[:, None, None], expert_world, u_world))
        held = formation.occupied(sim.poses[..., :2], slots, section.tolerance_m)
        held_for = np.where(held, held_for + 1, 0)
    return np.concatenate(features), np.concatenate(labels)


# ------------------------------------------------------------------------------------ the check
def closed_loop(config: FormationConfig, weights: FormationGnnWeights | str, seed: int) -> float:
    """Median time / lower bound over ``eval_cells`` (3 where a start does not succeed) of ``capt_gnn``
    with ``weights``, or of the controller kind named (the baseline, on the same starts)."""
    from swarm.scenarios.task_sweep import TaskSweepConfig, run_chunk

    rng = np.random.default_rng(seed)
    ratios = []
    for topology, count in config.eval_cells:
        section = formation.sweep_section(count)
        poses = starts(config, topology, count, config.eval_starts, rng)
        adjacency = None
        if not topologies.get(topology).proximity:
            adjacency = fixed_graphs(topology, count, len(poses), rng)
        sweep = TaskSweepConfig(
            task="formation", v_max_mps=config.v_max_mps, disk_radius_m=config.disk_radius_m
        )
        robot = RobotParams(v_max_mps=config.v_max_mps)
        controller = (
            weights
            if isinstance(weights, str)
            else CaptGnn(robot, config.control_period_s, section, count, weights)
        )
        times, frames = run_chunk(sweep, section, controller, poses, adjacency, 0.0, 0)
        for b in range(len(poses)):
            result = formation.outcome(times, frames[:, b], section, config.v_max_mps)
            ratio = result.get("ratio_to_lower_bound")
            ratios.append(ratio if result.get("converged") and ratio is not None else 3.0)
    return float(np.median(ratios))


# ------------------------------------------------------------------------------------ the loop
def train(config: FormationConfig) -> Path:
    meta = {"config": asdict(config), "features": list(FEATURES), "speed": config.speed}
    return dagger(
        config,
        weights_class=FormationGnnWeights,
        meta=meta,
        episode=episode,
        closed_loop=closed_loop,
        score="median_ratio",
        references=("capt_flood",),
        imitate_speed=config.speed == "imitated",
    )
