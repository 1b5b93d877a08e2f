"""Cost of authenticating the run's samples (swarm.runtime.wire.RunKey): per sample, in microseconds.

``python bench/bench_auth.py`` prints a table: tagging and checking a sim pose (60 bytes) and a
local-consensus message (the agent's own layout), and what an agent's receive ring costs per sample
with and without the tag in the Zenoh attachment (a sample put ``--samples`` times through one
Zenoh peer session into a ring of 1024 and taken by ``try_recv``: the agent's path). Best of
``--repeats`` (a loaded machine slows the rest).
"""

from __future__ import annotations

import argparse
import time
import timeit

import zenoh

from swarm.runtime import wire


def per_call_us(function, number: int, repeats: int) -> float:
    return min(timeit.repeat(function, number=number, repeat=repeats)) / number * 1e6


def ring_us(session, key: str, payload: bytes, attachment: bytes | None, samples: int, repeats: int) -> float:
    """Per sample: put through the session into a ring, then take and read payload (and attachment)."""
    best = float("inf")
    for _ in range(repeats):
        subscriber = session.declare_subscriber(key, zenoh.handlers.RingChannel(1024))
        publisher = session.declare_publisher(key)
        taken, start_s = 0, time.perf_counter()
        for _ in range(samples // 512):
            for _ in range(512):
                publisher.put(payload, attachment=attachment)
            while (sample := subscriber.try_recv()) is not None:
                sample.payload.to_bytes()
                if attachment is not None:
                    wire.attachment_of(sample)
                taken += 1
        best = min(best, (time.perf_counter() - start_s) / max(taken, 1) * 1e6)
        publisher.undeclare()
        subscriber.undeclare()
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--number", type=int, default=100_000)
    parser.add_argument("--samples", type=int, default=20_480)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    key = wire.RunKey(wire.new_run_key())
    keys = wire.Keys("bench-auth")
    pose = bytes(wire.PoseEncoder(1).encode(123, 6.15, [(0.5, -0.25, 1.0)])[0])
    message = wire.encode_message(123, (0.5, -0.25))
    rows = []
    for name, topic, payload in (("pose", keys.pose(0), pose), ("message", keys.msg(0), message)):
        tag = key.tag(topic, payload)
        rows.append(
            (
                f"tag a {name} ({len(payload)} B)",
                per_call_us(lambda t=topic, p=payload: key.tag(t, p), args.number, args.repeats),
            )
        )
        rows.append(
            (
                f"check a {name}",
                per_call_us(lambda t=topic, p=payload, g=tag: key.check(t, p, g), args.number, args.repeats),
            )
        )
    config = wire.session_config("peer")
    with zenoh.open(config) as session:
        topic = keys.pose(0)
        plain = ring_us(session, topic, pose, None, args.samples, args.repeats)
        tagged = ring_us(session, topic, pose, key.tag(topic, pose), args.samples, args.repeats)
    rows.append(("ring: put + take a pose, no attachment", plain))
    rows.append(("ring: put + take a pose with its tag, read the attachment", tagged))
    print("| per sample | us |\n|---|---|")
    for name, value in rows:
        print(f"| {name} | {value:.2f} |")


if __name__ == "__main__":
    main()
