"""Minimum-enclosing-circle control, one robot at a time, in plain floats (no numpy, no numba).

The robot agents (``robot_agent``) call these functions as they are; ``swarm.sim.mec_kernels`` compiles
the very same functions with numba for the batched kinematic engine, so both engines do the same
floating-point arithmetic. Each function is self-contained (no calls to other Python functions),
which is what lets numba compile it unchanged.

- :func:`welzl_circle`: the exact smallest circle enclosing ``count`` points (Welzl's algorithm in its
  iterative form, in the order given); the one implementation of the circle, which
  ``swarm.core.metrics.minimum_enclosing_circle`` also runs (on a fixed shuffle).
- :func:`merge_support`: the flood's max-consensus over per-direction support points.
- :func:`drive_toward`: full speed toward a target, forward or in reverse (``swarm.core.experts``).
- :func:`flood_step`, :func:`centralized_mec_step`: the batched engine's loops over B x N robots.

The loops live here too, next to what they call, so that numba's on-disk cache (keyed on the source
file of each compiled function) is invalidated by any edit of this file.

Flood message layout, ``D = 2 M + 1``: the support points ``(x_m, y_m)`` for ``m < M``, then a
flag that is 1 once the robot has a message at all (a zero inbox, at tick 0, has flag 0).
"""

from __future__ import annotations

import math

prange = range  # numba.prange in the compiled loops (swarm.sim.mec_kernels)


def welzl_circle(xs, ys, count: int) -> tuple[float, float, float]:
    """Smallest circle containing points ``(xs[k], ys[k])``, ``k < count``: ``(cx, cy, radius)``.

    Welzl's algorithm, three nested loops over the points in the order given (expected O(n) on a
    random order, O(n^3) at worst; callers shuffle large sets). Repeated and collinear points are
    handled: a (near-)degenerate triple gives the circle on its farthest pair. A point is inside when
    its distance is at most ``r + 1e-12 extent + 1e-14 max |coordinate|``: relative to the swarm's
    extent, plus the rounding of its coordinates (points 1e-5 m apart at 2 m from the origin once
    judged a repeated point outside its circle by 4e-16, a circle twice too big). Distances are
    ``sqrt(dx dx + dy dy)``, not ``math.hypot``, whose Python and numba forms differ in the last bit.
    The radius returned is the largest distance from the centre to a point.
    """
    scale, magnitude = 0.0, 0.0
    for k in range(count):
        scale = max(scale, abs(xs[k] - xs[0]), abs(ys[k] - ys[0]))
        magnitude = max(magnitude, abs(xs[k]), abs(ys[k]))
    tol = 1e-12 * (scale if scale > 0.0 else 1.0) + 1e-14 * magnitude
    cx, cy, r = xs[0], ys[0], 0.0
    for i in range(1, count):
        dx, dy = xs[i] - cx, ys[i] - cy
        if math.sqrt(dx * dx + dy * dy) <= r + tol:
            continue
        cx, cy, r = xs[i], ys[i], 0.0
        for j in range(i):
            dx, dy = xs[j] - cx, ys[j] - cy
            if math.sqrt(dx * dx + dy * dy) <= r + tol:
                continue
            dx, dy = xs[i] - xs[j], ys[i] - ys[j]
            cx, cy, r = 0.5 * (xs[i] + xs[j]), 0.5 * (ys[i] + ys[j]), 0.5 * math.sqrt(dx * dx + dy * dy)
            for k in range(j):
                dx, dy = xs[k] - cx, ys[k] - cy
                if math.sqrt(dx * dx + dy * dy) <= r + tol:
                    continue
                # circumcircle of i, j, k (a degenerate triple: the circle on its farthest pair)
                ax, ay = xs[i], ys[i]
                bx, by = xs[j] - ax, ys[j] - ay
                qx, qy = xs[k] - ax, ys[k] - ay
                det = 2.0 * (bx * qy - by * qx)
                b2, q2 = bx * bx + by * by, qx * qx + qy * qy
                if abs(det) <= 1e-12 * max(b2, q2):
                    dx, dy = xs[j] - xs[k], ys[j] - ys[k]
                    d_ij, d_ik, d_jk = b2, q2, dx * dx + dy * dy
                    if d_ij >= d_ik and d_ij >= d_jk:
                        u, w = i, j
                    elif d_ik >= d_jk:
                        u, w = i, k
                    else:
                        u, w = j, k
                    dx, dy = xs[u] - xs[w], ys[u] - ys[w]
                    cx, cy = 0.5 * (xs[u] + xs[w]), 0.5 * (ys[u] + ys[w])
                    r = 0.5 * math.sqrt(dx * dx + dy * dy)
                else:
                    ux = (qy * b2 - by * q2) / det
                    uy = (bx * q2 - qx * b2) / det
                    cx, cy, r = ax + ux, ay + uy, math.sqrt(ux * ux + uy * uy)
    radius = 0.0
    for k in range(count):
        dx, dy = xs[k] - cx, ys[k] - cy
        radius = max(radius, math.sqrt(dx * dx + dy * dy))
    return cx, cy, radius


