"""ROS 2 topics over Zenoh exactly as ``rmw_zenoh_cpp`` maps them (docs/ros2.md): the one module that knows.

A ROS 2 node on ``rmw_zenoh_cpp`` is a Zenoh session; every topic is a key expression and every
message a CDR payload, so a process that speaks Zenoh can talk to ROS 2 nodes with no bridge and no
ROS installation. The mapping (rmw_zenoh ``liveliness_utils.cpp``, ``attachment_helpers.cpp``):

* **Topic key**: ``<domain_id>/<topic without its leading and trailing slash>/<dds type>/<type hash>``,
  the DDS type ``<pkg>::msg::dds_::<Type>_`` and the hash ``RIHS01_<sha256 hex>`` of REP 2011
  (Humble writes ``TypeHashNotSupported``), e.g.
  ``0/robot_3/cmd_vel/geometry_msgs::msg::dds_::Twist_/RIHS01_9c45...``.
* **Payload**: standard CDR with its 4-byte encapsulation header (``00 01 00 00``: CDR little endian),
  serialized by ``rosbags`` (a Twist is 52 bytes).
* **Attachment** on every sample (a subscriber drops a sample without one): the ``zenoh-ext``
  serialization of ``(int64 sequence_number, int64 source_timestamp_ns, uint8[16] source_gid)``:
  8 + 8 bytes little endian, then the GID as a sequence (LEB128 length 16, then 16 bytes); 33 bytes.
  rmw_zenoh up to Jazzy 0.2.3 wrote a string label before each field; 0.2.4 on (and Kilted,
  Rolling) write none, which is what is produced here.
* **Discovery**: liveliness tokens ``@ros2_lv/<domain>/<zid>/<node id>/<entity id>/<NN|MP|MS>/
  <enclave>/<namespace>/<node name>[/<topic>/<dds type>/<type hash>/<qos>]``, each name *mangled*
  (every ``/`` becomes ``%``; an empty namespace is ``%``). ``ros2 node list`` reads the ``NN`` tokens,
  ``ros2 topic list`` the ``MP`` and ``MS`` ones. The GID of an entity is a 16-byte hash of its token
  (rmw_zenoh: XXH3-128; here BLAKE2b-128: a GID is opaque to its receivers).

Importable without torch or pybullet (robot agents use it); needs ``rosbags`` (extra ``ros2``).
"""

from __future__ import annotations

import hashlib
import itertools
import math
import struct
import time
from dataclasses import dataclass
from typing import Any

from rosbags.typesys import Stores, get_typestore

TWIST = "geometry_msgs/msg/Twist"
ODOMETRY = "nav_msgs/msg/Odometry"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
CLOCK = "rosgraph_msgs/msg/Clock"
MESSAGE_TYPES = (TWIST, ODOMETRY, POSE_STAMPED, CLOCK)
"""Every ROS 2 message type the project sends or reads."""

POSE_TYPES = {"odometry": ODOMETRY, "pose_stamped": POSE_STAMPED}
"""How an agent may read its pose: ``odometry`` on ``<ns>/odom`` (a robot's odometry, the default) or
``pose_stamped`` from a motion-capture system (e.g. ``<ns>/pose``)."""

ADMIN_SPACE = "@ros2_lv"
NODE, PUBLISHER, SUBSCRIPTION = "NN", "MP", "MS"
GID_BYTES = 16
ATTACHMENT_BYTES = 8 + 8 + 1 + GID_BYTES
CDR_LE_HEADER = b"\x00\x01\x00\x00"
DEFAULT_ROUTER = "tcp/localhost:7447"
"""Where a ROS 2 node on rmw_zenoh looks for its router by default (``rmw_zenohd``)."""

# rmw_zenoh's liveliness QoS field for the default profile (reliable, volatile, keep last 10):
# every component equal to the default is left empty; ``:`` between policies, ``,`` within.
DEFAULT_QOS = "::,:,:,:,,"
"""QoS of the entities here, as rmw_zenoh writes it in a token: reliability, durability, history
(kind, depth), deadline, lifespan, liveliness, each empty where it is the default; depth 10."""

