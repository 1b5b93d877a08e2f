"""The ``pybullet`` engine: a scenario run as a distributed system of OS processes over Zenoh.

``run_distributed`` starts one ``sim_server`` and the robots' controllers (``robot_agent``: one
process per robot, forked by one launcher; or, for ``controller.kind: centralized``, the single
``robot_agent.central`` process) on free loopback TCP ports, shows the server's progress (ticks
in ``trajectory.jsonl``), waits, and writes the same results directory as the kinematic engine
plus the processes' logs and runtime statistics. Every process lives in a process group that is
stopped (SIGTERM, then SIGKILL after a grace period) when the run ends, fails or is interrupted;
the children also die with their parent (``swarm.runtime.procs.die_with_parent``).

The scenario's process faults (``kill_agent``, ``hang_agent``, ``restart_agent``, ``kill_server``)
are done here, at sim time, to the real processes, and logged to ``events.jsonl``
(``FaultInjector``); see docs/distributed-runtime.md, "Faults done to processes".

No Zenoh session is opened here: the sim server is the Zenoh router the agents connect to.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import signal
import subprocess
import sys
import threading
import time
import uuid
from collections.abc import Callable
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from swarm.core import graphs
from swarm.core.faults import PROCESS_FAULTS
from swarm.runtime import health, wire
from swarm.runtime.acl import write_credentials
from swarm.runtime.procs import Supervisor, free_tcp_port
from swarm.scenarios.fault_results import add_fault_results, read_events
from swarm.scenarios.results import (
    prepare_results_dir,
    read_trajectory,
    task_outcome,
    write_metrics,
    write_partial_results,
)
from swarm.scenarios.scenario import Scenario, ScenarioError, parse_scenario, policy_path
from swarm.scenarios.task_report import task_pictures

log = logging.getLogger(__name__)

AGENTS_EXIT_GRACE_S = 5.0
"""How long the agents get to notice that the sim has gone and exit by themselves (plus
``sim.server_lost_s`` when the server did not end the run itself)."""

FAULT_POLL_S = 0.005
"""How often the runner looks at the trajectory while a process fault is still to come."""


class RunFailed(RuntimeError):
    """The processes ran but could not complete the run (a server killed from outside, agents that
    never came up): CLI exit status 1, one line for the user. Bad input is a ScenarioError (exit 2)."""


def _run_id(name: str) -> str:
    slug = "".join(ch if ch.isalnum() or ch in "_-" else "-" for ch in name)[:40].strip("-") or "run"
    return f"{slug}-{uuid.uuid4().hex[:8]}"


AGENT_NICE = 5
"""Niceness the runner adds to the agents' launcher (``robot-agent --nice``; its forked agents inherit
it): the sim server, whose work is on the critical path of every tick, wins a contended core (CFS
weights 1024 : 335 per runnable thread). Restarted agents (``restart_agent``) get it too."""


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


"""Fault kinds the runner does to the processes themselves (the link faults act in the agents)."""


@dataclass(order=True)
class _Action:
    """One thing the fault injector does at a sim time: a fault or the end of a hang."""

    at_s: float  # sim time to act at
    order: int  # scenario order among actions at the same time
    kind: str = field(compare=False)  # a PROCESS_FAULTS kind or "resume_agent"
    robot: int | None = field(compare=False)


class FaultInjector:
    """Does the scenario's process faults to the real processes at sim time and appends each one,
    when done, as a line to ``events.jsonl`` (flushed at once; see ``EVENT_KEYS``).

    The sim time is the runner's view of the server's progress: when ``ticks`` lines of the
    trajectory are on disk the server is on tick ``ticks``, at ``ticks * control_period_s``; an
    action due at ``at_s`` is done at the first look at which that time is reached (the ``tick``
    of its event says when that was). ``done_tick`` is the ticks on disk right after it was done: a
    runner starved of CPU between its look and the signal lets the server run on, and the fault took
    effect at a tick in ``[tick, done_tick + 1]``. Agent PIDs come from ``logs/agent_<i>.json``, a
    restarted agent's from the process the injector started.
    """

    EVENT_KEYS = ("kind", "robot", "at_s", "tick", "done_tick", "wall_s", "detail")

    def __init__(
        self,
        scenario: Scenario,
        out_dir: Path,
        started_s: float,
        start_agent,
        ticks_now: Callable[[], int] | None = None,
    ):
        self.dt_s = scenario.sim.control_period_s
        self.ticks_now = ticks_now  # the trajectory lines on disk now (None: the tick it was due at)
        self.logs = out_dir / "logs"
        self.started_s = started_s
        self.start_agent = start_agent  # (robot, restart number) -> subprocess.Popen
        self.actions: list[_Action] = []
        for order, fault in enumerate(scenario.faults):
            if fault.kind not in PROCESS_FAULTS:
                continue
            at_s = fault.at_s or 0.0
            self.actions.append(_Action(at_s, order, fault.kind, fault.robot))
            if fault.kind == "hang_agent":
                resume_s = at_s + (fault.duration_s or 0.0)  # the schema requires a hang's duration
                self.actions.append(_Action(resume_s, order, "resume_agent", fault.robot))
        self.actions.sort()
        self.server_pid: int | None = None
        self.server_killed_tick: int | None = None
        self.pids: dict[int, int] = {}  # robot -> pid of its agent process now
        self.stopped: set[int] = set()  # robots whose agent is SIGSTOPped
        self.restarted: list = []  # processes started by restart_agent
        self.events: list[dict] = []
        self._file = open(out_dir / "events.jsonl", "w", buffering=1)  # noqa: SIM115 (closed by close)

    @property
    def pending(self) -> bool:
        return bool(self.actions)

    def close(self) -> None:
        self._file.close()

    def _event(self, kind: str, robot: int | None, at_s: float, tick: int, detail: str, **extra) -> None:
        event = {
            "kind": kind,
            "robot": robot,
            "at_s": round(at_s, 9),
            "tick": tick,
            "done_tick": tick if self.ticks_now is None else max(tick, self.ticks_now()),
            "wall_s": round(time.perf_counter() - self.started_s, 4),
            "detail": detail,
            **extra,
        }
        self.events.append(event)
        self._file.write(json.dumps(event, separators=(",", ":")) + "\n")
        self._file.flush()

    def _pid(self, robot: int) -> int | None:
        if robot not in self.pids:
            pid = _read_json(self.logs / f"agent_{robot}.json").get("pid")
            if isinstance(pid, int):
                self.pids[robot] = pid
        return self.pids.get(robot)

    def _signal(self, robot: int, sig: int) -> tuple[int | None, str]:
        """Send ``sig`` to robot's agent; (its pid, what happened)."""
        pid = self._pid(robot)
        if pid is None:
            return None, f"no pid of robot {robot}'s agent (no logs/agent_{robot}.json)"
        try:
            os.kill(pid, sig)
        except ProcessLookupError:
            return pid, f"pid {pid} had already ended"
        return pid, f"{signal.Signals(sig).name} to pid {pid}"

    def step(self, ticks: int) -> None:
        """Do every action due when ``ticks`` trajectory lines are on disk."""
        now_s = ticks * self.dt_s
        while self.actions and self.actions[0].at_s <= now_s + 1e-9:
            action = self.actions.pop(0)
            self._do(action, ticks)

    def _do(self, action: _Action, tick: int) -> None:
        kind, robot, at_s = action.kind, action.robot, action.at_s
        if kind == "kill_server":
            detail = "the server's pid is unknown"
            if self.server_pid is not None:
                with contextlib.suppress(ProcessLookupError):
                    os.kill(self.server_pid, signal.SIGKILL)
                    self.server_killed_tick = tick
                detail = f"SIGKILL to the sim server, pid {self.server_pid}"
            self._event(kind, None, at_s, tick, detail)
            return
        assert robot is not None  # every other kind acts on one robot's agent
        if kind == "kill_agent":
            pid, detail = self._signal(robot, signal.SIGKILL)
            self.stopped.discard(robot)
            self._event(kind, robot, at_s, tick, detail, pid=pid)
        elif kind == "hang_agent":
            pid, detail = self._signal(robot, signal.SIGSTOP)
            self.stopped.add(robot)
            self._event(kind, robot, at_s, tick, detail, pid=pid)
        elif kind == "resume_agent":
            pid, detail = self._signal(robot, signal.SIGCONT)
            self.stopped.discard(robot)
            self._event(kind, robot, at_s, tick, detail, pid=pid)
        elif kind == "restart_agent":
            old_pid, killed = self._signal(robot, signal.SIGKILL)
            self.stopped.discard(robot)
            record = self.logs / f"agent_{robot}.json"
            if record.exists() and old_pid is not None:  # keep the killed agent's record
                (self.logs / "replaced").mkdir(exist_ok=True)
                os.replace(record, self.logs / "replaced" / f"agent_{robot}_pid{old_pid}.json")
            process = self.start_agent(robot, len(self.restarted) + 1)
            self.restarted.append(process)
            self.pids[robot] = process.pid
            detail = f"{killed}; new agent pid {process.pid}"
            self._event(kind, robot, at_s, tick, detail, pid=process.pid, old_pid=old_pid)

    def finish(self) -> None:
        """The run is over: continue every agent still stopped, else it could not exit (not an event:
        the fault lasted until the end of the run)."""
        for robot in sorted(self.stopped):
            self._signal(robot, signal.SIGCONT)
        self.stopped.clear()
        self.actions.clear()  # faults planned after the end of the run are not done


