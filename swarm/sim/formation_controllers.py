"""Batched controllers of the formation task (``swarm.core.tasks.formation``), numpy.

``capt`` (:class:`CaptExpert`, centralized): at its first tick it takes the CAPT assignment of the
initial axle positions (bottleneck-optimal, ties by least sum of squares) and drives every axle
toward its slot, time-synchronized: every robot's displacement to its slot is scaled by one common
factor ``min(v_max / D, 1 / T)`` (``D`` the largest remaining distance, ``T`` the control period), so
that in the holonomic limit every robot moves on its straight line and all arrive together, the
bottleneck robot at full speed (``swarm.core.experts.drive_toward_velocity`` with per-robot speeds
``v_max d_i / D``; the axle is steered, reversing when the slot is behind, as ``mec_flood`` does).

``capt_flood`` (:class:`CaptFlood`, decentralized): every robot floods, over the communication graph
only, the initial axle positions of the robots it knows of (its message is ``N x (known, x, y)``; the
merge is a union, idempotent under loss and repetition, exact after graph-diameter many ticks). Each
tick it computes, from the robots it knows, the CAPT assignment of those robots to all N slots and
drives its axle at full speed toward its own slot (reversing). Once it knows everyone it computes the
expert's assignment from the expert's input, so all robots agree and no slot is claimed twice. Its
memory is its own message of last tick, ``inbox[:, i]`` (as ``mec_flood``).
"""

from __future__ import annotations

import numpy as np

from swarm.core.experts import drive_toward_velocity
from swarm.core.robot import RobotParams
from swarm.core.tasks.formation import (
    FormationSection,
    assignment_of_distances,
    capt_assignment,
    distances,
    placed_slots,
    sync_ratio,
)
from swarm.sim.formation_gnn import FormationGnnWeights, local_command, steering_features, to_world
from swarm.sim.links import Links, heard_slots


class CaptExpert:
    """``capt``: the centralized formation expert (module docstring)."""

    message_dim = 0
    centralized = True

    def __init__(
        self, robot: RobotParams, control_period_s: float, section: FormationSection, reverse: bool = True
    ):
        self.robot = robot
        self.control_period_s = float(control_period_s)
        self.section = section
        self.reverse = bool(reverse)
        self.targets: np.ndarray | None = None  # (B, N, 2), fixed at the first tick

    def act(
        self, poses: np.ndarray, points: np.ndarray, inbox: np.ndarray, heard: Links
    ) -> tuple[np.ndarray, np.ndarray]:
        batch, count = poses.shape[:2]
        if self.targets is None or self.targets.shape[:2] != (batch, count):
            slots = self.section.slot_positions(count)
            placed = [placed_slots(self.section, poses[b, :, :2], slots) for b in range(batch)]
            self.targets = np.stack(
                [placed[b][capt_assignment(poses[b, :, :2], placed[b])] for b in range(batch)]
            )
        u_world = capt_velocity(
            poses, self.targets, self.robot.v_max_mps, self.control_period_s, self.reverse
        )
        return u_world, inbox


def capt_velocity(
    poses: np.ndarray, targets: np.ndarray, v_max_mps: float, control_period_s: float, reverse: bool = True
) -> np.ndarray:
    """``capt``'s time-synchronized command ``(B, N, 2)``: every axle toward its target at
    ``v_max d_i / max_j d_j`` of the current distances (module docstring)."""
    delta = targets - poses[..., :2]
    remaining = np.sqrt((delta * delta).sum(-1))  # (B, N)
    largest = remaining.max(axis=-1, keepdims=True)
    speeds = v_max_mps * remaining / np.where(largest > 0.0, largest, 1.0)
    return drive_toward_velocity(poses, targets, speeds, control_period_s, reverse)


