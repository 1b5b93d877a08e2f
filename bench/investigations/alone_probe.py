"""Where an agent's (and the server's) CPU goes when run alone: real agents against bare stand-ins.

Runs ``bench/runtime_limit.py``'s runs (``real``: ``swarm run``; ``bare``: a sim server alone and
``bare_agent.py --role stand-in``), alternating, and, while each runs, reads ``/proc`` of every agent
process and of the server at the first tick, at a quarter and three quarters of the run and at its
last tick (by the trajectory's line count): CPU per thread (summed by thread name; ``python`` is
the main thread) and voluntary and involuntary context switches, per tick of the middle half (start-up
and exit left out), and the CPU of each phase from ready to exit. The record-based figure (ready to
exit / ticks, as ``runtime_limit.py`` reports it) is beside it.

``--base COMMIT``: the same runs of that commit (a ``git worktree`` of it in a temporary directory,
its own code on ``PYTHONPATH``, this script copied in) and of this working tree, alternating (base,
head, base, head, ...), in one invocation, so that both see the same machine.

Run: ``python bench/investigations/alone_probe.py --base main --count 100 --repeats 2 --update-results``
(writes ``alone_probe.{json,md}`` to the output directory).
"""

from __future__ import annotations

import sys as _sys
from pathlib import Path as _Path

_sys.path.insert(0, str(_Path(__file__).resolve().parent.parent))  # bench/: its helpers and benchmarks

import argparse
import collections
import json
import os
import shlex
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import psutil
import yaml
from _output import add_output_arguments, output_dir
from _worktree import ROOT, base_worktree, short_commit
from bench_runtime import run_once, scenario_data
from runtime_limit import run_standin

from sim_server.physics import LARGE_SWARM_PHYSICS_HZ, LARGE_SWARM_SOLVER_ITERATIONS
from swarm.runtime.distributed import AGENT_NICE


def proc_figures(pid: int) -> dict[str, float]:
    """CPU seconds by thread name (``/proc/<pid>/task/*/schedstat``, nanoseconds; ``main``: the main
    thread), and the process's voluntary and involuntary context switches (all threads)."""
    out: collections.defaultdict[str, float] = collections.defaultdict(float)
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            name = (task / "comm").read_text().strip()
            cpu_ns = int((task / "schedstat").read_text().split()[0])
            status = (task / "status").read_text()
        except (OSError, ValueError, IndexError):
            continue
        name = "main" if name.startswith("python") else name.rstrip("0123456789-")
        out[f"cpu_{name}"] += cpu_ns / 1e9
        for line in status.splitlines():
            if line.startswith("voluntary_ctxt_switches"):
                out["voluntary"] += int(line.split()[1])
            elif line.startswith("nonvoluntary_ctxt_switches"):
                out["involuntary"] += int(line.split()[1])
    return dict(out)


def _figures(pid: int) -> dict[str, float] | None:
    try:
        return proc_figures(pid)
    except OSError:  # it exited meanwhile
        return None


