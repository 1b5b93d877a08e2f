"""``sim_server --ros2``: the simulated robots as ROS 2 differential-drive robots (docs/ros2.md).

For each robot i, in the namespace of the scenario's ``ros2`` block (default ``robot_<i>``), a ROS 2
node ``sim_robot_<i>`` (:mod:`swarm.runtime.ros2`, rmw_zenoh's mapping) that

* publishes ``nav_msgs/msg/Odometry`` on ``<ns>/odom`` every tick: the axle-centre pose in frame
  ``odom`` and the twist (v, omega) of the wheel speeds being applied in ``base_link``, stamped with
  the sim time of the tick (k * control period); with ``ros2.pose: pose_stamped`` a
  ``geometry_msgs/msg/PoseStamped`` on the pose topic instead (what a motion-capture system gives);
* subscribes ``geometry_msgs/msg/Twist`` on ``<ns>/cmd_vel``: the twist becomes wheel speeds
  l = v - b omega, r = v + b omega (b the half axle), the command of the tick current when it comes
  (saturated as every command); a robot keeps it for ``sim.watchdog_s``, as a ROS 2 base does.

and one node ``sim_clock`` publishing ``rosgraph_msgs/msg/Clock`` on ``/clock`` each tick, so that ROS 2
nodes with ``use_sim_time`` follow the sim in lockstep. A robot's controller counts as alive (waited for
in lockstep) while a ROS 2 publisher on its ``cmd_vel`` holds its ``MP`` liveliness token, or the
project's agent token is up: a ROS 2 controller drives the simulated swarm with no project code.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import zenoh

from swarm.runtime import ros2, wire


class Ros2Face:
    """The ROS 2 nodes of one sim server's robots (module docstring)."""

    def __init__(self, server: Any, session: zenoh.Session, stream: dict[str, Any]):
        self.server = server
        self.settings = settings = ros2.Ros2Settings.from_scenario(server.scenario.model_dump(mode="json"))
        self.half_axle_m = float(server.scenario.robot.half_axle_m)
        count = server.count
        self.pose_type = settings.pose_type()
        self.nodes = [
            ros2.Node(session, settings.domain_id, settings.namespace_of(i), f"sim_robot_{i}")
            for i in range(count)
        ]
        self.clock_node = ros2.Node(session, settings.domain_id, "/", "sim_clock")
        self.pose_publishers = [
            node.publisher(settings.pose_source(i), self.pose_type, **stream)
            for i, node in enumerate(self.nodes)
        ]
        self.clock = self.clock_node.publisher("/clock", ros2.CLOCK, **stream)
        self._robot_of_cmd_topic = {settings.cmd_vel(i): i for i in range(count)}
        self._robot_of_cmd_key: dict[str, int] = {}
        guard = lambda callback: wire.guarded(callback, server.stats, "sim_server ros2")  # noqa: E731
        for i, node in enumerate(self.nodes):
            self._robot_of_cmd_key[ros2.topic_key(settings.domain_id, settings.cmd_vel(i), ros2.TWIST)] = i
            node.subscription(settings.cmd_vel(i), ros2.TWIST, guard(self._on_cmd_vel))
        self._own_tokens = {token for node in (*self.nodes, self.clock_node) for token in node.tokens}
        self.graph = session.liveliness().declare_subscriber(
            f"{ros2.ADMIN_SPACE}/{settings.domain_id}/**", guard(self._on_token), history=True
        )
        server.stats["ros2"] = {
            "domain_id": settings.domain_id,
            "odom": [settings.pose_source(i) for i in range(count)],
            "cmd_vel": [settings.cmd_vel(i) for i in range(count)],
            "twists_received": 0,
            "twists_by_robot": [0] * count,
            "twists_invalid": 0,
            "twists_without_attachment": 0,
        }

    def _on_cmd_vel(self, sample: zenoh.Sample) -> None:
        now_s = time.perf_counter()
        robot = self._robot_of_cmd_key.get(str(sample.key_expr))
        stats = self.server.stats["ros2"]
        if ros2.decode_attachment(wire.attachment_of(sample)) is None:
            stats["twists_without_attachment"] += 1  # rmw_zenoh drops these too
            return
        twist = ros2.decode_twist(sample.payload.to_bytes())
        if twist is None or robot is None:
            stats["twists_invalid"] += 1
            return
        stats["twists_received"] += 1
        stats["twists_by_robot"][robot] += 1
        left, right = ros2.wheels_of_twist(twist[0], twist[1], self.half_axle_m)
        command = wire.Command(max(self.server._tick, 0), left, right)
        self.server._accept_command(robot, command, now_s)

    def _on_token(self, sample: zenoh.Sample) -> None:
        token = str(sample.key_expr)
        if token in self._own_tokens:
            return
        parsed = ros2.parse_token(token)
        if parsed is None or parsed["kind"] != ros2.PUBLISHER:
            return
        robot = self._robot_of_cmd_topic.get(parsed.get("topic", ""))
        if robot is not None and parsed.get("type") == ros2.dds_type(ros2.TWIST):
            self.server._agent_token(robot, token, sample.kind == zenoh.SampleKind.PUT)

    def publish(self, time_s: float, poses: np.ndarray) -> None:
        """Each robot's odometry (or pose) of this tick and the clock."""
        wheels = self.server.applied_wheels
        odometry = self.pose_type == ros2.ODOMETRY
        for i, publisher in enumerate(self.pose_publishers):
            pose = (float(poses[i, 0]), float(poses[i, 1]), float(poses[i, 2]))
            if odometry:
                twist = ros2.twist_of_wheels(float(wheels[i, 0]), float(wheels[i, 1]), self.half_axle_m)
                publisher.put(ros2.encode_odometry(time_s, pose, twist, ("odom", f"robot_{i}/base_link")))
            else:
                publisher.put(ros2.encode_pose_stamped(time_s, pose, "world"))
        self.clock.put(ros2.encode_clock(time_s))

    def undeclare(self) -> None:
        self.graph.undeclare()
        for node in (*self.nodes, self.clock_node):
            node.undeclare()
