"""Fuzzing a real run: a separate fuzzer process floods the run's pose, command and message keys with
malformed and replayed samples while the PyBullet runtime runs in lockstep.

Every process must survive with a normal exit, the run must complete every tick, and what the
receivers counted as invalid (did not decode) and old (tick not newer than the newest accepted) must
match what the fuzzer sent to them, as reported in ``metrics.json``.

The fuzzer is this file run as a script (``python tests/test_fuzz.py ...``): its own OS process with its
own Zenoh client session, connected to the sim server's router like any agent. It paces itself on the
real poses of robot 0 (so it knows the current tick and spreads its samples evenly over the ticks of
the run) and checks the class of every sample it sends with the same decoders the receivers use.
"""

from __future__ import annotations

import argparse
import json
import math
import random
import subprocess
import sys
import time
from pathlib import Path

import msgpack
import numpy as np
import yaml

PROJECT_ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(PROJECT_ROOT))

from swarm import wire  # noqa: E402 (after the path, for the script)

TARGET_SAMPLES = 10_000
OLD_MARGIN_TICKS = 10
"""An "old" sample carries a tick at least this far behind the newest real pose: every receiver has
accepted a newer one from that sender (a receiver would have to miss this many ticks in a row)."""
STOP_BEFORE_END_TICKS = 20
"""The fuzzer stops this many ticks before the end, so that every agent drains what it was sent."""
MESSAGE_DIM = 2  # local consensus: the sender's controlled point


# ----------------------------------------------------------------------------- samples


def _pack(body: object) -> bytes:
    return msgpack.packb(body, use_bin_type=True)


def _garbage(rng: random.Random) -> object:
    return rng.choice(["1.0", None, [1.0, 2.0], {"a": 1}, True, b"\x00", "nan"])


def malformed(stream: str, rng: random.Random, tick_now: int) -> tuple[str, bytes]:
    """One malformed sample for ``stream`` (pose, cmd or msg): its kind and payload. The receiver's
    decoder rejects it (the fuzzer checks)."""
    v = wire.SCHEMA_VERSION
    tick = max(0, tick_now - rng.randrange(0, 50))
    good = {
        "pose": {"v": v, "k": tick, "t": tick * 0.05, "x": 0.5, "y": -0.5, "th": 0.1},
        "cmd": {"v": v, "k": tick, "l": 0.1, "r": 0.1},
        "msg": {"v": v, "k": tick, "m": np.zeros(MESSAGE_DIM).tobytes()},
    }[stream]
    numbers = [key for key in good if key not in ("v", "k", "m")]
    kind = rng.choice(
        [
            "random_bytes",
            "not_a_map",
            "wrong_type",
            "missing_field",
            "nan",
            "inf",
            "huge_value",
            "huge_tick",
            "negative_tick",
            "wrong_version",
            "oversized",
            *(["wrong_dim", "nan_in_vector", "huge_in_vector"] if stream == "msg" else []),
        ]
    )
    body = dict(good)
    if kind == "random_bytes":
        return kind, rng.randbytes(rng.randrange(0, 200))
    if kind == "not_a_map":
        return kind, _pack(rng.choice([[1, 2, 3], 7, "pose", None, [good]]))
    if kind == "wrong_type":
        body[rng.choice([*numbers, "k"] if numbers else ["k", "m"])] = _garbage(rng)
    elif kind == "missing_field":
        del body[rng.choice([key for key in body])]
    elif kind in ("nan", "inf", "huge_value"):
        value = {"nan": math.nan, "inf": rng.choice([math.inf, -math.inf]), "huge_value": 1e12}[kind]
        if numbers:
            body[rng.choice(numbers)] = value
        else:
            body["m"] = np.full(MESSAGE_DIM, value).tobytes()
    elif kind == "huge_tick":
        body["k"] = rng.choice([wire.MAX_TICK + 1, 2**64 - 1])
    elif kind == "negative_tick":
        body["k"] = -rng.randrange(1, 1000)
    elif kind == "wrong_version":
        body["v"] = rng.choice([0, 2, 99, "1", None])
    elif kind == "oversized":
        body["pad"] = "x" * (wire.MAX_MESSAGE_PAYLOAD + 10)
    elif kind == "wrong_dim":
        body["m"] = np.zeros(rng.choice([0, 1, 3, 7])).tobytes()
    elif kind == "nan_in_vector":
        body["m"] = np.array([0.0, math.nan]).tobytes()
    elif kind == "huge_in_vector":
        body["m"] = np.array([1e10, 0.0]).tobytes()
    return kind, _pack(body)