def merge_support(known, message, directions_x, directions_y, count: int) -> None:
    """Max-consensus of the flood, in place: for each of the ``count`` directions ``d_m``, keep the
    support point (``known[2m], known[2m + 1]``) or the message's one, whichever is larger in the
    order: projection ``<q, d_m>``, ties broken by larger x, then larger y. A total order, so the
    result is the same whatever order messages are merged in (commutative, associative and
    idempotent: a message merged twice changes nothing)."""
    for m in range(count):
        qx, qy = message[2 * m], message[2 * m + 1]
        kx, ky = known[2 * m], known[2 * m + 1]
        pq = qx * directions_x[m] + qy * directions_y[m]
        pk = kx * directions_x[m] + ky * directions_y[m]
        if pq > pk or (pq == pk and (qx > kx or (qx == kx and qy > ky))):
            known[2 * m] = qx
            known[2 * m + 1] = qy


def flood_directions(count: int) -> tuple[list[float], list[float]]:
    """The flood's ``count`` unit directions ``d_m = (cos 2 pi m / M, sin 2 pi m / M)``."""
    angles = [2.0 * math.pi * m / count for m in range(count)]
    return [math.cos(a) for a in angles], [math.sin(a) for a in angles]


def drive_toward(
    x_m: float,
    y_m: float,
    theta_rad: float,
    target_x_m: float,
    target_y_m: float,
    v_max_mps: float,
    control_period_s: float,
    reverse: bool,
) -> tuple[float, float]:
    """``swarm.core.experts.drive_toward_velocity`` for one robot, in floats: the world velocity of the
    FORWARD controlled point that drives the robot's AXLE toward the target (what success judges), at
    ``min(v_max, distance / T)``, forward or in reverse when the target is behind the axle."""
    c, s = math.cos(theta_rad), math.sin(theta_rad)
    dx = target_x_m - x_m
    dy = target_y_m - y_m
    backward = reverse and dx * c + dy * s < 0.0
    distance = math.sqrt(dx * dx + dy * dy)
    if distance <= 0.0:
        return 0.0, 0.0
    scale = min(v_max_mps / distance, 1.0 / control_period_s)
    ux, uy = dx * scale, dy * scale
    if backward:  # eq. 2.3 with offset -l = eq. 2.3 with +l on the command reflected across the heading
        along = ux * c + uy * s
        ux, uy = 2.0 * along * c - ux, 2.0 * along * s - uy
    return ux, uy


