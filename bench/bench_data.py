"""Expert-data generation speed: ``swarm collect`` (swarm.learn.data) samples per wall-clock second.

The default recipe (centralized expert, six graph kinds x six sizes N = 4..12, every robot random,
K = 8 hop features with the policy's message timing). Target: 10^6 samples in at most 10 s.
The first, smaller run compiles and warms the numba kernels and is not counted. Writes
bench/results/data.json.

    python bench/bench_data.py [--samples 1000000] [--repeats 3]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from dataclasses import asdict

import numpy as np
from _output import add_output_arguments, output_dir, progress

from swarm.learn.data import collect, collect_config

TARGET_S = 10.0


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--samples", type=int, default=1_000_000)
    parser.add_argument("--repeats", type=int, default=3)
    add_output_arguments(parser)
    args = parser.parse_args()
    out = output_dir(args) / "data.json"
    collect(collect_config(samples=20_000, seed=99), progress=False)  # compile and warm up
    seconds = []
    for repeat in progress(range(args.repeats), args, desc="bench_data", unit="run"):
        started = time.perf_counter()
        dataset = collect(collect_config(samples=args.samples, seed=repeat), progress=False)
        seconds.append(time.perf_counter() - started)
        print(
            f"run {repeat}: {len(dataset)} samples in {seconds[-1]:.2f} s"
            f" ({len(dataset) / seconds[-1]:.3g} samples/s)"
        )
    median_s = float(np.median(seconds))
    load = os.getloadavg()
    report = {
        "benchmark": "expert data generation (swarm collect, default recipe)",
        "command": "python bench/bench_data.py",
        "samples": args.samples,
        "target_s": TARGET_S,
        "median_s": round(median_s, 3),
        "samples_per_s_median": round(args.samples / median_s),
        "all_s": [round(value, 3) for value in seconds],
        "meets_target": median_s <= TARGET_S,
        "config": asdict(collect_config(samples=args.samples)),
        "machine": {
            "python": platform.python_version(),
            "cpu_count": os.cpu_count(),
            "load_average_1_5_15": [round(value, 2) for value in load],
        },
    }
    out.write_text(json.dumps(report, indent=2) + "\n")
    verdict = "meets" if report["meets_target"] else "MISSES"
    print(
        f"median {median_s:.2f} s for {args.samples} samples: {verdict} the {TARGET_S:g} s target;"
        f" written {out}"
    )


if __name__ == "__main__":
    main()
