"""The distributed runtime across emulated hosts: the sim server in one network namespace, the agents
in four more (N / 4 each, one ``robot-agent --robots`` launcher per namespace), all joined by a bridge
(``swarm.runtime.netns.Hosts``), optionally with a netem delay on each agent namespace's link.

Each run is the runtime benchmark's scenario (``bench/bench_runtime.py``: N robots, random graph of
mean degree ~4, local consensus, 20 Hz, physics 40 Hz / 30 iterations), started by hand as a user on
several hosts would (``python -m sim_server --listen tcp/0.0.0.0:7447``; ``robot-agent --robots a-b
--connect tcp/<sim>:7447 --nice 5``). Per run: converged or not (``max_pairwise`` at the end against
``--threshold``, 3 m), ticks served, command latency p50 / p99 and its histogram (pose published
-> command received, ``server_stats.json``), agents ready. With ``--delay-ms`` (default 0 and 2) each
delay is a run of its own, so the histograms show what the delay adds (2 ms on both directions of an
agent's link: the pose and the command each cross it once, ~4 ms more per tick); where ``tc`` cannot
add netem (no ``sch_netem`` in the kernel) those runs are skipped with the reason in the results.

Run: ``python bench/bench_namespaces.py --update-results`` (writes ``bench/results/runtime_namespaces.json``
and ``.md``; without it ``runs/bench/``). Needs Linux, root and iproute2; exits 1 with the reason
otherwise. The machine's load average is recorded with every run.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
import uuid
from pathlib import Path

import yaml
from _output import add_output_arguments, output_dir, progress
from bench_runtime import scenario_data

from sim_server.physics import LARGE_SWARM_PHYSICS_HZ, LARGE_SWARM_SOLVER_ITERATIONS
from swarm.runtime.netns import Hosts, NamespaceError, Processes, why_no_namespaces
from swarm.scenarios.results import read_trajectory, summarize
from swarm.scenarios.scenario import load_scenario

ROOT = Path(__file__).resolve().parent.parent
PORT = 7447
AGENT_HOSTS = 4


def _env() -> dict[str, str]:
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), *filter(None, [env.get("PYTHONPATH")])])
    return env


def run_once(hosts: Hosts, scenario_path: Path, work: Path, count: int, timeout_s: float) -> dict:
    """One run: the server on host ``sim``, ``count / 4`` agents on each agent host."""
    scenario = load_scenario(scenario_path)
    out, run_id = work / "results", f"ns-{uuid.uuid4().hex[:6]}"
    (out / "logs").mkdir(parents=True, exist_ok=True)
    processes = Processes(hosts, work, cwd=ROOT)
    load_before = os.getloadavg()[0]
    started_s = time.perf_counter()
    try:
        server = processes.start(
            "sim_server",
            "sim",
            *("-m", "sim_server", "--scenario", str(scenario_path), "--out", str(out), "--run", run_id),
            *("--listen", f"tcp/0.0.0.0:{PORT}", "--no-report", "--die-with-parent"),
            env=_env(),
        )
        endpoint = f"tcp/{hosts.address('sim')}:{PORT}"
        per_host = -(-count // AGENT_HOSTS)
        launchers = []
        for k in range(AGENT_HOSTS):
            low, high = k * per_host, min(count, (k + 1) * per_host) - 1
            launchers.append(
                processes.start(
                    f"agents_{k}",
                    f"robots-{k}",
                    *(
                        "-m",
                        "robot_agent",
                        "--robots",
                        f"{low}-{high}",
                        "--connect",
                        endpoint,
                        "--run",
                        run_id,
                    ),
                    *("--log-dir", str(out / "logs"), "--nice", "5", "--die-with-parent"),
                    env=_env(),
                )
            )
        try:
            server_code = server.wait(timeout=timeout_s)
            agent_codes = [launcher.wait(timeout=30) for launcher in launchers]
        except Exception:
            return {"error": f"the run did not end: {processes.log('sim_server')}"}
    finally:
        processes.stop()
    wall_s = time.perf_counter() - started_s
    if server_code != 0:
        return {"error": f"sim server exited {server_code}: {processes.log('sim_server')}"}
    stats = json.loads((out / "server_stats.json").read_text())
    times_s, poses, _ = read_trajectory(out / "trajectory.jsonl")
    outcome = summarize(scenario, times_s, poses, scenario.adjacency())
    ticks = stats.get("ticks") or scenario.steps
    return {
        "converged": bool(outcome["converged"]),
        "final_metric": outcome["final_metric"],
        "ticks": ticks,
        "served_share": round(stats.get("ticks_served", 0) / ticks, 4),
        "latency_ms": stats.get("latency_ms"),
        "latency_histogram_ms": stats.get("latency_histogram_ms"),
        "realtime_factor": stats.get("realtime_factor"),
        "agents_ready_s": round(stats["startup_s"], 3) if "startup_s" in stats else None,
        "agent_exit_codes": sorted(set(agent_codes)),
        "wall_s": round(wall_s, 1),
        "load_avg_1min_before": round(load_before, 2),
        "load_avg_1min_after": round(os.getloadavg()[0], 2),
    }


def markdown(report: dict) -> str:
    lines = [
        f"`python bench/bench_namespaces.py`: N = {report['robots']}, the sim server in one network"
        f" namespace, {AGENT_HOSTS} agent namespaces of {report['robots'] // AGENT_HOSTS} agents each,"
        f" joined by a bridge; {report['duration_s']:g} s of sim per run, 20 Hz,"
        f" physics {report['physics_hz']:g} Hz /"
        f" {report['solver_iterations']} iterations, agents at nice 5, converged: max pairwise <="
        f" {report['threshold_m']:g} m at the end. {report['machine_cores']} cores; 1-min"
        f" load average {report['load_avg_before']} before the first run.",
        "",
    ]
    if report.get("delay_skipped"):
        lines += [f"Delay runs skipped: {report['delay_skipped']}", ""]
    lines += [
        "| mode | delay ms | converged | final max pairwise m | ticks served | p50 ms | p99 ms | RTF"
        " | agents ready s | load before / after | latency histogram (ms: count) |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in report["results"]:
        if "error" in r:
            lines.append(f"| {r['mode']} | {r['delay_ms']:g} | error: {r['error'][-300:]} |")
            continue
        latency = r["latency_ms"] or {}
        histogram = ", ".join(f"{k}: {v}" for k, v in (r["latency_histogram_ms"] or {}).items() if v)
        lines.append(
            f"| {r['mode']} | {r['delay_ms']:g} | {'yes' if r['converged'] else '**no**'}"
            f" | {r['final_metric']:.3f} | {100 * r['served_share']:.1f}% | {latency.get('p50')}"
            f" | {latency.get('p99')} | {r['realtime_factor']:.2f} | {r['agents_ready_s']}"
            f" | {r['load_avg_1min_before']} / {r['load_avg_1min_after']} | {histogram} |"
        )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--count", type=int, default=100, help="robots (default 100: 25 per agent namespace)")
    parser.add_argument(
        "--modes", nargs="+", default=["lockstep", "realtime"], choices=["lockstep", "realtime"]
    )
    parser.add_argument("--delay-ms", type=float, nargs="+", default=[0.0, 2.0], help="netem delay per run")
    parser.add_argument("--duration", type=float, default=30.0, help="simulated seconds per run (default 30)")
    parser.add_argument(
        "--threshold",
        type=float,
        default=3.0,
        help="converged: max pairwise distance at the end at most this, m (default 3.0: 100 packed bodies"
        " need at least 1.87; the kinematic engine's 100 points take ~20 s to come within 1 m)",
    )
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--timeout", type=float, default=300.0, help="seconds per run")
    add_output_arguments(parser)
    args = parser.parse_args(argv)
    if args.count < AGENT_HOSTS:
        print(
            f"bench_namespaces: --count: {args.count} is fewer than {AGENT_HOSTS} agent hosts",
            file=sys.stderr,
        )
        return 2
    reason = why_no_namespaces()
    if reason:
        print(f"bench_namespaces: cannot run: {reason}", file=sys.stderr)
        return 1
    out = output_dir(args) / "runtime_namespaces.json"
    report: dict = {
        "benchmark": "runtime_namespaces",
        "robots": args.count,
        "duration_s": args.duration,
        "physics_hz": LARGE_SWARM_PHYSICS_HZ,
        "solver_iterations": LARGE_SWARM_SOLVER_ITERATIONS,
        "seed": args.seed,
        "threshold_m": args.threshold,
        "machine_cores": os.cpu_count(),
        "load_avg_before": round(os.getloadavg()[0], 2),
        "results": [],
    }
    runs = [(delay, mode) for delay in args.delay_ms for mode in args.modes]
    bar = progress(total=len(runs), iterable=None, args=args, desc="bench_namespaces", unit="run")
    with tempfile.TemporaryDirectory(prefix="bench-namespaces-") as work:
        for delay_ms, mode in runs:
            try:
                with Hosts(["sim", *(f"robots-{k}" for k in range(AGENT_HOSTS))]) as hosts:
                    try:
                        for k in range(AGENT_HOSTS if delay_ms > 0 else 0):
                            hosts.delay(f"robots-{k}", delay_ms)
                    except NamespaceError as error:
                        report["delay_skipped"] = (
                            f"{delay_ms:g} ms: tc cannot add a netem delay here ({error})"
                        )
                        bar.update(1)
                        continue
                    data = scenario_data(
                        args.count,
                        mode,
                        args.duration,
                        LARGE_SWARM_PHYSICS_HZ,
                        LARGE_SWARM_SOLVER_ITERATIONS,
                        args.seed,
                    )
                    data["success"]["threshold"] = {"kinematic": 0.2, "pybullet": args.threshold}
                    run_dir = Path(work) / f"{mode}-{delay_ms:g}ms"
                    run_dir.mkdir()
                    scenario_path = run_dir / "scenario.yaml"
                    scenario_path.write_text(yaml.safe_dump(data))
                    result = run_once(hosts, scenario_path, run_dir, args.count, args.timeout)
            except NamespaceError as error:
                print(f"bench_namespaces: cannot create the hosts: {error}", file=sys.stderr)
                return 1
            result = {"mode": mode, "delay_ms": delay_ms, **result}
            report["results"].append(result)
            print(json.dumps(result), flush=True)
            bar.update(1)
    bar.close()
    out.write_text(json.dumps(report, indent=2) + "\n")
    out.with_suffix(".md").write_text(markdown(report))
    print(markdown(report))
    done = [r for r in report["results"] if "error" not in r]
    return 0 if done and len(done) == len(report["results"]) and all(r["converged"] for r in done) else 1


if __name__ == "__main__":
    sys.exit(main())
