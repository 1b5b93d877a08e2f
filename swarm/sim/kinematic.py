"""Batched kinematic simulator: B environments x N robots stepped together (numpy + numba kernels).

Same robot model and saturation as every other engine (``swarm.core.robot``), the
information timing of docs/design.md (``swarm.sim.controllers``), no bodies and no
collisions. Tick k: every robot acts on its pose at tick k and on the messages
its neighbours broadcast at tick k-1 over the graph of tick k-1; then the
unicycles integrate exactly over one control period. At tick 0 nobody has
heard anybody yet, so decentralized robots hold still for one tick.

Disk graphs are recomputed from the axle positions every tick.

Link faults (``swarm.core.faults.LinkFaults``: dropped links, packet loss, delay) apply as in the robot
agents of the PyBullet runtime: at tick k robot i uses, from neighbour j, the newest message it heard
among those of ticks ``k-1-d .. k-d-A`` (``d`` the link's delay at tick k, ``A`` the message age
limit), sent over the graph of its own tick. The controllers take one inbox row per sender, so the
faulty path lays the last ``H`` ticks' messages side by side, ``(B, H*N, D)``, and the links of tick k
point into it (age ``a`` of robot j at column ``(a-1)*N + j``).

The max-flooding GNN (``swarm.sim.flood_kernel``) is called by the engine itself, with what it knows:
without link faults the outbox of a tick is the next tick's inbox, so a neighbour whose memory did not
change and whose link was there at the last tick sends nothing new (``flood_kernel.Skip``); the
engine compares the links of consecutive ticks, and keeps that state itself (:class:`_FloodCall`).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from swarm.core.faults import DROPPED, HEARD, LOST, LinkFaults, usable
from swarm.core.robot import RobotParams, controlled_point
from swarm.sim import flood_kernel, kernels
from swarm.sim.controllers import BatchedController
from swarm.sim.links import Links
from swarm.sim.policy import FloodPolicy
from swarm.sim.safety_filter import SafetyFilter


class _FloodCall(NamedTuple):
    """The engine's last call of the flood kernel: what it returned (the inbox of the next tick, as long
    as nobody replaced it), the links it heard over and which robots' memories did not change."""

    outbox: np.ndarray
    heard: Links
    unchanged: np.ndarray  # (B, N) bool


def same_lists(now: Links, before: Links) -> np.ndarray:
    """``(B, N)`` bool: robot i hears over the same neighbour list in ``now`` as in ``before``."""
    if now is before:
        return np.ones(now.shape, dtype=bool)
    if now.shape != before.shape:
        return np.zeros(now.shape, dtype=bool)
    a, b = now.index, before.index
    slots = max(a.shape[2], b.shape[2])  # lists end at the first -1: pad the shorter with -1
    a = np.pad(a, ((0, 0), (0, 0), (0, slots - a.shape[2])), constant_values=-1)
    b = np.pad(b, ((0, 0), (0, 0), (0, slots - b.shape[2])), constant_values=-1)
    return np.all(a == b, axis=-1)