MAX_DOMAIN_ID = 232
"""ROS 2 domain ids are 0-232 (REP 2004's DDS port arithmetic)."""

_STORE = get_typestore(Stores.ROS2_JAZZY)


def dds_type(ros_type: str) -> str:
    """``geometry_msgs/msg/Twist`` -> ``geometry_msgs::msg::dds_::Twist_``."""
    package, kind, name = ros_type.split("/")
    return f"{package}::{kind}::dds_::{name}_"


def type_hash(ros_type: str) -> str:
    """The RIHS01 hash of a message type (REP 2011), computed by ``rosbags`` from its definition."""
    return str(_STORE.hash_rihs01(ros_type))


def topic_name(namespace: str, name: str) -> str:
    """The fully qualified topic ``/<namespace>/<name>`` (``name`` absolute when it starts with ``/``)."""
    if name.startswith("/"):
        return name
    namespace = namespace.strip("/")
    return f"/{namespace}/{name}" if namespace else f"/{name}"


def topic_key(domain_id: int, topic: str, ros_type: str) -> str:
    """The Zenoh key expression of ``topic`` with type ``ros_type`` in ``domain_id``."""
    check_domain_id(domain_id)
    return f"{int(domain_id)}/{topic.strip('/')}/{dds_type(ros_type)}/{type_hash(ros_type)}"


def topic_key_any_type(domain_id: int, topic: str) -> str:
    """Every type's key of ``topic`` (for the access-control rules): ``<domain>/<topic>/*/*``."""
    return f"{int(domain_id)}/{topic.strip('/')}/*/*"


def check_domain_id(domain_id: int) -> int:
    if isinstance(domain_id, bool) or not isinstance(domain_id, int) or not 0 <= domain_id <= MAX_DOMAIN_ID:
        raise ValueError(f"ros2.domain_id must be an integer in 0-{MAX_DOMAIN_ID}, got {domain_id!r}")
    return domain_id


def mangle(name: str) -> str:
    """A name as one key chunk (rmw_zenoh's ``mangle_name``): every ``/`` becomes ``%``."""
    return name.replace("/", "%")


# ----------------------------------------------------------------------------- attachment


def encode_attachment(sequence_number: int, source_timestamp_ns: int, gid: bytes) -> bytes:
    """The attachment of one sample (module docstring): 33 bytes."""
    if len(gid) != GID_BYTES:
        raise ValueError(f"a source GID is {GID_BYTES} bytes, got {len(gid)}")
    return struct.pack("<qqB", sequence_number, source_timestamp_ns, GID_BYTES) + bytes(gid)


@dataclass(frozen=True)
class Attachment:
    sequence_number: int
    source_timestamp_ns: int
    gid: bytes


def decode_attachment(data: bytes | None) -> Attachment | None:
    """An attachment of the form :func:`encode_attachment` writes, or None."""
    if data is None or len(data) != ATTACHMENT_BYTES or data[16] != GID_BYTES:
        return None
    sequence_number, timestamp_ns, _ = struct.unpack_from("<qqB", data)
    return Attachment(sequence_number, timestamp_ns, bytes(data[17:]))


def gid_of(token: str) -> bytes:
    """The 16-byte GID of the entity whose liveliness token is ``token``."""
    return hashlib.blake2b(token.encode(), digest_size=GID_BYTES).digest()


# ----------------------------------------------------------------------------- messages (rosbags)


def _msg(ros_type: str) -> Any:
    return _STORE.types[ros_type]


def _time(stamp_s: float) -> Any:
    sec = math.floor(stamp_s)
    nanosec = min(round((stamp_s - sec) * 1e9), 999_999_999)
    return _msg("builtin_interfaces/msg/Time")(sec=int(sec), nanosec=int(nanosec))


def _header(stamp_s: float, frame_id: str) -> Any:
    return _msg("std_msgs/msg/Header")(stamp=_time(stamp_s), frame_id=frame_id)


