"""A truthful summary and exit status (``swarm.runtime.health``): real ``swarm run`` processes, real
Zenoh sessions, real PyBullet and real signals sent from outside, by no fault of the scenario.

An agent SIGKILLed from outside, or the agents' launcher SIGKILLed (its forked agents die with it),
while the swarm still gathers: the run exits 1, the summary names every robot whose agent died and
the tick, and metrics.json's ``health`` block says it was not scheduled. The tick the run names is
checked against the trajectory: the server stops a robot (wheels 0) at the tick it saw its agent
go or the next, and the agent was killed when the trajectory had a known number of lines.
"""

from __future__ import annotations

import json
import os
import signal

import numpy as np
import psutil
import pytest
from test_process_faults import fault_scenario, read_events
from test_runtime import Run, agent_records, scenario_file

from swarm.runtime import health
from swarm.scenarios.results import read_trajectory

pytestmark = pytest.mark.runtime


def _wheels(out) -> np.ndarray:
    _, _, records = read_trajectory(out / "trajectory.jsonl")
    return np.array([record["wheels"] for record in records if "wheels" in record])


def _first_stopped_for_good(wheels: np.ndarray, robot: int, after: int) -> int:
    """The first tick >= ``after`` from which ``robot``'s wheels stay exactly 0 to the end."""
    moving = np.flatnonzero(np.abs(wheels[:, robot]).max(axis=1) > 0)
    last_moving = int(moving[moving >= after].max()) if (moving >= after).any() else after - 1
    return last_moving + 1


def _start(tmp_path):
    path = scenario_file(tmp_path, "cycle-local_consensus", sim__duration=12.0)
    out = tmp_path / "out"
    return Run(path, out), out


def test_an_agent_killed_from_outside_fails_the_run_and_the_summary_names_it(tmp_path):
    run, out = _start(tmp_path)
    run.wait_for(lambda: run.ticks() >= 40 and (out / "logs" / "agent_2.json").exists())
    pid = json.loads((out / "logs" / "agent_2.json").read_text())["pid"]
    killed_after = run.ticks()
    os.kill(pid, signal.SIGKILL)
    code, stdout, stderr = run.finish()
    metrics = json.loads((out / "metrics.json").read_text())
    assert code == 1, (stdout, stderr)
    died = [i for i in metrics["health"]["incidents"] if i["kind"] == "died"]
    assert [(i["robot"], i["scheduled"]) for i in died] == [(2, False)], metrics["health"]
    tick = died[0]["tick"]
    stopped = _first_stopped_for_good(_wheels(out), 2, killed_after)
    assert killed_after <= tick <= stopped, (killed_after, tick, stopped)
    assert f"robot 2's agent died at tick {tick}, no fault scheduled it" in stderr
    assert f"robot 2's agent went at tick {tick}" in stdout and "NOT scheduled" in stdout
    assert "killed by SIGKILL" in stdout  # the launcher saw its child die


def test_a_killed_launcher_fails_the_run_and_the_summary_names_every_robot(tmp_path):
    run, out = _start(tmp_path)
    run.wait_for(lambda: run.ticks() >= 40 and len(list((out / "logs").glob("agent_*.json"))) == 6)
    launcher = next(
        p
        for p in psutil.Process(run.process.pid).children(recursive=True)
        if "--robots" in p.cmdline() and "robot_agent" in p.cmdline()
    )
    killed_after = run.ticks()
    launcher.send_signal(signal.SIGKILL)
    code, stdout, stderr = run.finish()
    metrics = json.loads((out / "metrics.json").read_text())
    assert code == 1, (stdout, stderr)
    assert "the agents process killed by SIGKILL, no fault scheduled it" in stderr
    died = {i["robot"]: i for i in metrics["health"]["incidents"] if i["kind"] == "died"}
    assert sorted(died) == list(range(6)) and not any(i["scheduled"] for i in died.values())
    wheels = _wheels(out)
    for robot, incident in died.items():
        assert killed_after <= incident["tick"] <= _first_stopped_for_good(wheels, robot, killed_after)
        assert f"robot {robot}'s agent died at tick {incident['tick']}" in stderr


