"""Controllers one robot runs on board in the distributed runtime: numpy only.

A robot agent imports this module and nothing heavier (no numba kernels, no torch, no pybullet;
``swarm.controllers`` holds the batched versions and imports numba). An onboard controller has
the information timing of docs/design.md: at tick k it sees its own pose at tick k and the messages
its neighbours broadcast at tick k-1 (those that arrived), and returns::

    act_one(pose (3,), neighbour_messages (m, D), weights (m,)) -> (u_world (2,), message (D,))

``u_world`` is the world velocity of the controlled point (thesis eq. 2.2), turned into saturated
wheel speeds by :func:`swarm.robot.point_velocity_to_wheels`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, Protocol

import numpy as np

from swarm.robot import RobotParams

CONTROLLER_KINDS = ("local_consensus", "gnn")


class OnboardController(Protocol):
    message_dim: int

    def act_one(
        self, pose: np.ndarray, neighbour_messages: np.ndarray, weights: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]: ...


class OnboardLocalConsensus:
    """Thesis eq. 3.1 for one robot: ``u_i = -K sum_j A_ij (p_i(k) - p_j(k-1))`` over the neighbours
    heard; a robot that heard nobody holds still. Its message is its own controlled point, so it
    computes exactly what :class:`swarm.controllers.LocalConsensus` computes for that robot."""

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
        # Same formulas as swarm.robot.controlled_point and, in the same (neighbour index) order,
        # as swarm.kernels.delayed_consensus.
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
    """:func:`swarm.robot.point_velocity_to_wheels` for one robot in plain floats (same arithmetic):
    world velocity of the controlled point -> saturated (left, right) wheel speeds in m/s."""
    ux, uy = float(u_world[0]), float(u_world[1])
    c, s = math.cos(theta_rad), math.sin(theta_rad)
    v = c * ux + s * uy
    w = (-s * ux + c * uy) / robot.offset_m
    left, right = v - robot.half_axle_m * w, v + robot.half_axle_m * w
    scale = min(1.0, robot.v_max_mps / max(abs(left), abs(right), 1e-12))
    return left * scale, right * scale


class _PolicyAdapter:
    """A ``swarm.policy.Policy`` (``act_one(pose, neighbour_messages)``) behind the onboard interface;
    the policy ignores link weights (it learned from the graph structure)."""

    def __init__(self, policy: Any):
        self.policy = policy
        self.message_dim = int(policy.message_dim)

    def act_one(
        self, pose: np.ndarray, neighbour_messages: np.ndarray, weights: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        u_world, message = self.policy.act_one(pose, neighbour_messages)
        return np.asarray(u_world, dtype=np.float64), np.asarray(message, dtype=np.float64)


def robot_controller(
    kind: str,
    robot: RobotParams,
    gain: float = 1.0,
    policy_bytes: bytes | None = None,
    robot_count: int = 0,
) -> OnboardController:
    """The onboard controller of one robot. ``gnn`` loads the policy file's bytes with the scenario's
    robot parameters (``robot_count`` feeds the thesis's ``N - 1`` normaliser). ``centralized`` is not
    an onboard controller: it runs as one central process (``python -m robot_agent.central``)."""
    if kind == "local_consensus":
        return OnboardLocalConsensus(robot, gain)
    if kind == "gnn":
        if policy_bytes is None:
            raise ValueError("controller 'gnn' needs a policy file (controller.model)")
        try:
            from swarm.policy import load_policy
        except ImportError as error:
            raise ValueError(f"controller 'gnn' needs swarm.policy, not available here: {error}") from None
        return _PolicyAdapter(load_policy(policy_bytes, robot, robot_count))
    if kind == "centralized":
        raise ValueError("controller 'centralized' runs as one central process, not on board a robot")
    raise ValueError(f"unknown controller kind {kind!r} (known: {', '.join(CONTROLLER_KINDS)})")
