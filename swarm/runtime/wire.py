"""Zenoh key expressions and message schemas of the runtime (docs/design.md, "The wire protocol").

The one place that knows what travels on the wire. Key space of one run (``<run>`` is the run id)::

    swarm/<run>/robot/<i>/pose     sim -> agent i          Pose: tick, sim time, x, y, theta (axle centre)
    swarm/<run>/robot/<i>/cmd      agent i -> sim          Command: tick, wheel linear speeds left/right (m/s)
    swarm/<run>/robot/<i>/sense    sim -> agent i          Sensing: tick, what robot i's range sensor sees
                                                           (scenarios with ``safety`` only; docs/safety.md)
    swarm/<run>/agent/<i>/msg      agent i -> neighbours   AgentMessage: tick, message vector
    swarm/<run>/config/<i>         queryable of the sim    AgentConfig of robot i (scenario, graph, policy);
                                                           an agent without a run id asks swarm/*/config/<i>
    swarm/<run>/alive/sim          liveliness token of the sim server
    swarm/<run>/alive/agent/<i>    liveliness token of robot i's controller
    swarm/<run>/fault/...          runner -> everyone: injected faults (reserved)

With a run key (``SWARM_RUN_KEY``, :class:`RunKey`) every pose, message, command and config reply
carries in its Zenoh attachment a 16-byte tag of its key expression and payload; a receiver checks it
before decoding and counts a sample without a valid one as *unauthenticated*.

Payloads are msgpack maps carrying ``"v": SCHEMA_VERSION``. Every ``decode_*`` validates
the schema version, types, finiteness and magnitudes (and, for a message, its length) and returns
``None`` for anything malformed (the caller counts it as invalid and drops it); decoding never
raises. Ticks must also advance: a receiver drops and counts as *old* a pose, message or command
whose tick is not newer than the newest it accepted from that sender (a replay or a reordered
sample), and as *future* one dated beyond what its own clock allows (:mod:`swarm.runtime.ticks`). Zenoh
callbacks are wrapped in :func:`guarded`, so that no exception reaches Zenoh.

Importable without torch, pybullet or numba: robot agents use it.
"""

from __future__ import annotations

import json
import logging
import math
import re
import struct
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, cast

import msgpack
import numpy as np

SCHEMA_VERSION = 1
ROOT = "swarm"

MAX_TICK = 2**40
MAX_TIME_S = 1e9
MAX_COORD_M = 1e5
MAX_ANGLE_RAD = 4 * math.pi
MAX_WHEEL_MPS = 100.0
MAX_MESSAGE_DIM = 1024
MAX_MESSAGE_ABS = 1e9
MAX_ROBOTS = 100_000
MAX_SMALL_PAYLOAD = 1024
MAX_MESSAGE_PAYLOAD = 64 + 8 * MAX_MESSAGE_DIM
MAX_CONFIG_PAYLOAD = 256 * 2**20

CALLBACK_ERRORS_PRINTED = 5
"""Callback errors logged per process (all are counted)."""

log = logging.getLogger(__name__)

_RUN_ID = re.compile(r"^[A-Za-z0-9_.-]{1,64}$")


def check_run_id(run: str) -> str:
    """A run id is one key chunk: letters, digits, ``_ . -`` (no ``/``, wildcards or ``$``)."""
    if not isinstance(run, str) or not _RUN_ID.match(run):
        raise ValueError(f"run id must match {_RUN_ID.pattern}, got {run!r}")
    return run