def test_silent_spans_and_events_are_judged_against_what_the_runner_did():
    """Pure: a gone without a back is a death, scheduled only inside the window of a process fault of
    that robot; a long silence of a live agent is a freeze; a short one is nothing."""
    stats = {
        "agent_events": [
            {"robot": 1, "event": "gone", "tick": 50},
            {"robot": 2, "event": "gone", "tick": 30},
            {"robot": 2, "event": "back", "tick": 34},
        ],
        "silent_spans": [
            {"robot": 1, "from_tick": 48, "ticks": 52, "to_end": True},  # the death's silence
            {"robot": 4, "from_tick": 10, "ticks": health.FROZEN_AFTER_TICKS, "to_end": False},
            {"robot": 5, "from_tick": 10, "ticks": health.FROZEN_AFTER_TICKS - 1, "to_end": False},
        ],
    }
    events = [{"kind": "restart_agent", "robot": 2, "tick": 29}]
    found = health.incidents(stats, {}, events, [], [])
    kinds = {(i["kind"], i["robot"]): i["scheduled"] for i in found}
    assert kinds == {("died", 1): False, ("away", 2): True, ("froze", 4): False}
    reasons = health.failures(found, "agents", 0)
    assert reasons == [
        "robot 4's agent froze (20 ticks without a command) at tick 10, no fault scheduled it",
        "robot 1's agent died at tick 50, no fault scheduled it",
    ]
    events.append({"kind": "kill_agent", "robot": 1, "tick": 49})
    events.append({"kind": "hang_agent", "robot": 4, "tick": 9})
    events.append({"kind": "resume_agent", "robot": 4, "tick": 40})
    assert health.failures(health.incidents(stats, {}, events, [], []), "agents", 0) == []
    assert health.failures(health.incidents(stats, {}, events, [], [3]), "agents", 0) == [
        "robot 3's restarted agent never came back"
    ]


def test_lockstep_waits_for_a_restarted_agent_even_when_the_run_would_end_before_it_starts(tmp_path):
    """The restart race: 50 lockstep ticks take well under the second a fresh agent process needs
    to start, so a server that does not wait for it ends the run first ("robot 0: stopped",
    never back). It waits: the new process (the pid of the restart event) drives robot 0."""
    path, _ = fault_scenario(
        tmp_path, "restart-agent", duration=3.0, faults=[{"at": 0.5, "kind": "restart_agent", "robot": 0}]
    )
    out = tmp_path / "out"
    code, _, stderr = Run(path, out).finish()
    metrics = json.loads((out / "metrics.json").read_text())
    restart = next(e for e in read_events(out) if e["kind"] == "restart_agent")
    record = agent_records(out)[0]
    assert record["pid"] == restart["pid"] and record["first_tick"] >= restart["tick"], (record, stderr)
    assert metrics["faults"]["agents_restarted_never_back"] == [] and not metrics["health"]["failures"]
    wheels = _wheels(out)
    assert np.abs(wheels[record["first_tick"] :, 0]).max() > 0  # its commands moved robot 0
    assert code in (0, 1) and "the run failed" not in stderr


def _endpoint_of(run: Run) -> str:
    for child in psutil.Process(run.process.pid).children(recursive=True):
        command = child.cmdline()
        if "sim_server" in command and "--listen" in command:
            return command[command.index("--listen") + 1]
    raise AssertionError("no sim server")


def test_access_control_is_on_by_default_and_off_only_when_asked_with_one_warning(tmp_path):
    """The default run admits no client without the run's credentials (an outsider's session is
    refused mid-run) and says so; ``sim.acl: false`` runs open, with one warning line."""
    import outside  # imports none of the project's code

    run = Run(scenario_file(tmp_path, "cycle-local_consensus", sim__duration=8.0), tmp_path / "on")
    run.wait_for(lambda: run.ticks() >= 5)
    with pytest.raises(outside.zenoh.ZError):
        outside.open_session(_endpoint_of(run), deadline_s=3.0).close()
    code, stdout, stderr = run.finish()
    metrics = json.loads((tmp_path / "on" / "metrics.json").read_text())
    assert metrics["runtime"]["access_control"] is True and "access control: on" in stdout, stdout
    assert "access control is OFF" not in stderr and code in (0, 1)

    path = scenario_file(tmp_path, "cycle-local_consensus", sim__duration=2.0, sim__acl=False)
    code, stdout, stderr = Run(path, tmp_path / "off").finish()
    assert [line for line in stderr.splitlines() if "warning" in line] == [
        "swarm run: warning: sim.acl: false: access control is OFF; anyone who reaches the run's port can"
        " join it and publish on any key (docs/distributed-runtime.md)"
    ]
    assert "access control: OFF (sim.acl: false)" in stdout
    assert json.loads((tmp_path / "off" / "metrics.json").read_text())["runtime"]["access_control"] is False
