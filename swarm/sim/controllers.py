"""Batched controllers with the information timing of docs/design.md.

At tick k robot i knows its own pose at tick k and the message each neighbour
broadcast at tick k-1; it returns the world velocity of its controlled point
and its own message for tick k. Information from k hops away is therefore k
ticks old, in the batched simulator exactly as in the distributed runtime.

A controller implements::

    message_dim: int
    act(poses (B,N,3), points (B,N,2), inbox (B,N,D), heard (B,N,N)) -> (u_world (B,N,2), outbox (B,N,D))

``points`` are the controlled points (``swarm.core.robot.controlled_point`` of the poses),
``inbox[b, j]`` is what robot j broadcast last tick; ``heard[b, i, j]`` is 1
when robot i received it (graph edge and message delivered), else 0.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from swarm.core import mec
from swarm.core.experts import complete_consensus_velocity, neighbour_consensus_velocity
from swarm.core.robot import RobotParams, controlled_point
from swarm.sim import kernels, mec_kernels
from swarm.sim.links import Links


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


class MecFlood:
    """``mec_flood``: max-consensus flood of support points, then full speed toward the centre of
    their minimum enclosing circle (the strong decentralized baseline).

    Every robot's message holds, for M directions ``d_m = (cos 2 pi m / M, sin 2 pi m / M)``, the
    initial axle position of largest projection ``<p, d_m>`` it knows of: at tick 0 its own, then
    each tick the per-direction maximum of what it held and what its heard neighbours sent last
    tick (``swarm.core.mec.merge_support``; idempotent, so lost or repeated messages only delay the
    flood, which is exact after graph-diameter many ticks). Its target is the centre of the
    minimum enclosing circle of those M points; it drives its axle there at full
    speed, in reverse when the target is behind the axle and ``reverse`` is on
    (``swarm.core.experts.drive_toward_velocity``). A robot that knows of no other robot holds still.
    Its memory is its own message of last tick: ``inbox[:, i]`` (message layout in
    ``swarm.sim.mec_kernels``).
    """

    centralized = False

    def __init__(
        self, robot: RobotParams, control_period_s: float, directions: int = 16, reverse: bool = True
    ):
        self.robot = robot
        self.control_period_s = float(control_period_s)
        self.directions = int(directions)
        self.reverse = bool(reverse)
        self.message_dim = 2 * self.directions + 1
        dx, dy = mec.flood_directions(self.directions)
        self._directions = (np.array(dx), np.array(dy))

    def act(
        self, poses: np.ndarray, points: np.ndarray, inbox: np.ndarray, heard: Links
    ) -> tuple[np.ndarray, np.ndarray]:
        batch, count = poses.shape[:2]
        u_world = np.empty((batch, count, 2))
        outbox = np.empty((batch, count, self.message_dim))
        robot = self.robot
        mec_kernels.mec_flood(
            np.ascontiguousarray(poses),
            np.ascontiguousarray(inbox, dtype=np.float64),
            np.ascontiguousarray(heard.index),
            *self._directions,
            robot.v_max_mps,
            self.control_period_s,
            self.reverse,
            np.empty((batch, inbox.shape[1], self.directions)),
            np.empty((batch, count, self.directions)),
            u_world,
            outbox,
        )
        return u_world, outbox


class CentralizedMec:
    """``centralized_mec``: every robot drives at full speed (reversing if ``reverse``) toward the
    centre of the exact minimum enclosing circle of the current axle positions
    (``swarm.core.experts.centralized_mec_velocity``); one central process in the distributed runtime."""

    message_dim = 0
    centralized = True

    def __init__(self, robot: RobotParams, control_period_s: float, reverse: bool = True):
        self.robot = robot
        self.control_period_s = float(control_period_s)
        self.reverse = bool(reverse)
        self._order: np.ndarray | None = None

    def act(
        self, poses: np.ndarray, points: np.ndarray, inbox: np.ndarray, heard: Links
    ) -> tuple[np.ndarray, np.ndarray]:
        count = poses.shape[1]
        if self._order is None or len(self._order) != count:  # the shuffle of swarm.core.metrics
            self._order = np.random.default_rng(0).permutation(count).astype(np.int64)
        u_world = np.empty((*poses.shape[:2], 2))
        robot = self.robot
        mec_kernels.centralized_mec(
            np.ascontiguousarray(poses),
            self._order,
            np.empty(poses.shape[:2]),
            np.empty(poses.shape[:2]),
            robot.v_max_mps,
            self.control_period_s,
            self.reverse,
            u_world,
        )
        return u_world, inbox