class Keys:
    """Key expressions of one run."""

    def __init__(self, run: str):
        self.run = check_run_id(run)
        self.prefix = f"{ROOT}/{run}"

    def pose(self, robot: int) -> str:
        return f"{self.prefix}/robot/{int(robot)}/pose"

    def cmd(self, robot: int) -> str:
        return f"{self.prefix}/robot/{int(robot)}/cmd"

    def sense(self, robot: int) -> str:
        return f"{self.prefix}/robot/{int(robot)}/sense"

    def msg(self, robot: int) -> str:
        return f"{self.prefix}/agent/{int(robot)}/msg"

    def inbox(self, robot: int) -> str:
        """What the sim's radio relays to robot ``robot`` on a disk graph (``sim_server.radio``)."""
        return f"{self.prefix}/robot/{int(robot)}/inbox"

    def config(self, robot: int) -> str:
        return f"{self.prefix}/config/{int(robot)}"

    def alive_agent(self, robot: int) -> str:
        return f"{self.prefix}/alive/agent/{int(robot)}"

    @property
    def alive_sim(self) -> str:
        return f"{self.prefix}/alive/sim"

    # Wildcards: for the sim server and the centralized controller only, never for an agent.
    @property
    def all_poses(self) -> str:
        return f"{self.prefix}/robot/*/pose"

    @property
    def all_cmds(self) -> str:
        return f"{self.prefix}/robot/*/cmd"

    @property
    def all_msgs(self) -> str:
        return f"{self.prefix}/agent/*/msg"

    @property
    def all_configs(self) -> str:
        return f"{self.prefix}/config/*"

    @property
    def all_alive_agents(self) -> str:
        return f"{self.prefix}/alive/agent/*"

    @property
    def faults(self) -> str:
        return f"{self.prefix}/fault/**"

    @staticmethod
    def any_run_config(robot: int) -> str:
        """Robot ``robot``'s configuration in whichever run serves it (run-id discovery)."""
        return f"{ROOT}/*/config/{int(robot)}"

    @staticmethod
    def run_of_config(key: str) -> str | None:
        """The run id in a concrete ``swarm/<run>/config/<i>`` key, or None."""
        parts = str(key).split("/")
        if len(parts) != 4 or parts[0] != ROOT or parts[2] != "config" or not parts[3].isdigit():
            return None
        return parts[1] if _RUN_ID.match(parts[1]) else None

    def robot_of(self, key: str, kind: str) -> int | None:
        """Robot index in a concrete key of ``kind`` (``pose``, ``cmd``, ``sense``, ``inbox``, ``msg``,
        ``config``, ``alive``),
        or None when the key is not of that shape."""
        patterns = {
            "pose": (f"{self.prefix}/robot/", "/pose"),
            "cmd": (f"{self.prefix}/robot/", "/cmd"),
            "sense": (f"{self.prefix}/robot/", "/sense"),
            "inbox": (f"{self.prefix}/robot/", "/inbox"),
            "msg": (f"{self.prefix}/agent/", "/msg"),
            "config": (f"{self.prefix}/config/", ""),
            "alive": (f"{self.prefix}/alive/agent/", ""),
        }
        head, tail = patterns[kind]
        key = str(key)
        if not (key.startswith(head) and key.endswith(tail)):
            return None
        middle = key[len(head) : len(key) - len(tail)]
        if not middle.isdigit() or len(middle) > 6:
            return None
        return int(middle)


# ----------------------------------------------------------------------------- schemas


@dataclass(frozen=True)
class Pose:
    """Axle-centre pose of one robot at a control tick (sim -> agent)."""

    tick: int
    time_s: float
    x_m: float
    y_m: float
    theta_rad: float

    def array(self) -> np.ndarray:
        return np.array([self.x_m, self.y_m, self.theta_rad])


@dataclass(frozen=True)
class Command:
    """Wheel linear speeds (m/s) a robot's controller wants for a tick (agent -> sim)."""

    tick: int
    left_mps: float
    right_mps: float


@dataclass(frozen=True)
class Sensing:
    """What robot i's range sensor sees at a tick (sim -> agent i; ``swarm.sim.sensing``, robot frame):
    ``bodies (M, 3)`` the range (m), bearing (rad) and relative heading (rad) of every other body within
    the sensing radius, ``obstacles (K, 2)`` the range and bearing of each obstacle's nearest surface
    point within it."""

    tick: int
    bodies: np.ndarray = field(compare=False)
    obstacles: np.ndarray = field(compare=False)


