"""What the Python side of one agent tick costs, piece by piece, against the bare agent's pieces.

Each piece is timed on its own in this process (``timeit``, the best of ``--repeats`` rounds: the
figure least disturbed by other load), with the payloads a real run carries (local consensus, message
dimension 2, ``--neighbours`` neighbours, no link faults). The real agent's pieces call the functions
``robot_agent`` calls (``swarm.runtime.wire``, ``swarm.core.faults.select_message``,
``swarm.sim.onboard``); the
per-neighbour bookkeeping of ``RobotAgent._drain_messages`` and ``_loop`` is timed through a real
``RobotAgent`` where it is a method, and as the same statements where it is inline. Zenoh's own
work (``recv``, ``put``, its threads) is the floor both agents share and is not timed here
(``bench/bench_runtime.py`` measures the whole).

Run: ``python bench/investigations/agent_tick_costs.py --update-results`` (prints a table and writes
``agent_tick_costs.json`` to the output directory; ``--update-results``: ``bench/results/``).
"""

from __future__ import annotations

import sys as _sys
from pathlib import Path as _Path

_sys.path.insert(0, str(_Path(__file__).resolve().parent.parent))  # bench/: its helpers and benchmarks

import argparse
import json
import math
import struct
import sys
import time
import timeit

import msgpack
import numpy as np
import zenoh
from _output import add_output_arguments, output_dir

from robot_agent.agent import AgentOptions, RobotAgent
from swarm.core.faults import select_message
from swarm.core.robot import RobotParams
from swarm.runtime import wire
from swarm.sim.onboard import OnboardLocalConsensus, wheels_one


class _Channel:
    """A stand-in for a Zenoh ring channel holding samples (to time the Python around ``try_recv``)."""

    class _Sample:
        def __init__(self, data: bytes):
            self.payload = zenoh.ZBytes(data)

    def __init__(self, payloads: list[bytes]):
        self.samples = [self._Sample(p) for p in payloads]

    def try_recv(self):
        return self.samples.pop() if self.samples else None


_MESSAGE_HEAD = b"\x83\xa1v\x01\xa1k"  # msgpack {"v": 1, "k": ... as swarm.runtime.wire packs a message
_MESSAGE_BODY = b"\xa1m\xc4\x10"  # "m": bin 8 of 16 bytes (two float64)
_UINTS = {0xCC: 1, 0xCD: 2, 0xCE: 4, 0xCF: 8}


def fixed_layout_message(data: bytes) -> tuple[int, tuple[float, float]] | None:
    """Plan item 1, a prototype timed here (not used by the agent): ``wire.decode_message_values(data, 2)``
    for the one layout ``robot_agent`` sends, checked byte by byte with the same bounds; None for
    anything else (the agent would then call the general decoder)."""
    if data[:6] != _MESSAGE_HEAD or len(data) > 44:
        return None
    first = data[6]
    if first < 0x80:
        tick, at = first, 7
    elif first in _UINTS:
        at = 7 + _UINTS[first]
        tick = int.from_bytes(data[7:at], "big")
    else:
        return None
    if tick > wire.MAX_TICK or data[at : at + 4] != _MESSAGE_BODY or len(data) != at + 20:
        return None
    x, y = struct.unpack_from("<2d", data, at + 4)
    if not (abs(x) <= wire.MAX_MESSAGE_ABS and abs(y) <= wire.MAX_MESSAGE_ABS):  # NaN fails too
        return None
    return tick, (x, y)


