"""Benchmark of the distributed runtime (``swarm run`` with ``engine: pybullet``): real processes, real Zenoh.

For every swarm size N and timing mode it writes a scenario (N robots at random in a box that grows
with N, ``swarm.core.initial_poses.box_for``; a connected random graph of mean degree about 4; local
consensus; 20 Hz control), runs it with ``python -m swarm.cli run`` exactly as a user would, and
reads what the processes report:

- closed-loop latency: pose published by the sim server -> that tick's command received by it
  (``server_stats.json``), p50 / p99 over every command of the run;
- ticks served: share of control ticks at which every live agent's command was in before the
  deadline (lockstep: before the server stepped; realtime: before the tick boundary);
- per-agent memory: PSS (``psutil.Process.memory_full_info``) of every agent process, sampled
  once mid-run (in a short lockstep run of its own per N), averaged;
- start-up: runner start -> every agent's liveliness token seen by the server (``agents_ready_s``)
  and -> first tick (``first_tick_s``);
- real-time factor: simulated seconds per wall second of the control loop (realtime mode keeps 20 Hz
  when it is ~1 and there are no overruns; lockstep runs as fast as the swarm answers);
- CPU per agent and per server tick (the processes' own CPU clocks, start-up excluded), and how many
  cores other processes kept busy meanwhile (``/proc/stat`` minus this run's CPU time);
- the floor: per N, one more lockstep run (``--floor-duration``) in which a bare agent per robot
  (``bench/bare_agent.py``: zenoh, msgpack, numpy, the same I/O) shadows the real one; both sets'
  CPU per tick over the same window of ticks and their ratio, which holds on a loaded machine.

Swarms from ``--large`` (100) robots on run with ``physics_hz`` 40 and 30 solver iterations
(``sim_server.physics.LARGE_SWARM_PHYSICS_HZ``: as close to the unicycle model as 240 Hz with 10, at
a fifth of its cost; at 240 Hz the physics of 100 robots alone needs about a core); more rates with
``--large-physics-hz 40 120``. The targets are checked on the first rate.

Run: ``python bench/bench_runtime.py --update-results`` (writes ``bench/results/runtime.json`` and
``runtime.md``; without it, ``runs/bench/``); ``--counts 6 30 --modes lockstep --duration 5`` for a quick
look; ``--counts 6 100 --floor-only`` re-measures only the floor section of the results (the other
results in the file stay). The machine's load average is
recorded with every run: the figures depend on what else runs.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import platform
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from importlib.metadata import version
from pathlib import Path

import psutil
import yaml
import zenoh
from _output import add_output_arguments, output_dir, progress

from sim_server.physics import LARGE_SWARM_PHYSICS_HZ, LARGE_SWARM_SOLVER_ITERATIONS
from swarm.core.initial_poses import box_for
from swarm.runtime import wire
from swarm.runtime.distributed import AGENT_NICE

ROOT = Path(__file__).resolve().parent.parent
RESULTS = Path(__file__).resolve().parent / "results"

TARGETS = {
    "p99_ms_at_6": 3.0,
    "p99_ms_at_100": 50.0,
    "served_at_100": 0.99,
    "pss_mib_per_agent": 25.0,
    "ready_s_at_100": 5.0,
    "rtf_at_100": 1.0,
}


def scenario_data(
    count: int,
    mode: str,
    duration_s: float,
    physics_hz: float | None,
    solver_iterations: int | None,
    seed: int,
) -> dict:
    """A local-consensus scenario of ``count`` robots on a connected random graph (mean degree ~4)."""
    low, high = box_for(count)
    # acl off, as when these numbers were measured: the benchmark's probe session has no credentials
    sim: dict = {
        "engine": "pybullet",
        "mode": mode,
        "control_period": 0.05,
        "duration": duration_s,
        "acl": False,
    }
    if physics_hz is not None:
        sim["physics_hz"] = physics_hz
    if solver_iterations is not None:
        sim["solver_iterations"] = solver_iterations
    return {
        "name": f"bench-runtime-{count}-{mode}",
        "robots": {
            "count": count,
            "init": {"random": {"seed": seed, "x": [low, high], "y": [low, high], "min_separation": 0.4}},
        },
        "topology": {
            "kind": "random",
            "p": min(0.6, 4.0 / max(count - 1, 1)),
            "seed": seed,
            "connected": True,
        },
        "robot": {"v_max": 0.5},
        "controller": {"kind": "local_consensus", "gain": 1.0},
        "sim": sim,
        "success": {"metric": "max_pairwise", "threshold": {"kinematic": 0.2, "pybullet": 1.3}},
    }


def _agent_processes(cli: psutil.Process) -> list[psutil.Process]:
    """The agent processes: children of the launcher (``python -m robot_agent --robots ...``)."""
    agents = []
    with contextlib.suppress(psutil.NoSuchProcess):
        for child in cli.children(recursive=True):
            with contextlib.suppress(psutil.NoSuchProcess, psutil.AccessDenied):
                if "--robots" in child.cmdline():
                    agents += child.children()
    return agents


def _memory_mib(processes: list[psutil.Process]) -> dict:
    pss, uss, rss = [], [], []
    for process in processes:
        with contextlib.suppress(psutil.NoSuchProcess, psutil.AccessDenied):
            info = process.memory_full_info()
            pss.append(info.pss / 2**20)
            uss.append(info.uss / 2**20)
            rss.append(info.rss / 2**20)
    mean = lambda values: round(sum(values) / len(values), 2) if values else None  # noqa: E731
    return {"agents_sampled": len(pss), "pss_mean": mean(pss), "uss_mean": mean(uss), "rss_mean": mean(rss)}


def _process_mib(cli: psutil.Process, marker: str) -> float | None:
    with contextlib.suppress(psutil.NoSuchProcess):
        for child in cli.children(recursive=True):
            with contextlib.suppress(psutil.NoSuchProcess, psutil.AccessDenied):
                if marker in " ".join(child.cmdline()):
                    return round(child.memory_full_info().pss / 2**20, 2)
    return None


def _cpu_busy_cores() -> tuple[float, float]:
    """(busy, total) jiffies of the whole machine, from /proc/stat."""
    fields = [float(v) for v in Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]]
    idle = fields[3] + fields[4]
    return sum(fields) - idle, sum(fields)


def _children_cpu_s() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def _cpu_s_by_pid(processes: list[psutil.Process]) -> dict[int, float]:
    """User + system CPU seconds (every thread, ``/proc/<pid>/stat``) of each of ``processes`` that
    could be read (one that exited meanwhile is left out, not counted as 0)."""
    by_pid = {}
    for process in processes:
        with contextlib.suppress(psutil.NoSuchProcess, psutil.AccessDenied, psutil.ZombieProcess):
            times = process.cpu_times()
            by_pid[process.pid] = times.user + times.system
    return by_pid


def _server_endpoint(cli: psutil.Process) -> tuple[str, str] | None:
    """(endpoint, run id) from the sim server's command line, once it runs."""
    with contextlib.suppress(psutil.NoSuchProcess):
        for child in cli.children(recursive=True):
            with contextlib.suppress(psutil.NoSuchProcess, psutil.AccessDenied):
                line = child.cmdline()
                if "sim_server" in line and "--listen" in line and "--run" in line:
                    return line[line.index("--listen") + 1], line[line.index("--run") + 1]
    return None


