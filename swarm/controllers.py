"""Batched controllers with the information timing of docs/design.md.

At tick k robot i knows its own pose at tick k and the message each neighbour
broadcast at tick k-1; it returns the world velocity of its controlled point
and its own message for tick k. Information from k hops away is therefore k
ticks old, in the batched simulator exactly as in the distributed runtime.

A controller implements::

    message_dim: int
    act(poses (B,N,3), points (B,N,2), inbox (B,N,D), heard (B,N,N)) -> (u_world (B,N,2), outbox (B,N,D))

``points`` are the controlled points (``swarm.robot.controlled_point`` of the poses),
``inbox[b, j]`` is what robot j broadcast last tick; ``heard[b, i, j]`` is 1
when robot i received it (graph edge and message delivered), else 0.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from swarm import kernels
from swarm.experts import complete_consensus_velocity, neighbour_consensus_velocity
from swarm.links import Links
from swarm.robot import RobotParams, controlled_point


class BatchedController(Protocol):
    message_dim: int
    centralized: bool

    def act(
        self, poses: np.ndarray, points: np.ndarray, inbox: np.ndarray, heard: Links
    ) -> tuple[np.ndarray, np.ndarray]: ...


class LocalConsensus:
    """Eq. 3.1 on the robot's own graph, from the points its neighbours sent last tick.

    ``u_i = -K sum_j heard_ij (p_i(k) - p_j(k-1))``; a robot that heard nobody holds still.
    Its message is its own controlled point.
    """

    message_dim = 2
    centralized = False

    def __init__(self, robot: RobotParams, gain: float = 1.0):
        self.robot = robot
        self.gain = gain

    def act(
        self, poses: np.ndarray, points: np.ndarray, inbox: np.ndarray, heard: Links
    ) -> tuple[np.ndarray, np.ndarray]:
        u_world = np.empty_like(points)
        kernels.delayed_consensus(points, inbox, heard.index, heard.weight, self.gain, u_world)
        return u_world, points.copy()

    def act_one(self, pose: np.ndarray, neighbour_messages: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        point = controlled_point(np.asarray(pose, dtype=float), self.robot.offset_m)
        return neighbour_consensus_velocity(point, neighbour_messages, self.gain), point


class Centralized:
    """Eq. 3.1 on the complete graph with everyone's current points: the centralized expert.

    It needs every robot's pose at tick k, so it is one central process in the
    distributed runtime, not an agent; it ignores messages.
    """

    message_dim = 0
    centralized = True

    def __init__(self, robot: RobotParams, gain: float = 1.0):
        self.robot = robot
        self.gain = gain

    def act(
        self, poses: np.ndarray, points: np.ndarray, inbox: np.ndarray, heard: Links
    ) -> tuple[np.ndarray, np.ndarray]:
        return complete_consensus_velocity(points, self.gain), inbox
