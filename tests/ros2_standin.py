"""A ROS 2 stand-in written from rmw_zenoh's specification, without any code of this project.

It speaks ROS 2 over Zenoh as ``rmw_zenoh_cpp`` does, with ``eclipse-zenoh`` (sessions, liveliness,
and ``zenoh.ext``'s serializer for the attachment, the one rmw_zenoh's C++ uses), ``rosbags`` (CDR and
message classes) and, for the type hashes, the independent ``zenoh-ros2-sdk``'s RIHS01 computation
from the message definitions written out below (no network). Two roles:

``robots``: N simulated differential-drive ROS 2 robots (a router, like ``rmw_zenohd``): each tick k it
publishes every robot's ``nav_msgs/msg/Odometry`` on ``/<ns>/odom`` stamped k * dt, waits for a Twist on
every ``/<ns>/cmd_vel`` (or a timeout), integrates the unicycle x' = v cos th, y' = v sin th, th' = w
for dt, and goes on. It starts once a publisher of every robot's cmd_vel holds its liveliness token.

``controller``: a ROS 2 controller of N robots (a client of a router): on every robot's odometry it
publishes a Twist driving it to the centroid of the latest positions of all robots (v = k_v d cos e,
w = k_w e, e the heading error), until ``/clock`` stops for a while.

Either writes what it saw (every sample's key, payload size, CDR header, attachment) to ``--out``.
"""

from __future__ import annotations

import argparse
import json
import math
import struct
import threading
import time

import zenoh
import zenoh.ext
from rosbags.typesys import Stores, get_typestore
from zenoh_ros2_sdk.utils import get_type_hash

STORE = get_typestore(Stores.ROS2_JAZZY)
VECTOR3 = "float64 x\nfloat64 y\nfloat64 z\n"
DEFINITIONS = {  # (definition, dependencies) from ROS 2 Jazzy's common_interfaces / rcl_interfaces
    "geometry_msgs/msg/Twist": ("Vector3 linear\nVector3 angular\n", {"geometry_msgs/msg/Vector3": VECTOR3}),
    "nav_msgs/msg/Odometry": (
        "std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/PoseWithCovariance pose\n"
        "geometry_msgs/TwistWithCovariance twist\n",
        {
            "std_msgs/msg/Header": "builtin_interfaces/Time stamp\nstring frame_id\n",
            "builtin_interfaces/msg/Time": "int32 sec\nuint32 nanosec\n",
            "geometry_msgs/msg/PoseWithCovariance": "Pose pose\nfloat64[36] covariance\n",
            "geometry_msgs/msg/Pose": "Point position\nQuaternion orientation\n",
            "geometry_msgs/msg/Point": "float64 x\nfloat64 y\nfloat64 z\n",
            "geometry_msgs/msg/Quaternion": "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n",
            "geometry_msgs/msg/TwistWithCovariance": "Twist twist\nfloat64[36] covariance\n",
            "geometry_msgs/msg/Twist": "Vector3 linear\nVector3 angular\n",
            "geometry_msgs/msg/Vector3": VECTOR3,
        },
    ),
    "rosgraph_msgs/msg/Clock": (
        "builtin_interfaces/Time clock\n",
        {"builtin_interfaces/msg/Time": "int32 sec\nuint32 nanosec\n"},
    ),
}


def key(domain: int, topic: str, ros_type: str) -> str:
    package, _, name = ros_type.split("/")
    definition, dependencies = DEFINITIONS[ros_type]
    type_hash = get_type_hash(ros_type, definition, dependencies)
    return f"{domain}/{topic.strip('/')}/{package}::msg::dds_::{name}_/{type_hash}"