@dataclass(frozen=True)
class AgentMessage:
    """What a robot broadcasts to its graph neighbours at a tick (its controlled point first for
    local consensus; the GNN message for a learned policy)."""

    tick: int
    values: np.ndarray = field(compare=False)


@dataclass(frozen=True)
class Inbox:
    """What the sim's radio relays to robot i for a tick on a disk graph (sim -> agent i): the
    ``senders`` within range whose messages it hears, their link ``weights`` and ``values (n, dim)``,
    and ``counts`` of the messages of in-range robots it does not hear (``INBOX_COUNTS``)."""

    tick: int
    senders: tuple[int, ...]
    weights: tuple[float, ...]
    values: np.ndarray = field(compare=False)
    counts: dict[str, int] = field(compare=False)


INBOX_COUNTS = ("dropped_by_fault", "lost_by_fault", "delayed_by_fault", "lost")
"""Per inbox: in-range messages a link fault dropped or lost, heard late under a delay fault, and
that never reached the radio (a dead or silent sender)."""


@dataclass(frozen=True)
class AgentConfig:
    """Everything a robot agent needs that is not on its command line, served by the sim."""

    run: str
    robot: int
    robot_count: int
    controller: str
    gain: float
    robot_params: dict[str, float]
    neighbours: tuple[int, ...]
    weights: tuple[float, ...]
    mode: str
    control_period_s: float
    neighbour_deadline_s: float
    scenario: dict[str, Any]
    policy: bytes | None = None


_packb = msgpack.packb


def _pack(body: dict[str, Any]) -> bytes:
    return msgpack.packb({"v": SCHEMA_VERSION, **body}, use_bin_type=True)


def _unpack(data: bytes | bytearray | memoryview, limit: int) -> dict | None:
    try:
        if len(data) > limit:
            return None
        body = msgpack.unpackb(
            bytes(data),
            raw=False,
            strict_map_key=True,
            max_str_len=limit,
            max_bin_len=limit,
            max_array_len=MAX_ROBOTS,
            max_map_len=1024,
        )
    except Exception:  # any malformed input: msgpack raises many kinds
        return None
    if not isinstance(body, dict) or body.get("v") != SCHEMA_VERSION:
        return None
    return body


def _int(value: Any, low: int, high: int) -> int | None:
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
        return None
    return value


def _float(value: Any, bound: float) -> float | None:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    value = float(value)
    if not math.isfinite(value) or abs(value) > bound:
        return None
    return value


def _floats(body: dict, bounds: dict[str, float]) -> list[float] | None:
    values = [_float(body.get(key), bound) for key, bound in bounds.items()]
    return None if any(value is None for value in values) else cast("list[float]", values)


def encode_pose(tick: int, time_s: float, pose: Sequence[float]) -> bytes:
    x, y, theta = (float(value) for value in pose)
    return _pack({"k": int(tick), "t": float(time_s), "x": x, "y": y, "th": theta})


