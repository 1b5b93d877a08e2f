"""The results directory of a run (docs/design.md, "Results") and the outcome written to metrics.json.

Layout::

    scenario.yaml       the resolved scenario, every default filled in
    trajectory.jsonl    one line per tick, written as it happens (the sim server batches 0.1 s):
                        {"tick", "time_s", "poses": [[x, y, theta], ...]}
    metrics.json        the outcome (see ``summarize``); ``partial`` when the run did not complete
    convergence.png     the metric over time (``convergence.png.json``: what it shows, swarm.scenarios.report)
    animation.gif       the robots and their graph edges
    recording.mcap      on request (swarm.scenarios.recording; recording.rrd for rerun)
    logs/               one log per process
"""

from __future__ import annotations

import contextlib
import json
import math
import time
from pathlib import Path

import numpy as np

from swarm.core import graphs, metrics, tasks
from swarm.scenarios.scenario import Scenario, dump_scenario


class TrajectoryWriter:
    """Streams poses to ``trajectory.jsonl``, one complete line per tick.

    ``flush_every_s`` 0 (default): every line is flushed as it is written, so a crash loses at most
    the line being written. Above 0 the lines are batched in memory and written in one ``write``
    once the oldest unwritten line is that old (wall clock; and at :meth:`flush` / close): a killed
    writer leaves every line up to the last batch (a torn last line is skipped by the readers), and
    saves a system call per tick.
    """

    def __init__(self, path: Path, flush_every_s: float = 0.0):
        self.path = path
        self.flush_every_s = float(flush_every_s)
        self._file = open(path, "w")  # noqa: SIM115 (closed by close/__exit__)
        self._pending: list[str] = []
        self._oldest_s = 0.0

    def write(self, tick: int, time_s: float, poses: np.ndarray, **extra: object) -> None:
        record = {"tick": int(tick), "time_s": round(float(time_s), 9), "poses": np.asarray(poses).tolist()}
        record.update(extra)
        if not self._pending:
            self._oldest_s = time.perf_counter()
        self._pending.append(json.dumps(record, separators=(",", ":")) + "\n")
        if self.flush_every_s <= 0 or time.perf_counter() - self._oldest_s >= self.flush_every_s:
            self.flush()

    def flush(self) -> None:
        """Write every batched line and hand them to the OS."""
        if self._pending:
            self._file.write("".join(self._pending))
            self._pending.clear()
        self._file.flush()

    def close(self) -> None:
        self.flush()
        self._file.close()

    def __enter__(self) -> TrajectoryWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def prepare_results_dir(out_dir: Path, scenario: Scenario) -> Path:
    """Create the directory (and logs/) and write the resolved scenario."""
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "logs").mkdir(exist_ok=True)
    (out_dir / "scenario.yaml").write_text(dump_scenario(scenario))
    return out_dir


def read_jsonl(path: Path) -> list[dict]:
    """The records of a JSON-lines file written as it happened: a torn last line (the writer was
    killed mid-line) and everything after it are skipped."""
    records = []
    with open(path, errors="replace") as file:
        for line in file:
            try:
                record = json.loads(line)
            except json.JSONDecodeError:
                break
            if not isinstance(record, dict):
                break
            records.append(record)
    return records


def read_trajectory(path: Path) -> tuple[np.ndarray, np.ndarray, list[dict]]:
    """Times ``(T,)`` and poses ``(T, N, 3)`` from a trajectory file; a torn last line is skipped."""
    records = [r for r in read_jsonl(path) if "time_s" in r and "poses" in r]
    times = np.array([record["time_s"] for record in records], dtype=float)
    poses = np.array([record["poses"] for record in records], dtype=float)
    if not records:
        poses = poses.reshape(0, 0, 3)
    return times, poses, records


def _none_if_nan(value: float | np.ndarray | None) -> float | None:
    return None if value is None or math.isnan(value) else float(value)


def summarize(
    scenario: Scenario,
    times_s: np.ndarray,
    poses: np.ndarray,
    final_adjacency: np.ndarray,
) -> dict:
    """Outcome of a run from its trajectory: global consensus, per-component consensus and the
    lower bound of docs/design.md ("Metrics and the lower bound") for the ``max_pairwise`` metric."""
    metric, threshold = scenario.success.metric, scenario.threshold
    positions = poses[..., :2]
    values = metrics.METRICS[metric](positions)
    convergence_time_s = _none_if_nan(metrics.convergence_time(times_s, values, threshold))
    lower_bound_s = None
    if metric == "max_pairwise":
        lower_bound_s = metrics.lower_bound_s(positions[0], threshold, scenario.robot.v_max_mps)
    components = graphs.connected_components(final_adjacency)
    ratio = None
    if convergence_time_s is not None and lower_bound_s:
        ratio = convergence_time_s / lower_bound_s
    return {
        "scenario": scenario.name,
        "engine": scenario.sim.engine,
        "controller": scenario.controller.kind,
        "robots": scenario.robots.count,
        "metric": metric,
        "threshold": threshold,
        "converged": convergence_time_s is not None,
        "convergence_time_s": convergence_time_s,
        "final_metric": float(values[-1]),
        "initial_metric": float(values[0]),
        "lower_bound_s": lower_bound_s,
        "ratio_to_lower_bound": ratio,
        "duration_s": float(times_s[-1]),
        "ticks": int(len(times_s) - 1),
        "graph_connected": len(components) == 1,
        "components": metrics.component_results(times_s, positions, components, metric, threshold),
    }