class Probe:
    """Snapshots of the agents' and the server's /proc figures at two trajectory line counts."""

    def __init__(self, run_dir: Path, marks: tuple[int, ...]):
        self.run_dir, self.marks = run_dir, marks
        self.snaps: list[tuple[int, dict, dict]] = []
        self.thread = threading.Thread(target=self._watch, daemon=True)
        self.thread.start()

    def _processes(self) -> tuple[list[int], int | None]:
        agents, server = [], None
        for child in psutil.Process().children(recursive=True):
            try:
                cmd = " ".join(child.cmdline())
                if "sim_server" in cmd:
                    server = child.pid
                elif ("robot_agent" in cmd or "bare_agent.py" in cmd) and not child.children():
                    agents.append(child.pid)
            except psutil.Error:
                continue
        return agents, server

    def _watch(self) -> None:
        path, offset, lines = self.run_dir / "trajectory.jsonl", 0, 0
        for mark in self.marks:
            while lines < mark:
                time.sleep(0.05)
                if path.exists():
                    with open(path, "rb") as f:
                        f.seek(offset)
                        chunk = f.read()
                    offset += len(chunk)
                    lines += chunk.count(b"\n")
            agents, server = self._processes()
            snap = {pid: fig for pid in agents if (fig := _figures(pid)) is not None}
            self.snaps.append((lines, snap, (_figures(server) or {}) if server else {}))

    def result(self, records: list[dict], stats: dict) -> dict:
        """Per tick of the steady window (agents: mean over them), and each phase's CPU in ms: ready to
        the first tick, first tick to the window, the window, the window to the last tick, the last
        tick to exit (agents: their records' ``cpu_ready_s`` / ``cpu_s``; server: its stats')."""
        self.thread.join(timeout=5)
        if len(self.snaps) < 3:
            return {"error": "the run ended before the window closed"}
        _, (l1, a1, s1), (l2, a2, s2) = self.snaps[:3]
        ticks = l2 - l1
        common = [pid for pid in a1 if pid in a2]
        per: collections.Counter[str] = collections.Counter()
        for pid in common:
            for k, v in a2[pid].items():
                per[k] += v - a1[pid].get(k, 0.0)
        agent = {
            k: round(v * (1e3 if k.startswith("cpu") else 1.0) / ticks / len(common), 4)
            for k, v in per.items()
        }
        agent["cpu_total"] = round(sum(v for k, v in agent.items() if k.startswith("cpu")), 4)
        server = {
            k: round((s2[k] - s1.get(k, 0.0)) * (1e3 if k.startswith("cpu") else 1.0) / ticks, 3) for k in s2
        }
        server["cpu_total"] = round(sum(v for k, v in server.items() if k.startswith("cpu")), 3)

        def cpu_s(figures: dict) -> float:
            return sum(v for k, v in figures.items() if k.startswith("cpu"))

        names = ["ready_to_first", "first_to_window", "window", "window_to_last", "last_to_exit"]
        names = names if len(self.snaps) > 3 else [*names[:3], "window_to_exit"]
        phases: collections.defaultdict[str, list[float]] = collections.defaultdict(list)
        for r in records:
            if r.get("cpu_s") is None or any(r.get("pid") not in snap for _, snap, _ in self.snaps):
                continue
            ends = [
                r.get("cpu_ready_s", 0.0),
                *(cpu_s(snap[r["pid"]]) for _, snap, _ in self.snaps),
                r["cpu_s"],
            ]
            for name, a, b in zip(names, ends, ends[1:], strict=False):
                phases[name].append(b - a)
        server_ends = [
            stats.get("cpu_ready_s", 0.0),
            *(cpu_s(s) for _, _, s in self.snaps if s),  # the server may be gone at the last tick
            stats.get("cpu_s", 0.0),
        ]
        return {
            "window_ticks": ticks,
            "agents": len(common),
            "agent_per_tick": dict(sorted(agent.items())),
            "server_per_tick": dict(sorted(server.items())),
            "agents_in_phases": len(phases.get("window", [])),
            "agent_phase_cpu_ms": {n: round(1e3 * sum(v) / len(v), 1) for n, v in phases.items() if v},
            "server_phase_cpu_ms": {
                n: round(1e3 * (b - a), 1)
                for n, a, b in zip(
                    PHASES if len(server_ends) == 6 else [*PHASES[:3], "window_to_exit"],
                    server_ends,
                    server_ends[1:],
                    strict=False,
                )
            },
            "marks_lines": [s[0] for s in self.snaps],
        }


PHASES = ("ready_to_first", "first_to_window", "window", "window_to_last", "last_to_exit")


