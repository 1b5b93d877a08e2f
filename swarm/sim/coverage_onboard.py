"""The coverage baselines ``lloyd_local``, ``lloyd_flood`` and ``lloyd_predict`` on one robot (numpy only).

The same rules as ``swarm.sim.coverage_controllers`` for one robot: its cell is the set of quadrature
points no farther from it than from any robot it knows of (and within ``cell_radius_m`` when set), a
numpy mask here where the batched form loops in numba; the target is the cell's centroid under the
density, the density's centroid for an empty cell. ``tests/test_contract.py`` checks that both forms
compute the same commands and messages.
"""

from __future__ import annotations

import numpy as np

from swarm.core.experts import drive_toward_velocity
from swarm.core.robot import RobotParams
from swarm.core.tasks.coverage import CoverageSection, density_centroid


def cell_moments(
    own: np.ndarray,
    others: np.ndarray,
    points: np.ndarray,
    weights: np.ndarray,
    fallback: np.ndarray,
    radius_m: float | None = None,
) -> tuple[float, np.ndarray]:
    """The mass ``M`` and centroid ``(2,)`` of the cell of ``own (2,)`` among ``others (K, 2)`` (module
    docstring; the centroid is ``fallback`` where ``M`` is 0)."""
    dx, dy = points[:, 0] - own[0], points[:, 1] - own[1]
    mine = dx * dx + dy * dy
    inside = np.ones(len(points), dtype=bool) if radius_m is None else mine <= float(radius_m) ** 2
    for other in np.asarray(others, dtype=np.float64).reshape(-1, 2):
        ex, ey = points[:, 0] - other[0], points[:, 1] - other[1]
        inside &= ~(ex * ex + ey * ey < mine)
    mass = float(weights[inside].sum())
    if mass <= 0.0:
        return 0.0, np.array(fallback, dtype=np.float64)
    return mass, (weights[inside] @ points[inside]) / mass


def cell_centroid(
    own: np.ndarray,
    others: np.ndarray,
    points: np.ndarray,
    weights: np.ndarray,
    fallback: np.ndarray,
    radius_m: float | None = None,
) -> np.ndarray:
    """``(2,)`` the centroid of the cell of ``own (2,)`` among ``others (K, 2)`` (module docstring)."""
    return cell_moments(own, others, points, weights, fallback, radius_m)[1]


class CoverageDrive:
    """What both forms of the coverage kinds share (this one per robot, ``swarm.sim.coverage_controllers``
    batched): the robot, the control period, the section's quadrature and density centroid, and the
    drive to a target (:func:`swarm.core.experts.drive_toward_velocity`, which broadcasts over robots):
    full speed, or ``step_fraction`` of the way in one tick once within reach."""

    def __init__(
        self,
        robot: RobotParams,
        control_period_s: float,
        section: CoverageSection,
        reverse: bool,
        step_fraction: float = 1.0,
    ):
        self.robot = robot
        self.control_period_s = float(control_period_s)
        self.section = section
        self.reverse = bool(reverse)
        self.step_fraction = float(step_fraction)
        self.points, self.weights = section.quadrature()
        self.fallback = density_centroid(self.points, self.weights)

    def drive(self, poses: np.ndarray, targets: np.ndarray) -> np.ndarray:
        """World velocities ``(..., 2)`` of the poses ``(..., 3)`` toward the targets ``(..., 2)``."""
        return drive_toward_velocity(
            poses,
            targets,
            self.robot.v_max_mps,
            self.control_period_s,
            self.reverse,
            step_fraction=self.step_fraction,
        )


