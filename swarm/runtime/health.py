"""The health of a distributed run: what happened to its processes, told truthfully (``health`` in
metrics.json, its lines in the printed summary, and the exit status of ``swarm run``).

Positions say whether the swarm gathered; they do not say whether the run went as scheduled. This
module reads what the run's processes left (``server_stats.json``: the sim server's agent events and
its runs of ticks without a command; the agents' records; ``logs/launcher_exits.jsonl``: every exit the
agents' launcher saw; ``events.jsonl``: the process faults the runner did) and names every
*incident*, scheduled or not, with its robot and tick:

* ``died``: the agent's liveliness token went and did not come back (the server's ``gone`` event);
* ``away``: it went and came back (a frozen process past its lease, a cut link);
* ``hung``: lockstep, token up but ``HUNG_AFTER_DEADLINES`` deadlines missed in a row;
* ``froze``: no command for at least ``FROZEN_AFTER_TICKS`` ticks in a row, the agent not dead;
* ``clock_jump``: the agent's clock jumped ahead, confirmed by the next pose (``swarm.runtime.ticks``);
* ``never_back``: a restarted agent that never drove its robot
  (``swarm.scenarios.fault_results.never_back``);
* ``process_exit``: a process that ended by a signal or with an error status.

An incident is *scheduled* when a process fault that the runner did to that robot explains it:
``kill_agent`` (from its tick on), ``restart_agent`` (from its tick until the new agent's token is
up), ``hang_agent`` (from its tick until its agent is back after the resume). A run *failed* (exit 1,
whatever the positions) when an agent died or froze, or a process was killed, without a scheduled
fault, or when a restarted agent never came back.

It also sums the samples accepted and rejected, by reason, and compares the lockstep wall time with
what the median tick predicts: ``slowdown = loop_wall_s / (ticks * median tick wall s)``.
"""

from __future__ import annotations

import json
import signal
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

FROZEN_AFTER_TICKS = 20
"""An agent without a command for this many ticks in a row (1 s at 50 ms) froze, unless it died."""

HANG_SLACK_TICKS = 5
"""A hang or a restart explains what starts up to this many ticks after its agent is back (or, for a
hang whose agent never went, after the resume): the first poses of an agent back take a moment."""

SLOWDOWN_NAMED = 2.0
"""A lockstep run slower than this many times the median tick predicts is named in the summary."""

PROCESS_FAULT_KINDS = ("kill_agent", "restart_agent", "hang_agent")


def read_jsonl(path: Path) -> list[dict]:
    """Lines of a JSON-lines file that decode to objects; a torn line is skipped, no file is []."""
    out: list[dict] = []
    try:
        text = Path(path).read_text()
    except OSError:
        return out
    for line in text.splitlines():
        try:
            item = json.loads(line)
        except ValueError:
            continue
        if isinstance(item, dict):
            out.append(item)
    return out


def _status_words(status: int | None) -> str:
    if status is None:
        return "did not exit"
    if status < 0:
        try:
            return f"killed by {signal.Signals(-status).name}"
        except ValueError:
            return f"killed by signal {-status}"
    return f"exited with status {status}"


class _Explainer:
    """Which ticks of a robot the runner's process faults explain."""

    def __init__(self, events: Sequence[Mapping[str, Any]], agent_events: Sequence[Mapping[str, Any]]):
        self.windows: dict[int, list[tuple[int, float, str]]] = {}
        backs: dict[int, list[int]] = {}
        for event in agent_events:
            if event.get("event") in ("back", "answering") and isinstance(event.get("robot"), int):
                backs.setdefault(event["robot"], []).append(int(event.get("tick", 0)))
        resumes: dict[int, list[int]] = {}
        for event in events:
            if event.get("kind") == "resume_agent" and isinstance(event.get("robot"), int):
                resumes.setdefault(event["robot"], []).append(int(event.get("tick", 0)))

        def first_after(ticks: list[int], tick: int) -> int | None:
            later = [t for t in ticks if t >= tick]
            return min(later) if later else None

        for event in events:
            kind, robot = event.get("kind"), event.get("robot")
            if kind not in PROCESS_FAULT_KINDS or not isinstance(robot, int):
                continue
            start = int(event.get("tick", 0))
            end: float = float("inf")
            if kind == "restart_agent":
                back = first_after(backs.get(robot, []), start)
                end = float("inf") if back is None else back + HANG_SLACK_TICKS
            elif kind == "hang_agent":
                resume = first_after(resumes.get(robot, []), start)
                if resume is not None:
                    back = first_after(backs.get(robot, []), resume)
                    end = (back if back is not None else resume) + HANG_SLACK_TICKS
            self.windows.setdefault(robot, []).append((start, end, str(kind)))

    def fault(self, robot: int, tick: int) -> str | None:
        """The process fault of ``robot`` that explains an incident at ``tick``, or None."""
        for start, end, kind in self.windows.get(robot, []):
            if start <= tick <= end:
                return kind
        return None