def _check_faults(scenario: Scenario) -> None:
    for index, fault in enumerate(scenario.faults):
        where = f"faults[{index}] ({fault.kind})"
        if fault.kind in PROCESS_FAULTS and fault.kind != "kill_server":
            if fault.robot is None:
                raise ScenarioError(f"{where}: needs 'robot'")
            if scenario.controller.central:
                raise ScenarioError(
                    f"{where}: controller.kind '{scenario.controller.kind}' runs one process for every robot;"
                    " agent faults need one process per robot"
                )
        if fault.kind == "hang_agent" and fault.duration_s is None:
            raise ScenarioError(f"{where}: needs 'duration' (sim seconds until the agent continues)")


def run_distributed(
    scenario: Scenario,
    out_dir: Path,
    scenario_path: Path | None = None,
    progress: bool = True,
    agent_nice: int = AGENT_NICE,
) -> dict:
    """Run ``scenario`` as sim server + agent processes; returns the outcome (metrics.json).
    ``agent_nice``: niceness the agents get on top of the runner's (0-19).

    Interrupted (Ctrl-C, SIGTERM), it stops every process, writes ``metrics.json`` and the plots of the
    ticks on disk, marked partial, and raises ``KeyboardInterrupt`` again."""
    try:
        return _run_distributed(scenario, out_dir, scenario_path, progress, agent_nice)
    except KeyboardInterrupt:
        ticks = _TickCounter(Path(out_dir) / "trajectory.jsonl").update()
        write_partial_results(
            Path(out_dir), f"interrupted (Ctrl-C) after {ticks} of {scenario.steps + 1} ticks"
        )
        raise


