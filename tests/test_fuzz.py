"""Fuzzing a real run: a separate fuzzer process floods the run's pose, command and message keys with
malformed, replayed and forward-dated samples while the PyBullet runtime runs in lockstep.

Every process must survive with a normal exit and the run must complete every tick. The fuzzer is an
outside sender: it imports none of the project's code (``tests/outside.py``: the key space and payloads
as the docs give them) and classifies every sample by construction, since it knows what it made:
*invalid* (malformed in one of a dozen ways), *old* (well formed, tick 0-5: every receiver is far past
it), *future* (well formed, dated at least 10^6 ticks ahead). It does not hold the run's key
(``swarm run`` makes one per run: swarm.runtime.wire.RunKey), so every one of its samples must be
counted *unauthenticated*, whatever it holds, and none as anything else. What the receivers counted
(``metrics.json``, the agents' records, ``server_stats.json``) must account for exactly what the fuzzer
sent, however many it managed to send: the server's count equals what was sent to it; at each agent
every arrival (the genuine samples plus what was sent to it) is received, unauthenticated or unread at
exit, unless a drain found its receive ring full (``ring_full``: then some may have been pushed out,
and fewer are accounted for), and it never counted more than was sent nor less than was sent minus
what was pushed out.

The fuzzer is this file run as a script (``python tests/test_fuzz.py ...``): its own OS process with its
own Zenoh client session, connected to the sim server's router like any agent. It paces itself on the
real poses of robot 0 (so it knows the current tick and spreads its samples evenly over the ticks of
the run).
"""

from __future__ import annotations

import argparse
import json
import math
import random
import struct
import subprocess
import sys
import time
from pathlib import Path

import msgpack
import pytest
import yaml

PROJECT_ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(PROJECT_ROOT / "tests"))

import outside  # noqa: E402 (no project code: the key space and payloads as documented)
import swarm_run  # noqa: E402

pytestmark = pytest.mark.runtime  # real processes: the fast tier leaves it out

TARGET_SAMPLES = 10_000
OLD_TICKS = range(0, 6)
"""An "old" sample carries one of these ticks: the fuzzer starts at tick 10 or later, when every receiver
has accepted a newer one from every sender."""
FUTURE_AHEAD = 10**6
"""A "future" sample is dated ``FUTURE_AHEAD * (1 + u)`` ticks ahead, u in 0..999 drawn without
replacement per key: two to one receiver are never within a window of each other (so that two in a row
cannot confirm a jump: docs, "Ticks"). With replacement, two equal draws a tick apart did confirm one,
once in two runs on a loaded machine (the fuzzer's catch-up bursts put several on one key at once)."""
STOP_BEFORE_END_TICKS = 20
"""The fuzzer stops this many ticks before the end, so that every agent drains what it was sent."""
MESSAGE_DIM = 2  # local consensus: the sender's controlled point
# documented bounds (docs/distributed-runtime.md, "Validation"): beyond them a sample is invalid
MAX_TICK = 2**40
MAX_PAYLOAD_BYTES = 64 + 8 * 1024


# ----------------------------------------------------------------------------- samples


def _pack(body: object) -> bytes:
    return msgpack.packb(body, use_bin_type=True)


def _garbage(rng: random.Random) -> object:
    return rng.choice(["1.0", None, [1.0, 2.0], {"a": 1}, True, b"\x00", "nan"])


def _floats(values: list[float]) -> bytes:
    return struct.pack(f"<{len(values)}d", *values)