def _quaternion_of_yaw(theta_rad: float) -> Any:
    return _msg("geometry_msgs/msg/Quaternion")(
        x=0.0, y=0.0, z=math.sin(theta_rad / 2), w=math.cos(theta_rad / 2)
    )


def yaw_of(q: Any) -> float:
    """The yaw (rad) of a quaternion: atan2(2(wz + xy), 1 - 2(y^2 + z^2))."""
    return math.atan2(2 * (q.w * q.z + q.x * q.y), 1 - 2 * (q.y * q.y + q.z * q.z))


def encode_twist(linear_mps: float, angular_radps: float) -> bytes:
    """A ``geometry_msgs/msg/Twist`` of a planar robot: linear.x and angular.z, the rest 0."""
    vector = _msg("geometry_msgs/msg/Vector3")
    twist = _msg(TWIST)(
        linear=vector(x=float(linear_mps), y=0.0, z=0.0), angular=vector(x=0.0, y=0.0, z=float(angular_radps))
    )
    return bytes(_STORE.serialize_cdr(twist, TWIST))


def encode_odometry(
    stamp_s: float, pose: tuple[float, float, float], twist: tuple[float, float], frame: tuple[str, str]
) -> bytes:
    """A ``nav_msgs/msg/Odometry``: pose (x, y, theta) of the axle centre in ``frame[0]`` (``odom``),
    twist (linear.x, angular.z) in the child frame ``frame[1]`` (``base_link``); covariances 0."""
    x, y, theta = pose
    m = _msg
    odometry = m(ODOMETRY)(
        header=_header(stamp_s, frame[0]),
        child_frame_id=frame[1],
        pose=m("geometry_msgs/msg/PoseWithCovariance")(
            pose=m("geometry_msgs/msg/Pose")(
                position=m("geometry_msgs/msg/Point")(x=float(x), y=float(y), z=0.0),
                orientation=_quaternion_of_yaw(float(theta)),
            ),
            covariance=_zeros(36),
        ),
        twist=m("geometry_msgs/msg/TwistWithCovariance")(
            twist=m(TWIST)(
                linear=m("geometry_msgs/msg/Vector3")(x=float(twist[0]), y=0.0, z=0.0),
                angular=m("geometry_msgs/msg/Vector3")(x=0.0, y=0.0, z=float(twist[1])),
            ),
            covariance=_zeros(36),
        ),
    )
    return bytes(_STORE.serialize_cdr(odometry, ODOMETRY))


def encode_pose_stamped(stamp_s: float, pose: tuple[float, float, float], frame_id: str) -> bytes:
    """A ``geometry_msgs/msg/PoseStamped`` (what a motion-capture system publishes)."""
    x, y, theta = pose
    m = _msg
    stamped = m(POSE_STAMPED)(
        header=_header(stamp_s, frame_id),
        pose=m("geometry_msgs/msg/Pose")(
            position=m("geometry_msgs/msg/Point")(x=float(x), y=float(y), z=0.0),
            orientation=_quaternion_of_yaw(float(theta)),
        ),
    )
    return bytes(_STORE.serialize_cdr(stamped, POSE_STAMPED))


def encode_clock(stamp_s: float) -> bytes:
    """A ``rosgraph_msgs/msg/Clock`` (``/clock``: the sim time ROS 2 nodes with use_sim_time follow)."""
    return bytes(_STORE.serialize_cdr(_msg(CLOCK)(clock=_time(stamp_s)), CLOCK))


def _zeros(n: int) -> Any:
    import numpy as np

    return np.zeros(n, dtype=np.float64)


def _decode(data: bytes, ros_type: str) -> Any | None:
    if len(data) < 4 or data[:4] != CDR_LE_HEADER:
        return None
    try:
        return _STORE.deserialize_cdr(bytes(data), ros_type)
    except Exception:  # rosbags raises several kinds on a malformed payload
        return None


def _finite(*values: float) -> bool:
    return all(math.isfinite(v) for v in values)


