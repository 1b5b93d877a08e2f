"""The safety filter of ``swarm.core.safety`` for every robot of every environment at once (numba).

The same arithmetic, in the same order, as :func:`swarm.core.safety.filter_command` (saturate, rows
(B) for the seen bodies in index order, (O) for the seen obstacles, (W), normalise, then the
candidates ``u_sat``, the projections, the crossings), one robot per row; compiled without
``fastmath``, so that it equals the numpy form (``tests/test_safety_kernel.py``). A candidate whose
cost is not below the best so far is not checked for feasibility (the answer is the same: the first
feasible candidate of least cost).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from swarm.core import safety
from swarm.core.robot import RobotParams
from swarm.core.safety import SafetyParams
from swarm.sim import kernels

_TOLERANCE = safety.FEASIBILITY_TOLERANCE
_PARALLEL = 1e-12  # as swarm.core.safety._PARALLEL


def _filter_local(
    u_local: np.ndarray,
    bodies: np.ndarray,
    body_seen: np.ndarray,
    obstacles: np.ndarray,
    obstacle_seen: np.ndarray,
    half_axle_m: float,
    offset_m: float,
    v_max_mps: float,
    body_distance_m: float,
    obstacle_distance_m: float,
    gain_per_s: float,
    u_out: np.ndarray,
    status: np.ndarray,
) -> None:
    """For every row r: ``u_out[r], status[r] = filter_command(u_local[r], bodies[r][body_seen[r]],
    obstacles[r][obstacle_seen[r]])`` (robot frame). Shapes: ``u_local (R, 2)``, ``bodies (R, M, 2)``,
    ``body_seen (R, M)``, ``obstacles (R, K, 2)``, ``obstacle_seen (R, K)``, ``u_out (R, 2)``,
    ``status (R,)`` int8."""
    rows = u_local.shape[0]
    ratio = half_axle_m / offset_m
    for r in numba.prange(rows):
        ux = u_local[r, 0]
        uy = u_local[r, 1]
        largest = abs(ux) + ratio * abs(uy)
        if largest > v_max_mps:
            scale = v_max_mps / largest
            ux = ux * scale
            uy = uy * scale
        count = 0
        for j in range(bodies.shape[1]):
            if body_seen[r, j]:
                count += 1
        for j in range(obstacles.shape[1]):
            if obstacle_seen[r, j]:
                count += 1
        if count == 0:
            u_out[r, 0] = ux
            u_out[r, 1] = uy
            status[r] = safety.UNCHANGED
            continue
        nx = np.empty(count + 4)
        ny = np.empty(count + 4)
        c = np.empty(count + 4)
        m = 0
        infeasible = False
        for j in range(bodies.shape[1] + obstacles.shape[1] + 4):
            if j < bodies.shape[1]:
                if not body_seen[r, j]:
                    continue
                x = bodies[r, j, 0]
                y = bodies[r, j, 1]
                ax = 2.0 * x
                ay = 2.0 * y
                b = 0.5 * gain_per_s * (x * x + y * y - body_distance_m * body_distance_m)
            elif j < bodies.shape[1] + obstacles.shape[1]:
                k = j - bodies.shape[1]
                if not obstacle_seen[r, k]:
                    continue
                x = obstacles[r, k, 0]
                y = obstacles[r, k, 1]
                ax = 2.0 * x
                ay = 2.0 * y
                b = gain_per_s * (x * x + y * y - obstacle_distance_m * obstacle_distance_m)
            else:
                w = j - bodies.shape[1] - obstacles.shape[1]  # (W): [1, q], [1, -q], [-1, q], [-1, -q]
                ax = 1.0 if w < 2 else -1.0
                ay = ratio if w % 2 == 0 else -ratio
                b = v_max_mps
            length = math.sqrt(ax * ax + ay * ay)
            if length == 0.0:
                if b < 0.0:
                    infeasible = True
                continue
            nx[m] = ax / length
            ny[m] = ay / length
            c[m] = b / length
            m += 1
        if infeasible:
            u_out[r, 0] = 0.0
            u_out[r, 1] = 0.0
            status[r] = safety.INFEASIBLE
            continue
        feasible = True
        for k in range(m):
            if nx[k] * ux + ny[k] * uy - c[k] > _TOLERANCE:
                feasible = False
                break
        if feasible:
            u_out[r, 0] = ux
            u_out[r, 1] = uy
            status[r] = safety.UNCHANGED
            continue
        best = math.inf
        best_x = 0.0
        best_y = 0.0
        for k in range(m + m * (m - 1) // 2):
            if k < m:
                excess = nx[k] * ux + ny[k] * uy - c[k]
                px = ux - excess * nx[k]
                py = uy - excess * ny[k]
            else:
                pair = k - m  # (first, second) in lexicographic order, first < second
                first = 0
                while pair >= m - 1 - first:
                    pair -= m - 1 - first
                    first += 1
                second = first + 1 + pair
                det = nx[first] * ny[second] - ny[first] * nx[second]
                if abs(det) < _PARALLEL:
                    continue
                px = (c[first] * ny[second] - c[second] * ny[first]) / det
                py = (nx[first] * c[second] - nx[second] * c[first]) / det
            dx = px - ux
            dy = py - uy
            cost = dx * dx + dy * dy
            if not cost < best:
                continue
            ok = True
            for q in range(m):
                if nx[q] * px + ny[q] * py - c[q] > _TOLERANCE:
                    ok = False
                    break
            if ok:
                best = cost
                best_x = px
                best_y = py
        if best == math.inf:
            u_out[r, 0] = 0.0
            u_out[r, 1] = 0.0
            status[r] = safety.INFEASIBLE
        else:
            u_out[r, 0] = best_x
            u_out[r, 1] = best_y
            status[r] = safety.CHANGED


_serial, _parallel = kernels.jit_serial_and_parallel(_filter_local)


def filter_local(
    u_local: np.ndarray,
    bodies: np.ndarray,
    body_seen: np.ndarray,
    obstacles: np.ndarray,
    obstacle_seen: np.ndarray,
    robot: RobotParams,
    params: SafetyParams,
) -> tuple[np.ndarray, np.ndarray]:
    """``(u_out (R, 2), status (R,) int8)``: the compiled filter over rows (shapes of ``_filter_local``)."""
    rows = u_local.shape[0]
    u_out = np.empty((rows, 2))
    status = np.empty(rows, dtype=np.int8)
    kernel = _parallel if rows >= kernels.PARALLEL_MIN_ROBOTS else _serial
    kernel(
        np.ascontiguousarray(u_local, dtype=np.float64),
        np.ascontiguousarray(bodies, dtype=np.float64),
        np.ascontiguousarray(body_seen, dtype=np.bool_),
        np.ascontiguousarray(obstacles, dtype=np.float64),
        np.ascontiguousarray(obstacle_seen, dtype=np.bool_),
        robot.half_axle_m,
        robot.offset_m,
        robot.v_max_mps,
        safety.body_distance_m(robot, params),
        safety.obstacle_distance_m(robot, params),
        params.gain_per_s,
        u_out,
        status,
    )
    return u_out, status
