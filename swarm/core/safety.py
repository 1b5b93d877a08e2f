"""The per-robot safety filter: a control barrier function QP with two unknowns, solved exactly.

Robot i's controller asks for ``u_ref``, the velocity of its controlled point ``p_i`` (docs/design.md,
"The robot"). The filter returns the command closest to it that keeps every barrier non-negative
(Wang, Ames, Egerstedt, "Safety barrier certificates for collisions-free multirobot systems",
IEEE T-RO 2017; the unicycle through its controlled point, as the Robotarium does):

    u* = argmin_u |u - u_sat|^2   subject to   a_k . u <= b_k  for every constraint k        (QP)

with ``u_sat`` the command after the engine's wheel-speed saturation (``swarm.core.robot``), so that
a filter with nothing to avoid changes nothing. The constraints, all in the robot's frame:

* another body j, ``h_ij = |p_i - p_j|^2 - D_s^2`` with ``D_s = 2 (r + l) + margin`` (the bodies are
  discs of radius r at the axle, within ``l`` of the controlled points, so ``|p_i - p_j| >= 2 (r + l)``
  keeps them apart). The condition ``dh/dt >= -gamma h`` with ``dh/dt = 2 (p_i - p_j).(u_i - u_j)``,
  half of it taken by each robot (Wang et al. eq. 13-14), is for robot i
  ``2 (p_j - p_i) . u_i <= (gamma / 2) h_ij``;                                               (B)
* an obstacle, from the point ``q`` of its surface nearest ``p_i``: ``h_io = |p_i - q|^2 - rho^2``,
  ``rho = r + l + margin``; the squared distance to a convex set has gradient ``2 (p_i - q)``, and
  the obstacle does not move, so robot i takes all of it: ``2 (q - p_i) . u_i <= gamma h_io``;   (O)
* the wheels: ``|ux| + (d / l) |uy| <= v_max`` (``swarm.core.robot.largest_wheel_speed_local``), four
  half-planes, so the answer is a command the wheels execute without saturation.                (W)

Discrete time (zero-order hold over ``dt``): both barriers are convex in ``p_i``, so for a point that
moves by exactly ``u dt``, ``h(k+1) >= h(k) + dt dh/dt >= (1 - gamma dt) h(k)``; with ``gamma dt <= 1``
the barrier stays non-negative on every tick (``tests/test_safety.py`` checks it on rollouts). The
unicycle's point moves by ``u dt`` only to first order (its velocity turns with the heading during the
tick), which ``margin`` absorbs.

Exact solution (:func:`solve_qp`): the minimiser of a strictly convex quadratic over a non-empty planar
polygon is ``u_sat`` itself, the projection of ``u_sat`` on one constraint's line, or the crossing of
two constraints' lines. Every candidate is enumerated, in a fixed order, and the feasible one nearest
``u_sat`` is the answer (the first in the order on a tie). No feasible candidate means no feasible
command (the barriers were already violated, by more than the robot can undo in one step): the robot
brakes (``u = 0``) and the tick is flagged ``INFEASIBLE``.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from swarm.core.robot import RobotParams, rotate, world_to_local

UNCHANGED, CHANGED, INFEASIBLE = 0, 1, 2
"""What the filter did to a command: nothing, changed it, or found no feasible one and braked."""

FILTER_COUNTS = ("received", "invalid", "unauthenticated", "missing", "interventions", "infeasible")
"""What a robot's filter counts in the runtime (an agent's record, ``safety_filter``): sensor readings
received, invalid and unauthenticated, ticks without a reading (braked), commands it changed, and ticks
it found no safe command (braked)."""

FEASIBILITY_TOLERANCE = 1e-9
"""A candidate is feasible when every normalised constraint ``a_k . u - b_k`` (m/s) is at most this."""

_PARALLEL = 1e-12  # |a_k x a_l| of unit normals under which two lines count as parallel


class SafetyParams(BaseModel):
    """The barrier filter's settings (scenario key ``safety``)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    kind: Literal["barrier"] = "barrier"
    gain_per_s: float = Field(
        10.0, gt=0, description="gamma of dh/dt >= -gamma h; gamma dt <= 1 keeps it exact"
    )
    margin_m: float = Field(
        0.03,
        ge=0,
        description="added to the contact distances of the barriers (default per engine: kinematic 0.03,"
        " pybullet 0.05; ENGINE_MARGIN_M)",
    )
    sensing_radius_m: float = Field(1.5, gt=0, description="bodies and obstacles seen within this range")
    noise_m: float = Field(0.0, ge=0, description="standard deviation of the range and of r * bearing")
    dropout: float = Field(0.0, ge=0, lt=1, description="probability that a reading is missing at a tick")
    seed: int = 0


ENGINE_MARGIN_M = {"kinematic": 0.03, "pybullet": 0.05}
"""The default ``margin_m`` per engine. The kinematic engine moves every controlled point by exactly its
filtered command (to first order, the unicycle's turn within a tick: 0.03 m covers it). PyBullet's
robots lag their commands (finite wheel torque: about 4 cm to brake from 0.5 m/s), so a barrier can
already be violated when it is read; with 0.03 m one filtered run of ``scenarios/`` touched (the
strip of 6, clearance 0.002 m), with 0.05 m none did (``docs/safety.md``)."""


