"""Enforced decentralization (``sim.acl``, swarm/runtime/acl.py): Zenoh access control generated from the
graph.

The rules and credentials are checked as data; then a real run with access control on (sim server,
one agent process per robot, real Zenoh sessions) must converge while a rogue process, authenticated
as robot K with K's real credentials, tries everything an agent could try: subscribe to the whole run
(data and liveliness), subscribe to every robot's keys one by one, query every robot's configuration,
and put commands, poses and messages on other robots' keys. It must receive exactly robot K's
neighbourhood and nothing else, and nothing it puts outside its own keys may reach anyone (the server's
counters and trajectory, the agents' counters). Clients with a wrong password cannot connect at all.

The rogue is this file run as a script (``python tests/test_acl.py ...``): its own OS process.
"""

from __future__ import annotations

import argparse
import json
import re
import stat
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

PROJECT_ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(PROJECT_ROOT))

import outside  # noqa: E402
import swarm_run  # noqa: E402

from swarm.core.graphs import line  # noqa: E402
from swarm.runtime import acl, wire  # noqa: E402 (after the path, for the script)

ROGUE_WHEELS = (0.4321, -0.4321)
"""Wheel speeds the rogue puts on other robots' command keys: they must never show in the trajectory."""
FUTURE_TICK = 2**39
"""The rogue's commands on its own key carry this tick; without the run key they carry no valid tag:
the server counts them as unauthenticated (the proof that its puts do reach the server where they
are allowed) and never applies them."""


# ----------------------------------------------------------------------------- rules and credentials


def _keys_of(rules: list[dict], flow: str, message: str) -> set[str]:
    return {
        key
        for rule in rules
        if flow in rule["flows"] and message in rule["messages"]
        for key in rule["key_exprs"]
    }


def test_each_robot_is_allowed_its_own_keys_and_its_neighbours_only():
    keys = wire.Keys("r1")
    block = acl.access_control(keys, line(4))
    assert block["enabled"] is True and block["default_permission"] == "deny"
    assert [subject["usernames"] for subject in block["subjects"]] == [[f"robot-{i}"] for i in range(4)]
    rules = {rule["id"]: rule for rule in block["rules"]}
    assert all(rule["permission"] == "allow" and len(rule["flows"]) == 1 for rule in rules.values())
    policy = next(policy for policy in block["policies"] if policy["subjects"] == ["robot-1"])
    mine = [rules[name] for name in policy["rules"]]
    heard = {keys.pose(1), keys.sense(1), keys.inbox(1), keys.msg(0), keys.msg(2)}
    assert _keys_of(mine, "ingress", "declare_subscriber") == heard
    assert _keys_of(mine, "egress", "put") == heard
    assert _keys_of(mine, "ingress", "put") == {keys.cmd(1), keys.msg(1)}
    assert _keys_of(mine, "ingress", "liveliness_token") == {keys.alive_agent(1)}
    watched = {keys.alive_sim, keys.alive_agent(0), keys.alive_agent(2)}
    assert _keys_of(mine, "ingress", "declare_liveliness_subscriber") == watched
    assert _keys_of(mine, "egress", "liveliness_token") == watched
    assert _keys_of(mine, "ingress", "query") == {keys.config(1), "swarm/*/config/1"}
    assert _keys_of(mine, "egress", "reply") == {keys.config(1)}
    assert _keys_of(mine, "egress", "declare_subscriber") == {
        keys.all_cmds,
        keys.all_msgs,
        keys.cmd(1),
        keys.msg(1),
    }
    text = json.dumps(mine)  # robot 3 is two hops away: no key of it
    assert not re.search(r"/3(/|\")", text), text


def test_on_a_disk_graph_a_robot_hears_no_message_key_only_its_radio_inbox():
    """A disk graph (the sim's radio, ``sim_server.radio``): no robot may subscribe to any other robot's
    message or liveliness token; it hears its own pose, sensor reading and radio inbox."""
    keys = wire.Keys("r1")
    block = acl.access_control(keys, [[0.0] * 4 for _ in range(4)])
    rules = {rule["id"]: rule for rule in block["rules"]}
    for robot in range(4):
        policy = next(policy for policy in block["policies"] if policy["subjects"] == [f"robot-{robot}"])
        mine = [rules[name] for name in policy["rules"]]
        heard = {keys.pose(robot), keys.sense(robot), keys.inbox(robot)}
        assert _keys_of(mine, "ingress", "declare_subscriber") == heard
        assert _keys_of(mine, "egress", "put") == heard
        assert _keys_of(mine, "ingress", "declare_liveliness_subscriber") == {keys.alive_sim}
    assert not any(key.endswith("/**") for rule in mine for key in rule["key_exprs"])