class PoseEncoder:
    """Pose payloads of ``count`` robots packed each tick into buffers allocated once.

    The bytes are the msgpack map of :func:`encode_pose` with a fixed layout: the tick always as a
    uint 64 (``0xcf``) and every float as a float 64 (``0xcb``), so one ``struct.pack_into`` per
    robot fills its buffer (msgpack readers accept a uint 64 for any tick). 60 bytes per pose.
    """

    _LAYOUT = struct.Struct(">7sQ3sd3sd3sd4sd")
    _PARTS = (
        bytes.fromhex("86a17601a16bcf"),  # map of 6, "v": 1, "k": uint 64 follows
        bytes.fromhex("a174cb"),  # "t": float 64
        bytes.fromhex("a178cb"),  # "x"
        bytes.fromhex("a179cb"),  # "y"
        bytes.fromhex("a27468cb"),  # "th"
    )

    def __init__(self, count: int):
        self.buffers = [bytearray(self._LAYOUT.size) for _ in range(count)]

    def encode(self, tick: int, time_s: float, poses: Sequence[Sequence[float]]) -> list[bytearray]:
        """Fill robot i's buffer with its pose of ``tick``; returns the buffers (reused next tick)."""
        pack, (p0, p1, p2, p3, p4) = self._LAYOUT.pack_into, self._PARTS
        tick, time_s = int(tick), float(time_s)
        for buffer, (x, y, theta) in zip(self.buffers, poses, strict=True):
            pack(buffer, 0, p0, tick, p1, time_s, p2, x, p3, y, p4, theta)
        return self.buffers


_POSE_SIZE = PoseEncoder._LAYOUT.size


def _fixed_pose(data: bytes) -> Pose | None:
    """:class:`PoseEncoder`'s layout, checked byte by byte with :func:`decode_pose`'s bounds; None
    for anything else (the general decoder then decides: this only ever accepts what it accepts)."""
    try:
        p0, tick, p1, t, p2, x, p3, y, p4, th = PoseEncoder._LAYOUT.unpack(data)
    except (struct.error, TypeError):
        return None
    if (p0, p1, p2, p3, p4) != PoseEncoder._PARTS or tick > MAX_TICK:
        return None
    if not (0 <= t <= MAX_TIME_S and abs(x) <= MAX_COORD_M and abs(y) <= MAX_COORD_M):  # NaN fails
        return None
    if not abs(th) <= MAX_ANGLE_RAD:
        return None
    return Pose(tick, t, x, y, th)


def decode_pose(data: bytes) -> Pose | None:
    if len(data) == _POSE_SIZE and (pose := _fixed_pose(data)) is not None:
        return pose  # the sim's own layout: no msgpack map, no bounds dict
    return _pose_msgpack(data)


def _pose_msgpack(data: bytes) -> Pose | None:
    """:func:`decode_pose` of any msgpack layout."""
    body = _unpack(data, MAX_SMALL_PAYLOAD)
    if body is None:
        return None
    tick = _int(body.get("k"), 0, MAX_TICK)
    values = _floats(body, {"t": MAX_TIME_S, "x": MAX_COORD_M, "y": MAX_COORD_M, "th": MAX_ANGLE_RAD})
    if tick is None or values is None or values[0] < 0:
        return None
    return Pose(tick, *values)


def encode_command(tick: int, wheels_mps: Sequence[float]) -> bytes:
    left, right = wheels_mps
    return _packb(
        {"v": SCHEMA_VERSION, "k": int(tick), "l": float(left), "r": float(right)}, use_bin_type=True
    )


def decode_command(data: bytes) -> Command | None:
    body = _unpack(data, MAX_SMALL_PAYLOAD)
    if body is None:
        return None
    tick = _int(body.get("k"), 0, MAX_TICK)
    values = _floats(body, {"l": MAX_WHEEL_MPS, "r": MAX_WHEEL_MPS})
    if tick is None or values is None:
        return None
    return Command(tick, *values)


MAX_SENSED = 4096
"""Bodies or obstacles one sensing reading may hold (a reading is dropped, invalid, beyond it)."""


def encode_sensing(tick: int, bodies: np.ndarray, obstacles: np.ndarray) -> bytes:
    """``bodies (M, 3)`` and ``obstacles (K, 2)`` travel as little-endian float64 bytes."""
    body_bytes = np.ascontiguousarray(bodies, dtype="<f8").reshape(-1).tobytes()
    obstacle_bytes = np.ascontiguousarray(obstacles, dtype="<f8").reshape(-1).tobytes()
    return _pack({"k": int(tick), "b": body_bytes, "o": obstacle_bytes})


