"""Closed-loop check of a trained policy against local consensus on the kinematic engine.

Same random starts (box growing with N, headings uniform, 0.4 m apart), graphs and stopping rule
as ``swarm sweep``; convergence = max_pairwise <= 0.2 m held for 2 s. Reports per (topology, N):
success rate, median time, median ratio to the lower bound of docs/design.md, and the median over
starts of the time ratio to local consensus. ``--reference`` adds the untrained uniform-weight
filter (``u = G mean_k f_k``, the same G) to show what the learned hop weights add.
Writes bench/results/bc_vs_lc.json and .md.

    python bench/eval_bc.py models/gnn_bc.npz [--sizes 6 12 24] [--seeds 50]
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np
from _output import add_output_arguments, output_dir

from swarm.learn.train.evaluate import compare, format_rows, local_consensus
from swarm.sim.features import FeatureSpec
from swarm.sim.policy import FeatureController, load_policy


class UniformFilter(FeatureController):
    """``u = G mean_k f_k`` over K hops: the hand-made filter the learned one should beat."""

    def __init__(self, robot, hops: int, gain_per_s: float):
        super().__init__(FeatureSpec(hops), robot)
        self.gain_per_s = gain_per_s

    def forward(self, features_local: np.ndarray) -> np.ndarray:
        return self.gain_per_s * np.cumsum(features_local, axis=-2).mean(axis=-2)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("model", help="exported policy file")
    parser.add_argument(
        "--topologies", nargs="+", default=["complete", "cycle", "line", "star", "random", "disk"]
    )
    parser.add_argument("--sizes", nargs="+", type=int, default=[6, 12, 24])
    parser.add_argument("--seeds", type=int, default=50)
    parser.add_argument("--max-duration", type=float, default=3000.0)
    parser.add_argument("--reference", action="store_true", help="also run the uniform-weight filter")
    parser.add_argument(
        "--also", nargs="+", default=[], metavar="NAME=PATH", help="more policy files to compare"
    )
    parser.add_argument("--name", default="bc_vs_lc", help="file name of the results: NAME.json, NAME.md")
    add_output_arguments(parser)
    args = parser.parse_args()
    policy = load_policy(args.model)
    controllers = {
        "local_consensus": local_consensus,
        "gnn": lambda robot, count: load_policy(args.model, robot, count),
    }
    for item in args.also:
        name, path = item.split("=", 1)
        controllers[name] = lambda robot, count, path=path: load_policy(path, robot, count)
    if args.reference:
        gain = policy.model.get("gain_max_per_s", 20.0)
        controllers["uniform_filter"] = lambda robot, count: UniformFilter(robot, policy.spec.hops, gain)
    started = time.perf_counter()
    rows = compare(
        controllers,
        args.topologies,
        args.sizes,
        args.seeds,
        max_duration_s=args.max_duration,
        progress=not args.quiet,
    )
    table = format_rows(rows)
    print(table)
    report = {
        "benchmark": "trained policy vs local consensus, kinematic engine, simulated convergence time",
        "command": "python bench/eval_bc.py " + " ".join(sys.argv[1:]),
        "model": str(args.model),
        "model_metadata": {key: value for key, value in policy.metadata.items() if key != "training"},
        "seeds": args.seeds,
        "wall_s": round(time.perf_counter() - started, 1),
        "rows": rows,
    }
    out = output_dir(args) / args.name
    out.with_suffix(".json").write_text(json.dumps(report, indent=2) + "\n")
    out.with_suffix(".md").write_text(
        f"`{report['command']}` ({args.seeds} random starts per cell; t / first: median over starts of "
        "the time ratio to local consensus)\n\n" + table + "\n"
    )
    print(f"written {out.with_suffix('.json')} and .md")


if __name__ == "__main__":
    main()