def with_engine_margin(safety: SafetyParams, engine: str) -> SafetyParams:
    """``safety`` with its engine's default margin (:data:`ENGINE_MARGIN_M`) unless the scenario set one."""
    if "margin_m" in safety.model_fields_set:
        return safety
    return safety.model_copy(update={"margin_m": ENGINE_MARGIN_M[engine]})


def body_distance_m(robot: RobotParams, safety: SafetyParams) -> float:
    """``D_s = 2 (r + l) + margin``: the barrier's distance between two controlled points (B)."""
    return 2.0 * (robot.body_radius_m + robot.offset_m) + safety.margin_m


def obstacle_distance_m(robot: RobotParams, safety: SafetyParams) -> float:
    """``rho = r + l + margin``: the barrier's distance from a controlled point to an obstacle (O)."""
    return robot.body_radius_m + robot.offset_m + safety.margin_m


def wheel_constraints(robot: RobotParams) -> tuple[np.ndarray, np.ndarray]:
    """(W): ``|ux| + (d / l) |uy| <= v_max`` as four rows ``a . u <= b`` in the robot frame."""
    ratio = robot.half_axle_m / robot.offset_m
    normals = np.array([[1.0, ratio], [1.0, -ratio], [-1.0, ratio], [-1.0, -ratio]])
    return normals, np.full(4, robot.v_max_mps)


