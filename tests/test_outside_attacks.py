"""The outside attacks of the open mode (no access control), each against a real 6-robot lockstep run.

An outside client that imports none of the project's code (``tests/outside.py attack``) joins the run
beside it and attacks it one way; the run is started as a user starts it (``swarm run``: its run key
authenticates every pose, message, command and configuration, swarm.runtime.wire.RunKey). Each attack
must change nothing (the trajectory, poses and applied wheels of every tick, equals that of the clean
run: lockstep is deterministic) and be named in the receivers' counters, or, where it cannot change
nothing (a dead agent's token held by someone else), it must be named in the server's stats and stall
the swarm for no more than a few ticks.
"""

from __future__ import annotations

import json
import os
import secrets
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
import swarm_run
import yaml

pytestmark = pytest.mark.runtime

PROJECT_ROOT = Path(__file__).resolve().parent.parent
OUTSIDE = PROJECT_ROOT / "tests" / "outside.py"
COUNT = 6
DURATION_S = 5.0
STEPS = round(DURATION_S / 0.05)
AT_TICK = 20
HUNG_AFTER_DEADLINES = 3  # sim_server.server's (this test imports no project code)


def _scenario(tmp_path: Path, name: str = "open", **sim) -> Path:
    data = yaml.safe_load((PROJECT_ROOT / "scenarios/thesis/cycle-local_consensus.yaml").read_text())
    data["robots"]["count"] = COUNT
    # A deadline no loaded machine misses: a tick then waits only for what never comes.
    data["sim"].update(duration=DURATION_S, acl=False, deadline=3.0, neighbour_deadline=3.0)
    data["sim"].update(sim)
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def _attacker(out: Path, kind: str, *options: str, log: Path | None = None) -> list[str]:
    where = ["--server-log", str(log or out / "logs" / "sim_server.log")]
    return [sys.executable, str(OUTSIDE), "attack", "--kind", kind, *where, *options]


def _run(scenario: Path, out: Path, attack: list[str] | None = None) -> tuple[dict | None, list]:
    """``swarm run`` with the attacker beside it; (what the attacker sent, the trajectory lines)."""
    run = swarm_run.start(scenario, out)
    report = None
    try:
        if attack is not None:
            sent = out.parent / f"{out.name}-sent.json"
            attacker = subprocess.run(
                [*attack, "--out", str(sent)], capture_output=True, text=True, timeout=300
            )
            assert attacker.returncode == 0, attacker.stderr
            report = json.loads(sent.read_text())
        _, stderr = run.communicate(timeout=300)
    finally:
        if run.poll() is None:
            run.kill()
    assert run.returncode in (0, 1), stderr
    lines = [json.loads(line) for line in (out / "trajectory.jsonl").read_text().splitlines()]
    return report, lines


def _records(out: Path) -> dict[int, dict]:
    paths = (out / "logs").glob("agent_*.json")
    return {int(path.stem.split("_")[1]): json.loads(path.read_text()) for path in paths}


def _same_trajectory(a: list, b: list) -> None:
    assert len(a) == len(b) == STEPS + 1
    for line_a, line_b in zip(a, b, strict=True):
        assert line_a["tick"] == line_b["tick"]
        assert line_a["poses"] == line_b["poses"], line_a["tick"]
        assert line_a.get("wheels") == line_b.get("wheels"), line_a["tick"]


LATE_TICKS = 20
"""An attacker whose puts the router took (its flush query answered) this near the end or later may have
sent to agents that had left: its samples are then counted at most, not exactly."""


def _delivered(report: dict) -> bool:
    """Every put was with the router while the agents had ``LATE_TICKS`` ticks left to read it
    (``flushed_tick`` of tests/outside.py): what the test expects counted must then be counted."""
    return report["flushed_tick"] is not None and report["flushed_tick"] < STEPS - LATE_TICKS


def _accounted(stream: dict) -> int:
    """Every sample an agent read from a receive ring, by what became of it."""
    names = ("received", "unauthenticated", "invalid", "old", "future")
    return sum(stream[name] for name in names)


@pytest.fixture(scope="module")
def clean(tmp_path_factory) -> list:
    tmp_path = tmp_path_factory.mktemp("clean")
    _, first = _run(_scenario(tmp_path), tmp_path / "first")
    return first


