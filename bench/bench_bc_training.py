"""BC training wall time of the graph-filter GNN, measured: writes ``bench/results/bc_training.json``.

Runs exactly the documented reproduction of ``models/gnn_graph_filter.npz`` (``models/README.md``)::

    swarm collect --out DIR/bc.npz                       # seed 0, 10^6 samples
    swarm train --algo bc --data DIR/bc.npz --out DIR/bc  # preset default, seed 0, one thread

in a temporary directory, times both processes, reads the training loop's own time from the
policy's metadata (``training.train_time_s``), checks whether the weights equal the committed
model's, and records the machine's load (other jobs on a shared machine slow it down: the figure
is only comparable at the same load). Appends one run to the file (``--fresh``: start it anew).

    python bench/bench_bc_training.py [--fresh]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
OUT = ROOT / "bench" / "results" / "bc_training.json"
MODEL = ROOT / "models" / "gnn_graph_filter.npz"
TARGET_S = 120


def _timed(command: list[str]) -> float:
    started_s = time.perf_counter()
    subprocess.run(command, check=True, cwd=ROOT, stdout=subprocess.DEVNULL)
    return time.perf_counter() - started_s


def _same_weights(a: Path, b: Path) -> bool:
    with np.load(a) as left, np.load(b) as right:
        names = [name for name in left.files if name != "__metadata__"]
        return sorted(names) == sorted(n for n in right.files if n != "__metadata__") and all(
            np.array_equal(left[name], right[name]) for name in names
        )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--fresh", action="store_true", help="replace the file's runs instead of appending")
    args = parser.parse_args()
    swarm = [sys.executable, "-m", "swarm.cli"]
    load_before = os.getloadavg()[0]
    with tempfile.TemporaryDirectory(prefix="bc-training-") as work:
        data, out = Path(work) / "bc.npz", Path(work) / "bc"
        collect_s = _timed([*swarm, "collect", "--out", str(data), "--quiet"])
        train_s = _timed([*swarm, "train", "--algo", "bc", "--data", str(data), "--out", str(out)])
        policy = out / "policy.npz"
        with np.load(policy) as saved:
            metadata = json.loads(saved["__metadata__"].tobytes().decode())
        same = _same_weights(policy, MODEL)
    training = metadata.get("training", {})
    run = {
        "date_utc": time.strftime("%Y-%m-%d %H:%M", time.gmtime()),
        "train_time_s": round(float(training["train_time_s"]), 1),
        "process_wall_s": round(train_s, 1),
        "collect_s": round(collect_s, 1),
        "load_average_before": round(load_before, 1),
        "load_average_after": round(os.getloadavg()[0], 1),
        "cores": os.cpu_count(),
        "same_weights_as_committed_model": same,
    }
    previous = json.loads(OUT.read_text()) if OUT.is_file() and not args.fresh else {}
    runs = [r for r in previous.get("runs", []) if "load_average_before" in r] + [run]
    times = [r["train_time_s"] for r in runs]
    document = {
        "benchmark": "BC training wall time of the graph-filter GNN "
        "(models/gnn_graph_filter.npz, the default before the flooding GNN)",
        "command": "python bench/bench_bc_training.py",
        "what_it_runs": "swarm collect --out data/bc.npz && "
        "swarm train --algo bc --data data/bc.npz --out runs/bc",
        "target_s": TARGET_S,
        "samples": training.get("samples", 1_000_000),
        "epochs": training.get("config", {}).get("epochs"),
        "threads": training.get("config", {}).get("threads"),
        "runs": runs,
        "meets_target_at_lowest_load": min(runs, key=lambda r: r["load_average_before"])["train_time_s"]
        <= TARGET_S,
        "summary": f"training loop {min(times):.0f}-{max(times):.0f} s over {len(runs)} run(s); "
        "the load average says how many other jobs shared the cores",
    }
    OUT.write_text(json.dumps(document, indent=2) + "\n")
    print(json.dumps(run))
    return 0


if __name__ == "__main__":
    sys.exit(main())
