"""The ``pybullet`` engine: a scenario run as a distributed system of OS processes over Zenoh.

``run_distributed`` starts one ``sim_server`` and the robots' controllers (``robot_agent``: one
process per robot, forked by one launcher; or, for ``controller.kind: centralized``, the single
``robot_agent.central`` process) on free loopback TCP ports, shows the server's progress (ticks
in ``trajectory.jsonl``), waits, and writes the same results directory as the kinematic engine
plus the processes' logs and runtime statistics. Every process lives in a process group that is
stopped (SIGTERM, then SIGKILL after a grace period) when the run ends, fails or is interrupted;
the children also die with their parent (``swarm.procs.die_with_parent``).

No Zenoh session is opened here: the sim server is the Zenoh router the agents connect to.
"""

from __future__ import annotations

import json
import os
import signal
import sys
import threading
import time
import uuid
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from swarm.procs import Supervisor, free_tcp_port
from swarm.results import prepare_results_dir, read_trajectory, summarize, write_metrics
from swarm.scenario import Scenario, ScenarioError, parse_scenario, resolve_model_path

AGENTS_EXIT_GRACE_S = 5.0
"""How long the agents get to notice that the sim has gone and exit by themselves."""


class RunFailed(ScenarioError):
    """The processes could not complete the run (CLI exit status 2); one line for the user."""


def _run_id(name: str) -> str:
    slug = "".join(ch if ch.isalnum() or ch in "_-" else "-" for ch in name)[:40].strip("-") or "run"
    return f"{slug}-{uuid.uuid4().hex[:8]}"


def _child_env() -> dict[str, str]:
    """Environment of the children: this package importable, one BLAS thread per process."""
    env = dict(os.environ)
    root = str(Path(__file__).resolve().parent.parent)
    env["PYTHONPATH"] = os.pathsep.join([root, *filter(None, [env.get("PYTHONPATH")])])
    for name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        env[name] = "1"
    env["PYTHONUNBUFFERED"] = "1"
    return env


