"""Where the learned flooding GNN loses time at N = 6: its target or its learned steering.

Four controllers on the same starts (``swarm.scenarios.sweep.cell_starts``, the first ``--starts`` of each
cell), every combination of

- target: the GNN's own (its flooded memory's smoothed minimax centre, what its message carries)
  or the oracle (the exact minimum enclosing circle's centre of the current axle positions, as the
  expert ``centralized_mec``),
- steering: the GNN's learned MLP (``FloodPolicy.steer_local`` + the robot's saturation) or the
  exact law of ``mec_flood`` / ``centralized_mec`` (``swarm.core.experts.drive_toward_velocity``:
  full speed toward the target, reversing when it is behind the axle),

plus ``mec_flood`` itself. GNN target + learned steering is the shipped model; oracle + exact law
is ``centralized_mec``. A robot that has never heard a neighbour holds still in the GNN-target
forms (its flag in the message). Median / p95 ratio to the lower bound per graph, markdown.

    nice -n 10 python bench/investigations/flood_n6_limit.py --model models/gnn_flood.npz --sizes 6 \\
        --out docs/results/flood/n6_limit.md
"""

from __future__ import annotations

import sys as _sys
from pathlib import Path as _Path

_sys.path.insert(0, str(_Path(__file__).resolve().parent.parent))  # bench/: its helpers and benchmarks

import argparse
import time
from pathlib import Path

import numpy as np

from swarm.core import metrics
from swarm.core.experts import drive_toward_velocity
from swarm.core.robot import RobotParams, rotate
from swarm.scenarios.sweep import SweepConfig, cell_starts, converge_batch, make_controller
from swarm.sim.features import saturate_local_velocity
from swarm.sim.kinematic import KinematicSim
from swarm.sim.policy import load_policy

GRAPHS = ("complete", "cycle", "line", "star", "random", "disk")


class Hybrid:
    """The GNN's flood (batched kernel) for the messages; the target and the steering as chosen."""

    centralized = False

    def __init__(self, policy, target: str, steering: str, control_period_s: float):
        self.policy, self.target, self.steering = policy, target, steering
        self.robot, self.control_period_s = policy.robot, control_period_s
        self.message_dim = policy.message_dim

    def act(self, poses, points, inbox, heard):
        _, outbox = self.policy.act(poses, points, inbox, heard)
        dim = self.policy.memory_dim
        moving = outbox[..., dim + 2] > 1.5  # has heard a neighbour
        if self.target == "gnn":
            targets = outbox[..., dim : dim + 2]
        else:
            centres = np.stack([metrics.minimum_enclosing_circle(p[:, :2])[0] for p in poses])
            targets = np.broadcast_to(centres[:, None, :], poses[..., :2].shape)
            moving = np.ones_like(moving)
        if self.steering == "exact":
            robot = self.robot
            u = drive_toward_velocity(poses, targets, robot.v_max_mps, self.control_period_s)
        else:
            local = saturate_local_velocity(self.policy.steer_local(poses, targets), self.robot)
            u = rotate(local, poses[..., 2])
        return np.where(moving[..., None], u, 0.0), outbox


def ratios(sim: KinematicSim, poses: np.ndarray, config: SweepConfig) -> np.ndarray:
    times = converge_batch(sim, config.threshold_m, config.max_duration_s, config.hold_s)
    lower = np.array([metrics.lower_bound_s(p[:, :2], config.threshold_m, config.v_max_mps) for p in poses])
    keep = lower > 0
    return np.where(np.isnan(times[keep]), np.inf, times[keep] / lower[keep])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default="models/gnn_flood.npz")
    parser.add_argument("--sizes", type=int, nargs="+", default=[6])
    parser.add_argument("--graphs", nargs="+", default=list(GRAPHS))
    parser.add_argument("--starts", type=int, default=1000)
    parser.add_argument("--out", required=True)
    args = parser.parse_args(argv)
    config = SweepConfig(seeds=1000, first_starts=args.starts, max_duration_s=60.0)
    robot = RobotParams(v_max_mps=config.v_max_mps)
    forms = [
        ("GNN target, learned steering (shipped)", "gnn", "learned"),
        ("GNN target, exact steering", "gnn", "exact"),
        ("oracle target, learned steering", "oracle", "learned"),
        ("oracle target, exact steering (centralized_mec)", "oracle", "exact"),
    ]
    header = "| graph | N | " + " | ".join(name for name, _, _ in forms) + " | mec_flood |"
    lines = [
        f"Median / p95 ratio to the lower bound over the first {args.starts} starts of each sweep cell "
        f"(`swarm.scenarios.sweep.cell_starts`, seed 0), model `{args.model}`, kinematic engine.",
        "Command: `python bench/investigations/flood_n6_limit.py` (its docstring: what each column is).",
        "",
        header,
        "|" + "---|" * (header.count("|") - 1),
    ]
    started = time.perf_counter()
    for count in args.sizes:
        for graph in args.graphs:
            poses, adjacency, radius = cell_starts(config, graph, count)
            texts = []
            for _, target, steering in forms:
                policy = load_policy(args.model, robot, count)
                sim = KinematicSim(
                    robot,
                    Hybrid(policy, target, steering, config.control_period_s),
                    config.control_period_s,
                    poses,
                    adjacency,
                    radius,
                )
                r = ratios(sim, poses, config)
                texts.append(f"{np.median(r):.3f} / {np.percentile(r, 95):.3f}")
            mec = make_controller("mec_flood", robot, config.gain, None, count, config.control_period_s)
            r = ratios(
                KinematicSim(robot, mec, config.control_period_s, poses, adjacency, radius), poses, config
            )
            texts.append(f"{np.median(r):.3f} / {np.percentile(r, 95):.3f}")
            lines.append(f"| {graph} | {count} | " + " | ".join(texts) + " |")
            print(lines[-1], f"({time.perf_counter() - started:.0f} s)", flush=True)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