def old(stream: str, rng: random.Random, tick_now: int) -> bytes:
    """A well-formed sample whose tick every receiver has passed (with values that would do harm)."""
    tick = rng.randrange(0, tick_now - OLD_MARGIN_TICKS + 1)
    if stream == "pose":
        return wire.encode_pose(tick, tick * 0.05, (50.0, -50.0, 3.0))
    if stream == "cmd":
        return wire.encode_command(tick, (5.0, -5.0))
    return wire.encode_message(tick, (50.0, -50.0))


def decodes(stream: str, payload: bytes) -> bool:
    """Whether the receiver of ``stream`` would accept ``payload`` as well-formed."""
    if stream == "pose":
        return wire.decode_pose(payload) is not None
    if stream == "cmd":
        return wire.decode_command(payload) is not None
    return wire.decode_message_values(payload, MESSAGE_DIM) is not None


# ----------------------------------------------------------------------------- the fuzzer process


def fuzz(endpoint: str, run: str, count: int, steps: int, seed: int, out: Path) -> None:
    """Connect to the run, send about ``TARGET_SAMPLES`` samples paced on robot 0's poses, write what
    was sent (per stream, robot and class) to ``out``."""
    import zenoh

    rng = random.Random(seed)
    keys = wire.Keys(run)
    key_of = {"pose": keys.pose, "cmd": keys.cmd, "msg": keys.msg}
    sent = {stream: {"invalid": [0] * count, "old": [0] * count} for stream in key_of}
    kinds: dict[str, int] = {}
    with zenoh.open(wire.session_config("client", [endpoint])) as session:
        publishers = {
            (stream, i): session.declare_publisher(key(i), congestion_control=zenoh.CongestionControl.BLOCK)
            for stream, key in key_of.items()
            for i in range(count)
        }
        poses = session.declare_subscriber(
            keys.pose(0), zenoh.handlers.RingChannel(8), allowed_origin=zenoh.Locality.REMOTE
        )
        tick_now, first, total = -1, None, 0
        targets = [(stream, i) for stream in key_of for i in range(count)]
        position = len(targets)
        deadline_s = time.monotonic() + 120
        while total < TARGET_SAMPLES and time.monotonic() < deadline_s:
            sample = poses.try_recv()
            if sample is None:
                time.sleep(0.0005)
                continue
            pose = wire.decode_pose(sample.payload.to_bytes())
            if pose is None or pose.tick <= tick_now:
                continue
            tick_now = pose.tick
            if tick_now < OLD_MARGIN_TICKS:
                continue
            if first is None:
                first = tick_now
                last = max(first + 1, steps - STOP_BEFORE_END_TICKS - 10)  # all sent by this tick
            if tick_now >= steps - STOP_BEFORE_END_TICKS:
                break
            due = math.ceil(TARGET_SAMPLES * min(1.0, (tick_now - first + 1) / (last - first)))
            for _ in range(due - total):  # catches up on ticks it did not see (it is slower than the run)
                if position == len(targets):  # every key in turn, in a fresh random order each round:
                    rng.shuffle(targets)  # a key gets no burst (a burst could push real samples out
                    position = 0  # of a receiver's ring buffer)
                stream, robot = targets[position]
                position += 1
                if rng.random() < 0.15:
                    kind, payload, label = "old_tick", old(stream, rng, tick_now), "old"
                    assert decodes(stream, payload)
                else:
                    (kind, payload), label = malformed(stream, rng, tick_now), "invalid"
                    if decodes(stream, payload):
                        continue  # not malformed after all (cannot happen with these kinds)
                publishers[(stream, robot)].put(payload)
                sent[stream][label][robot] += 1
                kinds[kind] = kinds.get(kind, 0) + 1
                total += 1
        poses.undeclare()
        for publisher in publishers.values():
            publisher.undeclare()
    out.write_text(json.dumps({"sent": sent, "total": total, "kinds": kinds, "first_tick": first}))


# ----------------------------------------------------------------------------- the test


def wait_for_agent_record(
    out: Path, process: subprocess.Popen, robot: int = 0, timeout_s: float = 60.0
) -> dict:
    """The record of robot ``robot``'s agent once it is ready (run id, endpoint) in a run's results."""
    path = out / "logs" / f"agent_{robot}.json"
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        assert process.poll() is None, f"run ended early: {process.communicate()}"
        try:
            record = json.loads(path.read_text())
            if record.get("run") and record.get("ready_s") is not None:
                return record
        except (FileNotFoundError, json.JSONDecodeError):
            pass
        time.sleep(0.02)
    raise AssertionError(f"agent {robot} did not come up")