def decode_sensing(data: bytes) -> Sensing | None:
    """None unless the tick is valid, both arrays are whole rows of at most ``MAX_SENSED``, every range
    is in ``[0, MAX_COORD_M]`` and every angle finite within ``MAX_ANGLE_RAD``."""
    body = _unpack(data, 64 + 8 * 3 * MAX_SENSED + 8 * 2 * MAX_SENSED)
    if body is None:
        return None
    tick = _int(body.get("k"), 0, MAX_TICK)
    rows = []
    for key, width in (("b", 3), ("o", 2)):
        raw = body.get(key)
        if not isinstance(raw, bytes) or len(raw) % (8 * width) or len(raw) > 8 * width * MAX_SENSED:
            return None
        values = np.frombuffer(raw, dtype="<f8").astype(np.float64).reshape(-1, width)
        ranges, angles = values[:, 0], values[:, 1:]
        if not (np.all((ranges >= 0) & (ranges <= MAX_COORD_M)) and np.all(np.abs(angles) <= MAX_ANGLE_RAD)):
            return None  # NaN fails the comparisons too
        rows.append(values)
    if tick is None:
        return None
    return Sensing(tick, rows[0], rows[1])


def encode_inbox(
    tick: int,
    senders: Sequence[int],
    weights: Sequence[float],
    values: np.ndarray,
    counts: Sequence[int],
) -> bytes:
    """``values (n, dim)`` travel as little-endian float64 bytes, ``counts`` in ``INBOX_COUNTS`` order."""
    raw = np.ascontiguousarray(values, dtype="<f8").reshape(-1).tobytes()
    return _pack(
        {
            "k": int(tick),
            "s": [int(j) for j in senders],
            "w": [float(w) for w in weights],
            "m": raw,
            "c": [int(c) for c in counts],
        }
    )


def decode_inbox(data: bytes, dim: int, robot_count: int) -> Inbox | None:
    """None unless the tick is valid, every sender a distinct robot index, one finite weight per sender,
    ``len(senders) x dim`` message values within ``MAX_MESSAGE_ABS`` and one count per ``INBOX_COUNTS``."""
    body = _unpack(data, 64 + (8 * max(dim, 1) + 24) * max(robot_count, 1))
    if body is None:
        return None
    tick = _int(body.get("k"), 0, MAX_TICK)
    senders, weights, raw, counts = body.get("s"), body.get("w"), body.get("m"), body.get("c")
    if not (isinstance(senders, list) and isinstance(weights, list) and isinstance(counts, list)):
        return None
    if tick is None or not isinstance(raw, bytes) or len(weights) != len(senders):
        return None
    if len(set(senders)) != len(senders) or any(_int(j, 0, robot_count - 1) is None for j in senders):
        return None
    weight_values = [_float(w, MAX_MESSAGE_ABS) for w in weights]
    count_values = [_int(c, 0, MAX_TICK) for c in counts]
    if None in weight_values or len(counts) != len(INBOX_COUNTS) or None in count_values:
        return None
    if len(raw) != 8 * dim * len(senders):
        return None
    values = np.frombuffer(raw, dtype="<f8").astype(np.float64).reshape(len(senders), dim)
    if not np.all(np.abs(values) <= MAX_MESSAGE_ABS):
        return None  # NaN fails the comparison too
    return Inbox(
        tick,
        tuple(int(j) for j in senders),
        cast("tuple[float, ...]", tuple(weight_values)),
        values,
        dict(zip(INBOX_COUNTS, cast("list[int]", count_values), strict=True)),
    )


SHORT_MESSAGE_DIM = 64
"""Message vectors up to this length are packed and checked as plain floats (numpy costs more)."""