_USER_HZ = os.sysconf("SC_CLK_TCK")


def main_thread_cpu_s(pid: int) -> float | None:
    """User + system CPU seconds of the main thread of ``pid`` (``/proc/<pid>/task/<pid>/stat``: the
    agent's Python; its other threads are Zenoh's), or None if it is gone."""
    try:
        fields = Path(f"/proc/{pid}/task/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return None
    return (int(fields[11]) + int(fields[12])) / _USER_HZ


def _main_cpu_s(pids: list[int]) -> float:
    return sum(cpu for pid in pids if (cpu := main_thread_cpu_s(pid)) is not None)


class Floor:
    """Bare agents (``bench/bare_agent.py``) beside the real ones of one run, and the CPU per tick of
    both sets over the same window of ticks (``/proc`` CPU times of every agent process, sampled when
    the real agents have sent ``start_tick`` commands each, once every bare agent is up, and
    ``end_tick``, or as many ticks after the opening as from ``start_tick`` to ``end_tick`` where the
    bare agents came up late: start-up and exit excluded; each set's ticks are the commands it sent
    meanwhile)."""

    def __init__(self, count: int, log_dir: Path, start_tick: int, end_tick: int, nice: int = AGENT_NICE):
        self.count, self.log_dir, self.nice = count, log_dir, nice
        self.start_tick, self.end_tick = start_tick, end_tick
        self.process: subprocess.Popen | None = None
        self.session = None
        self.commands = 0  # bare agents' commands received (by this process: a consumer, as the sim is)
        self.commands_invalid = 0  # of those, rejected by the real decoder (wire.decode_command)
        self.real_commands = 0  # the real agents' commands, counted the same way: the window's tick clock
        self.samples: list[dict] = []
        self._ready = False
        self._end_tick = end_tick

    def start(self, endpoint: str, run: str) -> None:
        """Start the bare agents (they retry until the sim's router listens), then connect a consumer of
        their commands (``zenoh.ZError`` until the router listens: call again)."""
        if self.process is None:
            env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")
            command = [sys.executable, str(Path(__file__).resolve().parent / "bare_agent.py")]
            command += ["--robots", f"0-{self.count - 1}", "--connect", endpoint, "--run", run]
            command += ["--log-dir", str(self.log_dir), "--nice", str(self.nice)]
            self.process = subprocess.Popen(
                command, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE
            )
        config = zenoh.Config()
        config.insert_json5("mode", '"client"')
        config.insert_json5("connect/endpoints", json.dumps([endpoint]))
        config.insert_json5("scouting/multicast/enabled", "false")
        self.session = zenoh.open(config)

        def count(sample: zenoh.Sample) -> None:
            self.commands += 1
            self.commands_invalid += wire.decode_command(sample.payload.to_bytes()) is None

        def count_real(_sample: zenoh.Sample) -> None:
            self.real_commands += 1

        self.subscribers = [
            self.session.declare_subscriber(f"swarm/{run}/floor/*/cmd", count),
            self.session.declare_subscriber(f"swarm/{run}/robot/*/cmd", count_real),
        ]

    def _bare_ready(self) -> bool:
        """Every bare agent has declared its subscriptions and publishers (its ready record is written)."""
        if not self._ready:
            self._ready = len(list(self.log_dir.glob("floor_*.json"))) == self.count
        return self._ready

    def poll(self, cli: psutil.Process) -> None:
        """Sample both sets' CPU once the run passes each window edge (ticks: the real agents' commands
        received per agent; the trajectory's line count lags by tens of ticks at N = 100)."""
        if self.session is None or len(self.samples) == 2:
            return
        ticks = self.real_commands / self.count
        if ticks < (self.start_tick if not self.samples else self._end_tick):
            return
        if not self.samples and not self._bare_ready():
            return  # the window opens once the bare agents are up too
        real = _agent_processes(cli)
        bare = psutil.Process(self.process.pid).children()
        commands, real_commands = self.commands, self.real_commands
        real_cpu, bare_cpu = _cpu_s_by_pid(real), _cpu_s_by_pid(bare)
        real_cpu_s, bare_cpu_s = sum(real_cpu.values()), sum(bare_cpu.values())
        real_main_s, bare_main_s = _main_cpu_s(sorted(real_cpu)), _main_cpu_s(sorted(bare_cpu))
        if not self.samples:  # a window opened late (bare agents slow to start) keeps its length
            self._end_tick = max(self.end_tick, ticks + self.end_tick - self.start_tick)
        self.samples.append(
            {"real_cpu_s": real_cpu_s, "bare_cpu_s": bare_cpu_s, "bare_commands": commands}
            | {"real_main_cpu_s": real_main_s, "bare_main_cpu_s": bare_main_s}
            | {"real_commands": real_commands, "real_agents": len(real_cpu), "bare_agents": len(bare_cpu)}
            | {"real_pids": sorted(real_cpu), "bare_pids": sorted(bare_cpu)}
        )

    def finish(self) -> dict:
        """After the run: wait 10 s for the bare agents to end, then stop them (SIGTERM, then SIGKILL).

        A bare agent that lagged far behind when the lockstep run ended (the run waits for the real
        agents only) loses the poses the sim's router had not delivered yet, with that router: it is
        stopped here (``stopped_after_run``), as one was at tick 872 of 1199 beside 4 busy loops."""
        stopped_after_run = False
        if self.process is not None:
            try:
                self.process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                stopped_after_run = True
                self.process.terminate()
                try:
                    self.process.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    self.process.kill()
                    self.process.wait()
        if self.session is not None:
            self.session.close()
        records = [json.loads(p.read_text()) for p in sorted(self.log_dir.glob("floor_*.json"))]
        ran = [r for r in records if r.get("ticks") and r.get("cpu_s") is not None]
        self_ms = [1e3 * (r["cpu_s"] - r["cpu_ready_s"]) / r["ticks"] for r in ran]
        result: dict = {
            "bare_agents_ran": len(ran),
            "bare_self_cpu_ms_per_tick": round(sum(self_ms) / len(self_ms), 4) if self_ms else None,
            "bare_commands": self.commands,
            "bare_commands_invalid": self.commands_invalid,
            "stopped_after_run": stopped_after_run,
        }
        if len(self.samples) < 2:
            return result | {"error": "the run ended before the CPU window closed"}
        first, last = self.samples
        if (
            min(first["bare_agents"], last["bare_agents"], first["real_agents"], last["real_agents"])
            < self.count
        ):
            return result | {"error": f"agents missing from the CPU window: {self.samples}"}
        if first["real_pids"] != last["real_pids"] or first["bare_pids"] != last["bare_pids"]:
            # an agent exited (or was replaced) between the edges: its CPU is not in both sums
            return result | {"error": f"other agent processes at the CPU window's edges: {self.samples}"}
        # CPU per tick computed: commands sent in the window, per agent (a bare agent that fell behind
        # skips poses, as the real one would: it is charged only for the ticks it computed)
        ticks = (last["real_commands"] - first["real_commands"]) / self.count
        bare_ticks = (last["bare_commands"] - first["bare_commands"]) / self.count
        real_ms = 1e3 * (last["real_cpu_s"] - first["real_cpu_s"]) / (ticks * self.count)
        bare_ms = 1e3 * (last["bare_cpu_s"] - first["bare_cpu_s"]) / (bare_ticks * self.count)
        # the same CPU split by thread: the main thread (the agent's Python, Zenoh's recv and put in
        # it) and the rest (Zenoh's own threads: receiving, sending, timers)
        real_main_ms = 1e3 * (last["real_main_cpu_s"] - first["real_main_cpu_s"]) / (ticks * self.count)
        bare_main_ms = 1e3 * (last["bare_main_cpu_s"] - first["bare_main_cpu_s"]) / (bare_ticks * self.count)
        return result | {
            "real_main_thread_ms_per_tick": round(real_main_ms, 4),
            "real_zenoh_threads_ms_per_tick": round(real_ms - real_main_ms, 4),
            "bare_main_thread_ms_per_tick": round(bare_main_ms, 4),
            "bare_zenoh_threads_ms_per_tick": round(bare_ms - bare_main_ms, 4),
            "window_ticks": round(ticks, 1),
            "bare_ticks_in_window": round(bare_ticks, 1),
            "real_agents": last["real_agents"],
            "bare_agents": last["bare_agents"],
            "real_cpu_ms_per_tick": round(real_ms, 4),
            "bare_cpu_ms_per_tick": round(bare_ms, 4),
            "real_over_bare": round(real_ms / bare_ms, 3),
        }


def run_once(
    scenario_path: Path,
    out_dir: Path,
    steps: int,
    timeout_s: float,
    memory_at: int | None,
    floor: Floor | None = None,
    agent_nice: int | None = None,
) -> dict:
    """``swarm run`` one scenario; returns its measurements (or an ``error``).

    ``memory_at``: sample the processes' memory once this many ticks are done (None: never; reading
    ``/proc/<pid>/smaps_rollup`` of every agent stalls them briefly, which shows in the latency tail).
    ``floor``: run bare agents beside the real ones and measure both (``result["floor"]``)."""
    clock = MachineClock()
    started_s = time.perf_counter()
    process = subprocess.Popen(
        [sys.executable, "-m", "swarm.cli", "run", str(scenario_path), "--out", str(out_dir), "--quiet"]
        + ([] if agent_nice is None else ["--agent-nice", str(agent_nice)]),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=ROOT,
    )
    cli = psutil.Process(process.pid)
    trajectory = out_dir / "trajectory.jsonl"
    memory, server_pss, launcher_pss, cli_first_tick_s = {}, None, None, None
    try:
        while process.poll() is None:
            if time.perf_counter() - started_s > timeout_s:
                raise TimeoutError
            ticks = trajectory.read_bytes().count(b"\n") if trajectory.exists() else 0
            if ticks and cli_first_tick_s is None:
                cli_first_tick_s = time.perf_counter() - started_s
            if floor is not None:
                if floor.session is None and (found := _server_endpoint(cli)) is not None:
                    with contextlib.suppress(zenoh.ZError):  # not listening yet: again at the next poll
                        floor.start(*found)
                floor.poll(cli)
            if not memory and memory_at is not None and ticks >= memory_at:
                memory = _memory_mib(_agent_processes(cli))
                server_pss = _process_mib(cli, "-m sim_server")
                launcher_pss = _process_mib(cli, "--robots")
            time.sleep(0.02)
        _, stderr = process.communicate()
        wall_s = time.perf_counter() - started_s
    except TimeoutError:
        process.terminate()
        process.communicate(timeout=30)
        if floor is not None:
            floor.finish()
        return {"error": f"timed out after {timeout_s:g} s"}
    floor_result = floor.finish() if floor is not None else None
    if process.returncode not in (0, 1):
        return {"error": f"swarm run exited {process.returncode}: {stderr.strip()[-400:]}"}
    machine = clock.after(wall_s)
    metrics = json.loads((out_dir / "metrics.json").read_text())
    records = [json.loads(p.read_text()) for p in (out_dir / "logs").glob("agent_*.json")]
    stats = json.loads((out_dir / "server_stats.json").read_text())
    runtime = metrics["runtime"]
    return (
        server_figures(stats, steps)
        | {
            "first_tick_s": runtime.get("startup_s"),
            "agents_ready_s": runtime.get("agents_ready_s"),
            "cli_to_first_tick_s": None if cli_first_tick_s is None else round(cli_first_tick_s, 3),
            "agent_pss_mib": memory.get("pss_mean"),
            "agent_uss_mib": memory.get("uss_mean"),
            "agent_rss_mib": memory.get("rss_mean"),
            "agents_sampled": memory.get("agents_sampled"),
            "server_pss_mib": server_pss,
            "launcher_pss_mib": launcher_pss,
            "messages_lost": runtime.get("messages_lost"),
            "agent_cpu_ms_per_tick": agent_cpu_ms_per_tick(records),
            "server_cpu_ms_per_tick": server_cpu_ms_per_tick(stats, steps),
            "wall_s": runtime.get("wall_s"),
        }
        | machine
        | ({} if floor_result is None else {"floor": floor_result})
    )


class MachineClock:
    """The machine's load and busy cores while one run goes on: ``after`` gives the cores this
    process's (waited-for) children used per wall second, those other processes kept busy meanwhile
    (``/proc/stat`` minus the run's), and the 1-min load average before and after."""

    def __init__(self) -> None:
        self.load_before = os.getloadavg()[0]
        self.machine_before, self.children_before = _cpu_busy_cores(), _children_cpu_s()

    def after(self, wall_s: float) -> dict:
        busy, total = (
            after - before for after, before in zip(_cpu_busy_cores(), self.machine_before, strict=True)
        )
        machine_cores = (os.cpu_count() or 1) * busy / total if total else 0.0
        run_cores = (_children_cpu_s() - self.children_before) / wall_s
        return {
            "run_cores": round(run_cores, 2),
            "other_cores": round(max(0.0, machine_cores - run_cores), 2),
            "load_avg_1min_before": round(self.load_before, 2),
            "load_avg_1min_after": round(os.getloadavg()[0], 2),
        }


def server_figures(stats: dict, steps: int) -> dict:
    """Ticks served, latency, real-time factor and the tick's split, from ``server_stats.json``."""
    latency = stats.get("latency_ms", {})
    ticks = stats.get("ticks") or steps
    return {
        "latency_p50_ms": latency.get("p50"),
        "latency_p99_ms": latency.get("p99"),
        "latency_max_ms": latency.get("max"),
        "ticks": ticks,
        "ticks_served": stats.get("ticks_served"),
        "served_share": round(stats.get("ticks_served", 0) / ticks, 4),
        "realtime_factor": stats.get("realtime_factor"),
        "overruns": stats.get("overruns"),
        "physics_ms_per_tick": stats.get("physics_ms_per_tick"),
        "physics_cpu_ms_per_tick": stats.get("physics_cpu_ms_per_tick"),
        "publish_cpu_ms_per_tick": stats.get("publish_cpu_ms_per_tick"),
        "trajectory_cpu_ms_per_tick": stats.get("trajectory_cpu_ms_per_tick"),
        "publish_lag_ms": stats.get("publish_lag_ms"),
        "slowest_command_ms": stats.get("slowest_command_ms"),
        "late_agents_per_tick": stats.get("late_agents_per_tick"),
        "invalid_commands": stats.get("invalid_commands"),
    }


def server_cpu_ms_per_tick(stats: dict, steps: int) -> float | None:
    """The server process's CPU (every thread, Zenoh's router included) per tick, start-up excluded."""
    if stats.get("cpu_s") is None:
        return None
    ticks = stats.get("ticks") or steps
    return round(1e3 * (stats["cpu_s"] - stats.get("cpu_ready_s", 0.0)) / ticks, 3)


def agent_cpu_ms_per_tick(records: list[dict]) -> float | None:
    """Mean over the agents of their process CPU (every thread) from ready to exit per tick computed."""
    per_tick = [
        (r["cpu_s"] - r.get("cpu_ready_s", 0.0)) / r["ticks"]
        for r in records
        if r.get("cpu_s") is not None and r.get("ticks")
    ]
    return round(1e3 * sum(per_tick) / len(per_tick), 4) if per_tick else None


def _fmt(value: object, digits: int = 2) -> str:
    if value is None:
        return "-"
    if isinstance(value, float):
        return f"{value:.{digits}f}"
    return str(value)


def targets_met(results: list[dict]) -> dict[str, bool | None]:
    """Each runtime target against the measured rows (None: not measured)."""

    def row(count: int, mode: str) -> dict | None:
        return next(
            (r for r in results if r["robots"] == count and r["mode"] == mode and "error" not in r), None
        )

    def worst(rows: list[dict | None], key: str, fn) -> float | None:
        values = [r[key] for r in rows if r is not None and r.get(key) is not None]
        return fn(values) if values else None

    at6 = [row(6, m) for m in ("lockstep", "realtime")]
    at100 = [row(100, m) for m in ("lockstep", "realtime")]
    everyone = [r for r in results if "error" not in r]
    checks = {
        "p99_ms_at_6": (worst(at6, "latency_p99_ms", max), lambda v: v <= TARGETS["p99_ms_at_6"]),
        "p99_ms_at_100": (worst(at100, "latency_p99_ms", max), lambda v: v <= TARGETS["p99_ms_at_100"]),
        "served_at_100": (worst(at100, "served_share", min), lambda v: v >= TARGETS["served_at_100"]),
        "pss_mib_per_agent": (
            worst(everyone, "agent_pss_mib", max),
            lambda v: v <= TARGETS["pss_mib_per_agent"],
        ),
        "ready_s_at_100": (worst(at100, "agents_ready_s", max), lambda v: v <= TARGETS["ready_s_at_100"]),
        "rtf_at_100": (worst(at100, "realtime_factor", min), lambda v: v >= TARGETS["rtf_at_100"] - 0.01),
    }
    return {
        name: {
            "target": TARGETS[name],
            "measured": value,
            "met": None if value is None else bool(test(value)),
        }
        for name, (value, test) in checks.items()
    }


def markdown(report: dict) -> str:
    if "settings" not in report:
        return "\n".join(floor_markdown(report)) + "\n"
    settings = report["settings"]
    lines = [
        f"`python bench/bench_runtime.py`: {settings['duration_s']:g} s of sim per run, 20 Hz control, local"
        f" consensus on a random graph of mean degree ~4, {report['machine']['cpu_count']} cores. 1-min load"
        f" average {report['load_avg_before']} before the first run; 'other' = cores kept busy by processes"
        " outside the run while it ran. Targets are checked on the first physics rate of N >= 100. Agents"
        f" at nice {settings.get('agent_nice', 0)} (`swarm run --agent-nice`).",
        "",
        "| N | mode | physics Hz | p50 ms | p99 ms | ticks served | RTF | agents ready s | first tick s"
        " | PSS/agent MiB | agent CPU ms/tick | server CPU ms/tick | other cores |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in report["results"]:
        if "error" in r:
            lines.append(
                f"| {r['robots']} | {r['mode']} | {_fmt(r['physics_hz'], 0)} | error: {r['error']} |"
            )
            continue
        lines.append(
            f"| {r['robots']} | {r['mode']} | {_fmt(r['physics_hz'], 0)} | {_fmt(r['latency_p50_ms'])}"
            f" | {_fmt(r['latency_p99_ms'])} | {100 * r['served_share']:.1f}% | {_fmt(r['realtime_factor'])}"
            f" | {_fmt(r['agents_ready_s'])} | {_fmt(r['first_tick_s'])} | {_fmt(r['agent_pss_mib'], 1)}"
            f" | {_fmt(r['agent_cpu_ms_per_tick'])} | {_fmt(r['server_cpu_ms_per_tick'], 1)}"
            f" | {_fmt(r['other_cores'])} |"
        )
    lines += ["", "| target | measured | met |", "|---|---|---|"]
    for name, check in report.get("targets", {}).items():
        met = {True: "yes", False: "**no**", None: "-"}[check["met"]]
        lines.append(f"| {name} {check['target']:g} | {_fmt(check['measured'])} | {met} |")
    return "\n".join(lines + tick_markdown(report) + floor_markdown(report)) + "\n"


def tick_markdown(report: dict) -> list[str]:
    """The server's tick split (main-thread CPU) and, in realtime, how late the agents were per tick."""
    lines = [
        "",
        "### The server's tick and the agents' lateness",
        "",
        "Server main-thread CPU per tick: physics step, publishing the N poses, writing the trajectory"
        " (the rest of the server's CPU is Zenoh's router threads). Realtime: how late the poses went out"
        " after their wall-clock boundary (p99), the slowest agent's command after the poses (p50 / p99"
        " over the ticks where every command was in), and the ticks by how many agents' commands were"
        " not in when the server stepped.",
        "",
        "| N | mode | physics Hz / iterations | physics ms | publish ms | trajectory ms | poses late p99 ms"
        " | slowest command p50 / p99 ms | ticks by agents late (0 / 1 / 2-4 / 5-19 / 20+) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in report["results"]:
        if "error" in r:
            continue
        lag, slowest, late = (
            r.get("publish_lag_ms") or {},
            r.get("slowest_command_ms") or {},
            r.get("late_agents_per_tick"),
        )
        lines.append(
            f"| {r['robots']} | {r['mode']} | {_fmt(r['physics_hz'], 0)} / {r.get('solver_iterations')}"
            f" | {_fmt(r.get('physics_cpu_ms_per_tick'))} | {_fmt(r.get('publish_cpu_ms_per_tick'))}"
            f" | {_fmt(r.get('trajectory_cpu_ms_per_tick'))} | {_fmt(lag.get('p99'))}"
            f" | {_fmt(slowest.get('p50'))} / {_fmt(slowest.get('p99'))}"
            f" | {' / '.join(str(v) for v in late.values()) if late else '-'} |"
        )
    return lines


def floor_markdown(report: dict) -> list[str]:
    """The floor section: real agent vs bare agent (``bench/bare_agent.py``), same run, same ticks."""
    if not report.get("floor"):
        return []
    settings = report.get("floor_settings", {})
    lines = [
        "",
        "### Agent CPU against the floor",
        "",
        f"`python bench/bench_runtime.py --update-results` (alone: `--floor-only`): one lockstep run per N of"
        f" {settings.get('duration_s', 0):g} s of sim in which a bare agent per robot (`bench/bare_agent.py`:"
        " zenoh, msgpack and numpy only; the same pose key, neighbour count and payload sizes) runs beside"
        f" the real one, both at nice {settings.get('agent_nice', 0)}. CPU per tick: user + system time"
        " of every agent process (all threads, /proc) over"
        " the same window of ticks (the middle 60%: start-up and exit excluded), per agent, and split by"
        " thread: the main thread (the agent's Python, with Zenoh's recv and put called from it) and"
        " Zenoh's own threads (receiving, sending, timers). 1-min load"
        f" average {report.get('floor_load_avg_before')} before the first run (the ratio is the figure"
        " that holds on a loaded machine).",
        "",
        "| N | physics Hz | window ticks | real agent CPU ms/tick | bare agent CPU ms/tick | real / bare"
        " | main thread real / bare ms | Zenoh threads real / bare ms | load before | load after |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in report["floor"]:
        f = r.get("floor", {})
        if "error" in r or "error" in f:
            lines.append(
                f"| {r['robots']} | {_fmt(r.get('physics_hz'), 0)} | error: {r.get('error') or f['error']} |"
            )
            continue
        lines.append(
            f"| {r['robots']} | {_fmt(r['physics_hz'], 0)} | {f['window_ticks']}"
            f" | {_fmt(f['real_cpu_ms_per_tick'], 3)} | {_fmt(f['bare_cpu_ms_per_tick'], 3)}"
            f" | {_fmt(f['real_over_bare'])}"
            f" | {_fmt(f.get('real_main_thread_ms_per_tick'), 3)}"
            f" / {_fmt(f.get('bare_main_thread_ms_per_tick'), 3)}"
            f" | {_fmt(f.get('real_zenoh_threads_ms_per_tick'), 3)}"
            f" / {_fmt(f.get('bare_zenoh_threads_ms_per_tick'), 3)}"
            f" | {_fmt(r['load_avg_1min_before'])}"
            f" | {_fmt(r['load_avg_1min_after'])} |"
        )
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--counts", type=int, nargs="+", default=[6, 30, 100])
    parser.add_argument(
        "--modes", nargs="+", default=["lockstep", "realtime"], choices=["lockstep", "realtime"]
    )
    parser.add_argument("--duration", type=float, default=10.0, help="simulated seconds per run")
    parser.add_argument(
        "--physics-hz", type=float, help="sim.physics_hz below --large (default: the scenario's)"
    )
    parser.add_argument("--large", type=int, default=100, help="from this N on, use --large-physics-hz")
    parser.add_argument(
        "--large-physics-hz",
        type=float,
        nargs="+",
        default=[LARGE_SWARM_PHYSICS_HZ],
        help=f"sim.physics_hz of large swarms, one run each (default: {LARGE_SWARM_PHYSICS_HZ:g}; the"
        " targets use the first)",
    )
    parser.add_argument("--solver-iterations", type=int, help="scenario sim.solver_iterations below --large")
    parser.add_argument(
        "--large-solver-iterations",
        type=int,
        default=LARGE_SWARM_SOLVER_ITERATIONS,
        help=f"sim.solver_iterations of large swarms (default {LARGE_SWARM_SOLVER_ITERATIONS})",
    )
    parser.add_argument(
        "--floor-duration",
        type=float,
        default=20.0,
        help="simulated seconds of the lockstep run per N in which bare agents (bench/bare_agent.py) run"
        " beside the real ones (default 20; 0: none)",
    )
    parser.add_argument(
        "--floor-only",
        action="store_true",
        help="only the floor runs: replace the floor section of runtime.json in the output directory"
        " (--update-results: the committed one), keep its other results",
    )
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument(
        "--agent-nice",
        type=int,
        choices=range(20),
        metavar="0-19",
        help=f"swarm run --agent-nice (default: the runner's, {AGENT_NICE})",
    )
    parser.add_argument("--timeout", type=float, default=300.0, help="seconds per run")
    add_output_arguments(parser)
    parser.add_argument(
        "--keep", type=Path, help="keep every run's results directory here (default: failed runs only)"
    )
    args = parser.parse_args(argv)
    out = output_dir(args) / "runtime.json"
    nice = AGENT_NICE if args.agent_nice is None else args.agent_nice  # the real and the bare agents'
    floor_runs = len(args.counts) if args.floor_duration > 0 else 0
    timed_runs = sum(
        1 + len(args.modes) * (len(args.large_physics_hz) if n >= args.large else 1) for n in args.counts
    )
    bar = progress(
        total=floor_runs + (0 if args.floor_only else timed_runs),
        iterable=None,
        args=args,
        desc="bench_runtime",
        unit="run",
    )

    results, floors, load_before = [], [], os.getloadavg()[0]
    keep = args.keep or Path(tempfile.gettempdir()) / "bench-runtime-failed"
    memory_keys = ("agent_pss_mib", "agent_uss_mib", "agent_rss_mib", "agents_sampled")
    memory_keys += ("server_pss_mib", "launcher_pss_mib")
    with tempfile.TemporaryDirectory(prefix="bench-runtime-") as work:

        def run(
            count: int,
            mode: str,
            physics_hz: float | None,
            duration_s: float,
            memory: bool,
            floor: bool = False,
        ) -> dict:
            iterations = args.large_solver_iterations if count >= args.large else args.solver_iterations
            data = scenario_data(count, mode, duration_s, physics_hz, iterations, args.seed)
            data["name"] += (f"-{physics_hz:g}hz" if physics_hz is not None else "") + (
                "-memory" if memory else "-floor" if floor else ""
            )
            path = Path(work) / f"{data['name']}.yaml"
            path.write_text(yaml.safe_dump(data))
            steps = round(duration_s / 0.05)
            edge = max(10, steps // 5)
            bare = (
                Floor(count, Path(work) / f"{data['name']}-bare", edge, steps - edge, nice) if floor else None
            )
            result = run_once(
                path,
                Path(work) / data["name"],
                steps,
                args.timeout,
                steps // 3 if memory else None,
                bare,
                args.agent_nice,
            )
            if args.keep or "error" in result:
                kept = keep / f"{data['name']}-{time.strftime('%H%M%S')}"
                shutil.copytree(Path(work) / data["name"], kept, dirs_exist_ok=True)
                result["results_dir"] = str(kept)
            bar.update(1)
            resolved = yaml.safe_load((Path(work) / data["name"] / "scenario.yaml").read_text())
            return {
                "robots": count,
                "mode": mode,
                "physics_hz": resolved["sim"]["physics_hz"],
                "solver_iterations": resolved["sim"]["solver_iterations"],
                **result,
            }

        for count in args.counts:
            if args.floor_duration > 0:
                large = count >= args.large
                physics_hz = args.large_physics_hz[0] if large else args.physics_hz
                result = run(count, "lockstep", physics_hz, args.floor_duration, False, True)
                floors.append(result)
                print(json.dumps(result), flush=True)
            if args.floor_only:
                continue
            # Memory in a run of its own: reading every agent's smaps stalls them, which would show
            # in the latency tail of the timed runs.
            large = count >= args.large
            memory = run(count, "lockstep", args.large_physics_hz[0] if large else args.physics_hz, 3.0, True)
            for physics_hz in args.large_physics_hz if large else [args.physics_hz]:
                for mode in args.modes:
                    result = run(count, mode, physics_hz, args.duration, False)
                    result.update({key: memory.get(key) for key in memory_keys})
                    results.append(result)
                    print(json.dumps(result), flush=True)
    if args.floor_only:  # keep every other result of the file
        bar.close()
        report = json.loads(out.read_text()) if out.exists() else {"results": []}
        report.update(floor=floors, floor_load_avg_before=round(load_before, 2))
        report["floor_settings"] = {"duration_s": args.floor_duration, "seed": args.seed, "agent_nice": nice}
        out.write_text(json.dumps(report, indent=2) + "\n")
        out.with_suffix(".md").write_text(markdown(report))
        print(markdown(report))
        return 0 if all("error" not in f and "error" not in f.get("floor", {}) for f in floors) else 1
    report = {
        "benchmark": "runtime",
        "settings": {
            "duration_s": args.duration,
            "control_period_s": 0.05,
            "topology": "random, p = min(0.6, 4 / (N - 1)), connected",
            "controller": "local_consensus",
            "seed": args.seed,
            "agent_nice": nice,
        },
        "machine": {
            "python": platform.python_version(),
            "platform": platform.platform(),
            "cpu_count": os.cpu_count(),
            "zenoh": version("eclipse-zenoh"),
            "pybullet": version("pybullet"),
        },
        "load_avg_before": round(load_before, 2),
        "results": results,
        "floor": floors,
        "floor_load_avg_before": round(load_before, 2),
        "floor_settings": {"duration_s": args.floor_duration, "seed": args.seed, "agent_nice": nice},
    }
    first_large_hz = args.large_physics_hz[0]
    report["targets"] = targets_met(
        [r for r in results if r["robots"] < args.large or r["physics_hz"] == first_large_hz]
    )
    bar.close()
    out.write_text(json.dumps(report, indent=2) + "\n")
    out.with_suffix(".md").write_text(markdown(report))
    print(markdown(report))
    return 0 if all(c["met"] is not False for c in report["targets"].values()) else 1


if __name__ == "__main__":
    sys.exit(main())
