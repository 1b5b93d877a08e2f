"""The limit of the distributed runtime at N = 100 and 20 Hz on this machine, whatever the agent.

Can any agent meet "N = 100 at 20 Hz: >= 99% of ticks served and command latency p99 <= 50 ms in
lockstep and realtime, sim real-time factor >= 1"? The real agents (``robot_agent``, started by
``swarm run``) are measured in the same invocation as two lighter sets that stand in for them, in the
real run with no ``robot_agent`` process at all (a sim server started alone, as on several hosts,
and one ``bench/bare_agent.py`` launcher; ``docs/distributed-runtime.md``):

- ``bare``: ``bare_agent.py --role stand-in``: the real agent's I/O with zenoh, msgpack and numpy only
  (its pose, its neighbours' messages, local consensus, a message and a command per tick on the real
  keys, the real liveliness token): the floor of any Python agent doing this work;
- ``answer``: ``--role answer``: its pose, the token and a constant command per pose, nothing else:
  what the sim server and its Zenoh router cost with the agents' work taken away.

Runs alternate (real, bare, answer; lockstep then realtime; ``--repeats`` times), so that the sets
compare on a machine whose load drifts. Each run reports ticks served, p50 / p99 command latency,
real-time factor, agent and server CPU per tick (process CPU of every thread, start-up excluded) and
the machine's load before and after; the summary adds the CPU a tick needs, server + N x agent,
against the period's ``cores x 50 ms``.

Run: ``python bench/runtime_limit.py --update-results`` (writes ``bench/results/runtime_limit.json``
and ``.md``; without it, ``runs/bench/``). About 4-6 min on 2 cores (12 runs of 10 s of sim).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import platform
import shlex
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import time
import uuid
from importlib.metadata import version
from pathlib import Path

import yaml
from _output import add_output_arguments, output_dir, progress
from bench_runtime import (
    ROOT,
    TARGETS,
    MachineClock,
    _fmt,
    agent_cpu_ms_per_tick,
    run_once,
    scenario_data,
    server_cpu_ms_per_tick,
    server_figures,
)

from sim_server.physics import LARGE_SWARM_PHYSICS_HZ, LARGE_SWARM_SOLVER_ITERATIONS
from swarm.runtime.distributed import AGENT_NICE, AGENTS_EXIT_GRACE_S, _child_env
from swarm.runtime.procs import free_tcp_port

BARE_AGENT = Path(__file__).resolve().parent / "bare_agent.py"
ROLES = {"bare": "stand-in", "answer": "answer"}
"""Agent set -> ``bare_agent.py --role`` (``real``: ``robot_agent`` through ``swarm run``)."""
KINDS = ("real", *ROLES)


def _stop(process: subprocess.Popen) -> None:
    """SIGTERM ``process`` (the launcher forwards it to its agents), SIGKILL after 10 s."""
    if process.poll() is None:
        with contextlib.suppress(ProcessLookupError):
            process.send_signal(signal.SIGTERM)
        try:
            process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait(timeout=10)


def run_standin(
    scenario_path: Path, out_dir: Path, steps: int, timeout_s: float, role: str, agent_nice: int
) -> dict:
    """One real run: ``python -m sim_server`` alone and one ``bare_agent.py --role ROLE`` launcher of
    N agents (at ``agent_nice``, as ``swarm run`` starts ``robot-agent``); the same figures as
    ``bench_runtime.run_once``, plus how the agents ended."""
    count = yaml.safe_load(scenario_path.read_text())["robots"]["count"]
    logs = out_dir / "logs"
    logs.mkdir(parents=True, exist_ok=True)
    endpoint, run_id = f"tcp/127.0.0.1:{free_tcp_port()}", f"limit-{uuid.uuid4().hex[:8]}"
    python, env = sys.executable, _child_env()
    server_cmd = [python, "-m", "sim_server", "--scenario", str(scenario_path), "--out", str(out_dir)]
    server_cmd += ["--run", run_id, "--listen", endpoint, "--no-report", "--quiet", "--die-with-parent"]
    agents_cmd = [python, str(BARE_AGENT), "--robots", f"0-{count - 1}", "--connect", endpoint]
    agents_cmd += ["--run", run_id, "--log-dir", str(logs), "--nice", str(agent_nice), "--role", role]
    clock = MachineClock()
    started_s, started_unix_s = time.perf_counter(), time.time()
    with open(logs / "sim_server.log", "wb") as server_log, open(logs / "agents.log", "wb") as agents_log:
        server = subprocess.Popen(server_cmd, env=env, cwd=ROOT, stdout=server_log, stderr=subprocess.STDOUT)
        agents = subprocess.Popen(agents_cmd, env=env, cwd=ROOT, stdout=agents_log, stderr=subprocess.STDOUT)
    trajectory, first_tick_s = out_dir / "trajectory.jsonl", None
    try:
        while server.poll() is None:
            if time.perf_counter() - started_s > timeout_s:
                return {"error": f"timed out after {timeout_s:g} s"}
            if first_tick_s is None and trajectory.exists() and trajectory.stat().st_size:
                first_tick_s = time.perf_counter() - started_s
            time.sleep(0.02)
        wall_s = time.perf_counter() - started_s
        with contextlib.suppress(subprocess.TimeoutExpired):  # they exit on the last tick or the sim's end
            agents.wait(timeout=AGENTS_EXIT_GRACE_S)
    finally:
        for process in (server, agents):
            _stop(process)
    if server.returncode != 0:
        tail = (logs / "sim_server.log").read_text(errors="replace").strip()[-400:]
        return {"error": f"sim_server exited {server.returncode}: {tail}"}
    machine = clock.after(wall_s)
    stats = json.loads((out_dir / "server_stats.json").read_text())
    records = [json.loads(p.read_text()) for p in sorted(logs.glob("floor_*.json"))]
    ready_unix_s = stats.get("agents_ready_unix_s")
    return (
        server_figures(stats, steps)
        | {
            "first_tick_s": None if first_tick_s is None else round(first_tick_s, 3),
            "agents_ready_s": None if ready_unix_s is None else round(ready_unix_s - started_unix_s, 3),
            "agent_cpu_ms_per_tick": agent_cpu_ms_per_tick(records),
            "server_cpu_ms_per_tick": server_cpu_ms_per_tick(stats, steps),
            "wall_s": round(wall_s, 3),
            "agents": len(records),
            "agents_at_last_tick": sum(r.get("last_tick") == steps - 1 for r in records),
            "agent_exit_reasons": sorted({str(r.get("exit_reason")) for r in records}),
            "launcher_exit": agents.returncode,
        }
        | machine
    )


def cores_per_tick(result: dict, count: int, period_s: float) -> float | None:
    """Cores one control period needs: (server CPU + N x agent CPU per tick) / period."""
    server, agent = result.get("server_cpu_ms_per_tick"), result.get("agent_cpu_ms_per_tick")
    if server is None or agent is None:
        return None
    return round((server + count * agent) / (1e3 * period_s), 3)


def targets_for(count: int) -> dict[str, float]:
    """The targets a run of ``count`` robots is judged on (``bench_runtime.TARGETS``): at N <= 6 the
    command-latency p99 (3 ms), otherwise those of N = 100 (ticks served, p99, real-time factor)."""
    if count <= 6:
        return {"p99_ms": TARGETS["p99_ms_at_6"]}
    return {
        "served_share": TARGETS["served_at_100"],
        "p99_ms": TARGETS["p99_ms_at_100"],
        "realtime_factor": TARGETS["rtf_at_100"],
    }


def meets(result: dict) -> bool:
    """The targets of one run (``targets_for`` its robot count; the real-time factor within 1%)."""
    if "error" in result:
        return False
    targets = targets_for(result["robots"])
    return (
        result["served_share"] >= targets.get("served_share", 0.0)
        and (result["latency_p99_ms"] or float("inf")) <= targets["p99_ms"]
        and (result["realtime_factor"] or 0.0) >= targets.get("realtime_factor", 0.0) - 0.01
    )


def summary(results: list[dict]) -> list[dict]:
    """Per agent set and mode: the runs' range of each figure, and whether every run met the targets."""
    rows = []
    for kind in KINDS:
        for mode in ("lockstep", "realtime"):
            runs = [r for r in results if r["agents_kind"] == kind and r["mode"] == mode]
            if not runs:
                continue
            good = [r for r in runs if "error" not in r]
            row: dict = {"agents_kind": kind, "mode": mode, "runs": len(runs)}
            row["errors"] = len(runs) - len(good)
            keys = ("served_share", "latency_p50_ms", "latency_p99_ms", "realtime_factor")
            keys += ("agent_cpu_ms_per_tick", "server_cpu_ms_per_tick", "cores_per_tick", "other_cores")
            for key in keys:
                values = [r[key] for r in good if r.get(key) is not None]
                row[key] = [min(values), statistics.median(values), max(values)] if values else None
            row["every_run_met"] = bool(good) and len(good) == len(runs) and all(meets(r) for r in good)
            row["some_run_met"] = any(meets(r) for r in good)
            rows.append(row)
    return rows