def encode_message(tick: int, values: np.ndarray | Sequence[float]) -> bytes:
    """The message vector travels as little-endian float64 bytes."""
    if isinstance(values, tuple | list) and len(values) <= SHORT_MESSAGE_DIM:
        raw = struct.pack(f"<{len(values)}d", *values)
    else:
        raw = np.ascontiguousarray(values, dtype="<f8").reshape(-1).tobytes()
    return _packb({"v": SCHEMA_VERSION, "k": int(tick), "m": raw}, use_bin_type=True)


_MESSAGE_HEAD = bytes.fromhex("83a17601a16b")  # {"v": 1, "k": ... as encode_message packs it
_MESSAGE_BIN = bytes.fromhex("a16dc4")  # "m": bin 8
_UINT_BYTES = {0xCC: 1, 0xCD: 2, 0xCE: 4, 0xCF: 8}
_FLOATS = [struct.Struct(f"<{n}d") for n in range(32)]


def _fixed_message(data: bytes, dim: int | None) -> tuple[int, tuple[float, ...]] | None:
    """:func:`encode_message`'s layout (a vector of up to 31 floats), checked byte by byte with
    :func:`decode_message_values`'s bounds; None for anything else (the general decoder then
    decides: this only ever accepts what it accepts, with the same result)."""
    first = data[6]
    if first < 0x80:  # positive fixint
        tick, at = first, 7
    elif (width := _UINT_BYTES.get(first)) is not None:
        at = 7 + width
        tick = int.from_bytes(data[7:at], "big")
    else:
        return None
    size_bytes = data[at + 3] if len(data) > at + 3 else -1
    if tick > MAX_TICK or data[at : at + 3] != _MESSAGE_BIN or len(data) != at + 4 + size_bytes:
        return None
    size, rest = divmod(size_bytes, 8)
    if rest or (dim is not None and size != dim):
        return None
    floats = _FLOATS[size].unpack_from(data, at + 4)
    for value in floats:
        if not abs(value) <= MAX_MESSAGE_ABS:  # NaN fails the comparison too
            return None
    return tick, floats


def decode_message_values(data: bytes, dim: int | None = None) -> tuple[int, Sequence[float]] | None:
    """``(tick, values)`` of a message, values a tuple of floats for short vectors (else an array);
    None when malformed or, with ``dim``, of another length."""
    if data[:6] == _MESSAGE_HEAD and len(data) > 6 and (fast := _fixed_message(data, dim)) is not None:
        return fast  # a robot agent's own layout: no msgpack map
    return _message_values_msgpack(data, dim)


def _message_values_msgpack(data: bytes, dim: int | None) -> tuple[int, Sequence[float]] | None:
    """:func:`decode_message_values` of any msgpack layout."""
    body = _unpack(data, MAX_MESSAGE_PAYLOAD)
    if body is None:
        return None
    tick = _int(body.get("k"), 0, MAX_TICK)
    raw = body.get("m")
    if tick is None or not isinstance(raw, bytes) or len(raw) % 8 or len(raw) > 8 * MAX_MESSAGE_DIM:
        return None
    size = len(raw) // 8
    if dim is not None and size != dim:
        return None
    if size <= SHORT_MESSAGE_DIM:
        floats = struct.unpack(f"<{size}d", raw)
        if not all(abs(value) <= MAX_MESSAGE_ABS for value in floats):
            return None  # NaN fails the comparison too
        return tick, floats
    values: Any = np.frombuffer(raw, dtype="<f8").astype(np.float64)
    if not np.all(np.abs(values) <= MAX_MESSAGE_ABS):
        return None
    return tick, values


def decode_message(data: bytes, dim: int | None = None) -> AgentMessage | None:
    """Also rejects a vector whose length is not ``dim`` when ``dim`` is given."""
    decoded = decode_message_values(data, dim)
    if decoded is None:
        return None
    return AgentMessage(decoded[0], np.asarray(decoded[1], dtype=np.float64))


def encode_config(config: AgentConfig) -> bytes:
    body = {key: getattr(config, key) for key in AgentConfig.__dataclass_fields__}
    body["neighbours"] = list(config.neighbours)
    body["weights"] = list(config.weights)
    return _pack(body)