def malformed(stream: str, rng: random.Random, tick_now: int) -> tuple[str, bytes]:
    """One malformed sample for ``stream`` (pose, cmd or msg): its kind and payload, malformed by
    construction (the receivers' decoders are not consulted)."""
    v = outside.SCHEMA_VERSION
    tick = max(0, tick_now - rng.randrange(0, 50))
    good = {
        "pose": {"v": v, "k": tick, "t": tick * 0.05, "x": 0.5, "y": -0.5, "th": 0.1},
        "cmd": {"v": v, "k": tick, "l": 0.1, "r": 0.1},
        "msg": {"v": v, "k": tick, "m": _floats([0.0] * MESSAGE_DIM)},
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
            *(["wrong_dim", "nan_in_vector", "huge_in_vector", "ragged_vector"] if stream == "msg" else []),
        ]
    )
    body = dict(good)
    if kind == "random_bytes":  # never a msgpack map with "v": 1 (a fixmap starts 0x80-0x8f)
        return kind, bytes([rng.choice([0x00, 0x7F, 0xC1, 0xFF])]) + rng.randbytes(rng.randrange(0, 200))
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
            body["m"] = _floats([value] * MESSAGE_DIM)
    elif kind == "huge_tick":
        body["k"] = rng.choice([MAX_TICK + 1, 2**64 - 1])
    elif kind == "negative_tick":
        body["k"] = -rng.randrange(1, 1000)
    elif kind == "wrong_version":
        body["v"] = rng.choice([0, 2, 99, "1", None])
    elif kind == "oversized":
        body["pad"] = "x" * (MAX_PAYLOAD_BYTES + 10)
    elif kind == "wrong_dim":
        body["m"] = _floats([0.0] * rng.choice([0, 1, 3, 7]))
    elif kind == "nan_in_vector":
        body["m"] = _floats([0.0, math.nan])
    elif kind == "huge_in_vector":
        body["m"] = _floats([1e10, 0.0])
    elif kind == "ragged_vector":
        body["m"] = _floats([0.0, 0.0])[:-3]  # not a whole number of float64
    return kind, _pack(body)


def well_formed(stream: str, tick: int) -> bytes:
    """A well-formed sample of ``tick`` with values that would do harm if used."""
    if stream == "pose":
        return outside.pose(tick, 50.0, -50.0, 3.0)
    if stream == "cmd":
        return outside.command(tick, 5.0, -5.0)
    return outside.message(tick, [50.0, -50.0])


# ----------------------------------------------------------------------------- the fuzzer process


