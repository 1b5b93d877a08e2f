"""Where the sim server's tick goes: py-spy on ``sim_server`` during a runtime-benchmark run, and its
CPU by thread.

Runs the scenario of ``bench/bench_runtime.py`` (N robots, lockstep or realtime, ``--physics-hz``)
with ``swarm run``; once a fifth of the ticks are done it records the server with ``py-spy record
--nonblocking`` (active samples only: waiting for commands does not count) for ``--seconds`` and reads
its per-thread CPU (``/proc/<pid>/task``) over the same interval. Prints the share of the main
thread's active samples in each function (inclusive: physics step, pose publishing, trajectory
writing, ...) and the thread split (``python``: the main thread; the rest: Zenoh's router), and writes
them to ``server_profile_<N>.json`` in the output directory (``--update-results``: ``bench/results/``).

Run: ``python bench/investigations/profile_server.py --count 100 --duration 20 --update-results``.
"""

from __future__ import annotations

import sys as _sys
from pathlib import Path as _Path

_sys.path.insert(0, str(_Path(__file__).resolve().parent.parent))  # bench/: its helpers and benchmarks

import argparse
import collections
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import bench_runtime  # a sibling script
import psutil
from _output import add_output_arguments, output_dir
from profile_agent import thread_cpu_s


def inclusive(raw: Path, top: int) -> tuple[int, list[tuple[float, str]]]:
    """(active samples, [(share, function)]) by function (file:name, any line), inclusive."""
    counts: collections.Counter[str] = collections.Counter()
    total = 0
    for line in raw.read_text().splitlines():
        stack, _, count = line.rpartition(" ")
        total += int(count)
        functions = {frame.rsplit(":", 1)[0] + ")" for frame in stack.split(";")}
        for function in functions:
            counts[function] += int(count)
    return total, [(n / total, f) for f, n in counts.most_common(top)] if total else []


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--count", type=int, default=100)
    parser.add_argument("--mode", choices=["lockstep", "realtime"], default="lockstep")
    parser.add_argument("--physics-hz", type=float, default=120.0)
    parser.add_argument("--duration", type=float, default=20.0, help="simulated seconds")
    parser.add_argument("--seconds", type=float, default=10.0, help="py-spy recording length")
    parser.add_argument("--rate", type=int, default=200)
    parser.add_argument("--top", type=int, default=25)
    add_output_arguments(parser)
    args = parser.parse_args(argv)
    summary = output_dir(args) / f"server_profile_{args.count}.json"
    py_spy = str(Path(sys.executable).parent / "py-spy")
    work = Path(tempfile.mkdtemp(prefix="profile-server-"))
    out = work  # the raw stacks
    data = bench_runtime.scenario_data(args.count, args.mode, args.duration, args.physics_hz, None, 1)
    scenario = work / "scenario.yaml"
    scenario.write_text(bench_runtime.yaml.safe_dump(data))
    steps = round(args.duration / 0.05)
    run = subprocess.Popen(
        [sys.executable, "-m", "swarm.cli", "run", str(scenario), "--out", str(work / "run"), "--quiet"],
        cwd=bench_runtime.ROOT,
    )
    trajectory = work / "run" / "trajectory.jsonl"
    while run.poll() is None:
        if trajectory.exists() and trajectory.read_bytes().count(b"\n") >= steps // 5:
            break
        time.sleep(0.1)
    server = next(c for c in psutil.Process(run.pid).children(recursive=True) if "sim_server" in c.cmdline())
    before = thread_cpu_s(server.pid)
    ticks_before = trajectory.read_bytes().count(b"\n")
    command = [py_spy, "record", "-p", str(server.pid), "-d", f"{args.seconds:g}", "-r", str(args.rate)]
    command += ["--nonblocking", "-f", "raw", "-o", str(out / "server.txt")]
    subprocess.run(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=False)
    after = thread_cpu_s(server.pid)
    ticks = trajectory.read_bytes().count(b"\n") - ticks_before
    run.wait()
    total, rows = inclusive(out / "server.txt", args.top)
    report = {
        "count": args.count,
        "mode": args.mode,
        "physics_hz": args.physics_hz,
        "ticks_recorded": ticks,
        "threads_cpu_s": {name: round(after[name] - before.get(name, 0.0), 3) for name in after},
        "main_thread_active_samples": total,
        "inclusive_share": {function: round(share, 4) for share, function in rows},
    }
    summary.write_text(json.dumps(report, indent=1) + "\n")
    print(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