def decode_config(data: bytes) -> AgentConfig | None:
    body = _unpack(data, MAX_CONFIG_PAYLOAD)
    if body is None:
        return None
    try:
        count = _int(body["robot_count"], 1, MAX_ROBOTS)
        robot = _int(body["robot"], 0, MAX_ROBOTS - 1)
        neighbours = tuple(body["neighbours"])
        weights = tuple(_float(w, MAX_MESSAGE_ABS) for w in body["weights"])
        numbers = _floats(body, {"gain": MAX_MESSAGE_ABS, "control_period_s": 3600.0})
        deadline = _float(body["neighbour_deadline_s"], 3600.0)
        params = body["robot_params"]
        checks = [
            count is not None and robot is not None and robot < count,
            all(_int(j, 0, (count or 1) - 1) is not None and j != robot for j in neighbours),
            len(set(neighbours)) == len(neighbours) == len(weights),
            None not in weights and numbers is not None and numbers[1] > 0,
            deadline is not None and deadline >= 0,
            isinstance(params, dict) and all(_float(v, 1e6) is not None for v in params.values()),
            isinstance(body["run"], str) and isinstance(body["controller"], str),
            isinstance(body["mode"], str) and isinstance(body["scenario"], dict),
            body.get("policy") is None or isinstance(body["policy"], bytes),
        ]
        if not all(checks):
            return None
        assert count is not None and robot is not None and numbers is not None and deadline is not None
        return AgentConfig(
            run=body["run"],
            robot=robot,
            robot_count=count,
            controller=body["controller"],
            gain=numbers[0],
            robot_params=dict(params),
            neighbours=neighbours,
            weights=cast("tuple[float, ...]", weights),
            mode=body["mode"],
            control_period_s=numbers[1],
            neighbour_deadline_s=deadline,
            scenario=body["scenario"],
            policy=body.get("policy"),
        )
    except (KeyError, TypeError, ValueError):
        return None


# ----------------------------------------------------------------------------- sessions


def session_config(
    mode: str = "peer",
    connect: Sequence[str] = (),
    listen: Sequence[str] = (),
    lease_ms: int = 1000,
    settings: Mapping[str, Any] | None = None,
) -> Any:
    """A ``zenoh.Config``: explicit endpoints, multicast scouting off, a short lease.

    ``lease_ms`` bounds how long a frozen (not crashed) process keeps its liveliness tokens
    (NOTES-measured: ~1 s with 1000 ms; a killed process is noticed in milliseconds). ``settings``
    maps more configuration paths to JSON values (``swarm.runtime.acl``: authentication, access control).
    """
    import zenoh

    if mode not in ("peer", "client", "router"):
        raise ValueError(f"zenoh mode must be peer, client or router, got {mode!r}")
    config = zenoh.Config()
    config.insert_json5("mode", json.dumps(mode))
    config.insert_json5("connect/endpoints", json.dumps(list(connect)))
    config.insert_json5("listen/endpoints", json.dumps(list(listen)))
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("transport/link/tx/lease", str(int(lease_ms)))
    for path, value in (settings or {}).items():
        config.insert_json5(path, json.dumps(value))
    return config


def guarded(callback: Callable[[Any], None], stats: dict[str, Any], name: str) -> Callable[[Any], None]:
    """``callback`` for a Zenoh subscriber or queryable that never raises into Zenoh: an exception is
    counted in ``stats["callback_errors"]`` and its first lines are logged as errors, one line each (Zenoh
    would print a traceback per sample and carry on; the count makes it visible in the results)."""

    def run(sample: Any) -> None:
        try:
            callback(sample)
        except Exception as error:  # a bug or a sample no decoder foresaw: never the process's end
            stats["callback_errors"] = stats.get("callback_errors", 0) + 1
            if stats["callback_errors"] <= CALLBACK_ERRORS_PRINTED:
                log.error("%s: callback error: %s: %s", name, type(error).__name__, error)

    return run


