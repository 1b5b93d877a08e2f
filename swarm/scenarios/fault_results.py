"""The results of a faulty run: the ``faults`` block of metrics.json, judged on the live robots and the
graph at the end (docs/faults.md). The fault schedule itself (``LinkFaults``) is ``swarm.core.faults``,
which the engines and the robot agents run; this half reads the scenario and the run's files.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from swarm.core import graphs, metrics, tasks
from swarm.core.faults import LinkFaults, message_max_age_ticks, tick_of
from swarm.scenarios.scenario import Scenario


def read_events(path: Path) -> list[dict]:
    """The runner's process-fault log (``events.jsonl``), one dict per line; a torn last line is skipped."""
    events = []
    try:
        with open(path) as file:
            for line in file:
                try:
                    event = json.loads(line)
                except json.JSONDecodeError:
                    break
                if isinstance(event, dict):
                    events.append(event)
    except FileNotFoundError:
        pass
    return events


MESSAGE_COUNTERS = (
    "received",
    "invalid",
    "lost",
    "late",
    "dropped_by_fault",
    "lost_by_fault",
    "delayed_by_fault",
)
"""Per-agent message counters summed into the ``faults`` block (``robot_agent.agent`` records)."""


def _scheduled(scenario: Scenario) -> list[dict]:
    dt = scenario.sim.control_period_s
    out = []
    for index, fault in enumerate(scenario.faults):
        entry = {"index": index, **{k: v for k, v in fault.model_dump(mode="json").items() if v is not None}}
        entry["tick"] = tick_of(fault.at_s or 0.0, dt)
        out.append(entry)
    return out