def test_credentials_are_private_random_and_per_robot(tmp_path):
    users, per_robot = acl.write_credentials(tmp_path / "credentials", 3)
    directory = users.parent
    assert stat.S_IMODE(directory.stat().st_mode) == 0o700
    files = [users, *(Path(per_robot.replace("{robot}", str(i))) for i in range(3))]
    assert all(stat.S_IMODE(path.stat().st_mode) == 0o600 for path in files)
    lines = users.read_text().splitlines()
    assert [line.split(":")[0] for line in lines] == ["robot-0", "robot-1", "robot-2"]
    assert len({line.split(":")[1] for line in lines}) == 3  # a password each
    for i in range(3):
        assert acl.read_credentials(per_robot, i) == tuple(lines[i].split(":"))
        assert acl.read_credentials(users, i) == tuple(lines[i].split(":"))  # its line of several
    again, _ = acl.write_credentials(tmp_path / "credentials", 3)
    assert again.read_text() != "\n".join(lines) + "\n"  # fresh passwords every time


@pytest.mark.parametrize(
    ("content", "reason"),
    [
        (None, "no such credentials file"),
        ("justtext\n", "user:password"),
        ("robot-7:x\nrobot-8:y\n", "robot-1"),
    ],
)
def test_bad_credentials_file_is_one_clear_error(tmp_path, content, reason):
    path = tmp_path / "creds.txt"
    if content is not None:
        path.write_text(content)
    with pytest.raises(acl.CredentialsError, match=reason):
        acl.read_credentials(path, 1)


# ----------------------------------------------------------------------------- a real run and a rogue


def open_with_retries(config, deadline_s: float = 60.0):
    """``zenoh.open(config())``, retried until ``deadline_s`` from now: a loaded machine may refuse a
    connection for a moment ("Unable to connect"); the right credentials always get in eventually."""
    import zenoh

    give_up_s, delay_s = time.monotonic() + deadline_s, 0.05
    while True:
        try:
            return zenoh.open(config())
        except zenoh.ZError:
            if time.monotonic() + delay_s > give_up_s:
                raise
            time.sleep(delay_s)
            delay_s = min(2 * delay_s, 1.0)