def test_two_clean_lockstep_runs_are_bit_identical(clean, tmp_path):
    _, second = _run(_scenario(tmp_path), tmp_path / "second")
    _same_trajectory(clean, second)


@pytest.mark.parametrize("kind", ["future2", "near"])
def test_forged_poses_on_the_wildcard_change_nothing(clean, tmp_path, kind):
    """Two poses 10^6 ticks ahead (which froze every robot for the rest of the run), or dated +1/+2
    (which were accepted as genuine, and the genuine ones counted old)."""
    out = tmp_path / kind
    report, lines = _run(_scenario(tmp_path), out, _attacker(out, kind, "--at-tick", str(AT_TICK)))
    assert report is not None and report["sent"] == 2
    _same_trajectory(clean, lines)
    for i, agent in _records(out).items():
        poses = agent["poses"]
        # named, not blamed on the genuine ones (all of them, unless the attacker was starved to the end)
        assert poses["unauthenticated"] == 2 if _delivered(report) else poses["unauthenticated"] <= 2, (
            i,
            poses,
        )
        assert poses["old"] == poses["future"] == poses["jumps"] == poses["recovered"] == 0, (i, poses)
        assert agent["ticks"] == STEPS, i  # nobody froze
        assert _accounted(poses) == poses["taken"], (i, poses)


def test_a_burst_of_forty_poses_does_not_walk_the_clock(clean, tmp_path):
    out = tmp_path / "walk"
    attack = _attacker(out, "walk", "--robot", "5", "--at-tick", str(AT_TICK))
    report, lines = _run(_scenario(tmp_path), out, attack)
    assert report is not None and report["sent"] == 40
    _same_trajectory(clean, lines)
    poses = _records(out)[5]["poses"]
    forged = poses["unauthenticated"]
    assert forged == 40 if _delivered(report) else forged <= 40, (poses, report)
    assert poses["old"] == 0 and poses["jumps"] == 0, poses
    assert _accounted(poses) == poses["taken"], poses


def test_a_same_tick_message_replay_does_not_overwrite_the_genuine_one(clean, tmp_path):
    """Every message of agent 2 of ticks 20 ... 39 is put again the moment the attacker sees it (so most
    copies come before the sender's next message, whatever the load), unchanged and with other values
    under the genuine tag: each copy is counted old, each altered one unauthenticated, and every
    genuine message is still taken. The attacker copies no message of a later tick: a starved one
    once replayed what its ring still held after the run had ended, which no agent was there to count."""
    out = tmp_path / "replay"
    attack = _attacker(out, "replay", "--robot", "2", "--at-tick", str(AT_TICK), "--ticks", "20")
    report, lines = _run(_scenario(tmp_path), out, attack)
    assert report is not None and report["copies"] >= 1 and report["sent"] == 2 * report["copies"]
    assert all(AT_TICK <= tick < AT_TICK + 20 for tick in report["copied_ticks"]), report
    _same_trajectory(clean, lines)
    records = _records(out)
    for i in (1, 3):  # agent 2's neighbours on the cycle: the copy is old, the altered one forged
        messages = records[i]["messages"]
        copies = report["copies"]
        if _delivered(report):
            assert messages["old"] == copies and messages["unauthenticated"] == copies, (i, messages, report)
        else:  # a starved attacker's last copies may have come after the agents left
            assert messages["old"] <= copies and messages["unauthenticated"] <= copies, (i, messages, report)
        assert _accounted(messages) == messages["taken"], (i, messages)
        # what i's two neighbours sent, counted by the senders: all of it taken (or come after the end)
        genuine = sum(records[j]["commands_sent"] for j in ((i - 1) % COUNT, (i + 1) % COUNT))
        assert messages["received"] + messages["unread"] == genuine, (i, messages, genuine)


FLOOD = 6000
"""Forged samples a flood test sends: under the agents' ring size (8192, robot_agent.agent), with
room for the genuine ones that arrive meanwhile."""