class CaptFlood:
    """``capt_flood``: the decentralized formation baseline (module docstring)."""

    centralized = False

    def __init__(
        self,
        robot: RobotParams,
        control_period_s: float,
        section: FormationSection,
        robot_count: int,
        reverse: bool = True,
    ):
        self.robot = robot
        self.control_period_s = float(control_period_s)
        self.section = section
        self.count = int(robot_count)
        self.reverse = bool(reverse)
        self.message_dim = 3 * self.count
        self.slots = section.slot_positions(self.count)
        self._known: np.ndarray | None = None  # (B, N, N) what each target was computed from
        self._targets: np.ndarray | None = None  # (B, N, 2)
        self._sync: np.ndarray | None = None  # (B, N)
        self._known_fraction: np.ndarray | None = None  # (B, N)
        self._bottleneck: np.ndarray | None = None  # (B, N) of the last assignment (its known set's)
        self._own_starts: np.ndarray | None = None  # (B, N, 2) every robot's own start
        self._start_slot_m = np.zeros((0, 0, 0))  # (B, N, N) their distances to the slots

    def merge(self, poses: np.ndarray, inbox: np.ndarray, heard: Links) -> np.ndarray:
        """``(B, N, N, 3)``: robot i's knowledge of tick k, its own of k-1 (``inbox[:, i]``, or its own
        axle position when it knows nothing yet) united with its heard neighbours' of k-1."""
        batch, count = poses.shape[:2]
        memory = inbox[:, :count].reshape(batch, count, count, 3).copy()
        own = np.arange(count)
        fresh = memory[:, own, own, 0] == 0.0  # (B, N): does not know itself yet
        memory[:, own, own, 0] = 1.0
        memory[:, own, own, 1:] = np.where(fresh[..., None], poses[..., :2], memory[:, own, own, 1:])
        # Only robots that do not know everyone yet can learn anything (a union); once the flood is
        # complete this is a no-op, which keeps a complete graph's tick O(N^2) instead of O(N^3).
        rows, robots = np.nonzero(~(memory[..., 0] != 0.0).all(axis=-1))
        if len(rows) == 0:
            return memory
        mine = memory[rows, robots]  # (R, N, 3), a copy
        for valid, messages in heard_slots(inbox, heard, only=(rows, robots)):
            theirs = messages.reshape(-1, count, 3)
            new = valid[:, None] & (theirs[..., 0] != 0.0) & (mine[..., 0] == 0.0)
            mine[new] = theirs[new]
        memory[rows, robots] = mine
        return memory

    def update_targets(self, poses: np.ndarray, inbox: np.ndarray, heard: Links) -> np.ndarray:
        """Merge (``merge``) and, for each robot whose known set grew, the CAPT assignment of the robots
        it knows: its slot ``_targets`` ``(B, N, 2)``, ``_sync`` (its start-to-slot distance over the
        largest of that assignment, ``capt_gnn``'s feature) and ``_known_fraction``. Returns the memory."""
        batch, count = poses.shape[:2]
        memory = self.merge(poses, inbox, heard)
        known = memory[..., 0] != 0.0
        if self._known is None or self._known.shape != known.shape:
            self._known = np.zeros_like(known)
            self._targets = np.zeros((batch, count, 2))
            self._sync = np.zeros((batch, count))
            self._known_fraction = np.zeros((batch, count))
            self._bottleneck = np.zeros((batch, count))
        assert self._targets is not None and self._sync is not None and self._known_fraction is not None
        assert self._bottleneck is not None
        # Every known start is a bitwise copy of its robot's own (memory[b, j, j]), so with fixed slots
        # the distances of a known set are rows of one (N, N) matrix per start, kept while they hold.
        everyone = np.arange(count)
        own_starts = memory[:, everyone, everyone, 1:]
        fixed = not self.section.translation_free
        if fixed and (self._own_starts is None or not np.array_equal(own_starts, self._own_starts)):
            self._own_starts = own_starts.copy()
            self._start_slot_m = np.stack([distances(starts, self.slots) for starts in own_starts])
        solved: dict[tuple[int, bytes], np.ndarray] = {}  # robots that know the same set agree
        for b, i in zip(*np.nonzero(np.any(known != self._known, axis=-1)), strict=True):
            members = np.flatnonzero(known[b, i])
            starts = memory[b, i, members, 1:]
            key = (int(b), known[b, i].tobytes())
            if key not in solved:
                solved[key] = self.assign(int(b), members, starts, self._bottleneck[b, i])
            assigned = solved[key]
            self._bottleneck[b, i] = np.sqrt(((starts - assigned) ** 2).sum(-1)).max()
            own = np.searchsorted(members, i)
            self._targets[b, i] = assigned[own]
            self._sync[b, i] = sync_ratio(starts, assigned, own)
            self._known_fraction[b, i] = len(members) / count
            self._known[b, i] = known[b, i]
        return memory

    def assign(self, b: int, members: np.ndarray, starts: np.ndarray, at_least_m: float) -> np.ndarray:
        """``(K, 2)``: the slots of the K known robots ``members`` (starts ``starts``) in environment
        ``b``: their CAPT assignment. ``at_least_m``: the bottleneck of a subset they knew before (a
        lower bound, :func:`capt_assignment`; unused for a translation-free formation)."""
        if self.section.translation_free:
            slots = placed_slots(self.section, starts, self.slots)
            return slots[capt_assignment(starts, slots)]
        return self.slots[assignment_of_distances(self._start_slot_m[b, members], at_least_m)]

    def act(
        self, poses: np.ndarray, points: np.ndarray, inbox: np.ndarray, heard: Links
    ) -> tuple[np.ndarray, np.ndarray]:
        batch, count = poses.shape[:2]
        memory = self.update_targets(poses, inbox, heard)
        assert self._targets is not None
        u_world = drive_toward_velocity(
            poses, self._targets, self.robot.v_max_mps, self.control_period_s, self.reverse
        )
        return u_world, memory.reshape(batch, count, 3 * count)


class CaptGnn(CaptFlood):
    """``capt_gnn``, batched: ``capt_flood``'s flood and provisional slots, eq. (1)'s steering."""

    def __init__(
        self,
        robot: RobotParams,
        control_period_s: float,
        section: FormationSection,
        robot_count: int,
        weights: FormationGnnWeights,
        reverse: bool = True,
    ):
        super().__init__(robot, control_period_s, section, robot_count, reverse)
        self.weights = weights
        self.last_features: np.ndarray | None = None  # (B, N, 5) of the last tick (training reads it)

    def act(
        self, poses: np.ndarray, points: np.ndarray, inbox: np.ndarray, heard: Links
    ) -> tuple[np.ndarray, np.ndarray]:
        memory = self.update_targets(poses, inbox, heard)
        assert self._targets is not None and self._sync is not None and self._known_fraction is not None
        features, gate = steering_features(
            poses, self._targets, self._sync, self._known_fraction, self.robot, self.control_period_s
        )
        self.last_features = features
        u_local = local_command(self.weights, features, gate, self.robot.v_max_mps)
        return to_world(poses, u_local), memory.reshape(poses.shape[0], poses.shape[1], 3 * self.count)