def rogue(endpoint: str, run: str, robot: int, count: int, credentials: str, out: Path) -> None:
    """Robot ``robot``'s credentials in the wrong hands: try to see and touch everything; record what
    got through. Ends when the sim's token goes away."""
    import zenoh

    keys = wire.Keys(run)
    user, password = acl.read_credentials(credentials, robot)
    config = lambda: wire.session_config(  # noqa: E731
        "client", [endpoint], settings=acl.client_settings(user, password)
    )
    remote = zenoh.Locality.REMOTE
    got: dict[str, dict[str, int]] = {"wildcard": {}, "wildcard_alive": {}, "one_by_one": {}, "alive": {}}

    def counter(name: str):
        def count_sample(sample: zenoh.Sample) -> None:
            key = str(sample.key_expr)
            got[name][key] = got[name].get(key, 0) + 1

        return count_sample

    puts = {
        "own_future_commands": 0,
        "other_commands": 0,
        "other_poses": 0,
        "other_messages": 0,
        "other_readings": 0,
    }
    with (
        open_with_retries(config) as watcher,
        open_with_retries(config) as listener,
        open_with_retries(config) as writer,
    ):
        entities = [
            watcher.declare_subscriber(f"{keys.prefix}/**", counter("wildcard"), allowed_origin=remote),
            watcher.liveliness().declare_subscriber(
                f"{keys.prefix}/alive/**", counter("wildcard_alive"), history=True
            ),
        ]
        for i in range(count):
            for key in (keys.pose(i), keys.sense(i), keys.cmd(i), keys.msg(i)):
                entities.append(
                    listener.declare_subscriber(key, counter("one_by_one"), allowed_origin=remote)
                )
            entities.append(
                listener.liveliness().declare_subscriber(keys.alive_agent(i), counter("alive"), history=True)
            )
        sim_alive = listener.liveliness().declare_subscriber(
            keys.alive_sim, zenoh.handlers.RingChannel(8), history=True
        )
        own_pose = listener.declare_subscriber(
            keys.pose(robot), zenoh.handlers.RingChannel(8), allowed_origin=remote
        )

        def config_keys(i: int, timeout_s: float) -> list[str]:
            return [
                str(reply.ok.key_expr)
                for reply in listener.get(keys.config(i), timeout=timeout_s)
                if reply.ok is not None
            ]

        # its own config must answer: asked until it does (a loaded machine may answer late); the others'
        # are denied, and no amount of waiting turns a denial into an answer
        own_config, own_deadline_s = [], time.monotonic() + 60
        while not own_config and time.monotonic() < own_deadline_s:
            own_config = config_keys(robot, 5.0)
        others_configs = [key for i in range(count) if i != robot for key in config_keys(i, 1.0)]
        configs = sorted(own_config + others_configs)
        wildcard_configs = [
            str(reply.ok.key_expr)
            for reply in watcher.get(keys.all_configs, timeout=1.0)
            if reply.ok is not None
        ]
        others = [i for i in range(count) if i != robot]
        seen_sim, deadline_s = False, time.monotonic() + 120
        while time.monotonic() < deadline_s:
            event = sim_alive.try_recv()
            if event is not None:
                seen_sim = event.kind == zenoh.SampleKind.PUT
                got["alive"][str(event.key_expr)] = got["alive"].get(str(event.key_expr), 0) + 1
                if not seen_sim:
                    break  # the run is over
            sample = own_pose.try_recv()
            if sample is None:
                time.sleep(0.0005)
                continue
            pose = wire.decode_pose(sample.payload.to_bytes())
            if pose is None:
                continue
            writer.put(keys.cmd(robot), wire.encode_command(FUTURE_TICK, (0.0, 0.0)))
            puts["own_future_commands"] += 1
            for i in others:  # what a rogue robot would like to do to the others, at the current tick
                writer.put(keys.cmd(i), wire.encode_command(pose.tick, ROGUE_WHEELS))
                writer.put(keys.pose(i), wire.encode_pose(pose.tick + 1, pose.time_s, (40.0, 40.0, 0.0)))
                writer.put(keys.msg(i), wire.encode_message(pose.tick, (40.0, 40.0)))
                writer.put(keys.sense(i), wire.encode_sensing(pose.tick, np.zeros((0, 3)), np.zeros((0, 2))))
                puts["other_commands"] += 1
                puts["other_readings"] += 1
                puts["other_poses"] += 1
                puts["other_messages"] += 1
        for entity in [*entities, sim_alive, own_pose]:
            entity.undeclare()
    report = {"got": got, "puts": puts, "configs": configs, "wildcard_configs": wildcard_configs}
    out.write_text(json.dumps(report))