def decode_twist(data: bytes) -> tuple[float, float] | None:
    """(linear.x m/s, angular.z rad/s) of a Twist, or None when it does not decode or is not finite."""
    twist = _decode(data, TWIST)
    if twist is None or not _finite(twist.linear.x, twist.angular.z):
        return None
    return float(twist.linear.x), float(twist.angular.z)


@dataclass(frozen=True)
class StampedPose:
    stamp_s: float
    x_m: float
    y_m: float
    theta_rad: float


def decode_pose(data: bytes, ros_type: str) -> StampedPose | None:
    """The planar pose and header stamp of an Odometry or PoseStamped, or None."""
    message = _decode(data, ros_type)
    if message is None:
        return None
    pose = message.pose.pose if ros_type == ODOMETRY else message.pose
    stamp_s = message.header.stamp.sec + 1e-9 * message.header.stamp.nanosec
    theta = yaw_of(pose.orientation)
    if not _finite(stamp_s, pose.position.x, pose.position.y, theta):
        return None
    return StampedPose(stamp_s, float(pose.position.x), float(pose.position.y), theta)


def decode_clock(data: bytes) -> float | None:
    clock = _decode(data, CLOCK)
    return None if clock is None else clock.clock.sec + 1e-9 * clock.clock.nanosec


# ----------------------------------------------------------------------------- differential drive


def twist_of_wheels(left_mps: float, right_mps: float, half_axle_m: float) -> tuple[float, float]:
    """Wheel linear speeds -> (v, omega): v = (l + r) / 2, omega = (r - l) / (2 b) (thesis eq. 2.1)."""
    return 0.5 * (left_mps + right_mps), (right_mps - left_mps) / (2 * half_axle_m)


def wheels_of_twist(linear_mps: float, angular_radps: float, half_axle_m: float) -> tuple[float, float]:
    """(v, omega) -> wheel linear speeds: l = v - b omega, r = v + b omega (inverse of the above)."""
    return linear_mps - half_axle_m * angular_radps, linear_mps + half_axle_m * angular_radps


# ----------------------------------------------------------------------------- scenario key


@dataclass(frozen=True)
class Ros2Settings:
    """The scenario's ``ros2`` block: ``{domain_id, namespace, pose, pose_topic}``.

    ``namespace`` is a template (``{i}``: the robot id), default ``robot_{i}``; ``pose`` is
    ``odometry`` (``<ns>/odom``, the default) or ``pose_stamped`` (``pose_topic``, default ``<ns>/pose``:
    a motion-capture system's)."""

    domain_id: int = 0
    namespace: str = "robot_{i}"
    pose: str = "odometry"
    pose_topic: str | None = None

    @classmethod
    def from_scenario(cls, scenario: dict[str, Any]) -> Ros2Settings:
        block = scenario.get("ros2") or {}
        return cls(**block)

    def namespace_of(self, robot: int) -> str:
        return "/" + self.namespace.format(i=int(robot)).strip("/")

    def cmd_vel(self, robot: int) -> str:
        return topic_name(self.namespace_of(robot), "cmd_vel")

    def odom(self, robot: int) -> str:
        return topic_name(self.namespace_of(robot), "odom")

    def pose_type(self) -> str:
        return POSE_TYPES[self.pose]

    def pose_source(self, robot: int) -> str:
        """The topic robot ``robot``'s agent reads its pose from."""
        if self.pose_topic is not None:
            return topic_name(self.namespace_of(robot), self.pose_topic.format(i=int(robot)))
        return self.odom(robot) if self.pose == "odometry" else topic_name(self.namespace_of(robot), "pose")


# ----------------------------------------------------------------------------- nodes


