"""Tests for swarm.runtime.wire: key expressions, message round trips, and rejection of malformed input
(decoding returns None, never raises)."""

from __future__ import annotations

import json
import math

import msgpack
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from swarm.runtime import wire

finite = st.floats(min_value=-1e4, max_value=1e4, allow_nan=False, allow_infinity=False)
ticks = st.integers(min_value=0, max_value=wire.MAX_TICK)
DECODERS = [
    wire.decode_pose,
    wire.decode_command,
    wire.decode_message,
    wire.decode_config,
    lambda data: wire.decode_inbox(data, 3, 8),
]


def packed(body: dict) -> bytes:
    return msgpack.packb(body, use_bin_type=True)


def a_config(**changes: object) -> wire.AgentConfig:
    fields = {
        "run": "r1",
        "robot": 2,
        "robot_count": 6,
        "controller": "local_consensus",
        "gain": 1.0,
        "robot_params": {"wheel_radius_m": 0.04, "half_axle_m": 0.1, "offset_m": 0.05, "v_max_mps": 0.5},
        "neighbours": (1, 3),
        "weights": (1.0, 0.5),
        "mode": "lockstep",
        "control_period_s": 0.05,
        "neighbour_deadline_s": 0.5,
        "scenario": {"name": "x", "robots": {"count": 6}},
        "policy": b"\x00\x01policy",
    }
    fields.update(changes)
    return wire.AgentConfig(**fields)


# ----------------------------------------------------------------------------- keys


def test_keys_are_per_robot_and_parse_back():
    keys = wire.Keys("run-1")
    assert keys.pose(3) == "swarm/run-1/robot/3/pose"
    assert keys.cmd(3) == "swarm/run-1/robot/3/cmd"
    assert keys.msg(3) == "swarm/run-1/agent/3/msg"
    assert keys.config(3) == "swarm/run-1/config/3"
    assert keys.alive_agent(3) == "swarm/run-1/alive/agent/3"
    assert keys.alive_sim == "swarm/run-1/alive/sim"
    for key in (keys.pose(3), keys.cmd(3), keys.msg(3), keys.config(3), keys.alive_agent(3)):
        assert "*" not in key
    assert keys.robot_of(keys.pose(12), "pose") == 12
    assert keys.robot_of(keys.cmd(0), "cmd") == 0
    assert keys.robot_of(keys.msg(7), "msg") == 7
    assert keys.robot_of(keys.alive_agent(5), "alive") == 5
    assert keys.robot_of(keys.config(4), "config") == 4
    for bad in ("swarm/run-1/robot/x/cmd", "swarm/other/robot/1/cmd", "swarm/run-1/robot/1/pose", "", "a/b"):
        assert keys.robot_of(bad, "cmd") is None


@pytest.mark.parametrize("run", ["", "a/b", "a*", "$x", "a b", "x" * 65, "a?b", "a#b"])
def test_bad_run_ids_are_refused(run):
    with pytest.raises(ValueError, match="run id"):
        wire.Keys(run)


def test_session_config_has_explicit_endpoints_and_no_multicast():
    config = wire.session_config("client", ["tcp/127.0.0.1:7000"], (), lease_ms=800)
    assert json.loads(config.get_json("mode")) == "client"
    assert json.loads(config.get_json("connect/endpoints")) == ["tcp/127.0.0.1:7000"]
    assert json.loads(config.get_json("scouting/multicast/enabled")) is False
    assert json.loads(config.get_json("transport/link/tx/lease")) == 800
    with pytest.raises(ValueError, match="zenoh mode"):
        wire.session_config("server")


# ----------------------------------------------------------------------------- round trips


@given(tick=ticks, time_s=st.floats(0, 1e6), x=finite, y=finite, theta=st.floats(-math.pi, math.pi))
def test_pose_round_trip(tick, time_s, x, y, theta):
    pose = wire.decode_pose(wire.encode_pose(tick, time_s, (x, y, theta)))
    assert pose == wire.Pose(tick, time_s, x, y, theta)


