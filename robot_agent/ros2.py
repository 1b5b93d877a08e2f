"""``robot-agent --ros2``: the agent of a ROS 2 robot (docs/ros2.md).

The same agent as :class:`robot_agent.agent.RobotAgent`, with the robot behind ROS 2 topics
(:mod:`swarm.runtime.ros2`, the mapping of ``rmw_zenoh_cpp``): it reads its pose from
``nav_msgs/msg/Odometry`` on ``<ns>/odom`` (or ``geometry_msgs/msg/PoseStamped`` from a motion-capture
topic: the scenario's ``ros2.pose``) and publishes its wheel command as ``geometry_msgs/msg/Twist`` on
``<ns>/cmd_vel``: v = (l + r) / 2, omega = (r - l) / (2 b), b the half axle of the robot file. It is a
ROS 2 node ``swarm_agent_<i>`` in ``<ns>`` with its liveliness tokens, so ``ros2 node list`` and ``ros2
topic list`` on a ROS 2 host see it. Neighbours' messages stay on the project's own keys
(``swarm/<run>/agent/<j>/msg``).

The tick of a pose is its header stamp over the control period, rounded: a sim server with
``--ros2`` stamps tick k at k * period (sim time, also on ``/clock``); a real robot stamps wall-clock
time, and agents whose clocks agree (NTP, chrony) then agree on ticks.

Its configuration comes from the sim server as usual, or, with ``--scenario FILE`` (a real robot: no
sim server), from the scenario itself; it then ends after the scenario's ``sim.duration_s`` of ticks.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import zenoh

from robot_agent.agent import POSE_RING, AgentOptions, Inlet, RobotAgent
from swarm.runtime import ros2, wire


class TwistSink:
    """The command as a ROS 2 Twist on ``cmd_vel``, with rmw_zenoh's attachment (no tick: a ROS 2 robot
    applies the latest)."""

    __slots__ = ("half_axle_m", "key", "publisher")

    def __init__(self, publisher: ros2.Publisher, half_axle_m: float):
        self.publisher, self.half_axle_m, self.key = publisher, half_axle_m, publisher.key

    def send(self, tick: int, wheels: Sequence[float]) -> None:
        v, omega = ros2.twist_of_wheels(float(wheels[0]), float(wheels[1]), self.half_axle_m)
        self.publisher.put(ros2.encode_twist(v, omega))

    def undeclare(self) -> None:
        """The node undeclares its publisher."""


class Ros2RobotAgent(RobotAgent):
    """:class:`RobotAgent` whose robot speaks ROS 2 (module docstring)."""

    def __init__(
        self,
        options: AgentOptions,
        overrides: dict[str, Any] | None = None,
        config: wire.AgentConfig | None = None,
    ):
        super().__init__(options)
        self._overrides = overrides or {}
        self._local_config = config
        self._pose_tagged = False  # a ROS 2 pose carries rmw_zenoh's attachment, not the run key's tag
        self._settings = ros2.Ros2Settings()
        self._pose_type = ros2.ODOMETRY
        self._node: ros2.Node | None = None
        if config is not None:  # no sim server: the agent is its own configuration's source
            self._sim_alive = True
            self.record["config_source"] = "scenario file (no sim server)"
        self.record["ros2"] = {}

    def _fetch_config(self, session: zenoh.Session) -> wire.AgentConfig | None:
        config = self._local_config or super()._fetch_config(session)
        if config is not None:
            block = {**(config.scenario.get("ros2") or {}), **self._overrides}
            self._settings = ros2.Ros2Settings(**block)
            self._pose_type = self._settings.pose_type()
            if self._local_config is not None:
                duration_s = float(config.scenario.get("sim", {}).get("duration_s", 0.0))
                self._ticks_to_run = max(1, round(duration_s / config.control_period_s))
        return config

    def _node_of(self, session: zenoh.Session) -> ros2.Node:
        if self._node is None:
            settings = self._settings
            self._node = ros2.Node(
                session, settings.domain_id, settings.namespace_of(self.robot), f"swarm_agent_{self.robot}"
            )
        return self._node

    def _open_pose(self, session: zenoh.Session, keys: wire.Keys, entities: list[Any]) -> Inlet:
        node = self._node_of(session)
        entities.insert(0, node)  # undeclared after everything else
        topic = self._settings.pose_source(self.robot)
        node.announce(ros2.SUBSCRIPTION, topic, self._pose_type)
        self._pose_key = ros2.topic_key(self._settings.domain_id, topic, self._pose_type)
        return Inlet(session, self._pose_key, POSE_RING)

    def _decode_pose(self, payload: bytes) -> wire.Pose | None:
        stamped = ros2.decode_pose(payload, self._pose_type)
        if stamped is None or stamped.stamp_s < 0:
            return None
        assert self.config is not None
        tick = round(stamped.stamp_s / self.config.control_period_s)
        if tick > wire.MAX_TICK:
            return None
        return wire.Pose(tick, stamped.stamp_s, stamped.x_m, stamped.y_m, stamped.theta_rad)

    def _declare_command(self, session: zenoh.Session, keys: wire.Keys, options: dict) -> Any:
        node, settings = self._node_of(session), self._settings
        assert self.config is not None
        publisher = node.publisher(settings.cmd_vel(self.robot), ros2.TWIST, **options)
        self.record["ros2"] = {
            "domain_id": settings.domain_id,
            "node": f"{node.namespace}/{node.name}",
            "pose_topic": settings.pose_source(self.robot),
            "pose_type": self._pose_type,
            "cmd_vel": settings.cmd_vel(self.robot),
            "liveliness_tokens": list(node.tokens),
        }
        return TwistSink(publisher, float(self.config.robot_params["half_axle_m"]))


def local_config(scenario_path: str, robot: int, run: str, model: str | None = None) -> wire.AgentConfig:
    """Robot ``robot``'s configuration from a scenario file (ValueError, ScenarioError: bad input)."""
    from swarm.runtime.agent_config import agent_configs
    from swarm.scenarios.scenario import load_scenario, resolve_model_path

    scenario = load_scenario(scenario_path)
    if robot >= scenario.robots.count:
        raise ValueError(
            f"{scenario_path}: robots.count is {scenario.robots.count}: there is no robot {robot}"
        )
    if scenario.topology.proximity:
        raise ValueError(
            f"{scenario_path}: topology.kind: a disk graph needs the sim server's radio to say who is in"
            " range (docs/distributed-runtime.md); without a sim server give a fixed graph"
        )
    policy = None
    if scenario.controller.kind == "gnn":
        policy = resolve_model_path(model or scenario.controller.model, Path(scenario_path)).read_bytes()
    return agent_configs(scenario, run, policy)[robot]