class Graph:
    """This process's liveliness tokens: one node, its publishers and subscriptions."""

    ids = iter(range(1, 10**6))

    def __init__(self, session, domain: int, namespace: str, name: str):
        self.session, self.domain = session, domain
        self.prefix = f"@ros2_lv/{domain}/{session.info.zid()}"
        self.node_id = next(self.ids)
        self.tail = f"%/{namespace.replace('/', '%') or '%'}/{name}"
        self.tokens = [
            session.liveliness().declare_token(f"{self.prefix}/{self.node_id}/{self.node_id}/NN/{self.tail}")
        ]

    def endpoint(self, kind: str, topic: str, ros_type: str) -> None:
        package, _, name = ros_type.split("/")
        type_hash = key(self.domain, topic, ros_type).rsplit("/", 1)[1]
        token = (
            f"{self.prefix}/{self.node_id}/{next(self.ids)}/{kind}/{self.tail}/{topic.replace('/', '%')}/"
            f"{package}::msg::dds_::{name}_/{type_hash}/::,:,:,:,,"
        )
        self.tokens.append(self.session.liveliness().declare_token(token))


class Writer:
    def __init__(self, session, topic_key: str):
        self.publisher = session.declare_publisher(topic_key)
        self.sequence = 0
        self.gid = struct.pack("<QQ", hash(topic_key) & (2**64 - 1), 7)

    def put(self, message, ros_type: str) -> None:
        self.sequence += 1
        attachment = zenoh.ext.z_serialize(
            (zenoh.ext.Int64(self.sequence), zenoh.ext.Int64(time.time_ns()), self.gid)
        )
        self.publisher.put(bytes(STORE.serialize_cdr(message, ros_type)), attachment=attachment)


def check_sample(sample, ros_type: str) -> dict:
    """What a receiver on rmw_zenoh checks: a CDR payload with its header, an attachment it can read."""
    payload = sample.payload.to_bytes()
    entry = {"key": str(sample.key_expr), "bytes": len(payload), "header": payload[:4].hex()}
    try:
        message = STORE.deserialize_cdr(payload, ros_type)
    except Exception as error:
        entry["cdr_error"] = repr(error)
        message = None
    if sample.attachment is None:
        entry["attachment"] = None
    else:
        raw = sample.attachment.to_bytes()
        try:
            seq, stamp_ns, gid = zenoh.ext.z_deserialize(
                tuple[zenoh.ext.Int64, zenoh.ext.Int64, bytes], sample.attachment
            )
            entry["attachment"] = {
                "bytes": len(raw),
                "sequence_number": seq,
                "source_timestamp_ns": stamp_ns,
                "gid": gid.hex(),
            }
        except zenoh.ext.ZDeserializeError as error:
            entry["attachment"] = {"bytes": len(raw), "error": repr(error)}
    return {"entry": entry, "message": message}


def yaw(q) -> float:
    return math.atan2(2 * (q.w * q.z + q.x * q.y), 1 - 2 * (q.y * q.y + q.z * q.z))


def stamp(t_s: float):
    sec = math.floor(t_s)
    return STORE.types["builtin_interfaces/msg/Time"](sec=sec, nanosec=round((t_s - sec) * 1e9))


