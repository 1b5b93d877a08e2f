"""Where an agent's CPU goes: py-spy on one real and one bare agent of a floor run, and per-thread CPU.

Runs the floor run of ``bench/bench_runtime.py`` (a lockstep ``swarm run`` of N robots with a bare
agent, ``bench/bare_agent.py``, beside each real one); once the CPU window opens it records robot 0's
real and bare agent with ``py-spy record --nonblocking`` (``pip install py-spy``) for ``--seconds``
and reads both processes' per-thread CPU (``/proc/<pid>/task/*/stat``, by thread name: ``python``
is the main thread, the others are Zenoh's) over the same interval. Prints the main thread's
hottest lines (py-spy's active samples) and the thread split, and writes them to
``agent_profile_<N>.json`` in the output directory (``--update-results``: ``bench/results/``).

Run: ``python bench/investigations/profile_agent.py --count 6 --duration 120 --update-results``
(the run must outlast the window and the recording: lockstep at N = 6 runs ~4x faster than real
time on a loaded 2-core machine).
"""

from __future__ import annotations

import sys as _sys
from pathlib import Path as _Path

_sys.path.insert(0, str(_Path(__file__).resolve().parent.parent))  # bench/: its helpers and benchmarks

import argparse
import collections
import json
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import bench_runtime  # a sibling script
import psutil
from _output import add_output_arguments, output_dir


def thread_cpu_s(pid: int) -> dict[str, float]:
    """CPU seconds (user + system) of each thread of ``pid``, summed by thread name."""
    ticks_per_s = 100.0  # USER_HZ
    by_name: collections.Counter[str] = collections.Counter()
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            name = (task / "comm").read_text().strip()
            fields = (task / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        by_name[name] += (int(fields[11]) + int(fields[12])) / ticks_per_s
    return dict(by_name)


def hottest(raw: Path, top: int) -> tuple[int, list[tuple[float, str]]]:
    """(active samples, [(share, innermost frame)]) of a ``py-spy -f raw`` file."""
    counts: collections.Counter[str] = collections.Counter()
    total = 0
    for line in raw.read_text().splitlines():
        stack, _, count = line.rpartition(" ")
        total += int(count)
        counts[stack.split(";")[-1]] += int(count)
    return total, [(n / total, frame) for frame, n in counts.most_common(top)] if total else []


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--count", type=int, default=6)
    parser.add_argument("--duration", type=float, default=120.0, help="simulated seconds (lockstep)")
    parser.add_argument("--seconds", type=float, default=8.0, help="py-spy recording length")
    parser.add_argument("--rate", type=int, default=250, help="py-spy samples per second")
    parser.add_argument("--top", type=int, default=12)
    add_output_arguments(parser)
    args = parser.parse_args(argv)
    summary = output_dir(args) / f"agent_profile_{args.count}.json"
    py_spy = shutil.which("py-spy") or str(Path(sys.executable).parent / "py-spy")
    work = Path(tempfile.mkdtemp(prefix="profile-agent-"))
    out = work  # the raw stacks
    physics_hz = 120.0 if args.count >= 100 else None
    data = bench_runtime.scenario_data(args.count, "lockstep", args.duration, physics_hz, None, 1)
    scenario = work / "scenario.yaml"
    scenario.write_text(bench_runtime.yaml.safe_dump(data))
    steps = round(args.duration / 0.05)
    floor = bench_runtime.Floor(args.count, work / "bare", steps // 5, steps - steps // 5)
    report: dict = {"count": args.count}

    def profile() -> None:
        me = psutil.Process()
        while not floor.samples:  # the window is open: both sets are up and ticking
            time.sleep(0.2)
        launchers = [c for c in me.children(recursive=True) if "robot_agent" in c.cmdline()]
        real = [p for launcher in launchers for p in launcher.children()]
        bare = psutil.Process(floor.process.pid).children()
        pids = {"real": min(real, key=lambda p: p.pid).pid, "bare": min(bare, key=lambda p: p.pid).pid}
        before = {name: thread_cpu_s(pid) for name, pid in pids.items()}
        spies = [
            subprocess.Popen(
                [
                    *(py_spy, "record", "-p", str(pid), "-d", f"{args.seconds:g}", "-r", str(args.rate)),
                    *("--nonblocking", "-f", "raw", "-o", str(out / f"{name}.txt")),
                ],
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
            )
            for name, pid in pids.items()
        ]
        for spy in spies:
            spy.wait()
        after = {name: thread_cpu_s(pid) for name, pid in pids.items()}
        report["threads_cpu_s"] = {
            name: {t: round(after[name][t] - before[name].get(t, 0.0), 3) for t in after[name]}
            for name in pids
        }

    thread = threading.Thread(target=profile, daemon=True)
    thread.start()
    result = bench_runtime.run_once(scenario, work / "run", steps, 1800.0, None, floor)
    thread.join(timeout=60)
    report["floor"] = result.get("floor", result)
    summary.write_text(json.dumps(report, indent=1) + "\n")
    print(json.dumps(report, indent=1))
    for name in ("real", "bare"):
        if (out / f"{name}.txt").exists():
            total, rows = hottest(out / f"{name}.txt", args.top)
            print(f"--- {name} agent, main thread: {total} active samples")
            for share, frame in rows:
                print(f"{100 * share:5.1f}%  {frame}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