def incidents(
    stats: Mapping[str, Any],
    records: Mapping[int, Mapping[str, Any]],
    events: Sequence[Mapping[str, Any]],
    launcher_exits: Sequence[Mapping[str, Any]],
    never_back: Sequence[int],
) -> list[dict]:
    """Every incident of the run, by tick (see the module docstring)."""
    agent_events = [e for e in stats.get("agent_events", []) if isinstance(e, Mapping)]
    explain = _Explainer(events, agent_events)
    out: list[dict] = []

    def add(kind: str, robot: int | None, tick: int | None, detail: str, **extra: Any) -> None:
        fault = None if robot is None or tick is None else explain.fault(robot, tick)
        out.append(
            {
                "kind": kind,
                "robot": robot,
                "tick": tick,
                "scheduled": fault is not None,
                "fault": fault,
                "detail": detail,
                **extra,
            }
        )

    died: dict[int, int] = {}  # robot -> tick its token went for good
    for robot in sorted({e["robot"] for e in agent_events if isinstance(e.get("robot"), int)}):
        mine = [e for e in agent_events if e.get("robot") == robot]
        for index, event in enumerate(mine):
            tick = int(event.get("tick", 0))
            if event.get("event") == "gone":
                back = next((e for e in mine[index + 1 :] if e.get("event") == "back"), None)
                if back is None:
                    died[robot] = tick
                    add("died", robot, tick, f"robot {robot}'s agent went at tick {tick} and never came back")
                else:
                    add(
                        "away",
                        robot,
                        tick,
                        f"robot {robot}'s agent went at tick {tick}, back at tick {back.get('tick')}",
                        until_tick=back.get("tick"),
                    )
            elif event.get("event") == "hung":
                answer = next((e for e in mine[index + 1 :] if e.get("event") in ("answering", "gone")), None)
                until = None if answer is None else answer.get("tick")
                add("hung", robot, tick, f"robot {robot}'s agent hung at tick {tick}", until_tick=until)
    for span in stats.get("silent_spans", []):
        robot, start, ticks = span.get("robot"), span.get("from_tick"), span.get("ticks")
        if not (isinstance(robot, int) and isinstance(start, int) and isinstance(ticks, int)):
            continue
        if ticks < FROZEN_AFTER_TICKS or (robot in died and died[robot] <= start + ticks):
            continue  # short, or the silence of an agent that died
        end = "the end" if span.get("to_end") else f"tick {start + ticks}"
        add(
            "froze",
            robot,
            start,
            f"robot {robot} had no command from tick {start} to {end} ({ticks} ticks)",
            ticks=ticks,
        )
    for robot, record in sorted(records.items()):
        jumps = record.get("poses", {}).get("jump_ticks", []) if isinstance(record, Mapping) else []
        first_tick = record.get("first_tick", 0) if isinstance(record, Mapping) else 0
        for tick in jumps if isinstance(jumps, list) else []:
            # a restarted agent's first pose is a jump by design (swarm.runtime.ticks)
            if isinstance(tick, int) and tick > (first_tick if isinstance(first_tick, int) else 0):
                add("clock_jump", robot, tick, f"robot {robot}'s clock jumped to tick {tick}")
    for robot in never_back:
        add("never_back", robot, None, f"robot {robot}'s restarted agent never drove it")
        out[-1]["scheduled"] = False  # a restart that did not come back is never what was scheduled
    for exit_ in launcher_exits:
        robot, status = exit_.get("robot"), exit_.get("exit_status")
        if isinstance(status, int) and status != 0 and isinstance(robot, int):
            death = died.get(robot)
            words = f"robot {robot}'s agent (pid {exit_.get('pid')}) {_status_words(status)}"
            add("process_exit", robot, death, words, process=f"agent_{robot}", exit_status=status)
            if death is None:  # no server event dates it: scheduled if its robot had any process fault
                out[-1]["scheduled"] = bool(explain.windows.get(robot))
                out[-1]["fault"] = explain.windows.get(robot, [(0, 0, None)])[0][2]
    return sorted(out, key=lambda i: (i["tick"] if i["tick"] is not None else 1 << 60, i["robot"] or 0))


def samples(stats: Mapping[str, Any], records: Mapping[int, Mapping[str, Any]], rejected: Mapping) -> dict:
    """Samples accepted (poses, messages, commands) and rejected by reason and stream."""

    def total(stream: str, kind: str) -> int:
        streams = [r.get(stream) for r in records.values() if isinstance(r, Mapping)]
        return sum(int(s.get(kind, 0) or 0) for s in streams if isinstance(s, Mapping))

    return {
        "accepted": {
            "poses": total("poses", "received"),
            "messages": total("messages", "received"),
            "commands": int(stats.get("accepted_commands", 0) or 0),
        },
        "rejected": dict(rejected),
        "late": {"messages": total("messages", "late"), "commands": int(stats.get("late_commands", 0) or 0)},
    }