@pytest.mark.parametrize(
    ("kind", "robot", "stream"), [("flood-pose", 5, "poses"), ("flood-msg", 2, "messages")]
)
def test_a_flood_pushes_no_genuine_sample_out(clean, tmp_path, kind, robot, stream):
    """Forged samples at 12,000 per second on one key for 60 ticks, at most 6000: every one is read and
    named, every genuine one taken and nothing changed. The agents' rings hold 8192 samples, so this
    holds however starved the receiver is during the flood (the rings of 16 of before lost genuine
    ones within 2 ms); the oracle is the count of what was sent, never the machine's speed."""
    out = tmp_path / kind
    attack = _attacker(
        out,
        kind,
        "--robot",
        str(robot),
        "--at-tick",
        str(AT_TICK),
        "--ticks",
        str(STEPS // 2 - AT_TICK),  # done by mid-run: the rest of the run drains what it sent
        "--most",
        str(FLOOD),
    )
    report, lines = _run(_scenario(tmp_path), out, attack)
    assert report is not None and 0 < report["sent"] <= FLOOD  # however many it managed: the oracle
    records = _records(out)
    receivers = [robot] if stream == "poses" else [(robot - 1) % COUNT, (robot + 1) % COUNT]
    for i in receivers:
        counted = records[i][stream]
        assert _accounted(counted) == counted["taken"], (i, counted)  # every sample read is named
        assert counted["ring_full"] == 0, (i, counted)  # no drain found its ring full: none pushed out
        senders = [(i - 1) % COUNT, (i + 1) % COUNT]  # the cycle: what i's neighbours sent
        genuine = sum(records[j]["commands_sent"] for j in senders) if stream == "messages" else STEPS
        # every sample that was put is accounted for: named when read, or still queued when the agent
        # left (a loaded machine delivers the flood's tail late; an unloaded one reads it all)
        assert counted["unauthenticated"] <= report["sent"] and counted["received"] <= genuine, (i, counted)
        total = counted["unauthenticated"] + counted["received"] + counted["unread"]
        assert total == report["sent"] + genuine, (i, counted, report, genuine)
    _same_trajectory(clean, lines)
    for i, agent in records.items():
        assert agent["ticks"] == STEPS, i


KILL_TICK = 20
"""The zombie test kills agent 3 at this tick (1.0 s)."""


def test_a_zombie_token_stalls_the_swarm_for_a_few_deadlines_only(tmp_path):
    """Agent 3 is killed at tick 20 while an outsider holds a token on its key: the server waits
    ``HUNG_AFTER_DEADLINES`` deadlines, names robot 3 hung and goes on without waiting for it; so do
    robot 3's neighbours (they see the token too), within the server's deadline (the defaults)."""
    data = yaml.safe_load(_scenario(tmp_path, deadline=1.0, neighbour_deadline=0.5).read_text())
    data["faults"] = [{"at": KILL_TICK * 0.05, "kind": "kill_agent", "robot": 3}]
    scenario = tmp_path / "zombie.yaml"
    scenario.write_text(yaml.safe_dump(data))
    out = tmp_path / "zombie"
    run = swarm_run.start(scenario, out)
    try:
        attacker = subprocess.Popen(
            [*_attacker(out, "zombie", "--robot", "3", "--at-tick", "0"), "--out", str(tmp_path / "z.json")],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
        )
        _, stderr = run.communicate(timeout=300)
        assert run.returncode in (0, 1), stderr
        assert attacker.wait(timeout=60) == 0, attacker.stderr.read() if attacker.stderr else ""
    finally:
        for process in (run, attacker):
            if process.poll() is None:
                process.kill()
    stats = json.loads((out / "server_stats.json").read_text())
    events = [(e["robot"], e["event"]) for e in stats["agent_events"]]
    gone = (3, "gone") in events
    if not gone:  # the zombie kept robot 3 "alive": the server found it hung, once, and said so
        assert events.count((3, "hung")) == 1, events
        assert stats["per_robot"][3]["hung_at_s"], stats["per_robot"][3]
    # either way the run went on: only the ticks before it was found hung waited for robot 3
    # a tick missed is one some expected command missed: robot 3's at most until it was found hung (and
    # any it sent late before it was killed), the others' (a loaded machine) each counted by the server
    missed = stats["missed_commands_by_robot"]
    others = sum(n for j, n in enumerate(missed) if j != 3)
    late_before_kill = max(0, missed[3] - (STEPS - KILL_TICK)) if not gone else missed[3]
    allowed = HUNG_AFTER_DEADLINES + 1 + others + late_before_kill
    assert stats["ticks_missed"] <= allowed, (stats["ticks_missed"], missed, events)
    if not gone:  # found hung within HUNG_AFTER_DEADLINES ticks of its death
        hung_tick = next(e["tick"] for e in stats["agent_events"] if (e["robot"], e["event"]) == (3, "hung"))
        # its death: the runner's kill, between the trajectory lines on disk when it looked (`tick`)
        # and right after its SIGKILL (`done_tick`; the server's tick then, or one more): a loaded
        # runner acts a few ticks after the scheduled one, and may be descheduled between the two
        (kill,) = [json.loads(line) for line in (out / "events.jsonl").read_text().splitlines()]
        assert (kill["kind"], kill["robot"]) == ("kill_agent", 3) and kill["tick"] >= KILL_TICK, kill
        assert kill["tick"] - 1 <= hung_tick <= kill["done_tick"] + HUNG_AFTER_DEADLINES + 1, (
            hung_tick,
            kill,
            events,
        )
    assert [robot for robot, event in events if event == "hung"] in ([3], []), events  # nobody else
    records = _records(out)
    for i in (2, 4):
        if not gone:
            assert [e["robot"] for e in records[i]["neighbour_events"]] == [3], records[i]["neighbour_events"]
    assert len((out / "trajectory.jsonl").read_text().splitlines()) == STEPS + 1


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def _standalone(tmp_path: Path, name: str, spoof: bool) -> tuple[list, dict[int, dict]]:
    """The sim server and the agents started by hand (as docs/distributed-runtime.md shows), with a
    run key; with ``spoof`` a config queryable answering gain -1 is up before the agents start."""
    scenario, out = _scenario(tmp_path, name), tmp_path / name
    endpoint, run_id = f"tcp/127.0.0.1:{_free_port()}", f"spoof-{secrets.token_hex(4)}"
    env = {**os.environ, "SWARM_RUN_KEY": secrets.token_hex(32), "PYTHONPATH": str(PROJECT_ROOT)}
    (out / "logs").mkdir(parents=True)
    server_log = out / "logs" / "sim_server.log"
    server = subprocess.Popen(
        [
            *(sys.executable, "-m", "sim_server", "--scenario", str(scenario), "--out", str(out)),
            *("--run", run_id, "--listen", endpoint, "--no-report"),
        ],
        stdout=server_log.open("w"),
        stderr=subprocess.STDOUT,
        cwd=PROJECT_ROOT,
        env=env,
    )
    processes = [server]
    try:
        if spoof:
            ready = tmp_path / f"{name}.ready"
            command = _attacker(out, "config", "--count", str(COUNT), "--ready", str(ready))
            processes.append(
                subprocess.Popen([*command, "--out", str(tmp_path / "c.json")], cwd=PROJECT_ROOT)
            )
            give_up_s = time.monotonic() + 120
            while not ready.exists():
                assert time.monotonic() < give_up_s and processes[-1].poll() is None, "no spoofer"
                time.sleep(0.05)
        agents = subprocess.run(
            [
                *(sys.executable, "-m", "robot_agent", "--robots", f"0-{COUNT - 1}", "--connect", endpoint),
                *("--run", run_id, "--log-dir", str(out / "logs")),
            ],
            capture_output=True,
            text=True,
            cwd=PROJECT_ROOT,
            env=env,
            timeout=300,
        )
        assert server.wait(timeout=120) == 0, server_log.read_text()
        assert agents.returncode == 0, agents.stderr
    finally:
        for process in processes:
            if process.poll() is None:
                process.kill()
    lines = [json.loads(line) for line in (out / "trajectory.jsonl").read_text().splitlines()]
    return lines, _records(out)


def test_an_agent_takes_its_configuration_only_from_its_sim(tmp_path):
    clean, _ = _standalone(tmp_path, "config-clean", spoof=False)
    spoofed, records = _standalone(tmp_path, "config-spoofed", spoof=True)
    _same_trajectory(clean, spoofed)  # gain -1 would have dispersed the swarm
    for i, agent in records.items():
        assert agent["config_source"] == "sim (run-key tag checked)", (i, agent["config_source"])
        assert agent["config_rejected"] >= 1, i  # the spoofer's answer came (every reply is read), refused
