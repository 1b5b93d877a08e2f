"""Batched kinematic simulator: B environments x N robots stepped together (numpy + numba kernels).

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

from swarm import kernels
from swarm.controllers import BatchedController
from swarm.links import Links
from swarm.robot import RobotParams, controlled_point


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
        return Links.disk(self.poses[..., :2], self.disk_radius_m)

    def adjacency(self) -> np.ndarray:
        """Communication graph at the current tick, ``(B, N, N)``."""
        return self.links().dense

    def step(self) -> np.ndarray:
        """Advance one control period; returns the poses ``(B, N, 3)``, updated in place."""
        links = self.links()
        u_world, outbox = self.controller.act(self.poses, self.points, self.inbox, self._sent_over)
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
        self.inbox = outbox
        self._sent_over = links
        self.tick += 1
        return self.poses

    def keep(self, environments: np.ndarray) -> None:
        """Drop every environment not selected by the boolean or index array ``environments``."""
        self.poses = np.ascontiguousarray(self.poses[environments])
        # select the carried (cos, sin) state rather than re-deriving it from theta, which differs in the
        # last bits and would make the kept environments drift from a run that never had the others
        self.headings = np.ascontiguousarray(self.headings[environments])
        self.points = np.ascontiguousarray(self.points[environments])
        self.inbox = self.inbox[environments]
        self._sent_over = self._sent_over.select(environments)
        if self._fixed_links is not None:
            self._fixed_links = self._fixed_links.select(environments)

    def rollout(self, steps: int) -> np.ndarray:
        """Run ``steps`` ticks; returns poses ``(steps + 1, B, N, 3)`` including the start."""
        trajectory = np.empty((steps + 1, *self.poses.shape), dtype=self.poses.dtype)
        trajectory[0] = self.poses
        for k in range(steps):
            trajectory[k + 1] = self.step()
        return trajectory
