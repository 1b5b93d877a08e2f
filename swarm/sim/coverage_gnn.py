"""The learned coverage controller ``lloyd_gnn``: ``lloyd_predict``'s messages, a learned steering (numpy).

Information and aggregation are ``lloyd_predict``'s (``swarm.sim.coverage_controllers``): every robot
floods the freshest position it knows of every robot, the target that robot computed there and the
entry's age in hops (``N x (age + 1, x, y, target x, target y)``; the merge keeps the least age), places
every robot it knows where its target takes it in the entry's age (at most the horizon its policy
file names, ``meta["horizon_ticks"]``: 3 ticks for the shipped one, ``lloyd_predict``'s 5 for a file
without the key) and takes its Voronoi cell among those points. From that a robot has, in its own
frame:

- ``r``: the vector from its axle to its cell's centroid ``c``; ``rho = |r|``, ``rho_n = rho / (v_max T)``;
- ``known``: the fraction of the N robots it knows (itself included);
- ``stale``: the mean age of the other robots' positions it knows, in ticks, over N (0 when it knows
  none): how far its cell may be from the true one;
- ``mass``: its cell's share of the density, times N, over 4 (at most 1): 1/4 in a balanced
  configuration, more while the swarm is still bunched;
- ``centre``: the vector from its axle to the density's centroid (public), over the region's longer
  side: where "outward" is.

Features ``f = (r_x / rho, r_y / rho, min(rho_n, 1), known, stale, mass, centre_x, centre_y)`` and the
MLP of ``swarm.sim.steering_mlp`` give the command, its eq. (1): full speed (``v_max min(rho_n, 1)``,
the expert's) in a learned direction ``(a, b)``. Imitation (``swarm.learn.train.coverage``) fits that
direction to the centralized Lloyd's (``lloyd``: toward the centroid of the robot's true Voronoi cell).
With the same information as ``lloyd_predict`` it can at best correct for what the staleness and the
bunching predict about the true cell; ``docs/tasks.md`` measures what it does.

File format ``coverage_gnn/2``; ``coverage_gnn/1`` (before 2026-12-06) steered from ``lloyd_flood``'s
cell and 3-float entries, and is refused (retrain: ``swarm train --algo coverage``).

The batched form (``swarm.sim.coverage_controllers.LloydGnn``) and the per-robot one
(:class:`OnboardLloydGnn`, here: numpy only, what the agents import) share :func:`coverage_features`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from swarm.core.robot import RobotParams
from swarm.core.tasks.coverage import CoverageSection
from swarm.sim.coverage_onboard import HORIZON_TICKS, OnboardLloydPredict
from swarm.sim.steering_mlp import PolicyFileError, SteeringMlp, local_command, target_features, to_world

FEATURES = ("dir_x", "dir_y", "near", "known", "stale", "mass", "centre_x", "centre_y")
DEFAULT_MODEL_NAME = "coverage/lloyd_gnn.npz"
"""The shipped policy, below ``<project root>/models`` (``swarm train --algo coverage``)."""
MASS_SCALE = 4.0


class CoverageGnnWeights(SteeringMlp):
    """The MLP ``g`` of eq. (1) for ``lloyd_gnn`` (``swarm.sim.steering_mlp``)."""

    FORMAT = "coverage_gnn/2"
    FEATURES = FEATURES
    KIND = "lloyd_gnn"

    @classmethod
    def load(cls, source: str | Path | bytes) -> CoverageGnnWeights:
        """``SteeringMlp.load``, its horizon checked: a bad one is refused with the file, not later."""
        weights = super().load(source)
        weights.horizon_ticks  # noqa: B018 (raises PolicyFileError)
        return weights

    @property
    def horizon_ticks(self) -> float:
        """The prediction horizon of the cell it was trained on and runs on (``meta["horizon_ticks"]``;
        a file written before the key existed was trained with ``lloyd_predict``'s ``HORIZON_TICKS``)."""
        value = self.meta.get("horizon_ticks", HORIZON_TICKS)
        if isinstance(value, bool) or not isinstance(value, int | float) or not value >= 0:
            raise PolicyFileError(f"meta horizon_ticks: {value!r} is not a number of ticks >= 0")
        return float(value)


def region_scale_m(points: np.ndarray) -> float:
    """The quadrature grid's longer side (m): the unit of the ``centre`` feature."""
    extent = points.max(axis=0) - points.min(axis=0)
    return float(max(extent.max(), 1e-9))


def coverage_features(
    poses: np.ndarray,
    targets: np.ndarray,
    tables: np.ndarray,
    own: np.ndarray,
    mass: np.ndarray,
    centre: np.ndarray,
    scale_m: float,
    robot: RobotParams,
    control_period_s: float,
) -> tuple[np.ndarray, np.ndarray]:
    """The module's features ``(..., 8)`` and the gate ``(...)``: poses ``(..., 3)``, cell centroids
    ``(..., 2)``, the flooded tables ``(..., N, F)`` (age + 1, x, y, ...; 0 unknown), ``own (..., N)`` true at
    the robot's own row, its cell's mass ``(...)``, the density's centroid ``(2,)`` and its scale."""
    count = tables.shape[-2]
    direction, gate = target_features(poses, targets, robot, control_period_s)
    known = tables[..., 0] > 0.0
    others = known & ~own
    number = others.sum(-1)
    age_sum = np.where(others, tables[..., 0] - 1.0, 0.0).sum(-1)
    stale = np.where(number > 0, age_sum / np.maximum(number, 1), 0.0) / count
    theta = poses[..., 2]
    cos, sin = np.cos(theta), np.sin(theta)
    delta = (centre - poses[..., :2]) / scale_m
    centre_x = cos * delta[..., 0] + sin * delta[..., 1]
    centre_y = -sin * delta[..., 0] + cos * delta[..., 1]
    features = np.concatenate(
        [
            direction,
            np.stack(
                [
                    known.sum(-1) / count,
                    stale,
                    np.minimum(mass * count / MASS_SCALE, 1.0),
                    centre_x,
                    centre_y,
                ],
                axis=-1,
            ),
        ],
        axis=-1,
    )
    return features, gate


class OnboardLloydGnn(OnboardLloydPredict):
    """``lloyd_gnn`` for robot ``robot_id`` (``swarm.sim.onboard``'s protocol; numpy only)."""

    def __init__(
        self,
        robot: RobotParams,
        control_period_s: float,
        section: CoverageSection,
        robot_count: int,
        robot_id: int,
        weights: CoverageGnnWeights,
        reverse: bool = True,
    ):
        super().__init__(
            robot, control_period_s, section, robot_count, robot_id, reverse, weights.horizon_ticks
        )
        self.policy = weights  # (self.weights are the quadrature's)
        self.scale_m = region_scale_m(self.points)
        self._own = np.arange(self.count) == self.robot_id

    def act_one(
        self, pose: np.ndarray, neighbour_messages: np.ndarray, weights: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        pose = np.asarray(pose, dtype=np.float64)
        table = self.update_target(pose, neighbour_messages)
        features, gate = coverage_features(
            pose,
            self._target,
            table,
            self._own,
            np.float64(self._mass),
            self.fallback,
            self.scale_m,
            self.robot,
            self.control_period_s,
        )
        u_local = local_command(self.policy, features, gate, self.robot.v_max_mps)
        return to_world(pose, u_local), table.reshape(-1).copy()