def odometry(t_s: float, pose, frame: str):
    m = STORE.types
    import numpy as np

    q = m["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=math.sin(pose[2] / 2), w=math.cos(pose[2] / 2))
    vector = m["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
    return m["nav_msgs/msg/Odometry"](
        header=m["std_msgs/msg/Header"](stamp=stamp(t_s), frame_id="odom"),
        child_frame_id=frame,
        pose=m["geometry_msgs/msg/PoseWithCovariance"](
            pose=m["geometry_msgs/msg/Pose"](
                position=m["geometry_msgs/msg/Point"](x=pose[0], y=pose[1], z=0.0), orientation=q
            ),
            covariance=np.zeros(36),
        ),
        twist=m["geometry_msgs/msg/TwistWithCovariance"](
            twist=m["geometry_msgs/msg/Twist"](linear=vector, angular=vector), covariance=np.zeros(36)
        ),
    )


def robots(args) -> dict:
    config = zenoh.Config()
    config.insert_json5("mode", '"router"')
    config.insert_json5("listen/endpoints", json.dumps([args.endpoint]))
    config.insert_json5("scouting/multicast/enabled", "false")
    poses = [list(p) for p in json.loads(args.poses)]
    n, domain, dt = len(poses), args.domain, args.dt
    twists: dict[int, tuple[float, float] | None] = dict.fromkeys(range(n))
    seen: list[dict] = []
    tokens: set[str] = set()
    cond = threading.Condition()
    with zenoh.open(config) as session:
        graph = Graph(session, domain, "/", "standin_robots")
        writers = []
        for i in range(n):
            ns = args.namespace.format(i=i)
            graph.endpoint("MP", f"/{ns}/odom", "nav_msgs/msg/Odometry")
            graph.endpoint("MS", f"/{ns}/cmd_vel", "geometry_msgs/msg/Twist")
            writers.append(Writer(session, key(domain, f"/{ns}/odom", "nav_msgs/msg/Odometry")))

        def on_cmd(i):
            def callback(sample):
                checked = check_sample(sample, "geometry_msgs/msg/Twist")
                with cond:
                    seen.append({"robot": i, **checked["entry"]})
                    if checked["message"] is not None and checked["entry"]["attachment"] is not None:
                        twists[i] = (checked["message"].linear.x, checked["message"].angular.z)
                        cond.notify_all()

            return callback

        subs = [
            session.declare_subscriber(
                key(domain, f"/{args.namespace.format(i=i)}/cmd_vel", "geometry_msgs/msg/Twist"), on_cmd(i)
            )
            for i in range(n)
        ]

        def on_token(sample):
            with cond:
                (tokens.add if sample.kind == zenoh.SampleKind.PUT else tokens.discard)(str(sample.key_expr))
                cond.notify_all()

        live = session.liveliness().declare_subscriber(f"@ros2_lv/{domain}/**", on_token, history=True)
        wanted = [f"/MP/%/%{args.namespace.format(i=i)}/" for i in range(n)]

        def ready():
            # every robot's node (NN) and its cmd_vel publisher (MP): the two tokens come on the same
            # session but not always in that order (a CI run once started between them)
            return all(
                any(w in t and t.split("/")[9] == f"%{args.namespace.format(i=i)}%cmd_vel" for t in tokens)
                and any(f"/NN/%/%{args.namespace.format(i=i)}/" in t for t in tokens)
                for i, w in enumerate(wanted)
            )

        deadline = time.monotonic() + args.startup_timeout
        with cond:
            while not ready() and time.monotonic() < deadline:
                cond.wait(0.1)
            started = ready()
            tokens_at_start = sorted(tokens)
        ticks_missed = 0
        missed_by_robot = [0] * n  # ticks stepped without this robot's twist (it came late or never)
        for k in range(args.ticks if started else 0):
            with cond:
                for i in range(n):
                    twists[i] = None
            for i, writer in enumerate(writers):
                writer.put(
                    odometry(k * dt, poses[i], f"{args.namespace.format(i=i)}/base_link"),
                    "nav_msgs/msg/Odometry",
                )
            until = time.monotonic() + args.tick_timeout
            with cond:
                while any(t is None for t in twists.values()) and time.monotonic() < until:
                    cond.wait(0.01)
                got = dict(twists)
            ticks_missed += any(t is None for t in got.values())
            for i, twist in got.items():
                missed_by_robot[i] += twist is None
            for i, twist in got.items():
                v, w = twist if twist is not None else (0.0, 0.0)
                x, y, th = poses[i]
                poses[i] = [x + v * math.cos(th) * dt, y + v * math.sin(th) * dt, th + w * dt]
        # a starved agent's last commands may come after the last tick: wait for one per robot and tick
        # (or 10 s), then a moment for any extra one
        flush_until = time.monotonic() + 10.0
        with cond:
            while len(seen) < n * args.ticks and time.monotonic() < flush_until:
                cond.wait(0.05)
        time.sleep(0.5)
        for entity in (*subs, live):
            entity.undeclare()
    return {
        "started": started,
        "ticks_missed": ticks_missed,
        "missed_by_robot": missed_by_robot,
        "final_poses": poses,
        "cmd_vel": seen,
        "tokens_at_start": tokens_at_start,
    }


def controller(args) -> dict:
    config = zenoh.Config()
    config.insert_json5("mode", '"client"')
    config.insert_json5("connect/endpoints", json.dumps([args.endpoint]))
    config.insert_json5("scouting/multicast/enabled", "false")
    n, domain = args.robots, args.domain
    latest: dict[int, tuple[float, float, float]] = {}
    seen: list[dict] = []
    clock = {"t": None, "wall": time.monotonic(), "count": 0}
    lock = threading.Lock()
    deadline = time.monotonic() + args.startup_timeout
    while True:  # a ROS 2 node waits for its router
        try:
            session = zenoh.open(config)
            break
        except zenoh.ZError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.2)
    with session:
        graph = Graph(session, domain, "/", "standin_controller")
        writers = []
        for i in range(n):
            ns = args.namespace.format(i=i)
            graph.endpoint("MS", f"/{ns}/odom", "nav_msgs/msg/Odometry")
            graph.endpoint("MP", f"/{ns}/cmd_vel", "geometry_msgs/msg/Twist")
            writers.append(Writer(session, key(domain, f"/{ns}/cmd_vel", "geometry_msgs/msg/Twist")))
        graph.endpoint("MS", "/clock", "rosgraph_msgs/msg/Clock")

        def on_odom(i):
            def callback(sample):
                checked = check_sample(sample, "nav_msgs/msg/Odometry")
                message = checked["message"]
                with lock:
                    if len(seen) < 5000:
                        seen.append({"robot": i, **checked["entry"]})
                    if message is None:
                        return
                    p = message.pose.pose
                    latest[i] = (p.position.x, p.position.y, yaw(p.orientation))
                    cx = sum(q[0] for q in latest.values()) / len(latest)
                    cy = sum(q[1] for q in latest.values()) / len(latest)
                x, y, th = latest[i]
                d = math.hypot(cx - x, cy - y)
                e = math.atan2(cy - y, cx - x) - th
                e = math.atan2(math.sin(e), math.cos(e))
                v = min(args.v_max, 1.0 * d) * math.cos(e)
                w = max(-3.0, min(3.0, 2.0 * e))
                vector = STORE.types["geometry_msgs/msg/Vector3"]
                twist = STORE.types["geometry_msgs/msg/Twist"](
                    linear=vector(x=v, y=0.0, z=0.0), angular=vector(x=0.0, y=0.0, z=w)
                )
                writers[i].put(twist, "geometry_msgs/msg/Twist")

            return callback

        def on_clock(sample):
            message = check_sample(sample, "rosgraph_msgs/msg/Clock")["message"]
            with lock:
                clock.update(
                    t=message.clock.sec + 1e-9 * message.clock.nanosec,
                    wall=time.monotonic(),
                    count=clock["count"] + 1,
                )

        subs = [
            session.declare_subscriber(
                key(domain, f"/{args.namespace.format(i=i)}/odom", "nav_msgs/msg/Odometry"), on_odom(i)
            )
            for i in range(n)
        ]
        subs.append(session.declare_subscriber(key(domain, "/clock", "rosgraph_msgs/msg/Clock"), on_clock))
        end = time.monotonic() + args.max_wall
        while time.monotonic() < end:
            time.sleep(0.1)
            with lock:
                if clock["count"] and time.monotonic() - clock["wall"] > args.idle:
                    break
        for entity in subs:
            entity.undeclare()
    return {"odom": seen, "clock_last_s": clock["t"], "clock_samples": clock["count"], "latest": latest}


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("role", choices=["robots", "controller"])
    parser.add_argument("--endpoint", required=True)
    parser.add_argument("--out", required=True)
    parser.add_argument("--domain", type=int, default=0)
    parser.add_argument("--namespace", default="robot_{i}")
    parser.add_argument("--poses", help="robots: JSON list of [x, y, theta]")
    parser.add_argument("--ticks", type=int, default=100)
    parser.add_argument("--dt", type=float, default=0.05)
    parser.add_argument("--tick-timeout", type=float, default=2.0)
    parser.add_argument("--startup-timeout", type=float, default=60.0)
    parser.add_argument("--robots", type=int, default=6, help="controller: robot count")
    parser.add_argument("--v-max", type=float, default=0.5)
    parser.add_argument(
        "--idle", type=float, default=3.0, help="controller: end after /clock is silent this long"
    )
    parser.add_argument("--max-wall", type=float, default=120.0)
    args = parser.parse_args()
    result = robots(args) if args.role == "robots" else controller(args)
    with open(args.out, "w") as file:
        json.dump(result, file)


if __name__ == "__main__":
    main()