def markdown(report: dict) -> str:
    """One row per run: record-based and steady-window figures, threads, wake-ups, phases."""
    lines = [
        f"`{report['command']}`: N = {report['count']}, {report['mode']}, runs of `bench/runtime_limit.py`"
        " (real: `swarm run`; bare: a sim server alone and `bare_agent.py --role stand-in`), alternating."
        " 'record': CPU from ready to exit / ticks, as `runtime_limit.py` reports it; 'window': ticks"
        " N/4 to 3N/4 of the run from /proc (schedstat, every thread), per agent per tick; main / Zenoh:"
        " the window split by thread; 'vol / invol': context switches per agent per tick; phases: ms"
        " of CPU per agent from ready to the first tick, in the window, and from 3/4 of the run to exit.",
        "",
        "| run | commit | agents | load | RTF | record ms/tick | window ms/tick | main / Zenoh ms"
        " | vol / invol | ready->first ms | window ms | 3/4->exit ms | server record / window ms/tick |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for i, r in enumerate(report["results"], 1):
        if "error" in r or "agent_per_tick" not in r:
            lines.append(f"| {i} | {r.get('commit', '-')} | {r['agents_kind']} | error: {r.get('error')} |")
            continue
        a, ph = r["agent_per_tick"], r["agent_phase_cpu_ms"]
        zenoh_ms = a["cpu_total"] - a.get("cpu_main", 0.0)
        tail = sum(ph.get(k, 0.0) for k in ("window_to_last", "last_to_exit", "window_to_exit"))
        rtf = r.get("realtime_factor")
        lines.append(
            f"| {i} | {r.get('commit', '-')} | {r['agents_kind']} | {r['load_before']}"
            f" | {'-' if rtf is None else f'{rtf:.2f}'} | {r.get('agent_cpu_ms_per_tick')}"
            f" | **{a['cpu_total']:.3f}**"
            f" | {a.get('cpu_main', 0.0):.3f} / {zenoh_ms:.3f} | {a.get('voluntary', 0):.1f} /"
            f" {a.get('involuntary', 0):.1f} | {ph.get('ready_to_first', '-')} | {ph.get('window', '-')}"
            f" | {tail:.1f} | {r.get('server_cpu_ms_per_tick')} / {r['server_per_tick']['cpu_total']} |"
        )
    return "\n".join(lines) + "\n"


def ab(args: argparse.Namespace, command: str) -> int:
    """``--base``: alternate this script's runs of the base commit and of this working tree."""
    base, head = short_commit(args.base), short_commit("HEAD")
    if base is None:
        print(f"alone_probe: error: --base {args.base!r}: not a commit of this repository", file=sys.stderr)
        return 2
    results = []
    with base_worktree(args.base, "alone-ab-") as base_tree:
        work = base_tree.parent
        (base_tree / "bench" / "investigations").mkdir(exist_ok=True)
        shutil.copy(Path(__file__), base_tree / "bench" / "investigations" / "alone_probe.py")
        for i, which in enumerate([w for _ in range(args.repeats) for w in ("base", "head")]):
            tree = base_tree if which == "base" else ROOT
            out = work / f"run{i}"
            script = tree / "bench" / "investigations" / "alone_probe.py"
            child = [sys.executable, str(script), "--count", str(args.count)]
            child += ["--duration", str(args.duration), "--mode", args.mode, "--repeats", "1"]
            child += ["--agents", *args.agents, "--out", str(out)]
            env = dict(os.environ, PYTHONPATH=str(tree))
            done = subprocess.run(child, cwd=tree, env=env, capture_output=True, text=True)
            found = out / "alone_probe.json"
            rows = json.loads(found.read_text())["results"] if found.exists() else []
            label = base if which == "base" else f"{head}+"
            why = f"exit {done.returncode}: {done.stderr.strip()[-300:]}"
            results += [{"commit": label} | row for row in rows] or [
                {"commit": label, "agents_kind": "-", "error": why}
            ]
            print(json.dumps(results[-len(rows or [0]) :]), flush=True)
    report = {"command": command, "count": args.count, "mode": args.mode, "base": base}
    report |= {"head": f"{head}+ (working tree)", "results": results}
    (output_dir(args) / "alone_probe.json").write_text(json.dumps(report, indent=1) + "\n")
    (output_dir(args) / "alone_probe.md").write_text(markdown(report))
    print(markdown(report))
    return 0 if all("error" not in r for r in results) else 1


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--count", type=int, default=100)
    parser.add_argument("--duration", type=float, default=10.0, help="simulated seconds per run")
    parser.add_argument("--mode", choices=("lockstep", "realtime"), default="lockstep")
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--agents", nargs="+", choices=("real", "bare"), default=["real", "bare"])
    parser.add_argument("--base", help="also run this commit, alternating with this working tree")
    add_output_arguments(parser)
    args = parser.parse_args(argv)
    if args.count < 1 or args.duration <= 0 or args.repeats < 1:
        print("alone_probe: error: --count, --duration and --repeats must be positive", file=sys.stderr)
        return 2
    given = argv if argv is not None else sys.argv[1:]
    command = "python bench/investigations/alone_probe.py " + shlex.join(given)
    if args.base:
        return ab(args, command)
    steps = round(args.duration / 0.05)
    results = []
    with tempfile.TemporaryDirectory(prefix="alone-probe-") as work:
        for number, kind in enumerate([k for _ in range(args.repeats) for k in args.agents]):
            data = scenario_data(
                args.count, args.mode, args.duration, LARGE_SWARM_PHYSICS_HZ, LARGE_SWARM_SOLVER_ITERATIONS, 1
            )
            data["name"] += f"-{kind}-{number}"
            path = Path(work) / f"{data['name']}.yaml"
            path.write_text(yaml.safe_dump(data))
            run_dir = Path(work) / data["name"]
            probe = Probe(run_dir, (1, steps // 4, 3 * steps // 4, steps + 1))
            load = os.getloadavg()[0]
            if kind == "real":
                run = run_once(path, run_dir, steps, 300.0, None, None, AGENT_NICE)
            else:
                run = run_standin(path, run_dir, steps, 300.0, "stand-in", AGENT_NICE)
            keep = ("agent_cpu_ms_per_tick", "server_cpu_ms_per_tick", "realtime_factor", "error")
            row = {"agents_kind": kind, "load_before": round(load, 2)}
            logs = run_dir / "logs"
            records = [
                json.loads(p.read_text())
                for p in logs.glob("agent_*.json" if kind == "real" else "floor_*.json")
            ]
            stats = (
                json.loads((run_dir / "server_stats.json").read_text())
                if (run_dir / "server_stats.json").exists()
                else {}
            )
            row |= {k: run[k] for k in keep if k in run} | probe.result(records, stats)
            results.append(row)
            print(json.dumps(row), flush=True)
    report = {"command": command, "count": args.count, "mode": args.mode, "results": results}
    (output_dir(args) / "alone_probe.json").write_text(json.dumps(report, indent=1) + "\n")
    (output_dir(args) / "alone_probe.md").write_text(markdown(report))
    return 0 if all("error" not in r for r in results) else 1


if __name__ == "__main__":
    sys.exit(main())