class OnboardLloydLocal(CoverageDrive):
    """``lloyd_local`` for one robot: ``act_one(pose (3,), neighbour_messages (m, 2), weights)``."""

    message_dim = 2

    def __init__(
        self,
        robot: RobotParams,
        control_period_s: float,
        section: CoverageSection,
        cell_radius_m: float | None = None,
        reverse: bool = True,
        step_fraction: float = 1.0,
    ):
        super().__init__(robot, control_period_s, section, reverse, step_fraction)
        self.cell_radius_m = cell_radius_m

    def act_one(
        self, pose: np.ndarray, neighbour_messages: np.ndarray, weights: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        pose = np.asarray(pose, dtype=np.float64)
        target = cell_centroid(
            pose[:2], neighbour_messages, self.points, self.weights, self.fallback, self.cell_radius_m
        )
        return self.drive(pose, target), pose[:2].copy()


def merge_freshest(table: np.ndarray, neighbour_messages: np.ndarray) -> None:
    """Unite heard tables (each ``N x (age + 1, x, y, ...)``, 0: unknown) into ``table (N, F)`` in place,
    one hop older: an entry replaces the robot's own where strictly fresher, in message order."""
    count, fields = table.shape
    for message in np.asarray(neighbour_messages, dtype=np.float64).reshape(-1, count, fields):
        age = np.where(message[:, 0] > 0.0, message[:, 0] + 1.0, 0.0)
        fresher = (age > 0.0) & ((table[:, 0] == 0.0) | (age < table[:, 0]))
        table[fresher, 0] = age[fresher]
        table[fresher, 1:] = message[fresher, 1:]


HORIZON_TICKS = 5
"""``lloyd_predict``'s default horizon: an entry is extrapolated over at most this many ticks of its age.
A target tens of ticks old is itself stale; capped at 5 ticks the rule is as fast as the better of
``lloyd_flood`` and the uncapped extrapolation on every cell measured
(``bench/results/coverage_prediction_cap.md``)."""


def predicted_positions(table: np.ndarray, step_m: float, horizon_ticks: float = HORIZON_TICKS) -> np.ndarray:
    """``(..., 2)`` where each entry of a ``lloyd_predict`` table ``(..., 5)`` (``age + 1, x, y,
    target x, target y``) places its robot: ``p + min(|c - p|, min(age - 1, H) step_m) (c - p) / |c - p|``,
    the point reached driving from ``p`` straight at its target ``c`` at ``step_m`` a tick for the
    entry's age in ticks, at most ``H = horizon_ticks`` of them (``p`` itself when ``c = p``, ``H`` is 0
    or the entry is of this tick or unknown)."""
    ticks_old = np.clip(table[..., 0] - 1.0, 0.0, horizon_ticks)
    toward = table[..., 3:5] - table[..., 1:3]
    gap_m = np.sqrt((toward * toward).sum(-1))
    reach_m = np.minimum(gap_m, ticks_old * step_m)
    moving = gap_m > 0.0
    scale = np.where(moving, reach_m / np.where(moving, gap_m, 1.0), 0.0)
    return table[..., 1:3] + toward * scale[..., None]


class OnboardLloydFlood(CoverageDrive):
    """``lloyd_flood`` for robot ``robot_id``: ``act_one(pose (3,), neighbour_messages (m, 3N), weights)``."""

    fields = 3
    """Floats an entry of the table: ``age + 1, x, y``."""

    def __init__(
        self,
        robot: RobotParams,
        control_period_s: float,
        section: CoverageSection,
        robot_count: int,
        robot_id: int,
        reverse: bool = True,
        step_fraction: float = 1.0,
    ):
        super().__init__(robot, control_period_s, section, reverse, step_fraction)
        self.count = int(robot_count)
        self.robot_id = int(robot_id)
        self.message_dim = self.fields * self.count
        self._table = np.zeros((self.count, self.fields))  # what it sent last tick
        self._target = np.zeros(2)
        self._mass = 0.0

    def update_target(self, pose: np.ndarray, neighbour_messages: np.ndarray) -> np.ndarray:
        """Merge the heard tables into its own and take its cell among every robot it knows (placed by
        :meth:`known_positions`): sets ``_target`` and ``_mass`` (its cell's). Returns the table it
        sends."""
        table = self._table.copy()
        table[:, 0] = np.where(table[:, 0] > 0.0, table[:, 0] + 1.0, 0.0)
        table[self.robot_id, :3] = (1.0, pose[0], pose[1])
        merge_freshest(table, neighbour_messages)
        others = table[:, 0] > 0.0
        others[self.robot_id] = False
        self._mass, self._target = cell_moments(
            pose[:2], self.known_positions(table[others]), self.points, self.weights, self.fallback
        )
        self._table = table
        return table

    def known_positions(self, entries: np.ndarray) -> np.ndarray:
        """``(K, 2)`` where the robot places the robots of its table's ``entries (K, fields)``: where they
        were sent from."""
        return entries[:, 1:3]

    def act_one(
        self, pose: np.ndarray, neighbour_messages: np.ndarray, weights: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        pose = np.asarray(pose, dtype=np.float64)
        table = self.update_target(pose, neighbour_messages)
        return self.drive(pose, self._target), table.reshape(-1).copy()


class OnboardLloydPredict(OnboardLloydFlood):
    """``lloyd_predict`` for robot ``robot_id``: ``act_one(pose (3,), neighbour_messages (m, 5N),
    weights)``; its cell among the known robots' predicted positions (:func:`predicted_positions`)."""

    fields = 5
    """Floats an entry of the table: ``age + 1, x, y, target x, target y``."""

    def __init__(
        self,
        robot: RobotParams,
        control_period_s: float,
        section: CoverageSection,
        robot_count: int,
        robot_id: int,
        reverse: bool = True,
        horizon_ticks: float = HORIZON_TICKS,
        step_fraction: float = 1.0,
    ):
        super().__init__(robot, control_period_s, section, robot_count, robot_id, reverse, step_fraction)
        self.horizon_ticks = float(horizon_ticks)  # math.inf: not capped

    def known_positions(self, entries: np.ndarray) -> np.ndarray:
        """``(K, 2)``: each entry where its target takes it in its age, at most ``horizon_ticks`` of it
        (:func:`predicted_positions`)."""
        return predicted_positions(entries, self.robot.v_max_mps * self.control_period_s, self.horizon_ticks)

    def update_target(self, pose: np.ndarray, neighbour_messages: np.ndarray) -> np.ndarray:
        """``lloyd_flood``'s, among the predicted positions; its own entry carries the target it computes,
        sent beside the position it was computed at."""
        table = super().update_target(pose, neighbour_messages)
        table[self.robot_id, 3:5] = self._target
        return table