@given(tick=ticks, time_s=st.floats(0, 1e6), x=finite, y=finite, theta=st.floats(-math.pi, math.pi))
def test_pose_encoder_packs_what_encode_pose_means(tick, time_s, x, y, theta):
    """The server's reusable buffers hold the same msgpack map as ``encode_pose`` (read by msgpack
    itself, not by our decoder) and decode to the same pose."""
    encoder = wire.PoseEncoder(2)
    encoder.encode(tick + 1, time_s + 1, [(0.0, 0.0, 0.0), (1.0, 2.0, 3.0)])  # stale content first
    buffers = encoder.encode(tick, time_s, [(x, y, theta), (-x, -y, -theta)])
    assert msgpack.unpackb(bytes(buffers[0])) == msgpack.unpackb(
        wire.encode_pose(tick, time_s, (x, y, theta))
    )
    assert wire.decode_pose(bytes(buffers[1])) == wire.Pose(tick, time_s, -x, -y, -theta)
    assert buffers is encoder.encode(tick, time_s, [(x, y, theta), (x, y, theta)])  # no new buffers


@given(tick=ticks, left=st.floats(-5, 5), right=st.floats(-5, 5))
def test_command_round_trip(tick, left, right):
    assert wire.decode_command(wire.encode_command(tick, (left, right))) == wire.Command(tick, left, right)


@given(tick=ticks, values=st.lists(finite, min_size=0, max_size=200))
def test_message_round_trip_is_exact(tick, values):
    message = wire.decode_message(wire.encode_message(tick, np.array(values)), dim=len(values))
    assert message is not None and message.tick == tick
    np.testing.assert_array_equal(message.values, np.array(values, dtype=np.float64))


def test_config_round_trip():
    config = a_config()
    assert wire.decode_config(wire.encode_config(config)) == config
    lonely = a_config(policy=None, neighbours=(), weights=())
    assert wire.decode_config(wire.encode_config(lonely)) == lonely


# ----------------------------------------------------------------------------- rejection


@settings(max_examples=300, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.binary(max_size=300))
def test_random_bytes_never_raise(data):
    for decode in DECODERS:
        decode(data)  # None or a validated value; an exception fails the test


scalars = st.none() | st.booleans() | st.integers(-(2**63), 2**64 - 1) | st.floats() | st.text(max_size=3)
values = scalars | st.binary(max_size=24) | st.lists(st.floats(), max_size=3)
fields = st.fixed_dictionaries(
    {"v": st.sampled_from([wire.SCHEMA_VERSION, 0, "1", None])},
    optional={key: values for key in ("k", "t", "x", "y", "th", "l", "r", "m")},
)


@settings(max_examples=300, suppress_health_check=[HealthCheck.too_slow])
@given(body=fields)
def test_arbitrary_maps_are_valid_or_none(body):
    pose = wire.decode_pose(packed(body))
    assert pose is None or all(math.isfinite(v) for v in (pose.time_s, pose.x_m, pose.y_m, pose.theta_rad))
    command = wire.decode_command(packed(body))
    assert command is None or abs(command.left_mps) <= wire.MAX_WHEEL_MPS
    message = wire.decode_message(packed(body))
    assert message is None or bool(np.all(np.isfinite(message.values)))


GOOD_POSE = {"v": wire.SCHEMA_VERSION, "k": 3, "t": 0.15, "x": 1.0, "y": -2.0, "th": 0.5}


@pytest.mark.parametrize(
    "change",
    [
        {"v": 99},
        {"v": None},
        {"k": -1},
        {"k": True},
        {"k": 1.5},
        {"k": wire.MAX_TICK + 1},
        {"t": -0.1},
        {"x": float("nan")},
        {"y": float("inf")},
        {"x": 1e9},
        {"th": 100.0},
        {"x": "1.0"},
        {"x": None},
    ],
    ids=repr,
)
def test_malformed_pose_is_rejected(change):
    assert wire.decode_pose(packed(GOOD_POSE)) is not None
    assert wire.decode_pose(packed({**GOOD_POSE, **change})) is None


@pytest.mark.parametrize("missing", ["v", "k", "t", "x", "y", "th"])
def test_pose_missing_field_is_rejected(missing):
    body = {key: value for key, value in GOOD_POSE.items() if key != missing}
    assert wire.decode_pose(packed(body)) is None


