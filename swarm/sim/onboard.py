"""Controllers one robot runs on board in the distributed runtime: numpy only.

A robot agent imports this module and nothing heavier (no numba kernels, no torch, no pybullet;
``swarm.sim.controllers`` holds the batched versions and imports numba). An onboard controller has
the information timing of docs/design.md: at tick k it sees its own pose at tick k and the messages
its neighbours broadcast at tick k-1 (those that arrived), and returns::

    act_one(pose (3,), neighbour_messages (m, D), weights (m,)) -> (u_world (2,), message (D,))

``u_world`` is the world velocity of the controlled point (thesis eq. 2.2), turned into saturated
wheel speeds by :func:`swarm.core.robot.point_velocity_to_wheels`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, Protocol

import numpy as np

from swarm.core import mec
from swarm.core.robot import RobotParams, wheel_speed_scale


class OnboardController(Protocol):
    message_dim: int

    def act_one(
        self, pose: np.ndarray, neighbour_messages: np.ndarray, weights: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]: ...


class OnboardLocalConsensus:
    """Thesis eq. 3.1 for one robot: ``u_i = -K sum_j A_ij (p_i(k) - p_j(k-1))`` over the neighbours
    heard; a robot that heard nobody holds still. Its message is its own controlled point, so it
    computes exactly what :class:`swarm.sim.controllers.LocalConsensus` computes for that robot."""

    message_dim = 2

    def __init__(self, robot: RobotParams, gain: float = 1.0):
        self.robot = robot
        self.gain = float(gain)

    def act_floats(
        self,
        x_m: float,
        y_m: float,
        theta_rad: float,
        neighbour_points: Sequence[Sequence[float]],
        weights: Sequence[float] | None = None,
    ) -> tuple[tuple[float, float], tuple[float, float]]:
        """:meth:`act_one` in plain floats (one robot: numpy per call costs more than the arithmetic),
        what the agent calls every tick: ``(u_world, own point)``."""
        # Same formulas as swarm.core.robot.controlled_point and, in the same (neighbour index) order,
        # as swarm.sim.kernels.delayed_consensus.
        px = x_m + self.robot.offset_m * math.cos(theta_rad)
        py = y_m + self.robot.offset_m * math.sin(theta_rad)
        w = [1.0] * len(neighbour_points) if weights is None else weights
        total, sum_x, sum_y = 0.0, 0.0, 0.0
        for a, (qx, qy) in zip(w, neighbour_points, strict=True):
            total += a
            sum_x += a * qx
            sum_y += a * qy
        return (-self.gain * (total * px - sum_x), -self.gain * (total * py - sum_y)), (px, py)

    def act_one(
        self, pose: np.ndarray, neighbour_messages: np.ndarray, weights: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        points = np.asarray(neighbour_messages, dtype=np.float64).reshape(-1, self.message_dim).tolist()
        w = None if weights is None else np.asarray(weights, dtype=np.float64).tolist()
        x, y, theta = (float(value) for value in pose[:3])
        u_world, point = self.act_floats(x, y, theta, points, w)
        return np.array(u_world), np.array(point)


def wheels_one(u_world: Sequence[float], theta_rad: float, robot: RobotParams) -> tuple[float, float]:
    """:func:`swarm.core.robot.point_velocity_to_wheels` for one robot in plain floats (same arithmetic):
    world velocity of the controlled point -> saturated (left, right) wheel speeds in m/s."""
    ux, uy = float(u_world[0]), float(u_world[1])
    c, s = math.cos(theta_rad), math.sin(theta_rad)
    v = c * ux + s * uy
    w = (-s * ux + c * uy) / robot.offset_m
    left, right = v - robot.half_axle_m * w, v + robot.half_axle_m * w
    scale = float(wheel_speed_scale(max(abs(left), abs(right)), robot.v_max_mps))
    return left * scale, right * scale


class _PolicyAdapter:
    """A ``swarm.sim.policy.Policy`` behind the onboard interface: each heard message weighted by its
    link's weight, as the batched form (``swarm.sim.features.gather_sums``) weights it."""

    def __init__(self, policy: Any):
        self.policy = policy
        self.message_dim = int(policy.message_dim)

    def act_one(
        self, pose: np.ndarray, neighbour_messages: np.ndarray, weights: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        u_world, message = self.policy.act_one(pose, neighbour_messages, weights=weights)
        return np.asarray(u_world, dtype=np.float64), np.asarray(message, dtype=np.float64)


class OnboardMecFlood:
    """``mec_flood`` on board one robot, in plain floats: the same functions (``swarm.core.mec``) the batched
    :class:`swarm.sim.controllers.MecFlood` compiles, so it computes what that computes for this robot.

    Its memory is its own last message (the support points it knows of). A new instance (a robot
    agent started, or restarted by ``restart_agent``) remembers nothing: at its first tick it starts
    afresh from its CURRENT axle position, and its neighbours, who still hold what it flooded
    before, send the rest back within graph-diameter ticks.
    """

    def __init__(
        self, robot: RobotParams, control_period_s: float, directions: int = 16, reverse: bool = True
    ):
        self.robot = robot
        self.control_period_s = float(control_period_s)
        self.directions = int(directions)
        self.reverse = bool(reverse)
        self.message_dim = 2 * self.directions + 1
        self._dx, self._dy = mec.flood_directions(self.directions)
        self._known: list[float] | None = None

    def act_floats(
        self,
        x_m: float,
        y_m: float,
        theta_rad: float,
        neighbour_messages: Sequence[Sequence[float]],
        weights: Sequence[float] | None = None,
    ) -> tuple[tuple[float, float], list[float]]:
        """One tick: merge the heard messages into what it knows, then drive toward the centre of their
        minimum enclosing circle; ``(u_world, own message)``. Weights are not used (who was heard is)."""
        count, flag = self.directions, 2 * self.directions
        if self._known is None:
            self._known = [x_m, y_m] * count + [1.0]
        known = self._known
        for message in neighbour_messages:
            if len(message) == self.message_dim and message[flag] > 0.5:
                mec.merge_support(known, message, self._dx, self._dy, count)
        cx, cy, radius = mec.welzl_circle(known[0:flag:2], known[1:flag:2], count)
        if radius > 0.0:
            u_world = mec.drive_toward(
                x_m,
                y_m,
                theta_rad,
                cx,
                cy,
                self.robot.v_max_mps,
                self.control_period_s,
                self.reverse,
            )
        else:
            u_world = (0.0, 0.0)
        return u_world, list(known)

    def act_one(
        self, pose: np.ndarray, neighbour_messages: np.ndarray, weights: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        messages = np.asarray(neighbour_messages, dtype=np.float64).reshape(-1, self.message_dim).tolist()
        x, y, theta = (float(value) for value in pose[:3])
        u_world, message = self.act_floats(x, y, theta, messages)
        return np.array(u_world), np.array(message)


def onboard_policy(
    policy_bytes: bytes | None, robot: RobotParams, robot_count: int, control_period_s: float | None = None
) -> OnboardController:
    """The ``gnn`` policy file's bytes as an onboard controller (``robot_count`` feeds the thesis's
    ``N - 1`` normaliser; ``control_period_s`` the scaled steering of ``gnn_flood``)."""
    if policy_bytes is None:
        raise ValueError("controller 'gnn' needs a policy file (controller.model)")
    try:
        from swarm.sim.policy import load_policy
    except ImportError as error:
        raise ValueError(f"controller 'gnn' needs swarm.sim.policy, not available here: {error}") from None
    return _PolicyAdapter(load_policy(policy_bytes, robot, robot_count, control_period_s))