def test_a_run_survives_ten_thousand_malformed_and_replayed_samples(tmp_path):
    count, duration_s = 5, 45.0  # room for a fuzzer that joins late on a loaded machine
    data = yaml.safe_load((PROJECT_ROOT / "scenarios/thesis/cycle-local_consensus.yaml").read_text())
    data["robots"]["count"] = count
    data["sim"]["duration"] = duration_s
    data["sim"]["deadline"] = 0.25  # a real pose pushed out of a ring by the flood costs a short wait
    scenario = tmp_path / "fuzz.yaml"
    scenario.write_text(yaml.safe_dump(data))
    steps = round(duration_s / data["sim"]["control_period"])
    out = tmp_path / "out"
    run = subprocess.Popen(
        [sys.executable, "-m", "swarm.cli", "run", str(scenario), "--out", str(out), "--quiet"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=PROJECT_ROOT,
    )
    try:
        record = wait_for_agent_record(out, run)
        sent_path = tmp_path / "sent.json"
        fuzzer = subprocess.run(
            [
                *(sys.executable, __file__, "--endpoint", record["connect"][0], "--run", record["run"]),
                *("--count", str(count), "--steps", str(steps), "--seed", "7", "--out", str(sent_path)),
            ],
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert fuzzer.returncode == 0, fuzzer.stderr
        _, stderr = run.communicate(timeout=120)
    finally:
        if run.poll() is None:
            run.kill()
    assert run.returncode in (0, 1), stderr  # ran to the end (converged or not), no failure
    assert "Traceback" not in stderr

    report = json.loads(sent_path.read_text())
    sent = report["sent"]
    assert report["total"] >= TARGET_SAMPLES, report
    assert len(report["kinds"]) >= 12  # every way of being malformed, and old ticks

    metrics = json.loads((out / "metrics.json").read_text())
    runtime = metrics["runtime"]
    stats = json.loads((out / "server_stats.json").read_text())
    paths = (out / "logs").glob("agent_*.json")
    records = {int(path.stem.split("_")[1]): json.loads(path.read_text()) for path in paths}

    # nobody crashed: the server finished every tick, every agent ran to the end and left because the
    # sim ended (a real pose pushed out of an agent's ring by the flood is a tick that agent missed)
    assert stats["exit"] == "done" and metrics["processes"]["agents_exit_status"] == 0
    assert sorted(records) == list(range(count))
    assert len((out / "trajectory.jsonl").read_text().splitlines()) == steps + 1
    # on a loaded machine the flood pushes more real poses out of the rings: allow up to a tenth of ticks
    missed_at_most = steps // 10
    assert runtime["ticks_served"] + runtime["ticks_missed"] == steps
    assert runtime["ticks_missed"] <= missed_at_most
    for i, agent in records.items():
        assert agent["exit_reason"] == "sim gone" and agent["last_tick"] == steps - 1, (i, agent)
        assert agent["ticks"] >= steps - missed_at_most, (i, agent["ticks"])
    assert runtime["rejected"]["callback_errors"] == 0

    # what each receiver counted against what was sent to it: never more (no real sample is
    # rejected), and most of it (a receiver's ring buffer may overflow under load and drop some)
    neighbours = {i: [(i - 1) % count, (i + 1) % count] for i in range(count)}  # the cycle
    for label in ("invalid", "old"):
        for i, agent in records.items():
            expected_poses = sent["pose"][label][i]
            expected_messages = sum(sent["msg"][label][j] for j in neighbours[i])
            assert 0.8 * expected_poses <= agent["poses"][label] <= expected_poses, (label, i, agent["poses"])
            assert 0.8 * expected_messages <= agent["messages"][label] <= expected_messages, (label, i)
        commands = stats[f"{label}_commands"]
        assert commands == sum(sent["cmd"][label]), (label, commands)  # a callback: no buffer to overflow

    # metrics.json reports the same counts
    rejected = runtime["rejected"]
    for label in ("invalid", "old"):
        assert rejected[label]["poses"] == sum(r["poses"][label] for r in records.values())
        assert rejected[label]["messages"] == sum(r["messages"][label] for r in records.values())
        assert rejected[label]["commands"] == stats[f"{label}_commands"]
    assert runtime["messages_invalid"] == rejected["invalid"]["messages"]
    assert runtime["invalid_commands"] == rejected["invalid"]["commands"]
    total_sent = sum(sum(sent[s][label]) * (2 if s == "msg" else 1) for s in sent for label in sent[s])
    total_counted = sum(sum(rejected[label].values()) for label in ("invalid", "old"))
    assert 0.9 * total_sent <= total_counted <= total_sent, (total_counted, total_sent)


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description="The fuzzer process of tests/test_fuzz.py")
    parser.add_argument("--endpoint", required=True)
    parser.add_argument("--run", required=True)
    parser.add_argument("--count", type=int, required=True)
    parser.add_argument("--steps", type=int, required=True)
    parser.add_argument("--seed", type=int, required=True)
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    fuzz(args.endpoint, args.run, args.count, args.steps, args.seed, args.out)