def test_malformed_commands_and_messages_are_rejected():
    good = {"v": wire.SCHEMA_VERSION, "k": 1, "l": 0.1, "r": 0.2}
    assert wire.decode_command(packed(good)) is not None
    for change in ({"l": float("nan")}, {"r": 1e3}, {"k": "1"}, {"l": [0.1]}):
        assert wire.decode_command(packed({**good, **change})) is None
    assert wire.decode_command(packed([1, 2, 3])) is None
    assert wire.decode_command(b"\xc1") is None  # never-used msgpack byte
    assert wire.decode_command(packed({**good, "pad": "x" * 2000})) is None  # oversized

    message = {"v": wire.SCHEMA_VERSION, "k": 1, "m": np.zeros(2).tobytes()}
    assert wire.decode_message(packed(message), dim=2) is not None
    assert wire.decode_message(packed(message), dim=3) is None  # wrong length for this controller
    assert wire.decode_message(packed({**message, "m": b"\x00" * 12})) is None  # not whole float64s
    assert wire.decode_message(packed({**message, "m": np.array([np.nan, 0.0]).tobytes()})) is None
    assert wire.decode_message(packed({**message, "m": np.array([1e12, 0.0]).tobytes()})) is None
    assert wire.decode_message(packed({**message, "m": [0.0, 0.0]})) is None
    for size in (2, 100):  # short vectors are checked in plain floats, long ones with numpy
        for bad in (np.nan, np.inf, 1e12):
            values = np.zeros(size)
            values[-1] = bad
            assert wire.decode_message(packed({**message, "m": values.tobytes()})) is None


def test_a_message_packs_the_same_from_floats_or_an_array():
    values = (1.5, -2.25e-7, 3.0)
    assert wire.encode_message(4, values) == wire.encode_message(4, np.array(values))
    assert wire.decode_message_values(wire.encode_message(4, list(values)), dim=3) == (4, values)


def test_run_id_discovery_keys():
    assert wire.Keys.any_run_config(3) == "swarm/*/config/3"
    assert wire.Keys.run_of_config(wire.Keys("bench-1_a.b").config(3)) == "bench-1_a.b"
    for key in (
        "swarm/r/config/x",
        "swarm/r/config",
        "swarm/*/config/3",
        "other/r/config/3",
        "swarm/r/pose/3",
    ):
        assert wire.Keys.run_of_config(key) is None


@pytest.mark.parametrize(
    "change",
    [
        {"robot": 6},
        {"robot_count": 0},
        {"neighbours": (2,)},  # itself
        {"neighbours": (1, 1)},
        {"neighbours": (1, 9)},
        {"weights": (1.0,)},
        {"gain": float("nan")},
        {"control_period_s": 0.0},
        {"neighbour_deadline_s": -1.0},
        {"robot_params": {"offset_m": "far"}},
        {"scenario": []},
        {"policy": "text"},
    ],
    ids=repr,
)
def test_malformed_config_is_rejected(change):
    assert wire.decode_config(wire.encode_config(a_config(**change))) is None


def test_config_without_a_field_is_rejected():
    body = msgpack.unpackb(wire.encode_config(a_config()), raw=False)
    for key in body:
        if key not in ("v", "policy"):
            partial = {k: v for k, v in body.items() if k != key}
            assert wire.decode_config(packed(partial)) is None, key


# ----------------------------------------------------------------------------- seeded garbage


def _accepted_value_is_sane(decoded: object) -> bool:
    """What a decoder lets through is within the wire's bounds, whatever the input was."""
    if isinstance(decoded, wire.Pose):
        values = (decoded.time_s, decoded.x_m, decoded.y_m, decoded.theta_rad)
        bounds = (wire.MAX_TIME_S, wire.MAX_COORD_M, wire.MAX_COORD_M, wire.MAX_ANGLE_RAD)
        return (
            0 <= decoded.tick <= wire.MAX_TICK
            and decoded.time_s >= 0
            and all(math.isfinite(v) and abs(v) <= bound for v, bound in zip(values, bounds, strict=True))
        )
    if isinstance(decoded, wire.Command):
        return 0 <= decoded.tick <= wire.MAX_TICK and all(
            math.isfinite(v) and abs(v) <= wire.MAX_WHEEL_MPS for v in (decoded.left_mps, decoded.right_mps)
        )
    if isinstance(decoded, wire.AgentMessage):
        return (
            0 <= decoded.tick <= wire.MAX_TICK
            and decoded.values.size <= wire.MAX_MESSAGE_DIM
            and bool(np.all(np.abs(decoded.values) <= wire.MAX_MESSAGE_ABS))
        )
    return isinstance(decoded, wire.AgentConfig)