def _run_distributed(
    scenario: Scenario,
    out_dir: Path,
    scenario_path: Path | None = None,
    progress: bool = True,
    agent_nice: int = AGENT_NICE,
) -> dict:
    """:func:`run_distributed` without the partial results of an interrupted run.

    Process faults of the scenario are done by a ``FaultInjector``. A ``kill_server`` fault ends
    the run early: the agents exit by themselves (``sim.server_lost_s``), metrics come from the
    trajectory so far and the outcome carries ``incomplete`` (the CLI then exits 1).
    """
    _check_faults(scenario)
    model = policy_path(scenario, scenario_path)
    if model is not None:
        model = model.resolve()
        from swarm.sim.controller_kinds import robot_controller

        try:  # before any process starts: a bad file is bad input, not agents that exit with 1
            robot_controller(
                scenario.controller.kind,
                scenario.robot,
                policy_bytes=model.read_bytes(),
                robot_count=scenario.robots.count,
                control_period_s=scenario.sim.control_period_s,
                options=scenario.controller.model_dump(),
                task=scenario.task,
            )
        except ValueError as error:  # swarm.sim.policy.PolicyFormatError is a ValueError
            raise ScenarioError(f"controller.model: {model}: {error}") from None
        data = scenario.model_dump(mode="json")
        data["controller"]["model"] = str(model)  # the server reads the copy in the results directory
        scenario = parse_scenario(data)
    if scenario.sim.acl is None:  # the default: access control on where the run can have it
        data = scenario.model_dump(mode="json")
        data["sim"]["acl"] = scenario.access_control
        scenario = parse_scenario(data)
    elif not scenario.sim.acl:
        log.warning(
            "swarm run: warning: sim.acl: false: access control is OFF; anyone who reaches the run's"
            " port can join it and publish on any key (docs/distributed-runtime.md)"
        )
    out_dir = Path(out_dir)
    prepare_results_dir(out_dir, scenario)
    logs = out_dir / "logs"
    stale = [
        out_dir / name for name in ("trajectory.jsonl", "server_stats.json", "metrics.json", "events.jsonl")
    ]
    stale.append(logs / "launcher_exits.jsonl")  # robot_agent.__main__.EXITS_FILE
    for path in [*stale, *logs.glob("agent_*.json"), *logs.glob("replaced/agent_*.json")]:
        path.unlink(missing_ok=True)
    run_id = _run_id(scenario.name)
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    count, steps = scenario.robots.count, scenario.steps
    python = sys.executable
    server_cmd = [python, "-m", "sim_server", "--scenario", str(out_dir / "scenario.yaml")]
    server_cmd += ["--out", str(out_dir), "--run", run_id, "--listen", endpoint, "--die-with-parent"]
    server_cmd += ["--no-report"]
    server_cmd += ["--model", str(model)] if model else []
    common = ["--connect", endpoint, "--run", run_id, "--log-dir", str(logs), "--die-with-parent"]
    if scenario.sim.acl:  # fresh credentials (0600) in the results directory, each agent its own file
        users, per_robot = write_credentials(out_dir / "credentials", count)
        server_cmd += ["--users", str(users)]
        common += ["--credentials", per_robot]
    if scenario.ros2 is not None and not scenario.controller.central:  # robots as ROS 2 robots: docs/ros2.md
        server_cmd += ["--ros2"]
        common += ["--ros2"]
    if scenario.controller.central:
        controller_name, controller_cmd = "central", [python, "-m", "robot_agent.central", *common]
    else:
        controller_name = "agents"
        controller_cmd = [python, "-m", "robot_agent", "--robots", f"0-{count - 1}", *common]
        controller_cmd += ["--nice", str(agent_nice)]

    ticks = _TickCounter(out_dir / "trajectory.jsonl")
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=steps + 1, desc=f"{scenario.name} (pybullet)", unit="tick", leave=False)
    started_s, started_unix_s = time.perf_counter(), time.time()
    first_tick_s = None
    child_env = _child_env()
    child_env[wire.RUN_KEY_ENV] = wire.new_run_key()  # authenticates the run's samples (wire.RunKey)
    with _sigterm_as_interrupt(), Supervisor(env=child_env) as supervisor:

        def start_agent(robot: int, number: int):
            command = [python, "-m", "robot_agent", "--robot", str(robot), *common, "--nice", str(agent_nice)]
            return supervisor.start(
                f"agent_{robot}.restart{number}", command, logs / f"agent_{robot}.restart{number}.log"
            )

        faults = FaultInjector(scenario, out_dir, started_s, start_agent, ticks.update)
        try:
            server = supervisor.start("sim_server", server_cmd, logs / "sim_server.log")
            faults.server_pid = server.pid
            controllers = supervisor.start(controller_name, controller_cmd, logs / f"{controller_name}.log")
            while server.poll() is None:
                done = ticks.update()
                if done and first_tick_s is None:
                    first_tick_s = time.perf_counter() - started_s
                if not done and controllers.poll() is not None:
                    log_path = logs / f"{controller_name}.log"
                    raise RunFailed(
                        f"the {controller_name} process exited with status {controllers.returncode} before"
                        f" the first tick: {_tail(log_path)} (logs in {logs})"
                    )
                if done:
                    faults.step(done)
                if bar is not None:
                    bar.update(done - bar.n)
                time.sleep(FAULT_POLL_S if faults.pending else 0.05)
            ticks.update()
            faults.finish()
            server_gone = server.returncode != 0
            grace_s = AGENTS_EXIT_GRACE_S + (scenario.sim.server_lost_s if server_gone else 0.0)
            deadline_s = time.perf_counter() + grace_s
            agents_exit = supervisor.wait(controller_name, grace_s)
            for process in faults.restarted:
                with contextlib.suppress(subprocess.TimeoutExpired):
                    process.wait(max(0.0, deadline_s - time.perf_counter()))
        finally:
            faults.close()
            if bar is not None:
                bar.close()
    wall_s = time.perf_counter() - started_s
    killed_by_fault = faults.server_killed_tick is not None
    incomplete = None
    if server.returncode != 0:
        failure = (
            f"sim server exited with status {server.returncode}: {_tail(logs / 'sim_server.log')}"
            f" (logs in {logs})"
        )
        if not killed_by_fault:
            write_partial_results(out_dir, f"the run failed: {failure}")
            raise RunFailed(failure)
        incomplete = (
            f"the sim server was killed by a kill_server fault at tick {faults.server_killed_tick}"
            f" of {steps}; metrics from the {ticks.lines} ticks before"
        )
    times_s, poses, _ = read_trajectory(out_dir / "trajectory.jsonl")
    if not len(times_s):
        raise RunFailed(f"no tick in the trajectory (logs in {logs})")
    if len(times_s) != steps + 1 and incomplete is None:
        write_partial_results(out_dir, f"the trajectory has {len(times_s)} of {steps + 1} ticks")
        raise RunFailed(f"trajectory has {len(times_s)} of {steps + 1} ticks (logs in {logs})")

    adjacency = scenario.adjacency()
    if adjacency is None:  # a disk graph (the sim's radio, sim_server.radio): that of the last poses
        assert scenario.topology.radius_m is not None
        adjacency = graphs.disk(poses[-1, :, :2], scenario.topology.radius_m)
    outcome = task_outcome(scenario, times_s, poses, adjacency)  # rendezvous: summarize
    if incomplete is not None:
        outcome.update(incomplete=incomplete, ticks_planned=steps)
    records = {int(path.stem.split("_")[1]): _read_json(path) for path in sorted(logs.glob("agent_*.json"))}
    stats = _read_json(out_dir / "server_stats.json")
    outcome["processes"] = {
        "server_pid": server.pid,
        f"{controller_name}_pid": controllers.pid,
        "agent_pids": {str(i): record.get("pid") for i, record in sorted(records.items())},
        "agents_exit_status": agents_exit,
        "restarted_agents_exit_status": [process.poll() for process in faults.restarted],
        "killed_process_groups": len(supervisor.killed),
    }
    central_record = _read_json(logs / "central.json")  # a central controller's own counts
    outcome.update(body_results(scenario, stats, [*records.values(), central_record], poses))
    outcome["runtime"] = runtime_summary(scenario, stats, records, endpoint, wall_s, first_tick_s)
    if stats.get("agents_ready_unix_s") is not None:
        outcome["runtime"]["agents_ready_s"] = round(stats["agents_ready_unix_s"] - started_unix_s, 3)
    if scenario.faults:  # judged on the live robots and graph at the end (swarm.scenarios.fault_results)
        add_fault_results(outcome, scenario, out_dir, records, times_s, poses)
    outcome["health"] = health.health(
        stats=stats,
        records=records,
        events=read_events(out_dir / "events.jsonl"),
        launcher_exits=health.read_jsonl(logs / "launcher_exits.jsonl"),
        never_back=(outcome.get("faults") or {}).get("agents_restarted_never_back", []),
        controller=controller_name,
        controller_status=agents_exit,
        rejected=outcome["runtime"]["rejected"],
        mode=scenario.sim.mode,
        control_period_s=scenario.sim.control_period_s,
        access_control=scenario.access_control,
        access_control_off_why=(
            "sim.acl: false" if scenario.sim.acl is False else scenario.access_control_unavailable()
        ),
    )
    write_metrics(out_dir, outcome)
    task_pictures(out_dir, scenario, times_s, poses, outcome)  # rendezvous: write_pictures
    return outcome


