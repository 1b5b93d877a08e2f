"""Faults done to the processes of a distributed run: real ``swarm run`` processes, real
Zenoh sessions, real PyBullet, real signals.

- the scenario's process faults (``kill_agent``, ``hang_agent``, ``restart_agent``, ``kill_server``)
  done by the runner at sim time, logged to ``events.jsonl`` and seen by the server;
- killing the runner, the server or an agent from outside at a random (seeded) moment leaves a
  results directory that reads back (``swarm report``) and no process behind;
- the trajectory reader skips a torn last line wherever the writer was cut.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys

import numpy as np
import psutil
import pytest
import yaml
from test_runtime import PROJECT_ROOT, Run, agent_records, max_pairwise_of

from swarm.core import metrics
from swarm.scenarios.results import read_trajectory
from swarm.scenarios.scenario import load_scenario

FAULTS = PROJECT_ROOT / "scenarios" / "faults"
EVENT_KEYS = {"kind", "robot", "at_s", "tick", "done_tick", "wall_s", "detail"}


def fault_scenario(tmp_path, name: str, **sim: object) -> tuple:
    """scenarios/faults/<name>.yaml with ``sim`` changes and the given faults, written to tmp_path."""
    data = yaml.safe_load((FAULTS / f"{name}.yaml").read_text())
    faults = sim.pop("faults", None)
    data["sim"].update(sim)
    if faults is not None:
        data["faults"] = faults
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(data))
    return path, load_scenario(path)


def read_events(out) -> list[dict]:
    return [json.loads(line) for line in (out / "events.jsonl").read_text().splitlines()]


def wheels_by_tick(out) -> np.ndarray:
    """``(T, N, 2)`` wheel speeds applied from each tick to the next."""
    _, _, records = read_trajectory(out / "trajectory.jsonl")
    return np.array([record["wheels"] for record in records if "wheels" in record])


def gone(pid: int) -> bool:
    try:
        return psutil.Process(pid).status() == psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return True


def report(out) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "swarm.cli", "report", str(out)],
        capture_output=True,
        text=True,
        cwd=PROJECT_ROOT,
        timeout=120,
    )


@pytest.mark.runtime
def test_killed_hung_and_restarted_agents(tmp_path):
    """One run, eight robots on a cycle: robot 3's agent killed for good, robot 6's frozen for 3 s of
    sim time, robot 0's killed and replaced by a fresh process. The live robots still gather."""
    faults = [
        {"at": 1.5, "kind": "kill_agent", "robot": 3},
        {"at": 2.0, "kind": "hang_agent", "robot": 6, "duration": 3.0},
        {"at": 2.5, "kind": "restart_agent", "robot": 0},
    ]
    path, scenario = fault_scenario(tmp_path, "kill-agent", duration=14.0, faults=faults)
    out = tmp_path / "out"
    run = Run(path, out, "--record", "mcap")
    code, stdout, stderr = run.finish()
    assert code in (0, 1), stderr
    assert run.survivors() == []

    dt, steps = scenario.sim.control_period_s, scenario.steps
    events = read_events(out)
    assert [(e["kind"], e["robot"]) for e in events] == [
        ("kill_agent", 3),
        ("hang_agent", 6),
        ("restart_agent", 0),
        ("resume_agent", 6),
    ]
    assert [e["at_s"] for e in events] == [1.5, 2.0, 2.5, 5.0]
    for event in events:
        assert set(event) >= EVENT_KEYS
        assert round(event["at_s"] / dt) <= event["tick"] < steps  # done at the sim time, not before
        assert event["tick"] <= event["done_tick"] <= steps + 1, event  # the ticks on disk right after
    assert [e["wall_s"] for e in events] == sorted(e["wall_s"] for e in events)
    restart = events[2]
    assert restart["pid"] != restart["old_pid"]
    for pid in (events[0]["pid"], restart["old_pid"], restart["pid"], events[1]["pid"]):
        assert gone(pid)

    # The server saw each of it: robot 3 gone for good, 6 and 0 gone and back.
    stats = json.loads((out / "server_stats.json").read_text())
    assert stats["exit"] == "done"
    per_robot = {entry["robot"]: entry for entry in stats["per_robot"]}
    assert len(per_robot[3]["gone_at_s"]) == 1 and per_robot[3]["back_at_s"] == []
    for robot in (0, 6):
        assert len(per_robot[robot]["gone_at_s"]) == 1 and len(per_robot[robot]["back_at_s"]) == 1
        # in lockstep the server waits for a restarted agent before the next tick: back at the same sim time
        assert per_robot[robot]["gone_at_s"][0] <= per_robot[robot]["back_at_s"][0]
    for robot in (1, 2, 4, 5, 7):
        assert per_robot[robot]["gone_at_s"] == []
        assert per_robot[robot]["ticks_without_command"] <= 3  # tick 0 at most (a loaded machine: a few)
    # robot 3 commanded no tick after the server's tick when its token went (a dead process sends
    # nothing; the kill itself may land a few ticks after the runner's decision on a loaded machine).
    # The runner's event tick counts the trajectory lines on disk: it kills once tick k - 1 is written,
    # which the server may still call its current tick until it publishes tick k (1 in 3 loaded runs)
    gone_tick = round(per_robot[3]["gone_at_s"][0] / dt)
    assert events[0]["tick"] - 1 <= gone_tick
    assert per_robot[3]["ticks_without_command"] >= steps - gone_tick - 1

    # A dead or frozen agent's robot stops; a thawed or restarted one moves again.
    wheels = wheels_by_tick(out)
    gone_tick = {e["robot"]: e["tick"] for e in stats["agent_events"] if e["event"] == "gone"}
    back_tick = {e["robot"]: e["tick"] for e in stats["agent_events"] if e["event"] == "back"}
    assert np.all(wheels[gone_tick[3] + 1 :, 3] == 0.0)
    # Until the runner thawed or restarted it (its event tick counts lines on disk, one ahead of the
    # server's; a restart follows the kill at once, so robot 0's window may be empty). A thawed agent's
    # first commands may reach the server before its token is seen back (CI once drove robot 6 a few
    # ticks before the server's "back"), so "back" does not bound it.
    acted_tick = {e["robot"]: e["tick"] for e in events if e["kind"] in ("restart_agent", "resume_agent")}
    for robot in (0, 6):
        still = min(back_tick[robot], acted_tick[robot] - 1)
        assert np.all(wheels[gone_tick[robot] + 1 : still, robot] == 0.0), robot
        assert np.any(wheels[back_tick[robot] :, robot] != 0.0)

    records = agent_records(out)
    assert records[0]["pid"] == restart["pid"] and 0 < records[0]["ticks"] < steps
    assert records[0]["queries"] == [f"swarm/{records[0]['run']}/config/0"]  # fetched its config again
    assert (out / "logs" / "replaced" / f"agent_0_pid{restart['old_pid']}.json").is_file()
    assert records[6]["ticks"] < steps and records[6]["sim_lost"] >= 1  # lost the sim while frozen
    assert {records[i]["exit_reason"] for i in (0, 1, 2, 4, 5, 6, 7)} == {"sim gone"}
    assert records[2]["messages"]["lost"] > 0 and records[4]["messages"]["lost"] > 0  # 3's neighbours

    # The seven live robots (a line once robot 3 is gone) gather.
    _, poses, _ = read_trajectory(out / "trajectory.jsonl")
    live = [i for i in range(8) if i != 3]
    spread = metrics.max_pairwise(poses[:, live, :2])
    assert spread[-1] <= scenario.threshold < spread[0]
    # metrics.json judges the run on the live robots (swarm.scenarios.fault_results) and lists the events.
    outcome = json.loads((out / "metrics.json").read_text())
    assert outcome["faults"]["events"] == events
    assert outcome["faults"]["agents_lost"] == [3] and outcome["faults"]["agents_restarted"] == [0]
    assert outcome["faults"]["live_robots"] == live and outcome["converged"] is True

    # The printed summary names what happened; the plot draws the live robots' metric over the faded
    # all-robot curve and marks every fault where the runner did it (plot data read from its artists).
    assert "kill_agent robot 3 at 1.50 s" in stdout and "restart_agent robot 0 at 2.50 s" in stdout
    assert "hang_agent robot 6 at 2.00 s" in stdout
    assert "agents lost (killed, not restarted): robots [3]" in stdout
    assert "agents restarted: robots [0]" in stdout
    assert f"converged (live robots {live})" in stdout
    plot = json.loads((out / "convergence.png.json").read_text())
    lines = {line["gid"]: line for line in plot["lines"]}
    times_s = np.asarray(lines["judged"]["x"])
    assert np.allclose(lines["judged"]["y"], max_pairwise_of(poses[:, live]), atol=1e-5)
    assert str(live) in lines["judged"]["label"]
    assert np.allclose(lines["all_robots"]["y"], max_pairwise_of(poses), atol=1e-5)
    assert lines["all_robots"]["alpha"] < 0.5
    for event in events:
        mark = lines[f"fault:{event['kind']} robot {event['robot']}"]
        assert mark["x"] == [pytest.approx(event["tick"] * dt)] * 2
    assert lines["converged"]["x"][0] == pytest.approx(outcome["convergence_time_s"])
    # ... and the MCAP recording holds every tick, the applied commands and the faults.
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    recorded: dict[str, list] = {}
    with open(out / "recording.mcap", "rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        for _, channel, _, decoded in reader.iter_decoded_messages():
            recorded.setdefault(channel.topic, []).append(decoded)
    assert len(recorded["/robots/poses"]) == len(times_s) == steps + 1
    assert [p.position.x for p in recorded["/robots/poses"][-1].poses] == pytest.approx(poses[-1, :, 0])
    wheels = wheels_by_tick(out)
    speeds = [msg.twist.linear.x for msg in recorded["/robot_1/cmd_vel"]]
    assert len(speeds) == len(wheels) + 1 and speeds[-1] == 0.0  # the last tick applies nothing
    assert np.allclose(speeds[:-1], 0.5 * (wheels[:, 1, 0] + wheels[:, 1, 1]), atol=1e-12)
    assert [json.loads(msg.data)["label"] for msg in recorded["/faults"]] == [
        f"{e['kind']} robot {e['robot']}" for e in events
    ]


@pytest.mark.runtime
def test_kill_server_fault_ends_the_run_and_the_agents_exit_cleanly(tmp_path):
    path, scenario = fault_scenario(tmp_path, "kill-server", duration=30.0)
    out = tmp_path / "out"
    run = Run(path, out)
    code, _, stderr = run.finish()
    assert code == 1
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and "run incomplete" in lines[0] and "kill_server" in lines[0], stderr
    assert run.survivors() == []

    (event,) = read_events(out)
    assert event["kind"] == "kill_server" and event["robot"] is None and event["at_s"] == 3.0
    records = agent_records(out)
    assert len(records) == 8
    assert {record["exit_reason"] for record in records.values()} == {"sim gone"}
    assert "8 agents ended" in (out / "logs" / "agents.log").read_text()  # every agent exited 0
    outcome = json.loads((out / "metrics.json").read_text())
    assert outcome["processes"]["agents_exit_status"] == 0
    times_s, _, _ = read_trajectory(out / "trajectory.jsonl")
    assert outcome["ticks"] == len(times_s) - 1 and len(times_s) <= event["tick"] + 2
    assert outcome["incomplete"] and outcome["ticks_planned"] == scenario.steps
    assert outcome["faults"]["server_killed"] is True and outcome["faults"]["events"] == [event]
    assert report(out).returncode == 1  # reads back, still incomplete


@pytest.mark.runtime
@pytest.mark.parametrize("victim", ["runner", "server", "agent"])
def test_a_process_killed_at_a_random_moment_leaves_a_readable_results_directory(tmp_path, victim):
    rng = np.random.default_rng({"runner": 11, "server": 12, "agent": 13}[victim])
    kill_tick = int(rng.integers(5, 120))
    path, scenario = fault_scenario(tmp_path, "kill-agent", duration=8.0, server_lost_s=1.0, faults=[])
    out = tmp_path / "out"
    run = Run(path, out)
    run.wait_for(lambda: run.ticks() >= kill_tick and len(agent_records(out)) == 8)
    run.watch()
    assert len(run.seen) >= 10  # server, launcher, 8 agents
    children = psutil.Process(run.process.pid).children()
    if victim == "runner":
        run.process.kill()
    elif victim == "server":
        next(p for p in children if p.cmdline()[1:3] == ["-m", "sim_server"]).kill()
    else:
        psutil.Process(agent_records(out)[int(rng.integers(8))]["pid"]).send_signal(signal.SIGKILL)
    code, _, stderr = run.finish(timeout_s=60)
    assert run.survivors(grace_s=10.0) == []
    expected_code = {"runner": -signal.SIGKILL, "server": 1, "agent": 0}[victim]  # 1: ran, incomplete
    assert code == expected_code or (victim == "agent" and code == 1), stderr

    # Whatever is on disk reads back: the scenario, the trajectory up to its last complete line, the
    # logs, and `swarm report` re-creates metrics.json and the plots.
    # the copy records what the run resolved: access control on (sim.acl unset means on)
    resolved = scenario.model_copy(update={"sim": scenario.sim.model_copy(update={"acl": True})})
    assert load_scenario(out / "scenario.yaml") == resolved
    times_s, poses, _ = read_trajectory(out / "trajectory.jsonl")
    assert len(times_s) >= kill_tick and poses.shape[1:] == (8, 3)
    np.testing.assert_allclose(times_s, np.arange(len(times_s)) * scenario.sim.control_period_s)
    assert (out / "logs" / "sim_server.log").is_file() and len(agent_records(out)) == 8
    (out / "metrics.json").unlink(missing_ok=True)
    (out / "convergence.png").unlink(missing_ok=True)
    result = report(out)
    assert result.returncode in (0, 1), result.stderr
    outcome = json.loads((out / "metrics.json").read_text())
    assert outcome["ticks"] == len(times_s) - 1 and (out / "convergence.png").is_file()
    assert ("incomplete" in outcome) == (len(times_s) < scenario.steps + 1)
    if victim == "server":
        assert "sim server exited" in stderr
        assert {record["exit_reason"] for record in agent_records(out).values()} == {"sim gone"}


def test_trajectory_reader_skips_a_torn_last_line(tmp_path):
    """Cut a trajectory at random (seeded) byte offsets, as a kill mid-write would."""
    lines = [
        json.dumps({"tick": k, "time_s": 0.05 * k, "poses": [[k, 0.5, 0.25]] * 3}) + "\n" for k in range(6)
    ]
    text = "".join(lines).encode()
    ends = np.cumsum([len(line) for line in lines])
    for cut in np.random.default_rng(5).integers(0, len(text) + 1, size=40):
        path = tmp_path / "trajectory.jsonl"
        path.write_bytes(text[:cut])
        times_s, poses, _ = read_trajectory(path)
        complete = int(np.sum(ends <= cut + 1))  # a line missing only its newline is complete
        assert len(times_s) == complete and poses.shape == ((complete, 3, 3) if complete else (0, 0, 3))


BATCHING_WRITER = """
import os, signal, sys, time
import numpy as np
from swarm.scenarios.results import TrajectoryWriter
flush_every_s, batched = float(sys.argv[2]), int(sys.argv[3])
writer = TrajectoryWriter(__import__("pathlib").Path(sys.argv[1]), flush_every_s)
for k in range(batched):
    writer.write(k, 0.05 * k, np.full((3, 3), float(k)))
writer.flush()
for k in range(batched, batched + 7):  # batched in memory, never written: lost with the process
    writer.write(k, 0.05 * k, np.full((3, 3), float(k)))
os.kill(os.getpid(), signal.SIGKILL)
"""


@pytest.mark.parametrize("flush_every_s", [0.0, 3600.0])
def test_a_killed_batching_trajectory_writer_leaves_every_line_up_to_its_last_batch(tmp_path, flush_every_s):
    """The server batches trajectory lines (``TrajectoryWriter(flush_every_s)``): a writer SIGKILLed
    with lines still batched leaves a readable file of every line up to the last batch written; with
    no batching (0 s: the default, and with process faults) every line written is on disk."""
    path = tmp_path / "trajectory.jsonl"
    result = subprocess.run(
        [sys.executable, "-c", BATCHING_WRITER, str(path), str(flush_every_s), "20"],
        cwd=PROJECT_ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == -signal.SIGKILL, result.stderr
    times_s, poses, _ = read_trajectory(path)
    expected = 20 if flush_every_s > 0 else 27
    assert len(times_s) == expected and poses.shape == (expected, 3, 3)
    np.testing.assert_allclose(poses[:, 0, 0], np.arange(expected))