class KinematicSim:
    """B x N unicycles under one controller.

    initial_poses: ``(B, N, 3)``; adjacency: ``(N, N)`` or ``(B, N, N)`` for a
    fixed graph, or ``disk_radius_m`` for a proximity graph. ``link_faults``: the same schedule in
    every environment (the centralized expert ignores links, so faults do not touch it);
    ``message_max_age_ticks``: how old, beyond the delay, a message may be (``swarm.core.faults``);
    ``safety``: the barrier filter wrapping every command (``swarm.sim.safety_filter``).
    """

    def __init__(
        self,
        robot: RobotParams,
        controller: BatchedController,
        control_period_s: float,
        initial_poses: np.ndarray,
        adjacency: np.ndarray | None = None,
        disk_radius_m: float | None = None,
        link_faults: LinkFaults | None = None,
        message_max_age_ticks: int = 1,
        safety: SafetyFilter | None = None,
    ):
        if (adjacency is None) == (disk_radius_m is None):
            raise ValueError("give exactly one of adjacency and disk_radius_m")
        self.robot = robot
        self.controller = controller
        self.control_period_s = float(control_period_s)
        self.disk_radius_m = disk_radius_m
        self.poses = np.array(initial_poses, dtype=np.float64, order="C")
        if self.poses.ndim != 3 or self.poses.shape[-1] != 3:
            raise ValueError(f"initial_poses must have shape (B, N, 3), got {self.poses.shape}")
        batch, count, _ = self.poses.shape
        self._fixed_links = None
        if adjacency is not None:
            adjacency = np.asarray(adjacency, dtype=np.float64)
            self._fixed_links = Links.from_dense(np.broadcast_to(adjacency, (batch, count, count)))
        self._derive_heading_state()
        self.tick = 0
        self.inbox = np.zeros((batch, count, controller.message_dim))
        self._sent_over = Links.nobody(batch, count)  # graph the inbox was sent over (tick k-1)
        faulty = link_faults is not None and not link_faults.empty and not controller.centralized
        self.link_faults = link_faults if faulty else None
        self.message_max_age_ticks = int(message_max_age_ticks)
        self._history: list[tuple[np.ndarray, Links]] = []  # faulty path: (outbox, links), newest first
        self._flood = isinstance(controller, FloodPolicy)
        self._flood_call: _FloodCall | None = None  # the flood kernel's skip state (module docstring)
        self.safety = safety  # wraps every command after the controller (swarm.sim.safety_filter)
        self.fault_counts = {"dropped_by_fault": 0, "lost_by_fault": 0, "delayed_by_fault": 0}
        """Faulty path, summed over environments and ticks: (robot, neighbour) pairs whose newest
        candidate message the schedule dropped (link down) or lost, and pairs heard with a delay."""

    def _derive_heading_state(self) -> None:
        """(cos, sin) of every heading and the controlled points, from the poses."""
        theta = self.poses[..., 2]
        self.headings = np.ascontiguousarray(np.stack([np.cos(theta), np.sin(theta)], axis=-1))
        self.points = np.ascontiguousarray(controlled_point(self.poses, self.robot.offset_m))

    @property
    def time_s(self) -> float:
        return self.tick * self.control_period_s

    @property
    def batch_size(self) -> int:
        return self.poses.shape[0]

    @property
    def robot_count(self) -> int:
        return self.poses.shape[1]

    def links(self) -> Links:
        """Communication graph at the current tick."""
        if self._fixed_links is not None:
            return self._fixed_links
        assert self.disk_radius_m is not None  # no fixed graph: a proximity graph
        return Links.disk(self.poses[..., :2], self.disk_radius_m)

    def adjacency(self) -> np.ndarray:
        """Communication graph at the current tick, ``(B, N, N)``."""
        return self.links().dense

    def set_poses(self, poses: np.ndarray) -> None:
        """Replace the poses ``(B, N, 3)`` of the current tick (to replay a logged trajectory)."""
        self.poses[...] = poses
        self._derive_heading_state()

    def act(self) -> np.ndarray:
        """The controller's world velocities ``(B, N, 2)`` for the current tick; the messages it sent
        become what the robots may hear next. :meth:`step` is ``act`` and the motion."""
        links = self.links()
        if self.link_faults is None:
            if self._flood:
                u_world, outbox = self._flood_act()
            else:
                u_world, outbox = self.controller.act(self.poses, self.points, self.inbox, self._sent_over)
            self.inbox = outbox
            self._sent_over = links
            return u_world
        heard, inbox = self._faulty_inbox()
        u_world, outbox = self.controller.act(self.poses, self.points, inbox, heard)
        self.inbox = outbox
        self._sent_over = links
        keep = self.link_faults.max_delay_ticks + self.message_max_age_ticks
        self._history = [(outbox, links), *self._history][:keep]
        return u_world

    def _flood_act(self) -> tuple[np.ndarray, np.ndarray]:
        """The flood GNN's tick without link faults, skipping what ``flood_kernel.Skip`` allows: the
        inbox must be the outbox of the last call (not replaced since; in-place edits other than
        zeroing whole rows, which invalidates them, are not supported), robot i's neighbour list the
        one of that call, and neighbour j's memory unchanged in it."""
        heard, last = self._sent_over, self._flood_call
        skip = None
        if last is not None and last.outbox is self.inbox:
            skip = flood_kernel.Skip(last.unchanged, same_lists(heard, last.heard))
        assert isinstance(self.controller, FloodPolicy)  # self._flood
        outputs = flood_kernel.act(self.controller, self.poses, self.inbox, heard, skip)
        self._flood_call = _FloodCall(outputs.outbox, heard, outputs.unchanged)
        return outputs.u_world, outputs.outbox

    def _faulty_inbox(self) -> tuple[Links, np.ndarray]:
        """Who hears which past message at the current tick under the link faults, as links into the
        past ``H`` ticks' messages laid side by side ``(B, H*N, D)`` (see the module docstring)."""
        batch, count = self.poses.shape[:2]
        if not self._history:
            return Links.nobody(batch, count), np.zeros((batch, count, self.controller.message_dim))
        faults, tick, max_age = self.link_faults, self.tick, self.message_max_age_ticks
        assert faults is not None  # the faulty path
        chosen = np.zeros((batch, count, count), dtype=bool)
        receivers = np.arange(count)[None, :, None]
        picked = []  # (env, receiver, sender, column, weight) per age
        for age, (_, links) in enumerate(self._history, start=1):
            index = links.index
            valid = index >= 0
            senders = np.where(valid, index, 0)
            delay = faults.delay_array(senders, receivers, tick)
            reasons = faults.reasons_array(senders, receivers, tick - age)
            newest = valid & (age == 1 + delay)  # the message the timing of docs/design.md (plus delay) names
            self.fault_counts["dropped_by_fault"] += int(np.count_nonzero(newest & (reasons == DROPPED)))
            self.fault_counts["lost_by_fault"] += int(np.count_nonzero(newest & (reasons == LOST)))
            chosen_now = valid & usable(age, delay, max_age, reasons == HEARD)  # swarm.core.faults' rule
            env, receiver, slot = np.nonzero(chosen_now)
            sender = index[env, receiver, slot]
            fresh = ~chosen[env, receiver, sender]  # a newer message of that neighbour came first
            env, receiver, slot, sender = env[fresh], receiver[fresh], slot[fresh], sender[fresh]
            chosen[env, receiver, sender] = True
            self.fault_counts["delayed_by_fault"] += int(np.count_nonzero(delay[env, receiver, slot] > 0))
            column = (age - 1) * count + sender
            picked.append((env, receiver, sender, column, links.weight[env, receiver, slot]))
        env, receiver, sender, column, weight = (np.concatenate(parts) for parts in zip(*picked, strict=True))
        order = np.lexsort((sender, receiver, env))  # neighbours in index order, as the agents sum them
        env, receiver, column, weight = env[order], receiver[order], column[order], weight[order]
        row = env * count + receiver
        per_row = np.bincount(row, minlength=batch * count)
        slots = int(per_row.max(initial=0))
        starts = np.concatenate([[0], np.cumsum(per_row)[:-1]])
        slot = np.arange(len(row)) - starts[row]
        index = np.full((batch, count, slots), -1, dtype=np.int32)
        weights = np.zeros((batch, count, slots))
        index[env, receiver, slot] = column
        weights[env, receiver, slot] = weight
        inbox = np.concatenate([outbox for outbox, _ in self._history], axis=1)
        return Links(index, weights), inbox

    def step(self) -> np.ndarray:
        """Advance one control period (the safety filter, if any, after the controller); returns the
        poses ``(B, N, 3)``, updated in place."""
        u_world = self.act()
        if self.safety is not None:
            u_world = self.safety.apply(self.poses, self.points, u_world)
        return self.move(u_world)

    def move(self, u_world: np.ndarray) -> np.ndarray:
        """The motion half of :meth:`step`: every robot drives with the world velocity ``u_world (B, N, 2)``
        of its controlled point for one control period (saturated, exact unicycle step); the tick
        advances. Returns the poses, updated in place."""
        robot = self.robot
        kernels.advance_unicycles(
            self.poses.reshape(-1, 3),
            self.headings.reshape(-1, 2),
            self.points.reshape(-1, 2),
            np.ascontiguousarray(u_world, dtype=np.float64).reshape(-1, 2),
            robot.offset_m,
            robot.half_axle_m,
            robot.v_max_mps,
            self.control_period_s,
        )
        self.tick += 1
        return self.poses

    def keep(self, environments: np.ndarray) -> None:
        """Drop every environment not selected by the boolean or index array ``environments``."""
        self.poses = np.ascontiguousarray(self.poses[environments])
        # select the carried (cos, sin) state rather than re-deriving it from theta, which differs in the
        # last bits and would make the kept environments drift from a run that never had the others
        self.headings = np.ascontiguousarray(self.headings[environments])
        self.points = np.ascontiguousarray(self.points[environments])
        last, inbox = self._flood_call, self.inbox
        self.inbox = self.inbox[environments]
        if last is not None and last.outbox is inbox:
            self._flood_call = _FloodCall(
                self.inbox, last.heard.select(environments), last.unchanged[environments]
            )
        self._sent_over = self._sent_over.select(environments)
        self._history = [
            (outbox[environments], links.select(environments)) for outbox, links in self._history
        ]
        if self._fixed_links is not None:
            self._fixed_links = self._fixed_links.select(environments)

    def restart(self, environments: np.ndarray, poses: np.ndarray) -> None:
        """Environments ``environments`` (indices) start over from ``poses (E, N, 3)`` at the current tick,
        as at tick 0: every robot remembers nothing and has heard nobody (their messages zeroed, no
        links of the last tick, no older messages left to hear under link faults)."""
        environments = np.asarray(environments)
        self.poses[environments] = poses
        theta = self.poses[environments, :, 2]
        self.headings[environments] = np.stack([np.cos(theta), np.sin(theta)], axis=-1)
        self.points[environments] = controlled_point(self.poses[environments], self.robot.offset_m)
        self.inbox[environments] = 0.0
        self._sent_over = _cut(self._sent_over, environments)
        self._history = [(outbox, _cut(links, environments)) for outbox, links in self._history]
        for outbox, _ in self._history:
            outbox[environments] = 0.0

    def rollout(self, steps: int) -> np.ndarray:
        """Run ``steps`` ticks; returns poses ``(steps + 1, B, N, 3)`` including the start."""
        trajectory = np.empty((steps + 1, *self.poses.shape), dtype=self.poses.dtype)
        trajectory[0] = self.poses
        for k in range(steps):
            trajectory[k + 1] = self.step()
        return trajectory


def _cut(links: Links, environments: np.ndarray) -> Links:
    """``links`` with nobody hearing anybody in ``environments``."""
    index, weight = links.index.copy(), links.weight.copy()
    index[environments], weight[environments] = -1, 0.0
    return Links(index, weight)