def body_results(scenario: Scenario, stats: dict, records: list[dict], poses: np.ndarray) -> dict:
    """``contacts`` as PyBullet reported them (robot-robot and robot-obstacle pairs touching at any
    physics substep of a tick: ``server_stats.json``), ``min_clearance_m`` from the trajectory (the
    bumpers' smallest gap at a tick), and ``safety_filter``: the agents' counts summed (None without a
    filter): ``interventions``, ``infeasible``, and the sensor readings ``missing`` (a tick braked
    blind), ``invalid`` and ``unauthenticated`` (docs/safety.md)."""
    from swarm.core.obstacles import Capsules
    from swarm.scenarios.safety_results import contact_results

    geometry = contact_results(poses, scenario.robot.body_radius_m, Capsules(scenario.obstacles))
    contacts = stats.get("contacts")
    filter_counts = None
    if scenario.safety is not None:
        filter_counts = dict.fromkeys(  # what the robots' filters did (their readings received: not here)
            ("interventions", "infeasible", "missing", "invalid", "unauthenticated"), 0
        )
        for record in records:
            for name, count in (record.get("safety_filter") or {}).items():
                if name in filter_counts:
                    filter_counts[name] += int(count)
    return {
        "contacts": contacts if isinstance(contacts, dict) else geometry["contacts"],
        "min_clearance_m": geometry["min_clearance_m"],
        "safety_filter": filter_counts,
    }


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
        "rejected": rejected_counts(stats, records),
        "access_control": scenario.access_control,
        "agent_exit_reasons": sorted({str(record.get("exit_reason")) for record in records.values()}),
    }