def fuzz(endpoint: str, run: str, count: int, steps: int, seed: int, out: Path) -> None:
    """Connect to the run, send about ``TARGET_SAMPLES`` samples paced on robot 0's poses, write what
    was sent (per stream, robot and class) to ``out``."""
    import zenoh

    rng = random.Random(seed)
    key_of = {
        "pose": lambda i: outside.pose_key(run, i),
        "cmd": lambda i: outside.cmd_key(run, i),
        "msg": lambda i: outside.msg_key(run, i),
    }
    labels = ("invalid", "old", "future")
    sent = {stream: {label: [0] * count for label in labels} for stream in key_of}
    kinds: dict[str, int] = {}
    session = outside.open_session(endpoint)
    publishers = {
        (stream, i): session.declare_publisher(key(i), congestion_control=zenoh.CongestionControl.BLOCK)
        for stream, key in key_of.items()
        for i in range(count)
    }
    poses = session.declare_subscriber(
        outside.pose_key(run, 0), zenoh.handlers.RingChannel(8), allowed_origin=zenoh.Locality.REMOTE
    )
    tick_now, first, total = -1, None, 0
    targets = [(stream, i) for stream in key_of for i in range(count)]
    future_multiples = {target: rng.sample(range(1000), 1000) for target in targets}  # ~100 used per key
    position = len(targets)
    deadline_s = time.monotonic() + 300
    while total < TARGET_SAMPLES and time.monotonic() < deadline_s:
        sample = poses.try_recv()
        if sample is None:
            time.sleep(0.0005)
            continue
        tick = outside.tick_of(sample.payload.to_bytes())
        if tick is None or tick <= tick_now:
            continue
        tick_now = tick
        if tick_now < 10:
            continue
        if first is None:
            first = tick_now
            last = max(first + 1, steps // 2)  # all sent by this tick: half a run for them to arrive
        if tick_now >= steps - STOP_BEFORE_END_TICKS:
            break
        due = math.ceil(TARGET_SAMPLES * min(1.0, (tick_now - first + 1) / (last - first)))
        for _ in range(due - total):  # catches up on ticks it did not see (it is slower than the run)
            if position == len(targets):  # every key in turn, in a fresh random order each round:
                rng.shuffle(targets)  # a key gets no burst (a burst could push real samples out
                position = 0  # of a receiver's buffer)
            stream, robot = targets[position]
            position += 1
            draw = rng.random()
            if draw < 0.15:
                kind, label = "old_tick", "old"
                payload = well_formed(stream, rng.choice(OLD_TICKS))
            elif draw < 0.3:
                kind, label = "future_tick", "future"
                multiple = 1 + future_multiples[(stream, robot)].pop()
                payload = well_formed(stream, tick_now + FUTURE_AHEAD * multiple)
            else:
                (kind, payload), label = malformed(stream, rng, tick_now), "invalid"
            publishers[(stream, robot)].put(payload)
            sent[stream][label][robot] += 1
            kinds[kind] = kinds.get(kind, 0) + 1
            total += 1
    # Closing the session may drop puts still queued in it (one invalid pose went uncounted that way
    # on a loaded machine: 487 of 488). A query that the sim server answers, asked after the last put
    # on the same session and priority, is answered only once the router has taken every put before
    # it: then the session may close.
    flushed, flush_deadline_s = False, time.monotonic() + 120
    while not flushed and time.monotonic() < flush_deadline_s:
        replies = session.get(f"swarm/{run}/config/0", timeout=5.0)
        flushed = any(reply.ok is not None for reply in replies)
    flushed_tick = None  # the run's tick once the router had taken every put: the next pose's
    pose_deadline_s = time.monotonic() + 10
    while flushed and flushed_tick is None and time.monotonic() < pose_deadline_s:
        while (sample := poses.try_recv()) is not None:  # the queued ones are older, the last is newest
            flushed_tick = outside.tick_of(sample.payload.to_bytes())
        time.sleep(0.01)
    poses.undeclare()
    for publisher in publishers.values():
        publisher.undeclare()
    session.close()
    report = {"sent": sent, "total": total, "kinds": kinds, "first_tick": first, "flushed_tick": flushed_tick}
    out.write_text(json.dumps(report))


# ----------------------------------------------------------------------------- the test


def test_a_run_survives_ten_thousand_malformed_replayed_and_forward_dated_samples(tmp_path):
    count, duration_s = 5, 45.0  # room for a fuzzer that joins late on a loaded machine
    data = yaml.safe_load((PROJECT_ROOT / "scenarios/thesis/cycle-local_consensus.yaml").read_text())
    data["robots"]["count"] = count
    data["sim"]["duration"] = duration_s
    data["sim"]["acl"] = False  # the fuzzer is an outsider without credentials (the run key still tags)
    steps = round(duration_s / data["sim"]["control_period"])
    scenario = tmp_path / "fuzz.yaml"
    scenario.write_text(yaml.safe_dump(data))
    out = tmp_path / "out"
    run = swarm_run.start(scenario, out)
    try:  # the fuzzer starts beside the run (the server's address from its log): it is there from tick 10
        sent_path = tmp_path / "sent.json"
        fuzzer = subprocess.run(
            [
                *(sys.executable, __file__, "--server-log", str(out / "logs" / "sim_server.log")),
                *("--count", str(count), "--steps", str(steps), "--seed", "7", "--out", str(sent_path)),
            ],
            capture_output=True,
            text=True,
            timeout=400,
        )
        assert fuzzer.returncode == 0, fuzzer.stderr
        _, stderr = run.communicate(timeout=400)
    finally:
        if run.poll() is None:
            run.kill()
    assert run.returncode in (0, 1), stderr  # ran to the end (converged or not), no failure
    assert "Traceback" not in stderr

    report = json.loads(sent_path.read_text())
    sent = report["sent"]
    # What the fuzzer managed to send on a loaded machine varies (9919 of 10,000 once): the oracle is
    # what it sent, counted by construction, whatever the number.
    assert report["total"] > 0, report
    assert report["total"] < 1000 or len(report["kinds"]) >= 14  # every way of being malformed, old, future

    metrics = json.loads((out / "metrics.json").read_text())
    runtime = metrics["runtime"]
    stats = json.loads((out / "server_stats.json").read_text())
    paths = (out / "logs").glob("agent_*.json")
    records = {int(path.stem.split("_")[1]): json.loads(path.read_text()) for path in paths}

    # nobody crashed: the server finished every tick, every agent ran to the end and left because the
    # sim ended
    assert stats["exit"] == "done" and metrics["processes"]["agents_exit_status"] == 0
    assert sorted(records) == list(range(count))
    assert len((out / "trajectory.jsonl").read_text().splitlines()) == steps + 1
    assert runtime["ticks_served"] + runtime["ticks_missed"] == steps
    for i, agent in records.items():
        assert agent["exit_reason"] == "sim gone" and agent["last_tick"] == steps - 1, (i, agent)
        assert agent["poses"]["jumps"] == 0  # no forward-dated pose moved an agent's clock
    assert runtime["rejected"]["callback_errors"] == 0

    # every sample accounted for, per receiver
    labels = ("invalid", "old", "future")
    neighbours = {i: [(i - 1) % count, (i + 1) % count] for i in range(count)}  # the cycle
    # the server: a callback per command, nothing to overflow; every forged one fails its tag
    commands_sent = sum(sum(sent["cmd"][label]) for label in labels)
    assert stats["unauthenticated_commands"] == commands_sent, (
        stats["unauthenticated_commands"],
        commands_sent,
    )
    assert all(stats[f"{label}_commands"] == 0 for label in labels), stats
    # an agent whose session the router dropped (lease expired: a process starved for a second on a
    # loaded machine) and that reconnected lost what was in flight meanwhile; the server saw it
    reconnected = {e["robot"] for e in stats["agent_events"] if e["event"] in ("gone", "back")}
    # every forged sample was with the router by this tick (its flush query answered); one the fuzzer,
    # starved on a loaded machine, put too near the end may reach an agent that has left (666 of 667
    # forged poses once in CI, with the fuzzer done 20 ticks before the end; it now sends by mid-run)
    flushed_tick = report["flushed_tick"]
    flushed_early = flushed_tick is not None and flushed_tick < steps - STOP_BEFORE_END_TICKS
    for i, agent in records.items():
        for stream, senders, genuine in (
            ("poses", [i], steps),  # one real pose per tick
            ("messages", neighbours[i], sum(records[j]["commands_sent"] for j in neighbours[i])),
        ):
            counted, key = agent[stream], "pose" if stream == "poses" else "msg"
            forged = sum(sent[key][label][j] for j in senders for label in labels)
            arrivals = sum(counted[name] for name in ("received", "unauthenticated", *labels, "unread"))
            assert arrivals == counted["taken"] + counted["unread"], (i, stream, counted)
            assert all(counted[label] == 0 for label in labels), (i, stream, counted)  # none got that far
            if reconnected & {i, *senders}:
                assert arrivals <= genuine + forged, (i, stream, counted, forged, genuine)
                assert agent["sim_lost"] >= 2 or reconnected & set(senders), (i, agent["sim_lost"])
                continue
            if counted["ring_full"] == 0 and flushed_early:  # nothing pushed out, nothing came too late
                assert arrivals == genuine + forged, (i, stream, counted, forged, genuine)
            else:
                assert arrivals <= genuine + forged, (i, stream, counted, forged, genuine)
            pushed_out = genuine + forged - arrivals
            assert forged - pushed_out <= counted["unauthenticated"] <= forged, (i, stream, counted)

    # metrics.json reports the same counts
    rejected = runtime["rejected"]
    for label in (*labels, "unauthenticated", "ring_full"):
        assert rejected[label]["poses"] == sum(r["poses"][label] for r in records.values())
        assert rejected[label]["messages"] == sum(r["messages"][label] for r in records.values())
        assert rejected[label]["commands"] == stats.get(f"{label}_commands", 0)
    assert runtime["messages_invalid"] == rejected["invalid"]["messages"]
    assert runtime["invalid_commands"] == rejected["invalid"]["commands"]
    assert rejected["unauthenticated"]["commands"] == stats["unauthenticated_commands"]


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description="The fuzzer process of tests/test_fuzz.py")
    parser.add_argument("--server-log", type=Path, required=True, help="the run's sim_server.log")
    parser.add_argument("--count", type=int, required=True)
    parser.add_argument("--steps", type=int, required=True)
    parser.add_argument("--seed", type=int, required=True)
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    endpoint, run = outside.server_address(args.server_log)
    fuzz(endpoint, run, args.count, args.steps, args.seed, args.out)