def flood_step(
    poses,
    inbox,
    neighbour_index,
    directions_x,
    directions_y,
    v_max_mps: float,
    control_period_s: float,
    reverse: bool,
    projections,
    known_projections,
    u_world,
    outbox,
) -> None:
    """One tick of ``mec_flood`` for every robot (``swarm.sim.controllers.MecFlood``); compiled by
    ``swarm.sim.mec_kernels``, runs as it is (slowly) on numpy arrays too.

    poses ``(B, N, 3)``; inbox ``(B, C, D)``, ``C >= N``: column i is robot i's own message of last
    tick (its memory), columns named by ``neighbour_index`` ``(B, N, K)`` (-1 ends a list) what it
    heard; projections ``(B, C, M)`` and known_projections ``(B, N, M)`` scratch. Writes u_world
    ``(B, N, 2)`` and outbox ``(B, N, D)``.
    The merge is :func:`merge_support`'s, with each message's projections ``<q, d_m>`` computed
    once per tick instead of once per receiver (same floats, fewer multiplications).
    """
    batch, count, slots = neighbour_index.shape
    columns = inbox.shape[1]
    directions = directions_x.shape[0]
    flag = 2 * directions
    for row in prange(batch * columns):
        env = row // columns
        j = row % columns
        for m in range(directions):
            projections[env, j, m] = (
                inbox[env, j, 2 * m] * directions_x[m] + inbox[env, j, 2 * m + 1] * directions_y[m]
            )
    for row in prange(batch * count):
        env = row // count
        i = row % count
        known = outbox[env, i]
        best = known_projections[env, i]
        if inbox[env, i, flag] > 0.5:
            known[:] = inbox[env, i]
        else:  # nothing remembered yet: its own (initial) axle position in every direction
            for m in range(directions):
                known[2 * m] = poses[env, i, 0]
                known[2 * m + 1] = poses[env, i, 1]
            known[flag] = 1.0
        for m in range(directions):
            best[m] = known[2 * m] * directions_x[m] + known[2 * m + 1] * directions_y[m]
        for k in range(slots):
            j = neighbour_index[env, i, k]
            if j < 0:
                break
            if inbox[env, j, flag] <= 0.5:
                continue
            for m in range(directions):
                pq = projections[env, j, m]
                qx, qy = inbox[env, j, 2 * m], inbox[env, j, 2 * m + 1]
                kx, ky = known[2 * m], known[2 * m + 1]
                pk = best[m]
                if pq > pk or (pq == pk and (qx > kx or (qx == kx and qy > ky))):
                    known[2 * m] = qx
                    known[2 * m + 1] = qy
                    best[m] = pq
        cx, cy, radius = welzl_circle(known[0:flag:2], known[1:flag:2], directions)
        if radius > 0.0:
            ux, uy = drive_toward(
                poses[env, i, 0],
                poses[env, i, 1],
                poses[env, i, 2],
                cx,
                cy,
                v_max_mps,
                control_period_s,
                reverse,
            )
        else:  # it knows of no other robot yet: hold still
            ux, uy = 0.0, 0.0
        u_world[env, i, 0] = ux
        u_world[env, i, 1] = uy


def centralized_mec_step(
    poses,
    order,
    xs,
    ys,
    v_max_mps: float,
    control_period_s: float,
    reverse: bool,
    u_world,
) -> None:
    """``centralized_mec`` for every environment: the exact MEC of the current axle positions (taken
    in the fixed shuffled ``order`` ``(N,)``; ``xs``, ``ys`` ``(B, N)`` scratch), then every robot
    drives toward its centre."""
    batch, count = poses.shape[0], poses.shape[1]
    for env in prange(batch):
        for k in range(count):
            xs[env, k] = poses[env, order[k], 0]
            ys[env, k] = poses[env, order[k], 1]
        cx, cy, _ = welzl_circle(xs[env], ys[env], count)
        for i in range(count):
            ux, uy = drive_toward(
                poses[env, i, 0],
                poses[env, i, 1],
                poses[env, i, 2],
                cx,
                cy,
                v_max_mps,
                control_period_s,
                reverse,
            )
            u_world[env, i, 0] = ux
            u_world[env, i, 1] = uy
