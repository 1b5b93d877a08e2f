"""Per-robot inference time of a policy file: ``Policy.act_one`` (numpy), what a robot agent runs per tick.

One call = features from the heard messages, the network, saturation, the next message. Random
poses and neighbour messages (2-8 neighbours, drawn per call, a typical neighbourhood); median
and p99 over calls, in microseconds, per neighbour count and overall. Target: median <= 50 us.
Writes bench/results/inference.json.

    python bench/bench_inference.py [models/gnn_default.npz] [--calls 20000]
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time

import numpy as np
from _output import add_output_arguments, output_dir, progress

from swarm.sim.policy import load_policy

TARGET_US = 50.0


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("model", nargs="?", default="models/gnn_default.npz")
    parser.add_argument("--calls", type=int, default=20_000)
    add_output_arguments(parser)
    args = parser.parse_args()
    policy = load_policy(args.model, robot_count=6)
    rng = np.random.default_rng(0)
    counts = rng.integers(2, 9, size=args.calls)
    poses = rng.uniform(-2, 2, size=(args.calls, 3))
    inboxes = [rng.uniform(-2, 2, size=(int(m), policy.message_dim)) for m in counts]
    for index in range(200):  # warm up
        policy.act_one(poses[index], inboxes[index])
    elapsed = np.empty(args.calls)
    for index in progress(range(args.calls), args, desc="bench_inference", unit="call", mininterval=0.5):
        start = time.perf_counter_ns()
        policy.act_one(poses[index], inboxes[index])
        elapsed[index] = (time.perf_counter_ns() - start) / 1000.0

    def stats(values: np.ndarray) -> dict:
        return {
            "median_us": round(float(np.median(values)), 2),
            "p99_us": round(float(np.percentile(values, 99)), 2),
            "calls": len(values),
        }

    report = {
        "benchmark": "Policy.act_one per robot per tick (numpy), 2-8 neighbours",
        "command": "python bench/bench_inference.py " + " ".join(sys.argv[1:]),
        "model": args.model,
        "model_kind": policy.kind,
        "hops": policy.spec.hops if hasattr(policy, "spec") else None,  # the flooding GNN has no hops
        "target_median_us": TARGET_US,
        "overall": stats(elapsed),
        "by_neighbours": {int(m): stats(elapsed[counts == m]) for m in range(2, 9)},
        "machine": {
            "python": platform.python_version(),
            "numpy": np.__version__,
            "cpu": platform.processor(),
        },
        "note": "shared 2-core machine; p99 includes interference from other processes",
    }
    report["meets_target"] = report["overall"]["median_us"] <= TARGET_US
    out = output_dir(args) / "inference.json"
    out.write_text(json.dumps(report, indent=2) + "\n")
    print(json.dumps(report["overall"]), "->", out)


if __name__ == "__main__":
    main()
