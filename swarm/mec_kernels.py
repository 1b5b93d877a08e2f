"""Compiled (numba) kernels of the minimum-enclosing-circle controllers, for the batched engine.

``swarm.mec`` holds the per-robot arithmetic in plain floats (what the robot agents run); this
module compiles those same functions with numba and loops them over B environments x N robots.
No ``fastmath`` here: the agents' Python floats and these kernels then round alike, so the
engines agree to the last bits (``tests/test_mec.py``).

Flood message layout, ``D = 2 M + 1``: the support points ``(x_m, y_m)`` for ``m < M``, then a
flag that is 1 once the robot has a message at all (a zero inbox, at tick 0, has flag 0).
"""

from __future__ import annotations

import numba
import numpy as np

from swarm import mec
from swarm.kernels import PARALLEL_MIN_ROBOTS

welzl_circle = numba.njit(cache=True)(mec.welzl_circle)
merge_support = numba.njit(cache=True)(mec.merge_support)
drive_toward = numba.njit(cache=True)(mec.drive_toward)


def _mec_flood(
    poses: np.ndarray,
    inbox: np.ndarray,
    neighbour_index: np.ndarray,
    directions_x: np.ndarray,
    directions_y: np.ndarray,
    offset_m: float,
    v_max_mps: float,
    control_period_s: float,
    reverse: bool,
    u_world: np.ndarray,
    outbox: np.ndarray,
) -> None:
    """One tick of ``mec_flood`` for every robot (``swarm.controllers.MecFlood``).

    poses ``(B, N, 3)``; inbox ``(B, >=N, D)``: column i is robot i's own message of last tick (its
    memory), columns named by ``neighbour_index`` ``(B, N, K)`` (-1 ends a list) what it heard.
    Writes u_world ``(B, N, 2)`` and outbox ``(B, N, D)``.
    """
    batch, count, slots = neighbour_index.shape
    directions = directions_x.shape[0]
    flag = 2 * directions
    for row in numba.prange(batch * count):
        env = row // count
        i = row % count
        known = outbox[env, i]
        if inbox[env, i, flag] > 0.5:
            known[:] = inbox[env, i]
        else:  # nothing remembered yet: its own (initial) axle position in every direction
            for m in range(directions):
                known[2 * m] = poses[env, i, 0]
                known[2 * m + 1] = poses[env, i, 1]
            known[flag] = 1.0
        for k in range(slots):
            j = neighbour_index[env, i, k]
            if j < 0:
                break
            if inbox[env, j, flag] > 0.5:
                merge_support(known, inbox[env, j], directions_x, directions_y, directions)
        cx, cy, radius = welzl_circle(known[0:flag:2], known[1:flag:2], directions)
        if radius > 0.0:
            ux, uy = drive_toward(
                poses[env, i, 0],
                poses[env, i, 1],
                poses[env, i, 2],
                cx,
                cy,
                offset_m,
                v_max_mps,
                control_period_s,
                reverse,
            )
        else:  # it knows of no other robot yet: hold still
            ux, uy = 0.0, 0.0
        u_world[env, i, 0] = ux
        u_world[env, i, 1] = uy


def _centralized_mec(
    poses: np.ndarray,
    order: np.ndarray,
    offset_m: float,
    v_max_mps: float,
    control_period_s: float,
    reverse: bool,
    u_world: np.ndarray,
) -> None:
    """``centralized_mec`` for every environment: the exact MEC of the current axle positions (taken
    in the fixed shuffled ``order`` ``(N,)``), then every robot drives toward its centre."""
    batch, count = poses.shape[0], poses.shape[1]
    for env in numba.prange(batch):
        xs = np.empty(count)
        ys = np.empty(count)
        for k in range(count):
            xs[k] = poses[env, order[k], 0]
            ys[k] = poses[env, order[k], 1]
        cx, cy, _ = welzl_circle(xs, ys, count)
        for i in range(count):
            ux, uy = drive_toward(
                poses[env, i, 0],
                poses[env, i, 1],
                poses[env, i, 2],
                cx,
                cy,
                offset_m,
                v_max_mps,
                control_period_s,
                reverse,
            )
            u_world[env, i, 0] = ux
            u_world[env, i, 1] = uy


def _serial_and_parallel(function):
    serial = numba.njit(cache=True)(function)
    parallel = numba.njit(cache=True, parallel=True)(function)

    def dispatch(*args):
        rows = args[0].shape[0] * args[0].shape[1]
        return (parallel if rows >= PARALLEL_MIN_ROBOTS else serial)(*args)

    dispatch.__doc__ = function.__doc__
    dispatch.__name__ = function.__name__.lstrip("_")
    return dispatch


mec_flood = _serial_and_parallel(_mec_flood)
centralized_mec = _serial_and_parallel(_centralized_mec)