def _mutate(rng: np.random.Generator, data: bytes) -> bytes:
    """Flip, overwrite, cut, duplicate or insert bytes of a valid sample."""
    buffer = bytearray(data)
    how = rng.integers(5)
    if how == 0 and buffer:
        position = rng.integers(len(buffer))
        buffer[position] ^= 1 << int(rng.integers(8))
    elif how == 1 and buffer:
        position = rng.integers(len(buffer))
        buffer[position] = int(rng.integers(256))
    elif how == 2:
        buffer = buffer[: rng.integers(len(buffer) + 1)]
    elif how == 3:
        buffer += buffer[rng.integers(len(buffer) + 1) :]
    else:
        position = rng.integers(len(buffer) + 1)
        buffer[position:position] = rng.bytes(int(rng.integers(1, 9)))
    return bytes(buffer)


def test_seeded_garbage_never_raises_and_what_passes_is_sane():
    """10,000 random byte strings and 10,000 mutations of valid samples (seeded): every decoder returns
    None or a value within the wire's bounds; none raises."""
    rng = np.random.default_rng(20240511)
    valid = [
        wire.encode_pose(12, 0.6, (1.0, -2.0, 0.5)),
        wire.encode_command(12, (0.2, -0.1)),
        wire.encode_message(12, (0.25, -1.5)),
        wire.encode_message(12, np.linspace(-1, 1, 80)),
        wire.encode_config(a_config()),
    ]
    accepted = 0
    for index in range(20_000):
        if index % 2:
            data = rng.bytes(int(rng.integers(0, 120)))
        else:
            data = valid[index // 2 % len(valid)]
            for _ in range(int(rng.integers(1, 4))):
                data = _mutate(rng, data)
        for decode in DECODERS:
            decoded = decode(data)
            if decoded is not None:
                accepted += 1
                assert _accepted_value_is_sane(decoded), (decode.__name__, data)
        assert wire.decode_message(data, dim=2) is None or wire.decode_message(data, dim=2).values.size == 2
    assert accepted > 0  # some mutations (a changed digit of a float) stay valid: the check saw them


def test_guarded_callbacks_count_errors_and_never_raise(caplog):
    stats: dict = {}
    seen = []

    def callback(sample: object) -> None:
        seen.append(sample)
        if sample == "bad":
            raise KeyError("no such field")

    guarded = wire.guarded(callback, stats, "test")
    for sample in ["ok", "bad", "ok", *["bad"] * 10]:
        guarded(sample)  # never raises
    assert len(seen) == 13 and stats["callback_errors"] == 11
    records = [record for record in caplog.records if record.name == "swarm.runtime.wire"]
    assert len(records) == wire.CALLBACK_ERRORS_PRINTED  # the first few, one line each, as errors
    assert {record.levelname for record in records} == {"ERROR"}
    assert records[0].getMessage() == "test: callback error: KeyError: 'no such field'"


def test_session_config_takes_more_settings():
    config = wire.session_config(
        "client", ["tcp/127.0.0.1:7000"], settings={"transport/auth/usrpwd": {"user": "u", "password": "p"}}
    )
    assert json.loads(config.get_json("transport/auth/usrpwd/user")) == "u"


# ----------------------------------------------------------------------------- fixed-layout fast paths
# decode_pose and decode_message_values take the sim's and the agents' own byte layouts without
# msgpack; whatever bytes they get, they must give what the msgpack path gives.

edge_floats = st.one_of(
    finite,
    st.sampled_from(
        [0.0, -0.0, math.nan, math.inf, -math.inf, 1e9, -1e9, 1.0000001e9, 1e5, -1e5, 4 * math.pi]
    ),
    st.floats(allow_nan=True, allow_infinity=True),
)
edge_ticks = st.one_of(
    ticks, st.sampled_from([0, 127, 128, 255, 256, 2**16, 2**32, wire.MAX_TICK, wire.MAX_TICK + 1])
)


def mutated(data: bytes, draw_edits: list[tuple[int, int]]) -> bytes:
    out = bytearray(data)
    for at, value in draw_edits:
        if out:
            out[at % len(out)] = value
    return bytes(out)


edits = st.lists(st.tuples(st.integers(0, 10_000), st.integers(0, 255)), max_size=3)


@settings(max_examples=400, suppress_health_check=[HealthCheck.too_slow])
@given(edge_ticks, edge_floats, edge_floats, edge_floats, edge_floats, edits, st.integers(-2, 2))
def test_fixed_pose_layout_decodes_as_msgpack_does(tick, time_s, x, y, theta, changes, cut):
    buffer = wire.PoseEncoder(1).encode(min(tick, 2**64 - 1), time_s, [(x, y, theta)])[0]
    data = mutated(bytes(buffer), changes)
    data = data[: len(data) + cut] if cut < 0 else data + b"\x00" * cut
    assert wire.decode_pose(data) == wire._pose_msgpack(data)


@settings(max_examples=400, suppress_health_check=[HealthCheck.too_slow])
@given(
    edge_ticks,
    st.lists(edge_floats, max_size=33),
    edits,
    st.integers(-2, 2),
    st.sampled_from([None, 1, 2, 3]),
)
def test_fixed_message_layout_decodes_as_msgpack_does(tick, values, changes, cut, dim):
    data = mutated(wire.encode_message(tick, values), changes)
    data = data[: len(data) + cut] if cut < 0 else data + b"\x00" * cut
    fast, general = wire.decode_message_values(data, dim), wire._message_values_msgpack(data, dim)
    assert (fast is None) == (general is None)
    if fast is not None:
        assert fast[0] == general[0] and list(fast[1]) == list(general[1])


def test_fixed_layouts_take_the_fast_path():
    """The layouts the sim and the agents send are the ones the fast paths take (else they would
    save nothing)."""
    pose = bytes(wire.PoseEncoder(1).encode(7, 0.35, [(1.0, -2.0, 0.5)])[0])
    assert wire._fixed_pose(pose) == wire.Pose(7, 0.35, 1.0, -2.0, 0.5)
    for tick in (0, 200, 70_000, 2**33):
        message = wire.encode_message(tick, (0.25, -1.5))
        assert wire._fixed_message(message, 2) == (tick, (0.25, -1.5))


def test_inbox_round_trip_and_rejections():
    """The radio's inbox (``sim_server.radio``): what goes in comes out; a payload built by hand with
    msgpack (the documented layout) is refused when any part is out of bounds."""
    values = np.array([[1.5, -2.0, 3.0], [0.0, 1e8, -7.25]])
    payload = wire.encode_inbox(12, [4, 0], [1.0, 0.5], values, [1, 2, 3, 4])
    inbox = wire.decode_inbox(payload, 3, 5)
    assert inbox is not None and inbox.tick == 12 and inbox.senders == (4, 0) and inbox.weights == (1.0, 0.5)
    np.testing.assert_array_equal(inbox.values, values)
    assert inbox.counts == dict(zip(wire.INBOX_COUNTS, [1, 2, 3, 4], strict=True))
    empty = wire.decode_inbox(wire.encode_inbox(0, [], [], np.zeros((0, 3)), [0, 0, 0, 0]), 3, 5)
    assert empty is not None and empty.senders == () and empty.values.shape == (0, 3)
    good = {"v": 1, "k": 12, "s": [4, 0], "w": [1.0, 0.5], "m": values.astype("<f8").tobytes(), "c": [0] * 4}
    assert wire.decode_inbox(msgpack.packb(good, use_bin_type=True), 3, 5) is not None
    bad = [
        {"s": [4, 4]},  # a sender twice
        {"s": [5, 0]},  # no robot 5 of 5
        {"s": [-1, 0]},
        {"w": [1.0]},  # one weight short
        {"w": [1.0, float("nan")]},
        {"m": values.astype("<f8").tobytes()[:-8]},  # not n x dim values
        {"m": np.array([[1.0, 2.0, float("inf")], [0, 0, 0]]).astype("<f8").tobytes()},
        {"c": [0, 0, 0]},  # a count short
        {"c": [0, 0, -1, 0]},
        {"k": -1},
        {"s": "04"},
    ]
    for change in bad:
        assert wire.decode_inbox(msgpack.packb({**good, **change}, use_bin_type=True), 3, 5) is None, change
    assert wire.decode_inbox(payload, 2, 5) is None  # another message length