def costs(neighbours: int, repeats: int, number: int) -> dict[str, float]:
    """Microseconds per tick of each piece."""
    params = RobotParams()
    controller = OnboardLocalConsensus(params, 1.0)
    tick = 1234
    pose_bytes = wire.encode_pose(tick, 61.7, (1.25, -0.5, 0.3))
    msg_bytes = [wire.encode_message(tick - 1, (0.1 * j, -0.2 * j)) for j in range(neighbours)]
    points = [(0.1 * j, -0.2 * j) for j in range(neighbours)]
    weights = [1.0] * neighbours

    def best(statement, per: int = 1) -> float:
        return 1e6 * min(timeit.repeat(statement, number=number, repeat=repeats)) / number / per

    agent = RobotAgent(AgentOptions(robot=0, run="r", connect=[]))
    agent._dim = 2
    ids = list(range(1, neighbours + 1))
    for j in ids:
        agent._inbox[j] = {}

    def drain() -> None:  # RobotAgent._drain_messages over channels holding one message each
        agent._msg_subs = {j: _Channel([msg_bytes[i]]) for i, j in enumerate(ids)}
        agent._newest_message_tick = {}
        agent._drain_messages()

    def channels_only() -> None:  # what drain() costs without the method: building the stand-ins
        {j: _Channel([msg_bytes[i]]) for i, j in enumerate(ids)}

    boxes = {j: {tick - 1: points[i]} for i, j in enumerate(ids)}

    def select() -> None:  # the per-neighbour selection of RobotAgent._loop (no faults), as written there
        heard, messages = [], []
        for j in ids:
            box = boxes[j]
            came = lambda k, box=box: k in box  # noqa: E731
            sent = select_message(tick, 0, 1, came)
            values = None if sent is None else box[sent]
            if values is not None:
                heard.append(j)
                messages.append(values)

    def prune() -> None:  # RobotAgent._loop: drop what can no longer be used
        oldest = tick - 1
        for box in boxes.values():
            for k in [k for k in box if k < oldest]:
                del box[k]

    samples: list[float] = []

    def clocks() -> None:  # two perf_counter calls and the per-tick list append of the compute time
        start = time.perf_counter()
        samples.append(time.perf_counter() - start)

    liveliness = [_Channel([]) for _ in ids]

    def drain_liveliness() -> None:  # RobotAgent._drain_liveliness with nothing queued (stand-ins)
        for channel in liveliness:
            while channel.try_recv() is not None:
                pass

    session = zenoh.open(wire.session_config("peer"))
    rings = [session.declare_subscriber(f"cost/{j}", zenoh.handlers.RingChannel(16)) for j in ids]

    def zenoh_try_recv_empty() -> None:  # the real channel, nothing queued (each liveliness channel)
        for ring in rings:
            ring.try_recv()

    offset, half = params.offset_m, params.half_axle_m
    unpackb, packb = msgpack.unpackb, msgpack.packb
    raws = [m[-16:] for m in msg_bytes]

    def bare_forward() -> None:  # bench/bare_agent.py: numpy consensus and wheels
        c, s = math.cos(0.3), math.sin(0.3)
        point = np.array([1.25 + offset * c, -0.5 + offset * s])
        u = -1.0 * (len(raws) * point - np.frombuffer(b"".join(raws), dtype="<f8").reshape(-1, 2).sum(axis=0))
        v, w = c * u[0] + s * u[1], (-s * u[0] + c * u[1]) / offset
        left, right = v - half * w, v + half * w
        min(1.0, 0.5 / max(abs(left), abs(right), 1e-12))

    for sample_tick in (0, 127, 128, 70_000, 2**33):  # the prototype agrees with the real decoder
        for values in ((0.1, -0.2), (1e9, -1e9), (float("nan"), 0.0), (2e9, 0.0)):
            data = wire.encode_message(sample_tick, values)
            assert fixed_layout_message(data) == wire.decode_message_values(data, 2), (sample_tick, values)

    result = {
        "real: decode_pose (validated, Pose dataclass)": best(lambda: wire.decode_pose(pose_bytes)),
        f"real: decode_message_values x{neighbours} (validated)": best(
            lambda: [wire.decode_message_values(m, 2) for m in msg_bytes]
        ),
        f"real: _drain_messages x{neighbours} (decode + inbox bookkeeping)": best(drain)
        - best(channels_only),
        f"real: per-neighbour selection x{neighbours} (select_message)": best(select),
        "real: inbox prune": best(prune),
        "real: act_floats (local consensus)": best(
            lambda: controller.act_floats(1.25, -0.5, 0.3, points, weights)
        ),
        "real: wheels_one": best(lambda: wheels_one((0.1, 0.2), 0.3, params)),
        "real: encode_message + encode_command": best(
            lambda: (wire.encode_message(tick, (0.1, 0.2)), wire.encode_command(tick, (0.1, 0.2)))
        ),
        "real: perf_counter x2 + compute_s append": best(clocks),
        f"real: _drain_liveliness x{neighbours} (Python loop, stand-in channels)": best(drain_liveliness),
        f"real: zenoh try_recv on {neighbours} empty channels (liveliness)": best(zenoh_try_recv_empty),
        f"plan: fixed-layout validated decode x{neighbours} (prototype, same answers)": best(
            lambda: [fixed_layout_message(m) for m in msg_bytes]
        ),
        "bare: unpackb pose": best(lambda: unpackb(pose_bytes)),
        f"bare: unpackb x{neighbours} messages": best(lambda: [unpackb(m)["m"] for m in msg_bytes]),
        "bare: numpy forward + wheels": best(bare_forward),
        "bare: packb message + command": best(
            lambda: (
                packb({"v": 1, "k": tick, "m": raws[0]}),
                packb({"v": 1, "k": tick, "l": 0.1, "r": 0.2}),
            )
        ),
    }
    session.close()
    return {name: round(value, 2) for name, value in result.items()}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--neighbours", type=int, default=4)
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--number", type=int, default=2000)
    add_output_arguments(parser)
    args = parser.parse_args(argv)
    out = output_dir(args) / "agent_tick_costs.json"
    table = costs(args.neighbours, args.repeats, args.number)
    real = sum(v for k, v in table.items() if k.startswith("real:") and "_drain_messages" not in k)
    # (the "plan:" rows are prototypes, in neither sum)
    real -= table[f"real: decode_message_values x{args.neighbours} (validated)"]  # inside _drain_messages
    real += table[f"real: _drain_messages x{args.neighbours} (decode + inbox bookkeeping)"]
    real -= table[f"real: _drain_liveliness x{args.neighbours} (Python loop, stand-in channels)"]
    bare = sum(v for k, v in table.items() if k.startswith("bare:"))
    for name, value in table.items():
        print(f"{value:8.2f} us  {name}")
    print(f"{real:8.2f} us  real agent, Python per tick (the pieces above, once each)")
    print(f"{bare:8.2f} us  bare agent, Python per tick")
    out.write_text(json.dumps({"us": table, "real_us": round(real, 2), "bare_us": round(bare, 2)}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
