"""The safety filter in the kinematic engine: sense (``swarm.sim.sensing``), then every robot's barrier
QP at once (``swarm.sim.safety_kernel``, the numba twin of ``swarm.core.safety``), after the controller.

The controller's world command of each robot is turned into its robot frame, filtered, and turned
back; a robot whose command the filter leaves unchanged keeps the controller's command bit for bit,
so a filtered run where no barrier is ever active is the unfiltered run.
"""

from __future__ import annotations

import numpy as np

from swarm.core import safety
from swarm.core.obstacles import Capsules
from swarm.core.robot import RobotParams, rotate, world_to_local
from swarm.core.safety import SafetyParams
from swarm.sim import safety_kernel
from swarm.sim.sensing import sense


class SafetyFilter:
    """Wraps the command of every robot after the controller (``KinematicSim(safety=...)``)."""

    def __init__(self, robot: RobotParams, params: SafetyParams, obstacles: Capsules | None = None):
        self.robot = robot
        self.params = params
        self.obstacles = obstacles if obstacles is not None else Capsules()
        self.rng = np.random.default_rng(params.seed)
        self.counts = {"interventions": 0, "infeasible": 0}
        """Robot-ticks, summed over environments: commands the filter changed, and robots that found no
        feasible command and braked."""
        self.last_status: np.ndarray | None = None  # (B, N) int8 of the last tick

    def apply(self, poses: np.ndarray, points: np.ndarray, u_world: np.ndarray) -> np.ndarray:
        """The safe world commands ``(B, N, 2)`` for robots at ``poses (B, N, 3)`` (points ``(B, N, 2)``)."""
        batch, count = poses.shape[:2]
        params, offset = self.params, self.robot.offset_m
        readings = sense(
            poses, points, self.obstacles, params.sensing_radius_m, params.noise_m, params.dropout, self.rng
        )
        bodies = safety.readings_to_points(
            readings.body_range_m, readings.body_bearing_rad, readings.body_heading_rad, offset
        )
        walls = safety.readings_to_points(
            readings.obstacle_range_m, readings.obstacle_bearing_rad, None, offset
        )
        theta = poses[..., 2]
        u_local = world_to_local(np.asarray(u_world, dtype=np.float64), theta)
        rows = batch * count
        u_safe, status = safety_kernel.filter_local(
            u_local.reshape(rows, 2),
            bodies.reshape(rows, count, 2),
            readings.body_seen.reshape(rows, count),
            walls.reshape(rows, len(self.obstacles), 2),
            readings.obstacle_seen.reshape(rows, len(self.obstacles)),
            self.robot,
            params,
        )
        status = status.reshape(batch, count)
        self.last_status = status
        self.counts["interventions"] += int(np.count_nonzero(status == safety.CHANGED))
        self.counts["infeasible"] += int(np.count_nonzero(status == safety.INFEASIBLE))
        out = rotate(u_safe.reshape(batch, count, 2), theta)
        unchanged = status == safety.UNCHANGED
        out[unchanged] = np.asarray(u_world)[unchanged]
        return out