def task_outcome(
    scenario: Scenario, times_s: np.ndarray, poses: np.ndarray, final_adjacency: np.ndarray
) -> dict:
    """What ``metrics.json`` holds for a run of ``scenario``'s task: rendezvous, :func:`summarize`; a task
    with its own ``outcome`` (``swarm.core.tasks``), that and the keys every run reports."""
    task = tasks.get(scenario.task.kind)
    if task.outcome is None:
        return summarize(scenario, times_s, poses, final_adjacency)
    results = task.outcome(times_s, poses[..., :2], scenario.task, scenario.robot.v_max_mps)
    components = graphs.connected_components(final_adjacency)
    return {
        "scenario": scenario.name,
        "task": task.name,
        "engine": scenario.sim.engine,
        "controller": scenario.controller.kind,
        "robots": scenario.robots.count,
        **results,
        "duration_s": float(times_s[-1]),
        "ticks": int(len(times_s) - 1),
        "graph_connected": len(components) == 1,
        "components": [
            {
                "robots": list(range(scenario.robots.count)),
                "converged": results["converged"],
                "convergence_time_s": results["convergence_time_s"],
                "final_metric": results["final_metric"],
            }
        ],
    }


def write_metrics(out_dir: Path, outcome: dict) -> None:
    """``metrics.json``; ``partial`` is true when the outcome is of a run that did not complete
    (``incomplete`` says why)."""
    outcome["partial"] = bool(outcome.get("incomplete"))
    (out_dir / "metrics.json").write_text(json.dumps(outcome, indent=2) + "\n")


def write_partial_results(out_dir: Path, why: str) -> dict | None:
    """``metrics.json`` and the plots of a run that ended early, from what is on disk, marked partial
    with ``why``; None (and nothing written) when there is not one complete tick to report on. Never
    raises: it runs on the way out of a failed or interrupted run."""
    import logging

    from swarm.scenarios.scenario import ScenarioError

    trajectory = Path(out_dir) / "trajectory.jsonl"
    if not trajectory.is_file() or trajectory.stat().st_size == 0:
        return None  # ended before its first tick: nothing to report on
    try:
        return report(out_dir, partial=why)
    except (ScenarioError, OSError, ValueError) as error:
        logging.getLogger(__name__).warning("no partial results in %s: %s", out_dir, error)
        return None


def write_startup_results(out_dir: Path, scenario: Scenario, why: str) -> dict:
    """``metrics.json`` of a run that ended before its first tick (Ctrl-C during start-up): what is
    known from the scenario alone (its robots, the metric and the lower bound of its initial poses),
    not converged, ``ticks`` 0, marked partial with ``why``; the scenario is written too. Keys of an
    earlier ``metrics.json`` are kept."""
    out_dir = Path(out_dir)
    prepare_results_dir(out_dir, scenario)
    poses = scenario.initial_poses()[None]
    adjacency = scenario.adjacency()
    if adjacency is None:
        assert scenario.topology.radius_m is not None  # no fixed graph: a disk graph
        adjacency = graphs.disk(poses[0, :, :2], scenario.topology.radius_m)
    outcome = summarize(scenario, np.zeros(1), poses, adjacency)
    outcome.update(converged=False, convergence_time_s=None, ratio_to_lower_bound=None)
    outcome["components"] = [
        {**component, "converged": False, "convergence_time_s": None} for component in outcome["components"]
    ]
    outcome.update(incomplete=why, ticks_planned=scenario.steps)
    try:
        previous = json.loads((out_dir / "metrics.json").read_text())
    except (OSError, ValueError):
        previous = {}
    outcome = {**(previous if isinstance(previous, dict) else {}), **outcome}
    write_metrics(out_dir, outcome)
    return outcome


def robots_text(count: int) -> str:
    """``1 robot``, ``6 robots``."""
    return f"{count} robot" if count == 1 else f"{count} robots"