@contextmanager
def _sigterm_as_interrupt():
    """While running, SIGTERM to the runner is handled like Ctrl-C: stop the children, then exit."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def interrupt(signum: int, frame: object) -> None:
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


class _TickCounter:
    """Counts the lines of a growing trajectory file (the server's progress)."""

    def __init__(self, path: Path):
        self.path = path
        self.lines = 0
        self._offset = 0

    def update(self) -> int:
        try:
            with open(self.path, "rb") as file:
                file.seek(self._offset)
                chunk = file.read()
        except FileNotFoundError:
            return self.lines
        self._offset += len(chunk)
        self.lines += chunk.count(b"\n")
        return self.lines


def _tail(path: Path, lines: int = 3) -> str:
    try:
        text = path.read_text(errors="replace").strip().splitlines()
    except FileNotFoundError:
        return ""
    return " | ".join(text[-lines:])


def _read_json(path: Path) -> dict:
    try:
        return json.loads(path.read_text())
    except (FileNotFoundError, json.JSONDecodeError):
        return {}


def run_distributed(
    scenario: Scenario, out_dir: Path, scenario_path: Path | None = None, progress: bool = True
) -> dict:
    """Run ``scenario`` as sim server + agent processes; returns the outcome (metrics.json)."""
    adjacency = scenario.adjacency()
    if adjacency is None:
        raise ScenarioError(
            "topology.kind: 'disk' graphs are not supported by the pybullet engine yet"
            " (use --engine kinematic)"
        )
    model = None
    if scenario.controller.kind == "gnn":
        model = resolve_model_path(scenario.controller.model, scenario_path).resolve()
        data = scenario.model_dump(mode="json")
        data["controller"]["model"] = str(model)  # the server reads the copy in the results directory
        scenario = parse_scenario(data)
    if scenario.faults:
        print("swarm run: note: faults are not injected by the pybullet engine yet", file=sys.stderr)
    out_dir = Path(out_dir)
    prepare_results_dir(out_dir, scenario)
    logs = out_dir / "logs"
    for stale in [out_dir / "trajectory.jsonl", out_dir / "server_stats.json", *logs.glob("agent_*.json")]:
        stale.unlink(missing_ok=True)
    run_id = _run_id(scenario.name)
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    count, steps = scenario.robots.count, scenario.steps
    python = sys.executable
    server_cmd = [python, "-m", "sim_server", "--scenario", str(out_dir / "scenario.yaml")]
    server_cmd += ["--out", str(out_dir), "--run", run_id, "--listen", endpoint, "--die-with-parent"]
    server_cmd += ["--model", str(model)] if model else []
    common = ["--connect", endpoint, "--run", run_id, "--log-dir", str(logs), "--die-with-parent"]
    if scenario.controller.kind == "centralized":
        controller_name, controller_cmd = "central", [python, "-m", "robot_agent.central", *common]
    else:
        controller_name = "agents"
        controller_cmd = [python, "-m", "robot_agent", "--robots", f"0-{count - 1}", *common]

    ticks = _TickCounter(out_dir / "trajectory.jsonl")
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=steps + 1, desc=f"{scenario.name} (pybullet)", unit="tick", leave=False)
    started_s, started_unix_s = time.perf_counter(), time.time()
    first_tick_s = None
    with _sigterm_as_interrupt(), Supervisor(env=_child_env()) as supervisor:
        try:
            server = supervisor.start("sim_server", server_cmd, logs / "sim_server.log")
            controllers = supervisor.start(controller_name, controller_cmd, logs / f"{controller_name}.log")
            while server.poll() is None:
                done = ticks.update()
                if done and first_tick_s is None:
                    first_tick_s = time.perf_counter() - started_s
                if not done and controllers.poll() is not None:
                    log = logs / f"{controller_name}.log"
                    raise RunFailed(
                        f"the {controller_name} process exited with status {controllers.returncode} before"
                        f" the first tick: {_tail(log)} (logs in {logs})"
                    )
                if bar is not None:
                    bar.update(done - bar.n)
                time.sleep(0.05)
            ticks.update()
            agents_exit = supervisor.wait(controller_name, AGENTS_EXIT_GRACE_S)
        finally:
            if bar is not None:
                bar.close()
    wall_s = time.perf_counter() - started_s
    if server.returncode != 0:
        raise RunFailed(
            f"sim server exited with status {server.returncode}: {_tail(logs / 'sim_server.log')}"
            f" (logs in {logs})"
        )
    times_s, poses, _ = read_trajectory(out_dir / "trajectory.jsonl")
    if len(times_s) != steps + 1:
        raise RunFailed(f"trajectory has {len(times_s)} of {steps + 1} ticks (logs in {logs})")

    outcome = summarize(scenario, times_s, poses, adjacency)
    records = {int(path.stem.split("_")[1]): _read_json(path) for path in sorted(logs.glob("agent_*.json"))}
    stats = _read_json(out_dir / "server_stats.json")
    outcome["processes"] = {
        "server_pid": server.pid,
        f"{controller_name}_pid": controllers.pid,
        "agent_pids": {str(i): record.get("pid") for i, record in sorted(records.items())},
        "agents_exit_status": agents_exit,
        "killed_process_groups": len(supervisor.killed),
    }
    outcome["runtime"] = runtime_summary(scenario, stats, records, endpoint, wall_s, first_tick_s)
    if stats.get("agents_ready_unix_s") is not None:
        outcome["runtime"]["agents_ready_s"] = round(stats["agents_ready_unix_s"] - started_unix_s, 3)
    write_metrics(out_dir, outcome)
    from swarm.runner import write_pictures

    write_pictures(out_dir, scenario, times_s, poses, outcome)
    return outcome


def runtime_summary(
    scenario: Scenario,
    stats: dict,
    records: dict[int, dict],
    endpoint: str,
    wall_s: float,
    first_tick_s: float | None,
) -> dict:
    """Timing and message statistics of a distributed run, for metrics.json."""
    messages = [record.get("messages", {}) for record in records.values()]
    ready = [record["ready_s"] for record in records.values() if "ready_s" in record]
    return {
        "mode": scenario.sim.mode,
        "zenoh_endpoint": endpoint,
        "wall_s": round(wall_s, 3),
        "startup_s": None if first_tick_s is None else round(first_tick_s, 3),
        "server_startup_s": stats.get("startup_s"),
        "agent_ready_s_max": max(ready) if ready else None,
        "ticks_served": stats.get("ticks_served"),
        "ticks_missed": stats.get("ticks_missed"),
        "command_latency_ms": stats.get("latency_ms"),
        "messages_received": int(np.sum([m.get("received", 0) for m in messages])),
        "messages_lost": int(np.sum([m.get("lost", 0) for m in messages])),
        "messages_invalid": int(np.sum([m.get("invalid", 0) for m in messages])),
        "invalid_commands": stats.get("invalid_commands"),
        "agent_exit_reasons": sorted({str(record.get("exit_reason")) for record in records.values()}),
    }
