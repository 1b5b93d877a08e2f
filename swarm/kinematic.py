"""Batched kinematic simulator: B environments x N robots as one numpy array program.

Same robot model and saturation as every other engine (``swarm.robot``), the
information timing of DESIGN.md (``swarm.controllers``), no bodies and no
collisions. Tick k: every robot acts on its pose at tick k and on the messages
its neighbours broadcast at tick k-1 over the graph of tick k-1; then the
unicycles integrate exactly over one control period. At tick 0 nobody has
heard anybody yet, so decentralized robots hold still for one tick.

Disk graphs are recomputed from the axle positions every tick.
"""

from __future__ import annotations

import numpy as np

from swarm import graphs
from swarm.controllers import BatchedController
from swarm.robot import RobotParams, integrate_unicycle, point_velocity_to_wheels


class KinematicSim:
    """B x N unicycles under one controller.

    initial_poses: ``(B, N, 3)``; adjacency: ``(N, N)`` or ``(B, N, N)`` for a
    fixed graph, or ``disk_radius_m`` for a proximity graph.
    """

    def __init__(
        self,
        robot: RobotParams,
        controller: BatchedController,
        control_period_s: float,
        initial_poses: np.ndarray,
        adjacency: np.ndarray | None = None,
        disk_radius_m: float | None = None,
        dtype: type = np.float64,
    ):
        if (adjacency is None) == (disk_radius_m is None):
            raise ValueError("give exactly one of adjacency and disk_radius_m")
        self.robot = robot
        self.controller = controller
        self.control_period_s = float(control_period_s)
        self.disk_radius_m = disk_radius_m
        self.poses = np.array(initial_poses, dtype=dtype)
        if self.poses.ndim != 3 or self.poses.shape[-1] != 3:
            raise ValueError(f"initial_poses must have shape (B, N, 3), got {self.poses.shape}")
        batch, count, _ = self.poses.shape
        if adjacency is not None:
            adjacency = np.asarray(adjacency, dtype=dtype)
            self._fixed_adjacency = np.broadcast_to(adjacency, (batch, count, count))
        else:
            self._fixed_adjacency = None
        self.tick = 0
        self.inbox = np.zeros((batch, count, controller.message_dim), dtype=dtype)
        self._sent_over: np.ndarray | None = None  # graph the inbox was sent over (tick k-1)

    @property
    def time_s(self) -> float:
        return self.tick * self.control_period_s

    @property
    def batch_size(self) -> int:
        return self.poses.shape[0]

    @property
    def robot_count(self) -> int:
        return self.poses.shape[1]

    def adjacency(self) -> np.ndarray:
        """Communication graph at the current tick, ``(B, N, N)``."""
        if self._fixed_adjacency is not None:
            return self._fixed_adjacency
        return graphs.disk(self.poses[..., :2], self.disk_radius_m)

    def step(self) -> np.ndarray:
        """Advance one control period; returns the new poses ``(B, N, 3)``."""
        adjacency = self.adjacency()
        heard = self._sent_over if self._sent_over is not None else np.zeros_like(adjacency)
        u_world, outbox = self.controller.act(self.poses, self.inbox, heard)
        wheels = point_velocity_to_wheels(u_world, self.poses[..., 2], self.robot)
        self.poses = integrate_unicycle(self.poses, wheels, self.robot.half_axle_m, self.control_period_s)
        self.inbox = outbox
        self._sent_over = adjacency
        self.tick += 1
        return self.poses

    def keep(self, environments: np.ndarray) -> None:
        """Drop every environment not selected by the boolean or index array ``environments``."""
        self.poses = self.poses[environments]
        self.inbox = self.inbox[environments]
        if self._sent_over is not None:
            self._sent_over = self._sent_over[environments]
        if self._fixed_adjacency is not None:
            self._fixed_adjacency = self._fixed_adjacency[environments]

    def rollout(self, steps: int) -> np.ndarray:
        """Run ``steps`` ticks; returns poses ``(steps + 1, B, N, 3)`` including the start."""
        trajectory = np.empty((steps + 1, *self.poses.shape), dtype=self.poses.dtype)
        trajectory[0] = self.poses
        for k in range(steps):
            trajectory[k + 1] = self.step()
        return trajectory