def _span(values: list | None, digits: int = 2, scale: float = 1.0, unit: str = "") -> str:
    if not values:
        return "-"
    low, _, high = (scale * v for v in values)
    if round(low, digits) == round(high, digits):
        return f"{low:.{digits}f}{unit}"
    return f"{low:.{digits}f}-{high:.{digits}f}{unit}"


def markdown(report: dict) -> str:
    s = report["settings"]
    count, cores = s["robots"], report["machine"]["cpu_count"]
    lines = [
        f"`{report['command']}` ({report['wall_s']:.0f} s): N = {count} at {1 / s['control_period_s']:g} Hz,"
        f" {s['duration_s']:g} s of sim per run, local consensus on a random graph of mean degree ~4,"
        f" physics {s['physics_hz']:g} Hz / {s['solver_iterations']} iterations, agents at nice"
        f" {s['agent_nice']}, {cores} cores. Runs alternate real, bare, answer (lockstep, then realtime),"
        f" {s['repeats']} times. 1-min load average {report['load_avg_before']} before the first run,"
        f" {report['load_avg_after']} after the last; 'other' = cores kept busy meanwhile by processes"
        " outside the run: the figures are only as good as the machine was quiet.",
        "",
        "- **real**: `robot_agent` through `swarm run` (the runtime as a user runs it);",
        "- **bare**: `bench/bare_agent.py --role stand-in` in place of every agent: zenoh, msgpack and numpy"
        " only, the real keys, payloads, neighbours and liveliness token, no `robot_agent` process (a sim"
        " server started alone);",
        "- **answer**: `bare_agent.py --role answer`: its pose, the token and a constant command per pose:"
        " the sim server and its Zenoh router with the agents' work taken away.",
        "",
        "CPU per tick: process CPU of every thread (Zenoh's included), start-up excluded; 'cores/tick' ="
        f" (server + {count} x agent CPU per tick) / 50 ms, against the {cores} cores there are.",
        "",
        "| # | agents | mode | ticks served | p50 ms | p99 ms | RTF | agent CPU ms/tick | server CPU ms/tick"
        " | cores/tick | other cores | load before / after | met |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for number, r in enumerate(report["results"], 1):
        head = f"| {number} | {r['agents_kind']} | {r['mode']} |"
        if "error" in r:
            lines.append(f"{head} error: {r['error']} |")
            continue
        lines.append(
            f"{head} {100 * r['served_share']:.1f}% | {_fmt(r['latency_p50_ms'])}"
            f" | {_fmt(r['latency_p99_ms'])} | {_fmt(r['realtime_factor'])}"
            f" | {_fmt(r['agent_cpu_ms_per_tick'], 3)} | {_fmt(r['server_cpu_ms_per_tick'], 1)}"
            f" | {_fmt(r['cores_per_tick'])} | {_fmt(r['other_cores'])}"
            f" | {_fmt(r['load_avg_1min_before'], 1)} / {_fmt(r['load_avg_1min_after'], 1)}"
            f" | {'yes' if meets(r) else 'no'} |"
        )
    lines += [
        "",
        "Per agent set and mode (min-max over the runs):",
        "",
        "| agents | mode | ticks served | p99 ms | RTF | agent CPU ms/tick | server CPU ms/tick | cores/tick"
        " | every run met | some run met |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for row in report["summary"]:
        lines.append(
            f"| {row['agents_kind']} | {row['mode']} | {_span(row['served_share'], 1, 100, '%')}"
            f" | {_span(row['latency_p99_ms'], 1)} | {_span(row['realtime_factor'])}"
            f" | {_span(row['agent_cpu_ms_per_tick'], 3)} | {_span(row['server_cpu_ms_per_tick'], 1)}"
            f" | {_span(row['cores_per_tick'])} | {'yes' if row['every_run_met'] else 'no'}"
            f" | {'yes' if row['some_run_met'] else 'no'} |"
        )
    wanted = ", ".join(
        f"{name} {'<=' if name == 'p99_ms' else '>='} {value:g}" for name, value in report["targets"].items()
    )
    lines += ["", f"Verdict (targets: {wanted}; both modes, every run):", ""]
    for kind, verdict in report["verdict"].items():
        lines.append(f"- {kind}: {'meets' if verdict else 'does not meet'} the N = {count} targets")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--count", type=int, default=100, help="robots (default 100)")
    parser.add_argument("--duration", type=float, default=10.0, help="simulated seconds per run (default 10)")
    parser.add_argument(
        "--modes", nargs="+", default=["lockstep", "realtime"], choices=["lockstep", "realtime"]
    )
    parser.add_argument(
        "--agents", nargs="+", default=list(KINDS), choices=KINDS, help="agent sets, in this order per mode"
    )
    parser.add_argument("--repeats", type=int, default=2, help="rounds of every set and mode (default 2)")
    parser.add_argument("--physics-hz", type=float, default=LARGE_SWARM_PHYSICS_HZ)
    parser.add_argument("--solver-iterations", type=int, default=LARGE_SWARM_SOLVER_ITERATIONS)
    parser.add_argument("--agent-nice", type=int, choices=range(20), metavar="0-19", default=AGENT_NICE)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--timeout", type=float, default=300.0, help="seconds per run")
    add_output_arguments(parser)
    args = parser.parse_args(argv)
    if args.count < 1 or args.duration <= 0 or args.repeats < 1:
        print("runtime_limit: error: --count, --duration and --repeats must be positive", file=sys.stderr)
        return 2
    out = output_dir(args) / "runtime_limit.json"
    command = "python bench/runtime_limit.py " + shlex.join(argv if argv is not None else sys.argv[1:])
    plan = [(mode, kind) for _ in range(args.repeats) for mode in args.modes for kind in args.agents]
    period_s, steps = 0.05, round(args.duration / 0.05)
    results, load_before, started_s = [], os.getloadavg()[0], time.perf_counter()
    keep = Path(tempfile.gettempdir()) / "runtime-limit-failed"
    with tempfile.TemporaryDirectory(prefix="runtime-limit-") as work:
        for number, (mode, kind) in enumerate(progress(plan, args, desc="runtime_limit", unit="run")):
            data = scenario_data(
                args.count, mode, args.duration, args.physics_hz, args.solver_iterations, args.seed
            )
            data["name"] += f"-{kind}-{number}"
            path = Path(work) / f"{data['name']}.yaml"
            path.write_text(yaml.safe_dump(data))
            run_dir = Path(work) / data["name"]
            if kind == "real":
                result = run_once(path, run_dir, steps, args.timeout, None, None, args.agent_nice)
            else:
                result = run_standin(path, run_dir, steps, args.timeout, ROLES[kind], args.agent_nice)
            if "error" in result:
                shutil.copytree(run_dir, keep / data["name"], dirs_exist_ok=True)
                result["results_dir"] = str(keep / data["name"])
            else:
                result["cores_per_tick"] = cores_per_tick(result, args.count, period_s)
            results.append({"agents_kind": kind, "mode": mode, "robots": args.count, **result})
            print(json.dumps(results[-1]), flush=True)
    rows = summary(results)
    verdict = {
        kind: all(row["every_run_met"] for row in rows if row["agents_kind"] == kind)
        for kind in args.agents
        if any(row["agents_kind"] == kind for row in rows)
    }
    report = {
        "benchmark": "runtime_limit",
        "command": command,
        "wall_s": round(time.perf_counter() - started_s, 1),
        "settings": {
            "robots": args.count,
            "duration_s": args.duration,
            "control_period_s": period_s,
            "physics_hz": args.physics_hz,
            "solver_iterations": args.solver_iterations,
            "agent_nice": args.agent_nice,
            "repeats": args.repeats,
            "seed": args.seed,
            "topology": "random, p = min(0.6, 4 / (N - 1)), connected",
            "controller": "local_consensus",
        },
        "targets": targets_for(args.count),
        "machine": {
            "python": platform.python_version(),
            "platform": platform.platform(),
            "cpu_count": os.cpu_count(),
            "zenoh": version("eclipse-zenoh"),
            "pybullet": version("pybullet"),
        },
        "load_avg_before": round(load_before, 2),
        "load_avg_after": round(os.getloadavg()[0], 2),
        "results": results,
        "summary": rows,
        "verdict": verdict,
    }
    out.write_text(json.dumps(report, indent=2) + "\n")
    out.with_suffix(".md").write_text(markdown(report))
    print(markdown(report))
    return 0 if all("error" not in r for r in results) else 1


if __name__ == "__main__":
    try:
        sys.exit(main())
    except KeyboardInterrupt:  # Ctrl-C reaches the runs too (one process group); run_standin stops its own
        print("runtime_limit: interrupted", file=sys.stderr)
        sys.exit(130)