def summary_lines(outcome: dict, out_dir: Path | str) -> list[str]:
    """What a finished run prints: its outcome, the faults it met and where its results are."""
    lines = [
        f"{outcome['scenario']}: {outcome['controller']} on {outcome['engine']}, "
        f"{robots_text(outcome['robots'])}",
    ]
    if outcome.get("incomplete"):
        lines.append(f"  PARTIAL: {outcome['incomplete']}")
    faults = outcome.get("faults") or {}
    live = faults.get("live_robots")
    who = f" (live robots {live})" if live is not None and len(live) < outcome["robots"] else ""
    if who and outcome.get("task", "rendezvous") != "rendezvous":  # its own rule: every body is judged
        who = f" (every robot's body judged; live agents {live})"
    unit = " " + outcome.get("unit", "m") if outcome.get("unit", "m") else ""  # coverage: a ratio, none
    metric = f"{outcome['metric']} <= {outcome['threshold']:g}{unit}"
    bound = outcome["lower_bound_s"]
    if outcome["converged"]:
        ratio = f", {outcome['ratio_to_lower_bound']:.2f}x the lower bound {bound:.2f} s" if bound else ""
        lines.append(f"  converged{who}: {metric} from {outcome['convergence_time_s']:.2f} s{ratio}")
    elif outcome.get("final_metric") is None:
        lines.append("  NOT converged: no live robot at the end")
    else:
        lines.append(
            f"  NOT converged{who}: final {outcome['metric']} {outcome['final_metric']:.3f}{unit}"
            f" ({metric} wanted)"
        )
    from swarm.scenarios.safety_results import safety_summary_line

    if (bodies := safety_summary_line(outcome)) is not None:
        lines.append(bodies)
    if len(outcome["components"]) > 1:
        lines.append(f"  graph has {len(outcome['components'])} components:")
        for component in outcome["components"]:
            state = (
                f"converged from {component['convergence_time_s']:.2f} s"
                if component["converged"]
                else f"not converged (final {component['final_metric']:.3f} m)"
            )
            lines.append(f"    robots {component['robots']}: {state}")
    if faults:
        lines += ["  " + line for line in fault_lines(faults)]
    lines += ["  " + line for line in (outcome.get("health") or {}).get("lines", [])]  # swarm.runtime.health
    lines.append(f"  results: {out_dir}")
    return lines


def fault_lines(faults: dict) -> list[str]:
    """The faults block of metrics.json in words: what was done, who is lost, what is down, what was lost."""
    lines = []
    for event in faults.get("events", []):
        who = "" if event.get("robot") is None else f" robot {event['robot']}"
        lines.append(f"fault: {event['kind']}{who} at {event['at_s']:.2f} s (tick {event['tick']})")
    for fault in faults.get("scheduled", []):
        if fault["kind"] in ("drop_link", "restore_link", "packet_loss", "delay"):
            details = ", ".join(
                f"{key} {fault[key]}"
                for key in ("link", "direction", "p", "ticks", "until_s")
                if key in fault
            )
            lines.append(f"fault: {fault['kind']} at {fault.get('at_s', 0.0):.2f} s ({details})")
    if faults.get("agents_lost"):
        lines.append(f"agents lost (killed, not restarted): robots {faults['agents_lost']}")
    if faults.get("agents_restarted"):
        lines.append(f"agents restarted: robots {faults['agents_restarted']}")
    if faults.get("agents_hung_at_end"):
        lines.append(f"agents hung at the end: robots {faults['agents_hung_at_end']}")
    if faults.get("server_killed"):
        lines.append("sim server killed")
    if faults.get("links_down_at_end"):
        lines.append(f"links down at the end: {faults['links_down_at_end']}")
    counts = faults.get("messages") or {}
    lost = {
        name: counts.get(name, 0)
        for name in ("lost", "dropped_by_fault", "lost_by_fault", "delayed_by_fault")
    }
    if any(lost.values()):
        lost = {name: value for name, value in lost.items() if value}
        lines.append(
            "messages: " + ", ".join(f"{value} {name.replace('_', ' ')}" for name, value in lost.items())
        )
    if not faults.get("live_graph_connected", True):
        lines.append("the live graph is split: no global consensus possible")
    return lines


