"""The sim's radio (``sim_server.radio``): who hears whom on a disk graph in the PyBullet runtime.

Oracles: the kinematic engine's own rule, read from what its robots actually received (every message
names its sender and tick), on moving robots under packet loss, a delay and a dropped link; and, in a
real run (sim server and agent processes, real Zenoh sessions), an outside client (``tests/outside.py``,
no project code) that records every inbox the server sends, checked against the distances of the
poses in the server's own trajectory file.
"""

from __future__ import annotations

import json
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import msgpack
import numpy as np
import pytest
import yaml

from sim_server.radio import Radio
from swarm.core.faults import LinkFaults
from swarm.core.robot import RobotParams
from swarm.sim.kinematic import KinematicSim

PROJECT_ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(PROJECT_ROOT / "tests"))

import outside  # noqa: E402

DT = 0.05


class _Tagged:
    """A controller whose message is ``(sender, tick)`` and that records, per tick, what each robot
    heard, read from the message values themselves; robots drive at fixed random velocities."""

    message_dim = 2
    centralized = False

    def __init__(self, velocities: np.ndarray):
        self.velocities = velocities
        self.tick = 0
        self.heard: list[list[set[tuple[int, int]]]] = []

    def act(self, poses, points, inbox, heard):
        count = poses.shape[1]
        got = []
        for i in range(count):
            columns = heard.index[0, i]
            got.append({(int(inbox[0, c, 0]), int(inbox[0, c, 1])) for c in columns if c >= 0})
        self.heard.append(got)
        outbox = np.stack([np.arange(count), np.full(count, self.tick)], -1)[None].astype(np.float64)
        self.tick += 1
        return self.velocities[None], outbox


@pytest.mark.parametrize("seed", range(3))
def test_the_radio_relays_what_the_kinematic_engine_delivers(seed):
    rng = np.random.default_rng(seed)
    count, radius_m, ticks, max_age = 7, 1.2, 120, 3
    poses = np.concatenate([rng.uniform(-1.5, 1.5, (count, 2)), rng.uniform(-3, 3, (count, 1))], -1)
    velocities = rng.uniform(-0.4, 0.4, (count, 2))
    poses[3, :2], velocities[3] = poses[2, :2] + [0.3, 0.0], velocities[2]  # the dropped link is in range
    faults_list = [
        {"kind": "packet_loss", "p": 0.3},
        {"kind": "delay", "ticks": 2, "link": [0, 1], "at_s": 1.0, "until_s": 3.0},
        {"kind": "drop_link", "link": [2, 3], "at_s": 0.5},
    ]
    faults = LinkFaults(faults_list, DT, seed=seed)
    controller = _Tagged(velocities)
    sim = KinematicSim(
        RobotParams(),
        controller,
        DT,
        poses[None],
        disk_radius_m=radius_m,
        link_faults=faults,
        message_max_age_ticks=max_age,
    )
    radio = Radio(count, radius_m, faults, max_age)
    totals = np.zeros(4, dtype=int)
    changed_graph = False
    for tick in range(ticks):
        axles = sim.poses[0, :, :2].copy()
        sim.step()  # the robots act on tick `tick`'s inbox, then move
        for i in range(count):
            senders, messages, counts = radio.inbox(i, tick)
            relayed = {(int(m[0]), int(m[1])) for m in messages}
            assert relayed == controller.heard[tick][i], (tick, i)
            assert [m[0] for m in messages] == senders
            totals += counts
        before = None if tick == 0 else radio.links[tick - 1].copy()
        radio.positions(tick, axles)
        changed_graph |= before is not None and not np.array_equal(before, radio.links[tick])
        for j in range(count):
            radio.offer(j, tick, np.array([j, tick], dtype=np.float64))
    assert changed_graph  # the robots moved through each other's range
    kinematic = sim.fault_counts
    assert totals[:3].tolist() == [
        kinematic["dropped_by_fault"],
        kinematic["lost_by_fault"],
        kinematic["delayed_by_fault"],
    ]
    assert totals[3] == 0 and kinematic["lost_by_fault"] > 0 and kinematic["dropped_by_fault"] > 0


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


@pytest.mark.runtime
def test_each_agent_hears_exactly_the_robots_in_range_in_a_real_run(tmp_path):
    """Six robots in a chain 1 m apart on a disk graph of 1.2 m, gathering (``mec_flood``): the outside
    client's record of every inbox must name, for tick k, exactly the robots within 1.2 m of the
    receiver at tick k-1 in ``trajectory.jsonl``; each hears one or two at first, all five later."""
    count, radius_m, run = 6, 1.2, "radio"
    starts = [[x, 0.0, 0.0] for x in (-2.5, -1.5, -0.5, 0.5, 1.5, 2.5)]  # a chain, 1 m apart
    data = {
        "name": "radio",
        "robots": {"count": count, "init": {"poses": starts}},
        "topology": {"kind": "disk", "radius_m": radius_m},
        "controller": {"kind": "mec_flood"},
        "sim": {"engine": "pybullet", "duration_s": 6.0},
        "success": {"threshold": 1.5},
    }
    scenario = tmp_path / "radio.yaml"
    scenario.write_text(yaml.safe_dump(data))
    endpoint, out = f"tcp/127.0.0.1:{_free_port()}", tmp_path / "out"
    python = sys.executable
    command = [python, "-m", "sim_server", "--scenario", str(scenario), "--out", str(out), "--run", run]
    server = subprocess.Popen(
        [*command, "--listen", endpoint, "--quiet"],
        cwd=PROJECT_ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    inboxes: dict[tuple[int, int], list[int]] = {}
    session = outside.open_session(endpoint)

    def record(sample) -> None:
        robot = int(str(sample.key_expr).split("/")[-2])
        body = msgpack.unpackb(sample.payload.to_bytes(), raw=False)  # documented: {"k", "s", ...}
        inboxes[(robot, int(body["k"]))] = [int(j) for j in body["s"]]

    subscriber = session.declare_subscriber(f"swarm/{run}/robot/*/inbox", record)
    agents = subprocess.Popen(
        [python, "-m", "robot_agent", "--robots", f"0-{count - 1}", "--connect", endpoint, "--run", run],
        cwd=PROJECT_ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        server.communicate(timeout=300)
        agents.communicate(timeout=120)
    finally:
        for process in (server, agents):
            if process.poll() is None:
                process.send_signal(signal.SIGTERM)
                process.communicate(timeout=60)
        time.sleep(0.2)
        subscriber.undeclare()
        session.close()
    assert server.returncode == 0 and agents.returncode == 0, (server.stderr, agents.stderr)
    lines = (out / "trajectory.jsonl").read_text().splitlines()
    axles = {line["tick"]: np.array(line["poses"])[:, :2] for line in map(json.loads, lines)}
    ticks = round(6.0 / 0.05)
    assert len(inboxes) == count * ticks  # every robot, every tick: none lost on the way out
    sizes = set()
    for (robot, tick), senders in inboxes.items():
        if tick == 0:
            assert senders == []  # nothing was sent before tick 0
            continue
        gaps = np.linalg.norm(axles[tick - 1] - axles[tick - 1][robot], axis=1)
        assert not np.any(np.abs(gaps - radius_m) < 1e-9)  # no pair on the boundary: the rule is exact
        in_range = [j for j in range(count) if j != robot and gaps[j] <= radius_m]
        assert senders == in_range, (robot, tick)
        sizes.add(len(senders))
    assert min(sizes) == 1 and max(sizes) == count - 1  # the chain's ends at first, everyone later
