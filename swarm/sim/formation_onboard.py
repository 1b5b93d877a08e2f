"""The formation baseline ``capt_flood`` on board one robot (numpy and the core install only).

The same rule as :class:`swarm.sim.formation_controllers.CaptFlood` for one robot ``robot_id``: its
memory is what it knows of every robot's initial axle position (``N x (known, x, y)``, its message);
each tick it unites the heard messages into it, recomputes the CAPT assignment of the robots it knows
to all slots when that set grew, and drives at full speed toward its own slot. The robot agents run it
(``controller_kinds``' onboard form of ``capt_flood``); ``tests/test_formation.py`` checks that it
computes what the batched form computes.
"""

from __future__ import annotations

import numpy as np

from swarm.core.experts import drive_toward_velocity
from swarm.core.robot import RobotParams
from swarm.core.tasks.formation import FormationSection, capt_assignment, placed_slots, sync_ratio


def first_memory(count: int, robot_id: int, pose: np.ndarray) -> np.ndarray:
    """``(N, 3)`` rows ``(known, x, y)`` of the start positions: at first only the robot's own."""
    memory = np.zeros((count, 3))
    memory[robot_id] = (1.0, pose[0], pose[1])
    return memory


def merge_starts(memory: np.ndarray, neighbour_messages: np.ndarray) -> np.ndarray:
    """Unite the heard messages (each ``N x (known, x, y)``) into ``memory`` in place: a start not known
    yet is taken from the first message that knows it. Returns which starts are known (``(N,)``)."""
    count = len(memory)
    for message in np.asarray(neighbour_messages, dtype=np.float64).reshape(-1, count, 3):
        new = (message[:, 0] != 0.0) & (memory[:, 0] == 0.0)
        memory[new] = message[new]
    return memory[:, 0] != 0.0


class OnboardCaptFlood:
    """``capt_flood`` for robot ``robot_id``: ``act_one(pose (3,), neighbour_messages (m, 3N), weights)
    -> (u_world (2,), message (3N,))`` (``swarm.sim.onboard``'s protocol)."""

    def __init__(
        self,
        robot: RobotParams,
        control_period_s: float,
        section: FormationSection,
        robot_count: int,
        robot_id: int,
        reverse: bool = True,
    ):
        self.robot = robot
        self.control_period_s = float(control_period_s)
        self.count = int(robot_count)
        self.robot_id = int(robot_id)
        self.reverse = bool(reverse)
        self.message_dim = 3 * self.count
        self.section = section
        self.slots = section.slot_positions(self.count)
        self._memory: np.ndarray | None = None  # (N, 3)
        self._known = np.zeros(self.count, dtype=bool)  # what the target was computed from
        self._target = np.zeros(2)
        self._sync = 0.0
        self._known_fraction = 0.0
        # capt_assignment's scipy, imported now (before the agent is ready) and not in its first tick:
        # 12 agents importing it at once on 2 cores took 6-11 s there, and the sim moved on without them
        import scipy.optimize  # noqa: F401

    def update_target(self, pose: np.ndarray, neighbour_messages: np.ndarray) -> np.ndarray:
        """Merge the heard messages and, when the known set grew, the CAPT assignment of the robots
        known: ``_target``, ``_sync`` and ``_known_fraction`` (as the batched form's
        ``update_targets``). Returns the memory."""
        if self._memory is None:
            self._memory = first_memory(self.count, self.robot_id, pose)
        memory = self._memory
        known = merge_starts(memory, neighbour_messages)
        if not np.array_equal(known, self._known):
            members = np.flatnonzero(known)
            starts = memory[members, 1:]
            slots = placed_slots(self.section, starts, self.slots)
            assigned = slots[capt_assignment(starts, slots)]
            own = int(np.searchsorted(members, self.robot_id))
            self._target = assigned[own]
            self._sync = sync_ratio(starts, assigned, own)
            self._known_fraction = len(members) / self.count
            self._known = known
        return memory

    def act_one(
        self, pose: np.ndarray, neighbour_messages: np.ndarray, weights: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        pose = np.asarray(pose, dtype=np.float64)
        memory = self.update_target(pose, neighbour_messages)
        u_world = drive_toward_velocity(
            pose, self._target, self.robot.v_max_mps, self.control_period_s, self.reverse
        )
        return u_world, memory.reshape(-1).copy()