def barrier_constraints(
    bodies: np.ndarray,
    obstacles: np.ndarray,
    body_distance: float,
    obstacle_distance: float,
    gain_per_s: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Rows of (B) for ``bodies (M, 2)``, the other robots' controlled points relative to this robot's,
    then (O) for ``obstacles (K, 2)``, the nearest surface points relative to it (robot frame)."""
    bodies = np.asarray(bodies, dtype=np.float64).reshape(-1, 2)
    obstacles = np.asarray(obstacles, dtype=np.float64).reshape(-1, 2)
    h_bodies = bodies[:, 0] * bodies[:, 0] + bodies[:, 1] * bodies[:, 1] - body_distance * body_distance
    h_obstacles = (
        obstacles[:, 0] * obstacles[:, 0]
        + obstacles[:, 1] * obstacles[:, 1]
        - obstacle_distance * obstacle_distance
    )
    normals = np.concatenate([2.0 * bodies, 2.0 * obstacles])
    bounds = np.concatenate([0.5 * gain_per_s * h_bodies, gain_per_s * h_obstacles])
    return normals, bounds


def solve_qp(u_ref: np.ndarray, normals: np.ndarray, bounds: np.ndarray) -> tuple[np.ndarray, int]:
    """Exact (QP) by enumeration (module docstring): ``(u*, status)`` with status ``UNCHANGED`` (u_ref is
    feasible and returned as it is), ``CHANGED`` or ``INFEASIBLE`` (``u* = 0``).

    Each row is normalised to a unit normal first (a zero row is dropped when ``b >= 0``, and makes the
    problem infeasible when ``b < 0``). Candidates, in order: ``u_ref``; the projection on line k,
    ``u_ref - (n_k . u_ref - c_k) n_k``, for k in order; the crossing of lines k < l, for (k, l) in
    lexicographic order (Cramer's rule; skipped when ``|n_k x n_l| < 1e-12``).
    """
    u_ref = np.asarray(u_ref, dtype=np.float64)
    normals = np.asarray(normals, dtype=np.float64).reshape(-1, 2)
    bounds = np.asarray(bounds, dtype=np.float64).reshape(-1)
    length = np.sqrt(normals[:, 0] * normals[:, 0] + normals[:, 1] * normals[:, 1])
    zero = length == 0.0
    if np.any(zero & (bounds < 0.0)):
        return np.zeros(2), INFEASIBLE
    keep = ~zero
    n = normals[keep] / length[keep, None]
    c = bounds[keep] / length[keep]

    def feasible(points: np.ndarray) -> np.ndarray:  # (P, 2) -> (P,) bool
        slack = n[None, :, 0] * points[:, None, 0] + n[None, :, 1] * points[:, None, 1] - c[None, :]
        return np.all(slack <= FEASIBILITY_TOLERANCE, axis=1)

    ux, uy = u_ref[0], u_ref[1]
    if feasible(u_ref[None])[0]:
        return u_ref.copy(), UNCHANGED
    excess = n[:, 0] * ux + n[:, 1] * uy - c
    singles = np.stack([ux - excess * n[:, 0], uy - excess * n[:, 1]], axis=1)
    first, second = np.triu_indices(len(c), k=1)
    n1, n2, c1, c2 = n[first], n[second], c[first], c[second]
    det = n1[:, 0] * n2[:, 1] - n1[:, 1] * n2[:, 0]
    crossing = np.abs(det) >= _PARALLEL
    n1, n2, c1, c2, det = n1[crossing], n2[crossing], c1[crossing], c2[crossing], det[crossing]
    pairs = np.stack([(c1 * n2[:, 1] - c2 * n1[:, 1]) / det, (n1[:, 0] * c2 - n2[:, 0] * c1) / det], axis=1)
    candidates = np.concatenate([singles, pairs])
    ok = feasible(candidates)
    if not np.any(ok):
        return np.zeros(2), INFEASIBLE
    dx, dy = candidates[:, 0] - ux, candidates[:, 1] - uy
    cost = np.where(ok, dx * dx + dy * dy, np.inf)
    return candidates[int(np.argmin(cost))].copy(), CHANGED


def saturate_local(u_local: np.ndarray, robot: RobotParams) -> np.ndarray:
    """The engine's wheel saturation of a robot-frame point velocity: scaled by
    ``wheel_speed_scale(|ux| + (d / l) |uy|)`` (``swarm.core.robot``), direction kept."""
    u_local = np.asarray(u_local, dtype=np.float64)
    largest = abs(u_local[0]) + robot.half_axle_m / robot.offset_m * abs(u_local[1])
    if largest <= robot.v_max_mps:
        return u_local.copy()
    return u_local * (robot.v_max_mps / largest)


def filter_command(
    u_local: np.ndarray,
    bodies: np.ndarray,
    obstacles: np.ndarray,
    robot: RobotParams,
    safety: SafetyParams,
) -> tuple[np.ndarray, int]:
    """One robot's safe command (robot frame): the controller's ``u_local`` saturated, then (QP) with
    (B) for ``bodies``, (O) for ``obstacles`` (both relative to this robot's controlled point) and (W)."""
    u_sat = saturate_local(u_local, robot)
    normals, bounds = barrier_constraints(
        bodies,
        obstacles,
        body_distance_m(robot, safety),
        obstacle_distance_m(robot, safety),
        safety.gain_per_s,
    )
    if len(bounds) == 0:
        return u_sat, UNCHANGED
    wheel_normals, wheel_bounds = wheel_constraints(robot)
    return solve_qp(u_sat, np.concatenate([normals, wheel_normals]), np.concatenate([bounds, wheel_bounds]))


def readings_to_points(
    ranges_m: np.ndarray, bearings_rad: np.ndarray, headings_rad: np.ndarray | None, offset_m: float
) -> np.ndarray:
    """Sensor readings (range and bearing from the axle centre, robot frame) to positions relative to
    this robot's controlled point ``(l, 0)``: a body's controlled point when its relative heading is
    given (``c + l (cos phi, sin phi)``), else the sensed point itself (an obstacle's)."""
    ranges_m = np.asarray(ranges_m, dtype=np.float64)
    x = ranges_m * np.cos(bearings_rad) - offset_m
    y = ranges_m * np.sin(bearings_rad)
    if headings_rad is not None:
        x = x + offset_m * np.cos(headings_rad)
        y = y + offset_m * np.sin(headings_rad)
    return np.stack([x, y], axis=-1)


def filter_reading(
    u_world: np.ndarray,
    theta_rad: float,
    bodies: np.ndarray,
    obstacles: np.ndarray,
    robot: RobotParams,
    safety: SafetyParams,
) -> tuple[np.ndarray, int]:
    """One robot's safe world command from its own reading, as a robot agent runs it: ``bodies (M, 3)``
    (range, bearing, relative heading) and ``obstacles (K, 2)`` (range, bearing) as the sim sends them
    (``swarm.runtime.wire.Sensing``). The same arithmetic as the kinematic engine's batched filter
    (``swarm.sim.safety_filter``): the controller's command turned into the robot frame, filtered
    (:func:`filter_command`) and turned back; returned as it came when the filter leaves it unchanged."""
    u_world = np.asarray(u_world, dtype=np.float64)
    bodies = np.asarray(bodies, dtype=np.float64).reshape(-1, 3)
    obstacles = np.asarray(obstacles, dtype=np.float64).reshape(-1, 2)
    theta = np.float64(theta_rad)
    body_points = readings_to_points(bodies[:, 0], bodies[:, 1], bodies[:, 2], robot.offset_m)
    wall_points = readings_to_points(obstacles[:, 0], obstacles[:, 1], None, robot.offset_m)
    u_safe, status = filter_command(world_to_local(u_world, theta), body_points, wall_points, robot, safety)
    if status == UNCHANGED:
        return u_world.copy(), status
    return rotate(u_safe, theta), status


def gain_is_exact(safety: SafetyParams, control_period_s: float) -> bool:
    """``gamma dt <= 1``: the discrete-time argument of the module docstring holds."""
    return safety.gain_per_s * control_period_s <= 1.0 + 1e-12


def min_sensing_radius_m(robot: RobotParams, safety: SafetyParams, control_period_s: float) -> float:
    """A body first seen at the sensing radius must still be outside ``D_s``: two robots close by at most
    ``2 v_max dt`` per tick, so the radius is at least ``D_s + 2 v_max dt``."""
    return body_distance_m(robot, safety) + 2.0 * robot.v_max_mps * control_period_s