def rejected_counts(stats: dict, records: dict[int, dict]) -> dict:
    """Samples dropped on receipt, per reason and stream: ``invalid`` (did not decode: swarm.runtime.wire),
    ``unauthenticated`` (no valid run-key tag: wire.RunKey),
    ``old`` (tick not newer than the newest accepted from that sender), ``future`` (tick beyond the
    receiver's window: swarm.runtime.ticks), ``ring_full`` (drains of an agent's receive ring that found it
    full: samples may have been pushed out unread; 0: none was; the server's commands go through a
    callback: none); and exceptions caught in callbacks."""

    def total(stream: str, kind: str) -> int:
        return sum(int((record.get(stream) or {}).get(kind, 0)) for record in records.values())

    counts: dict = {
        reason: {
            "poses": total("poses", reason),
            "messages": total("messages", reason),
            "commands": int(stats.get(f"{reason}_commands", 0)),
        }
        for reason in ("invalid", "unauthenticated", "old", "future", "ring_full")
    }
    for reason in ("invalid", "unauthenticated"):  # the sensor readings of a safety filter
        counts[reason]["readings"] = total("safety_filter", reason)
    counts["callback_errors"] = int(stats.get("callback_errors", 0)) + sum(
        int(record.get("callback_errors", 0)) for record in records.values()
    )
    return counts