def slowdown(stats: Mapping[str, Any], mode: str, control_period_s: float) -> dict | None:
    """Wall time of the server's loop against the expected one: lockstep, ticks x the median tick;
    realtime, ticks x the control period."""
    ticks, wall_s = stats.get("ticks"), stats.get("loop_wall_s")
    if not isinstance(ticks, int) or not isinstance(wall_s, int | float) or ticks <= 0:
        return None
    if mode == "lockstep":
        median_ms = (stats.get("tick_wall_ms") or {}).get("p50")
        if not isinstance(median_ms, int | float) or median_ms <= 0:
            return None
        expected_s = ticks * median_ms / 1e3
    else:
        expected_s = ticks * control_period_s
    return {
        "loop_wall_s": round(float(wall_s), 3),
        "expected_wall_s": round(expected_s, 3),
        "slowdown": round(float(wall_s) / expected_s, 3),
    }


def failures(found: Sequence[Mapping[str, Any]], controller: str, controller_status: int | None) -> list[str]:
    """Why the run failed, one phrase each (empty: it did not)."""
    out = []
    for incident in found:
        kind, scheduled = incident["kind"], incident["scheduled"]
        when = "" if incident["tick"] is None else f" at tick {incident['tick']}"
        if kind in ("died", "froze") and not scheduled:
            what = "died" if kind == "died" else f"froze ({incident.get('ticks')} ticks without a command)"
            out.append(f"robot {incident['robot']}'s agent {what}{when}, no fault scheduled it")
        elif kind == "never_back":
            out.append(f"robot {incident['robot']}'s restarted agent never came back")
        elif kind == "process_exit" and not scheduled and (incident.get("exit_status") or 0) < 0:
            out.append(f"{incident['detail']}{when}, no fault scheduled it")
    if controller_status is None or controller_status < 0:
        out.append(f"the {controller} process {_status_words(controller_status)}, no fault scheduled it")
    elif controller_status != 0 and not any(i["kind"] == "process_exit" for i in found):
        out.append(f"the {controller} process {_status_words(controller_status)}")
    return out


def health(
    *,
    stats: Mapping[str, Any],
    records: Mapping[int, Mapping[str, Any]],
    events: Sequence[Mapping[str, Any]],
    launcher_exits: Sequence[Mapping[str, Any]],
    never_back: Sequence[int],
    controller: str,
    controller_status: int | None,
    rejected: Mapping,
    mode: str,
    control_period_s: float,
    access_control: bool,
    access_control_off_why: str | None = None,
) -> dict:
    """The ``health`` block of metrics.json; ``failures`` not empty: the run failed (exit 1)."""
    found = incidents(stats, records, events, launcher_exits, never_back)
    slow = slowdown(stats, mode, control_period_s)
    block = {
        "failures": failures(found, controller, controller_status),
        "incidents": found,
        "processes": {
            controller: controller_status,
            "agent_exits": [dict(e) for e in launcher_exits],
        },
        "ticks": stats.get("ticks"),
        "ticks_missed": stats.get("ticks_missed"),
        "samples": samples(stats, records, rejected),
        "wall": slow,
        "access_control": access_control,
        "access_control_off_why": None if access_control else access_control_off_why,
        "frozen_after_ticks": FROZEN_AFTER_TICKS,
    }
    block["lines"] = health_lines(block)
    return block


def health_lines(block: Mapping[str, Any]) -> list[str]:
    """The health block in words, for the printed summary."""
    why = block.get("access_control_off_why")
    state = "on" if block.get("access_control") else "OFF"
    lines = [f"access control: {state}" + (f" ({why})" if why else "")]
    for incident in block.get("incidents", []):
        fault = incident.get("fault")
        why = f"scheduled ({fault})" if incident["scheduled"] and fault else "NOT scheduled"
        lines.append(f"{incident['kind']}: {incident['detail']} [{why}]")
    missed = block.get("ticks_missed")
    if missed:
        lines.append(f"ticks missed: {missed} of {block.get('ticks')}")
    rejected = (block.get("samples") or {}).get("rejected") or {}
    parts = [
        f"{count} {stream} {reason}"
        for reason, streams in rejected.items()
        if isinstance(streams, Mapping)
        for stream, count in streams.items()
        if count
    ]
    if rejected.get("callback_errors"):
        parts.append(f"{rejected['callback_errors']} callback errors")
    if parts:
        lines.append("samples rejected: " + ", ".join(parts))
    wall = block.get("wall")
    if wall and wall["slowdown"] >= SLOWDOWN_NAMED:
        lines.append(
            f"slow: {wall['loop_wall_s']:.1f} s, {wall['slowdown']:.1f}x the"
            f" {wall['expected_wall_s']:.1f} s expected"
        )
    for failure in block.get("failures", []):
        lines.append(f"FAILED: {failure}")
    return lines