class Node:
    """A ROS 2 node's graph presence on a Zenoh session: its ``NN`` token and one ``MP`` / ``MS`` token
    per publisher and subscription, so that ``ros2 node list`` and ``ros2 topic list`` show it."""

    _ids = itertools.count(1)

    def __init__(self, session: Any, domain_id: int, namespace: str, name: str, enclave: str = "/"):
        self.session = session
        self.domain_id = check_domain_id(domain_id)
        self.namespace, self.name = "/" + namespace.strip("/") if namespace.strip("/") else "/", name
        self.zid = str(session.info.zid())
        self.node_id = next(Node._ids)
        self._prefix = f"{ADMIN_SPACE}/{domain_id}/{self.zid}/{self.node_id}"
        self._suffix = f"{mangle(enclave)}/{mangle(self.namespace)}/{mangle(name)}"
        self.tokens: list[str] = [f"{self._prefix}/{self.node_id}/{NODE}/{self._suffix}"]
        self._entities: list[Any] = [session.liveliness().declare_token(self.tokens[0])]

    def endpoint_token(self, kind: str, topic: str, ros_type: str) -> str:
        entity_id = next(Node._ids)
        return (
            f"{self._prefix}/{entity_id}/{kind}/{self._suffix}/{mangle(topic)}/"
            f"{dds_type(ros_type)}/{type_hash(ros_type)}/{DEFAULT_QOS}"
        )

    def announce(self, kind: str, topic: str, ros_type: str) -> str:
        """Declare the ``MP`` or ``MS`` token of an endpoint of this node; returns the token."""
        token = self.endpoint_token(kind, topic, ros_type)
        self._entities.append(self.session.liveliness().declare_token(token))
        self.tokens.append(token)
        return token

    def publisher(self, topic: str, ros_type: str, **options: Any) -> Publisher:
        token = self.announce(PUBLISHER, topic, ros_type)
        key = topic_key(self.domain_id, topic, ros_type)
        publisher = Publisher(self.session.declare_publisher(key, **options), key, gid_of(token))
        self._entities.append(publisher.publisher)
        return publisher

    def subscription(self, topic: str, ros_type: str, handler: Any) -> Any:
        """A subscriber of ``topic`` (``handler``: a callback or a Zenoh channel) and its ``MS`` token."""
        self.announce(SUBSCRIPTION, topic, ros_type)
        subscriber = self.session.declare_subscriber(topic_key(self.domain_id, topic, ros_type), handler)
        self._entities.append(subscriber)
        return subscriber

    def undeclare(self) -> None:
        """Undeclare every token, publisher and subscriber of the node."""
        for entity in reversed(self._entities):
            entity.undeclare()
        self._entities.clear()


class Publisher:
    """A ROS 2 publisher: every sample with its attachment (sequence number from 1, source time)."""

    __slots__ = ("gid", "key", "publisher", "sequence_number")

    def __init__(self, publisher: Any, key: str, gid: bytes):
        self.publisher, self.key, self.gid = publisher, key, gid
        self.sequence_number = 0

    def put(self, payload: bytes) -> None:
        self.sequence_number += 1
        attachment = encode_attachment(self.sequence_number, time.time_ns(), self.gid)
        self.publisher.put(payload, encoding="application/cdr", attachment=attachment)


def parse_token(token: str) -> dict[str, str] | None:
    """The parts of an ``@ros2_lv`` token (``kind``, ``namespace``, ``node``, and for endpoints
    ``topic``, ``type``, ``hash``), names demangled; None for another key."""
    parts = token.split("/")
    if len(parts) < 9 or parts[0] != ADMIN_SPACE:
        return None
    out = {"domain": parts[1], "kind": parts[5], "namespace": parts[7].replace("%", "/"), "node": parts[8]}
    if len(parts) >= 13:
        out.update(topic=parts[9].replace("%", "/"), type=parts[10], hash=parts[11], qos=parts[12])
    return out


# ----------------------------------------------------------------------------- access control


def acl_key_exprs(settings: Ros2Settings, robot: int) -> dict[str, list[str]]:
    """Robot ``robot``'s ROS 2 keys for the access-control rules (``swarm.runtime.acl``): the pose it
    hears, the command it publishes, and its liveliness tokens (only those of its own namespace)."""
    domain = settings.domain_id
    return {
        "heard": [topic_key_any_type(domain, settings.pose_source(robot))],
        "published": [topic_key_any_type(domain, settings.cmd_vel(robot))],
        "tokens": [f"{ADMIN_SPACE}/{domain}/*/*/*/*/*/{mangle(settings.namespace_of(robot))}/**"],
    }