def process_fault_state(events: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """Who is dead, hung and restarted after the runner's events, in their order."""
    dead, hung, restarted, killed = set(), set(), set(), set()
    server_killed = False
    for event in events:
        kind, robot = event.get("kind"), event.get("robot")
        if kind == "kill_server":
            server_killed = True
        if not isinstance(robot, int):
            continue
        if kind == "kill_agent":
            dead.add(robot)
            killed.add(robot)
        elif kind == "restart_agent":
            dead.discard(robot)
            hung.discard(robot)
            restarted.add(robot)
        elif kind == "hang_agent":
            hung.add(robot)
        elif kind == "resume_agent":
            hung.discard(robot)
    return {
        "agents_killed": sorted(killed),
        "agents_lost": sorted(dead),
        "agents_restarted": sorted(restarted),
        "agents_hung_at_end": sorted(hung),
        "server_killed": server_killed,
    }


def never_back(
    events: Sequence[Mapping[str, Any]],
    state: Mapping[str, Any],
    records: Mapping[int, Mapping[str, Any]],
) -> list[int]:
    """Restarted robots whose new agent never drove them: no record written by the process the last
    ``restart_agent`` event started (its ``pid``), or one with no tick computed (it crashed or
    hung before its first command). Such a robot is out of the live swarm, as a killed one is."""
    new_pid = {
        event["robot"]: event.get("pid")
        for event in events
        if event.get("kind") == "restart_agent" and isinstance(event.get("robot"), int)
    }
    out = []
    for robot in state["agents_restarted"]:
        if robot in state["agents_lost"]:
            continue  # killed again after its restart: already out
        record = records.get(robot)
        same_process = isinstance(record, Mapping) and record.get("pid") == new_pid.get(robot)
        ticks = record.get("ticks") if same_process and isinstance(record, Mapping) else None
        if not isinstance(ticks, int) or ticks <= 0:
            out.append(robot)
    return out


def fault_summary(
    scenario: Scenario,
    out_dir: Path,
    records: Mapping[int, Mapping[str, Any]],
    times_s: np.ndarray,
    poses: np.ndarray,
    message_counts: Mapping[str, int] | None = None,
) -> dict:
    """The ``faults`` block of metrics.json for a run of ``scenario`` (a ``Scenario``).

    Consensus is judged over the robots whose agents are alive at the end (killed and not restarted,
    hung, or restarted by a process that never drove the robot (:func:`never_back`), per
    ``<out_dir>/events.jsonl`` and the records, are out), per connected component of the live graph at the
    end: the scenario's graph minus the links down both ways at the last tick, minus the dead robots.
    ``records``: the agents' records (``logs/agent_<i>.json``) whose ``messages`` counters are summed,
    with those of replaced agents (``logs/replaced/``); ``message_counts`` instead, from an engine
    without agents (the kinematic one).
    """

    events = read_events(Path(out_dir) / "events.jsonl")
    state = process_fault_state(events)
    count = scenario.robots.count
    times_s = np.asarray(times_s, dtype=np.float64)
    positions = np.asarray(poses, dtype=np.float64)[..., :2]
    end_tick = len(times_s) - 1
    schedule = LinkFaults.from_scenario(scenario)
    adjacency = scenario.adjacency()
    if adjacency is None:  # disk graph: the graph of the last positions
        radius_m = scenario.topology.radius_m
        assert radius_m is not None, "a disk topology has a radius (swarm.scenarios.scenario)"
        adjacency = graphs.disk(positions[-1], radius_m)
    live_adjacency = schedule.live_adjacency(adjacency, end_tick)
    if message_counts is None:  # real agents: a restart counts once its new process drove the robot
        state["agents_restarted_never_back"] = never_back(events, state, records)
    out = set(state["agents_lost"]) | set(state["agents_hung_at_end"])
    out |= set(state.get("agents_restarted_never_back", []))
    live = [i for i in range(count) if i not in out]
    down = [
        [i, j]
        for i in range(count)
        for j in range(i + 1, count)
        if adjacency[i, j] and not live_adjacency[i, j]
    ]
    sub = live_adjacency[np.ix_(live, live)]
    components = (
        [[live[i] for i in component] for component in graphs.connected_components(sub)] if live else []
    )
    metric, threshold = scenario.success.metric, scenario.threshold
    results = metrics.component_results(times_s, positions, components, metric, threshold) if live else []
    if message_counts is None:
        counters = {name: 0 for name in MESSAGE_COUNTERS}
        replaced = []  # records of agents that a restart_agent replaced (swarm.runtime.distributed)
        for path in sorted((Path(out_dir) / "logs" / "replaced").glob("agent_*.json")):
            try:
                replaced.append(json.loads(path.read_text()))
            except (OSError, ValueError):
                continue
        for record in [*records.values(), *replaced]:
            messages = record.get("messages") if isinstance(record, Mapping) else None
            for name in MESSAGE_COUNTERS:
                value = messages.get(name) if isinstance(messages, Mapping) else None
                counters[name] += value if isinstance(value, int) else 0
    else:
        counters = {name: int(value) for name, value in message_counts.items()}
    return {
        "scheduled": _scheduled(scenario),
        "events": events,
        "faults_seed": scenario.faults_seed,
        "message_max_age_ticks": message_max_age_ticks(scenario.sim),
        "messages": counters,
        **state,
        "live_robots": live,
        "links_down_at_end": down,
        "live_graph_connected": len(components) == 1,
        "components": results,
        "every_component_converged": bool(results) and all(c["converged"] for c in results),
    }


def apply_fault_summary(
    outcome: dict, summary: dict, scenario: Scenario, times_s: np.ndarray, poses: np.ndarray
) -> dict:
    """Put ``summary`` under ``outcome["faults"]`` and judge the run on its live robots.

    The top-level keys keep their meaning for the live swarm: ``components`` and ``graph_connected`` are
    those of the live graph at the end; ``converged`` means the live robots reached one consensus (the
    live graph is connected and converged; a live graph split in several components, even if each of them
    converged, cannot, as docs/design.md says of the disconnected thesis graph: exit status 1, with the
    per-component results listed); ``convergence_time_s``, ``final_metric``, ``initial_metric`` and the
    lower bound are those of the live robots. The fault-blind values over every robot move to
    ``faults.all_robots``.
    """

    summary = dict(summary)
    summary["all_robots"] = {
        key: outcome.get(key) for key in ("converged", "convergence_time_s", "final_metric", "components")
    }
    outcome["faults"] = summary
    if tasks.get(scenario.task.kind).outcome is not None:  # a task with its own success rule (formation)
        summary["components"] = outcome.get("components")  # judged every robot already: a dead robot's
        return outcome  # slot stays empty unless it died on it, which the rule sees (not consensus)
    live, components = summary["live_robots"], summary["components"]
    outcome["components"] = components
    outcome["graph_connected"] = summary["live_graph_connected"]
    one = summary["live_graph_connected"] and components[0]["converged"]
    outcome["converged"] = bool(one)
    outcome["convergence_time_s"] = components[0]["convergence_time_s"] if one else None
    if not live:
        outcome["final_metric"] = outcome["initial_metric"] = outcome["lower_bound_s"] = None
        outcome["ratio_to_lower_bound"] = None
        return outcome
    metric, threshold = scenario.success.metric, scenario.threshold
    positions = np.asarray(poses, dtype=np.float64)[:, live, :2]
    values = metrics.METRICS[metric](positions) if len(live) > 1 else np.zeros(len(times_s))
    outcome["final_metric"], outcome["initial_metric"] = float(values[-1]), float(values[0])
    bound = None
    if metric == "max_pairwise":
        bound = metrics.lower_bound_s(positions[0], threshold, scenario.robot.v_max_mps)
    outcome["lower_bound_s"] = bound
    time_s = outcome["convergence_time_s"]
    outcome["ratio_to_lower_bound"] = time_s / bound if time_s is not None and bound else None
    return outcome


def add_fault_results(
    outcome: dict,
    scenario: Scenario,
    out_dir: Path,
    records: Mapping[int, Mapping[str, Any]],
    times_s: np.ndarray,
    poses: np.ndarray,
    message_counts: Mapping[str, int] | None = None,
) -> dict:
    """:func:`fault_summary` then :func:`apply_fault_summary`: what a runner calls once, after
    ``swarm.scenarios.results.summarize``, for a scenario with faults."""
    summary = fault_summary(scenario, out_dir, records, times_s, poses, message_counts)
    return apply_fault_summary(outcome, summary, scenario, times_s, poses)