def blocks_from_disk(out_dir: Path, scenario: Scenario) -> dict:
    """The ``runtime`` and ``processes`` blocks a distributed run leaves on disk when it ended before
    writing them (Ctrl-C, a failed run): the sim server's ``server_stats.json`` (ticks served and
    missed, command latency) and the agents' records ``logs/agent_<i>.json`` (pids, messages); empty
    without them (a kinematic run). ``runtime.source`` says where it came from."""
    out_dir = Path(out_dir)
    try:
        stats = json.loads((out_dir / "server_stats.json").read_text())
    except (OSError, ValueError):
        return {}
    if not isinstance(stats, dict):
        return {}
    records = {}
    for record_path in sorted((out_dir / "logs").glob("agent_*.json")):
        with contextlib.suppress(OSError, ValueError, IndexError):
            records[int(record_path.stem.split("_")[1])] = json.loads(record_path.read_text())
    messages = [record.get("messages") or {} for record in records.values()]
    ready = [record["ready_s"] for record in records.values() if "ready_s" in record]
    runtime = {
        "source": "server_stats.json and logs/agent_*.json (the run ended before its own summary)",
        "mode": stats.get("mode", scenario.sim.mode),
        "server_startup_s": stats.get("startup_s"),
        "agent_ready_s_max": max(ready) if ready else None,
        "ticks_served": stats.get("ticks_served"),
        "ticks_missed": stats.get("ticks_missed"),
        "command_latency_ms": stats.get("latency_ms"),
        "messages_received": int(sum(m.get("received", 0) for m in messages)),
        "messages_lost": int(sum(m.get("lost", 0) for m in messages)),
        "messages_invalid": int(sum(m.get("invalid", 0) for m in messages)),
        "invalid_commands": stats.get("invalid_commands"),
        "access_control": scenario.sim.acl,
        "agent_exit_reasons": sorted({str(record.get("exit_reason")) for record in records.values()}),
    }
    processes = {"agent_pids": {str(i): record.get("pid") for i, record in sorted(records.items())}}
    return {"runtime": runtime, "processes": processes}


def report(out_dir: Path, partial: str | None = None) -> dict:
    """Re-create ``metrics.json``, ``convergence.png`` and ``animation.gif`` from what a run left on
    disk, however it ended (``swarm report RUN_DIR``): the scenario, the trajectory up to its last
    complete line, and ``events.jsonl`` when there is one. Keys of an earlier ``metrics.json`` that
    the trajectory cannot give (``processes``, ``runtime``, ...) are kept; where it has none (a run
    interrupted before writing them) they are read back from the processes' files
    (:func:`blocks_from_disk`). ``partial``: why the run
    ended early (the outcome is then marked partial even if every tick is there). Raises
    ``ScenarioError`` with one line when the directory cannot be read."""
    from swarm.scenarios.scenario import ScenarioError, load_scenario

    out_dir = Path(out_dir)
    if not out_dir.is_dir():
        raise ScenarioError(f"{out_dir}: no such results directory")
    scenario = load_scenario(out_dir / "scenario.yaml")
    path = out_dir / "trajectory.jsonl"
    try:
        times_s, poses, _ = read_trajectory(path)
    except FileNotFoundError:
        raise ScenarioError(f"{path}: no trajectory (the run ended before its first tick)") from None
    except ValueError as error:
        raise ScenarioError(f"{path}: unreadable poses: {error}") from None
    count = scenario.robots.count
    if not len(times_s):
        raise ScenarioError(f"{path}: no complete tick (the run ended before its first tick)")
    if poses.shape[1] != count:
        raise ScenarioError(f"{path}: poses of {poses.shape[1]} robots but the scenario has {count}")
    adjacency = scenario.adjacency()
    if adjacency is None:
        assert scenario.topology.radius_m is not None  # no fixed graph: a disk graph
        adjacency = graphs.disk(poses[-1, :, :2], scenario.topology.radius_m)
    from swarm.scenarios.task_report import task_pictures

    outcome = task_outcome(scenario, times_s, poses, adjacency)  # rendezvous: summarize
    try:
        previous = json.loads((out_dir / "metrics.json").read_text())
    except (OSError, ValueError):
        previous = {}
    if not isinstance(previous, dict):
        previous = {}
    outcome = {**blocks_from_disk(out_dir, scenario), **previous, **outcome}  # the run's own blocks win
    if scenario.sim.engine == "kinematic":  # overlaps from the trajectory; the filter's counts are kept
        from swarm.core.obstacles import Capsules
        from swarm.scenarios.safety_results import contact_results

        outcome.update(contact_results(poses, scenario.robot.body_radius_m, Capsules(scenario.obstacles)))
        outcome.setdefault("safety_filter", None)
    steps = scenario.steps
    if partial:
        outcome["incomplete"] = partial
        outcome["ticks_planned"] = steps
    elif len(times_s) < steps + 1:
        outcome.setdefault("incomplete", f"the trajectory has {len(times_s)} of {steps + 1} ticks")
        outcome["ticks_planned"] = steps
    if scenario.faults:  # judged on the live robots, from events.jsonl and the agents' records
        from swarm.scenarios.fault_results import add_fault_results

        records = {}
        for record_path in (out_dir / "logs").glob("agent_*.json"):
            with contextlib.suppress(OSError, ValueError, IndexError):
                records[int(record_path.stem.split("_")[1])] = json.loads(record_path.read_text())
        add_fault_results(outcome, scenario, out_dir, records, times_s, poses)
    write_metrics(out_dir, outcome)
    task_pictures(out_dir, scenario, times_s, poses, outcome)  # rendezvous: write_pictures
    return outcome
