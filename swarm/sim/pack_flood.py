"""``pack_flood``: gathering bodies, decentralized, in both forms (batched and on board one robot).

Driving every robot at one common point (``mec_flood``) with a safety filter jams: bodies that must
stay apart block each other on their way to the same point (the known deadlock of barrier filters on
a common goal; docs/safety.md). ``pack_flood`` gives every robot a point of its own instead: the slots
of a tight packing (``swarm.core.packing.hex_packing``, spacing ``spacing_m``) centred on the minimum
enclosing circle of the robots' *start* positions, assigned by CAPT (bottleneck-optimal, ties by
least sum of squares; Turpin, Michael, Kumar), and time-synchronized straight-line motion, which
CAPT proves collision-free for well-separated starts and slots; the slots nearest the centre are
reached first (``STAGGER``), so that the outer bodies do not wall them off.

Information: as ``capt_flood``, every robot floods over the communication graph only the start
positions of the robots it knows (its message ``N x (known, x, y)``; the merge is a union, idempotent
under loss and repetition). A robot holds still until it knows every start, or for at most ``N`` ticks
of its own (the longest a flood can take on a connected graph of N); then it computes from what it
knows the centre, the slots and the assignment, and drives its axle toward its slot at the constant
speed that brings it there at its turn (:func:`plan`); it recomputes whenever it learns of more
robots. Robots that know everyone compute the same assignment from the same input: no slot is claimed
twice.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from swarm.core.experts import drive_toward_velocity
from swarm.core.mec import welzl_circle
from swarm.core.packing import hex_packing
from swarm.core.robot import RobotParams
from swarm.core.tasks.formation import capt_assignment
from swarm.sim.formation_controllers import CaptFlood
from swarm.sim.formation_onboard import first_memory, merge_starts
from swarm.sim.links import Links

SPACING_MARGIN_M = 0.05
"""Default slot spacing ``2 (r + l) + SPACING_MARGIN_M``: a bumper's width and a controlled-point offset
each side, plus the safety filter's default margin (0.03 m) and 2 cm to spare (4 cm instead: no better
on the 24 starts of ``STAGGER``)."""


def default_spacing_m(robot: RobotParams) -> float:
    return 2.0 * (robot.body_radius_m + robot.offset_m) + SPACING_MARGIN_M


HEADING_OUT = True
"""Each robot arrives with its heading pointing away from the centre (it drives backward when its way
in points inward), so that its controlled point, ``l`` ahead of its axle, lies outward of its slot.
Why: the barrier keeps controlled points ``D_s`` apart and the slots are only 2 cm wider than that; a
robot that drove in forward has its controlled point ``l`` inward of its slot, and two neighbours'
points can meet ``2 l`` (10 cm) closer than their slots, so the filter holds the later one short of its
slot (the jams of two-cluster starts, where the two halves meet head on). With every heading radial
and outward the points are ``F(s_i) = s_i + l (s_i - c) / |s_i - c|``, and ``F`` is the gradient of the
1-strongly convex ``|x - c|^2 / 2 + l |x - c|``, so ``|F(s_i) - F(s_j)| >= |s_i - s_j|``: no two
controlled points closer than their slots. A heading that arrives along the way in is radial only
roughly; measured in ``docs/safety.md``."""

STAGGER = 1.0
"""Arrival order, inner slots first: a slot at distance ``rho`` from the centre is reached ``STAGGER rho /
v_max`` after the centre would be, so that outer bodies do not wall inner slots off. Measured on 24
starts (kinematic, filter on, complete graph; N = 6, 12, 20 x uniform, two-cluster, strip and ring x
two seeds; final max_pairwise over the packing's lower bound): 0 (all arrive together) left 3 of the
24 above 1.3 (worst 1.42), 1 left 2 (worst 1.34), 2 left 2 (worst 1.40). Some starts still jam:
bodies the filter stops short of their slot (issue 21's open point)."""


def plan(starts: np.ndarray, shape: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(slots (M, 2), speed factors (M,), backward (M,))`` for M known starts: the packing ``shape``
    centred on the starts' minimum enclosing circle, each start's CAPT slot, each robot's fraction of
    ``v_max`` so that it arrives at ``t_i = t_0 + STAGGER rho_i`` (in metres at ``v_max``; ``rho_i`` its
    slot's distance from the centre, ``t_0`` the least that lets every robot make it: ``max_j (d_j -
    STAGGER rho_j)``, ``d_j`` the distance to go): ``d_i / t_i``, at most 1; and whether it drives
    there backward: when its way in points inward, ``<s_i - x_i, s_i - c> < 0`` (:data:`HEADING_OUT`)."""
    cx, cy, _ = welzl_circle(starts[:, 0].tolist(), starts[:, 1].tolist(), len(starts))
    centre = np.array([cx, cy])
    slots = shape + centre
    targets = slots[capt_assignment(starts, slots)]
    distance = np.sqrt(((targets - starts) ** 2).sum(-1))
    radius = np.sqrt(((targets - centre) ** 2).sum(-1))
    arrival = np.max(distance - STAGGER * radius) + STAGGER * radius
    factors = np.where(arrival > 0, distance / np.where(arrival > 0, arrival, 1.0), 1.0)
    backward = ((targets - starts) * (targets - centre)).sum(-1) < 0.0
    return targets, np.minimum(factors, 1.0), backward


class OnboardPackFlood:
    """``pack_flood`` for robot ``robot_id``: ``act_one(pose (3,), neighbour_messages (m, 3N), weights)
    -> (u_world (2,), message (3N,))`` (``swarm.sim.onboard``'s protocol)."""

    def __init__(
        self,
        robot: RobotParams,
        control_period_s: float,
        robot_count: int,
        robot_id: int,
        spacing_m: float | None = None,
        reverse: bool = True,
    ):
        self.robot = robot
        self.control_period_s = float(control_period_s)
        self.count = int(robot_count)
        self.robot_id = int(robot_id)
        self.reverse = bool(reverse)
        self.message_dim = 3 * self.count
        self.shape = hex_packing(self.count, spacing_m or default_spacing_m(robot))
        self._memory: np.ndarray | None = None  # (N, 3)
        self._known = np.zeros(self.count, dtype=bool)  # what the plan was computed from
        self._target: np.ndarray | None = None
        self._speed = 0.0
        self._backward: bool | None = None
        self._ticks = 0
        import scipy.optimize  # noqa: F401  (capt_assignment's, before the agent is ready: formation_onboard)

    def act_one(
        self, pose: np.ndarray, neighbour_messages: np.ndarray, weights: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        pose = np.asarray(pose, dtype=np.float64)
        self._ticks += 1
        if self._memory is None:
            self._memory = first_memory(self.count, self.robot_id, pose)
        memory = self._memory
        known = merge_starts(memory, neighbour_messages)
        ready = bool(known.all()) or self._ticks > self.count
        if ready and not np.array_equal(known, self._known):
            members = np.flatnonzero(known)
            targets, factors, backward = plan(memory[members, 1:], self.shape)
            mine = np.searchsorted(members, self.robot_id)
            self._target, self._speed = targets[mine], self.robot.v_max_mps * factors[mine]
            self._backward = bool(backward[mine]) if HEADING_OUT else None
            self._known = known
        if self._target is None:
            return np.zeros(2), memory.reshape(-1).copy()
        u_world = drive_toward_velocity(
            pose, self._target, self._speed, self.control_period_s, self.reverse, backward=self._backward
        )
        return u_world, memory.reshape(-1).copy()


class PackFlood(CaptFlood):
    """``pack_flood`` for B swarms at once (the kinematic engine): the rule of :class:`OnboardPackFlood`
    for every robot, its memory in its own message of last tick (``inbox[:, i]``, merged as
    ``capt_flood`` merges it). A robot whose own entry there is empty starts over (tick 0, or an
    environment restarted by ``KinematicSim.restart``): its tick count and plan are forgotten."""

    def __init__(
        self,
        robot: RobotParams,
        control_period_s: float,
        robot_count: int,
        spacing_m: float | None = None,
        reverse: bool = True,
    ):
        self.robot = robot
        self.control_period_s = float(control_period_s)
        self.count = int(robot_count)
        self.reverse = bool(reverse)
        self.message_dim = 3 * self.count
        self.shape = hex_packing(self.count, spacing_m or default_spacing_m(robot))
        self._known: np.ndarray | None = None  # (B, N, N) what each plan was computed from
        self._slot_of = np.zeros((0, self.count, 2))
        self._speeds = np.zeros((0, self.count))
        self._planned = np.zeros((0, self.count), dtype=bool)
        self._backward = np.zeros((0, self.count), dtype=bool)
        self._ticks = np.zeros((0, self.count), dtype=np.int64)

    def act(
        self, poses: np.ndarray, points: np.ndarray, inbox: np.ndarray, heard: Links
    ) -> tuple[np.ndarray, np.ndarray]:
        batch, count = poses.shape[:2]
        own = np.arange(count)
        fresh = inbox[:, own, 3 * own] == 0.0  # (B, N): remembers nothing, not even itself
        memory = self.merge(poses, inbox, heard)
        known = memory[..., 0] != 0.0
        if self._known is None or self._known.shape != known.shape:
            self._known = np.zeros_like(known)
            self._slot_of = np.zeros((batch, count, 2))
            self._speeds = np.zeros((batch, count))
            self._planned = np.zeros((batch, count), dtype=bool)
            self._backward = np.zeros((batch, count), dtype=bool)
            self._ticks = np.zeros((batch, count), dtype=np.int64)
        assert self._known is not None
        self._ticks[fresh] = 0
        self._planned[fresh] = False
        self._known[fresh] = False
        self._ticks += 1
        ready = known.all(axis=-1) | (self._ticks > count)
        for b, i in zip(*np.nonzero(ready & np.any(known != self._known, axis=-1)), strict=True):
            members = np.flatnonzero(known[b, i])
            targets, factors, backward = plan(memory[b, i, members, 1:], self.shape)
            mine = np.searchsorted(members, i)
            self._slot_of[b, i] = targets[mine]
            self._speeds[b, i] = self.robot.v_max_mps * factors[mine]
            self._backward[b, i] = backward[mine]
            self._planned[b, i] = True
            self._known[b, i] = known[b, i]
        targets = np.where(self._planned[..., None], self._slot_of, poses[..., :2])
        speeds: Any = self._speeds  # per robot (drive_toward_velocity broadcasts it)
        law = self._backward if HEADING_OUT else None
        period_s = self.control_period_s
        u_world = drive_toward_velocity(poses, targets, speeds, period_s, self.reverse, backward=law)
        u_world[~self._planned] = 0.0
        return u_world, memory.reshape(batch, count, 3 * count)