def publisher_options(mode: str) -> dict[str, Any]:
    """Keyword arguments of ``declare_publisher`` for the pose, command and message streams.

    ``lockstep`` needs every sample delivered (a dropped pose or command is a missed tick), so it
    blocks on congestion; a stalled reader is bounded by the deadlines and the lease. ``realtime``
    streams latest values, so it drops (NOTES-measured: BLOCK stalled ``put`` for seconds behind a
    slow reader). Both skip batching (``express``) for latency.
    """
    import zenoh

    congestion = zenoh.CongestionControl.BLOCK if mode == "lockstep" else zenoh.CongestionControl.DROP
    return {"congestion_control": congestion, "express": True}


# ----------------------------------------------------------------------------- authentication

RUN_KEY_ENV = "SWARM_RUN_KEY"
"""Environment variable holding the run key (hex, 32 bytes) given to the sim server and its agents."""

TAG_BYTES = 16
"""Length of a sample's authentication tag (keyed BLAKE2b, in the Zenoh attachment)."""


def new_run_key() -> str:
    """A fresh run key, hex (the runner makes one per run and hands it to its children)."""
    import secrets

    return secrets.token_hex(32)


class RunKey:
    """Authentication of the run's samples with a per-run secret (docs/distributed-runtime.md).

    The tag of a payload put on key expression ``key`` is the keyed BLAKE2b (key: the run key) of
    ``key``, a NUL byte and the payload, 16 bytes, carried in the sample's Zenoh attachment. A
    sender without the run key can neither make a sample nor move a genuine one to another key or
    tick (the tag covers both). A genuine sample can still be replayed unchanged on its own key:
    receivers drop it by its tick (old). Cost per 60-byte pose: 0.34 us to tag, 0.43 us to check
    (``bench/bench_auth.py``)."""

    __slots__ = ("_bases", "_key")

    def __init__(self, key_hex: str):
        key = bytes.fromhex(key_hex)
        if not 16 <= len(key) <= 64:
            raise ValueError("a run key is 16 to 64 bytes in hex")
        self._key = key
        self._bases: dict[str, Any] = {}

    @classmethod
    def from_env(cls, environ: Mapping[str, str] | None = None) -> RunKey | None:
        """The run key of ``SWARM_RUN_KEY``, or None when it is not set (authentication off)."""
        import os

        text = (os.environ if environ is None else environ).get(RUN_KEY_ENV)
        return cls(text) if text else None

    def _base(self, key: str) -> Any:
        base = self._bases.get(key)
        if base is None:
            import hashlib

            base = hashlib.blake2b(key=self._key, digest_size=TAG_BYTES)
            base.update(key.encode() + b"\x00")
            self._bases[key] = base
        return base

    def tag(self, key: str, payload: bytes | bytearray) -> bytes:
        digest = self._base(key).copy()
        digest.update(payload)
        return digest.digest()

    def check(self, key: str, payload: bytes, tag: bytes | None) -> bool:
        """Whether ``tag`` authenticates ``payload`` on ``key`` (constant-time comparison)."""
        import hmac

        return tag is not None and len(tag) == TAG_BYTES and hmac.compare_digest(self.tag(key, payload), tag)


def attachment_of(sample: Any) -> bytes | None:
    """A sample's (or reply's) attachment as bytes, or None."""
    attachment = sample.attachment
    return None if attachment is None else attachment.to_bytes()


def config_query_options() -> dict[str, Any]:
    """Keyword arguments of ``session.get`` for a configuration: every reply, unconsolidated (Zenoh's
    default keeps one reply per key, which could be another answerer's in place of the sim's)."""
    import zenoh

    return {"consolidation": zenoh.ConsolidationMode.NONE, "timeout": 1.0}