@pytest.mark.runtime
def test_acl_run_converges_and_a_rogue_robot_reaches_only_its_neighbourhood(tmp_path):
    import zenoh

    count, rogue_robot = 5, 0
    data = yaml.safe_load((PROJECT_ROOT / "scenarios/security/acl.yaml").read_text())
    data["robots"]["count"] = count
    data["sim"]["deadline"] = 5.0  # a loaded machine misses no tick: every tick is served, as counted below
    data["safety"] = {"kind": "barrier"}  # each robot's own sensor reading on its own key, too
    scenario = tmp_path / "acl.yaml"
    scenario.write_text(yaml.safe_dump(data))
    steps = round(data["sim"]["duration"] / data["sim"]["control_period"])
    out = tmp_path / "out"
    run = swarm_run.start(scenario, out)
    rogue_process = None
    try:
        # the rogue starts beside the run (it reads the server's address from its log): connected
        # while the agents start, not after a fast lockstep run is over
        credentials = out / "credentials" / f"robot-{rogue_robot}.cred"
        report_path = tmp_path / "rogue.json"
        server_log = out / "logs" / "sim_server.log"
        rogue_process = subprocess.Popen(
            [
                *(sys.executable, __file__, "--server-log", str(server_log)),
                *("--robot", str(rogue_robot), "--count", str(count)),
                *("--credentials", str(credentials), "--out", str(report_path)),
            ],
            stderr=subprocess.PIPE,
            text=True,
        )
        endpoint, run_id = outside.server_address(server_log)
        # no session without the run's credentials: a wrong password, another robot's, none at all
        users = dict(line.split(":") for line in (out / "credentials" / "users.txt").read_text().splitlines())
        for user, password in [
            ("robot-1", "wrong"),
            ("robot-1", users["robot-2"]),
            ("intruder", "x"),
            (None, None),
        ]:
            settings = acl.client_settings(user, password) if user else {}
            with pytest.raises(zenoh.ZError):
                zenoh.open(wire.session_config("client", [endpoint], settings=settings)).close()
        _, rogue_err = rogue_process.communicate(timeout=120)
        assert rogue_process.returncode == 0, rogue_err
        stdout, stderr = run.communicate(timeout=120)
    finally:
        for process in (run, rogue_process):
            if process is not None and process.poll() is None:
                process.kill()
    assert run.returncode == 0, stdout + stderr  # converged
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["converged"] and metrics["runtime"]["access_control"] is True
    assert metrics["runtime"]["ticks_served"] == steps

    keys = wire.Keys(run_id)
    neighbours = [(rogue_robot - 1) % count, (rogue_robot + 1) % count]
    report = json.loads(report_path.read_text())
    got = report["got"]
    # the whole run, by wildcard: nothing (the router refuses the declarations)
    assert got["wildcard"] == {} and got["wildcard_alive"] == {} and report["wildcard_configs"] == []
    # every key one by one: exactly its own pose and reading and its neighbours' messages, many of them
    own = {keys.pose(rogue_robot), keys.sense(rogue_robot), *(keys.msg(j) for j in neighbours)}
    assert set(got["one_by_one"]) == own
    assert all(number > 10 for number in got["one_by_one"].values()), got["one_by_one"]
    assert set(got["alive"]) == {keys.alive_sim, *(keys.alive_agent(j) for j in neighbours)}
    assert report["configs"] == [keys.config(rogue_robot)]

    # what it put on others' keys reached nobody; what it put on its own command key did
    puts = report["puts"]
    assert puts["other_commands"] > 10 * (count - 1) and puts["own_future_commands"] > 10
    stats = json.loads((out / "server_stats.json").read_text())
    # it holds robot 3's password, not the run key: its own-key commands reach the server, which
    # refuses them by their tag (swarm.runtime.wire.RunKey) before reading their tick
    assert 0 < stats["unauthenticated_commands"] <= puts["own_future_commands"]
    assert stats["future_commands"] == 0
    assert stats["invalid_commands"] == 0 and stats["old_commands"] == 0
    lines = [json.loads(line) for line in (out / "trajectory.jsonl").read_text().splitlines()]
    assert len(lines) == steps + 1
    assert not any(list(ROGUE_WHEELS) in line.get("wheels", []) for line in lines)
    for path in (out / "logs").glob("agent_*.json"):
        agent = json.loads(path.read_text())
        assert agent["poses"]["old"] == 0 and agent["poses"]["invalid"] == 0, agent["poses"]
        assert agent["messages"]["old"] == 0 and agent["messages"]["invalid"] == 0, agent["messages"]
        readings = agent["safety_filter"]  # the rogue's empty readings reached no one
        assert readings["unauthenticated"] == readings["invalid"] == readings["missing"] == 0, readings
        assert agent["ticks"] == steps and agent["exit_reason"] == "sim gone"


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description="The rogue process of tests/test_acl.py")
    parser.add_argument("--server-log", type=Path, required=True, help="the run's sim_server.log")
    parser.add_argument("--robot", type=int, required=True)
    parser.add_argument("--count", type=int, required=True)
    parser.add_argument("--credentials", required=True)
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    endpoint, run = outside.server_address(args.server_log)
    rogue(endpoint, run, args.robot, args.count, args.credentials, args.out)
