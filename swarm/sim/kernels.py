"""Compiled (numba) inner loops of the batched kinematic simulator.

Each kernel is the same arithmetic as the numpy reference in ``swarm.core.robot`` and
``swarm.core.experts``, fused into one pass over all robots of all environments;
``tests/test_kinematic.py`` checks them against that reference. Compiled once
and cached on disk, in a serial and a multi-threaded variant: threads pay off only for
large batches (and cost a lot when the cores are busy), see ``PARALLEL_MIN_ROBOTS``.
"""

from __future__ import annotations

import inspect
import math
import os
import types
from collections.abc import Callable

import numba
import numpy as np

from swarm.core import robot

# Below this half-turn |w dt / 2| the kernel uses series (first omitted terms x^10/11! for sinc
# and x^10/10! for cos: under 3e-13 at the limit, under 1e-16 at the default 0.125 rad of a
# full-speed turn in 0.05 s); above it, it calls sin and cos.
_SERIES_LIMIT = 0.25

wheel_speed_scale = numba.njit(cache=True)(robot.wheel_speed_scale)
largest_wheel_speed_local = numba.njit(cache=True)(robot.largest_wheel_speed_local)


def _advance_unicycles(
    poses: np.ndarray,
    headings: np.ndarray,
    points: np.ndarray,
    u_world: np.ndarray,
    offset_m: float,
    half_axle_m: float,
    v_max_mps: float,
    dt_s: float,
) -> None:
    """In place, for every robot: point velocity -> (v, w) (eq. 2.3) -> wheels (eq. 2.4) ->
    common-factor saturation -> exact unicycle step (eq. 2.1).

    poses ``(R, 3)``; headings ``(R, 2)`` = (cos theta, sin theta), kept alongside theta so
    that no step needs a trigonometric call; points ``(R, 2)``, the controlled points, are
    rewritten for the new poses; u_world ``(R, 2)``.
    """
    count = poses.shape[0]
    for index in numba.prange(count):
        cos_t = headings[index, 0]
        sin_t = headings[index, 1]
        ux = u_world[index, 0]
        uy = u_world[index, 1]
        v = cos_t * ux + sin_t * uy
        w = (-sin_t * ux + cos_t * uy) / offset_m
        largest = max(abs(v - half_axle_m * w), abs(v + half_axle_m * w))
        if largest > v_max_mps:  # else the factor is 1
            scale = wheel_speed_scale(largest, v_max_mps)
            v *= scale
            w *= scale
        half_turn = 0.5 * w * dt_s
        if abs(half_turn) < _SERIES_LIMIT:
            h2 = half_turn * half_turn
            sinc_h = 1.0 - h2 * (1.0 / 6.0) * (
                1.0 - h2 * (1.0 / 20.0) * (1.0 - h2 * (1.0 / 42.0) * (1.0 - h2 * (1.0 / 72.0)))
            )
            cos_h = 1.0 - h2 * 0.5 * (
                1.0 - h2 * (1.0 / 12.0) * (1.0 - h2 * (1.0 / 30.0) * (1.0 - h2 * (1.0 / 56.0)))
            )
        else:
            sinc_h = math.sin(half_turn) / half_turn
            cos_h = math.cos(half_turn)
        sin_h = half_turn * sinc_h
        chord = v * dt_s * sinc_h
        cos_mid = cos_t * cos_h - sin_t * sin_h
        sin_mid = sin_t * cos_h + cos_t * sin_h
        cos_new = cos_mid * cos_h - sin_mid * sin_h
        sin_new = sin_mid * cos_h + cos_mid * sin_h
        renormalize = 1.5 - 0.5 * (cos_new * cos_new + sin_new * sin_new)
        cos_new *= renormalize
        sin_new *= renormalize
        x = poses[index, 0] + chord * cos_mid
        y = poses[index, 1] + chord * sin_mid
        heading = poses[index, 2] + 2.0 * half_turn
        if heading >= math.pi or heading < -math.pi:
            heading = (heading + math.pi) % (2.0 * math.pi) - math.pi
        poses[index, 0] = x
        poses[index, 1] = y
        poses[index, 2] = heading
        headings[index, 0] = cos_new
        headings[index, 1] = sin_new
        points[index, 0] = x + offset_m * cos_new
        points[index, 1] = y + offset_m * sin_new


def _delayed_consensus(
    points: np.ndarray,
    inbox: np.ndarray,
    neighbour_index: np.ndarray,
    neighbour_weight: np.ndarray,
    gain: float,
    u_world: np.ndarray,
) -> None:
    """Eq. 3.1 with last tick's neighbour points: ``u_i = -K sum_j heard_ij (p_i - inbox_j)``.

    Neighbours as padded lists ``(B, N, K)``: index -1 ends a robot's list.
    """
    batch, count, slots = neighbour_index.shape
    for row in numba.prange(batch * count):
        env = row // count
        i = row % count
        sum_x = 0.0
        sum_y = 0.0
        weight = 0.0
        for k in range(slots):
            j = neighbour_index[env, i, k]
            if j < 0:
                break
            a = neighbour_weight[env, i, k]
            weight += a
            sum_x += a * inbox[env, j, 0]
            sum_y += a * inbox[env, j, 1]
        u_world[env, i, 0] = -gain * (weight * points[env, i, 0] - sum_x)
        u_world[env, i, 1] = -gain * (weight * points[env, i, 1] - sum_y)


def _dense_to_lists(adjacency: np.ndarray, neighbour_index: np.ndarray, neighbour_weight: np.ndarray) -> None:
    """Fill padded neighbour lists ``(B, N, K)`` from a dense ``(B, N, N)`` adjacency."""
    batch, count = adjacency.shape[0], adjacency.shape[1]
    slots = neighbour_index.shape[2]
    for row in numba.prange(batch * count):
        env = row // count
        i = row % count
        k = 0
        for j in range(count):
            a = adjacency[env, i, j]
            if a != 0.0:
                neighbour_index[env, i, k] = j
                neighbour_weight[env, i, k] = a
                k += 1
        for rest in range(k, slots):
            neighbour_index[env, i, rest] = -1
            neighbour_weight[env, i, rest] = 0.0


@numba.njit(cache=True, inline="always")
def _linked(positions: np.ndarray, env: int, i: int, j: int, radius_sq: float) -> bool:
    """Robots i != j of environment env are within the disk radius of each other."""
    dx = positions[env, i, 0] - positions[env, j, 0]
    dy = positions[env, i, 1] - positions[env, j, 1]
    return j != i and dx * dx + dy * dy <= radius_sq


def _disk_degrees(positions: np.ndarray, radius_m: float, degrees: np.ndarray) -> None:
    """Neighbours within ``radius_m`` of each robot (the disk graph of ``swarm.core.graphs.disk``)."""
    batch, count = positions.shape[0], positions.shape[1]
    radius_sq = radius_m * radius_m
    for row in numba.prange(batch * count):
        env = row // count
        i = row % count
        degree = 0
        for j in range(count):
            if _linked(positions, env, i, j, radius_sq):
                degree += 1
        degrees[env, i] = degree


def _disk_lists(
    positions: np.ndarray, radius_m: float, neighbour_index: np.ndarray, neighbour_weight: np.ndarray
) -> None:
    batch, count = positions.shape[0], positions.shape[1]
    slots = neighbour_index.shape[2]
    radius_sq = radius_m * radius_m
    for row in numba.prange(batch * count):
        env = row // count
        i = row % count
        k = 0
        for j in range(count):
            if _linked(positions, env, i, j, radius_sq):
                neighbour_index[env, i, k] = j
                neighbour_weight[env, i, k] = 1.0
                k += 1
        for rest in range(k, slots):
            neighbour_index[env, i, rest] = -1
            neighbour_weight[env, i, rest] = 0.0


def _diameter_above(positions: np.ndarray, threshold_m: float, above: np.ndarray) -> None:
    """``above[b]``: is max_pairwise of environment b larger than ``threshold_m``? positions ``(B, N, >=2)``.

    With r the largest distance to the centroid, ``r <= max_pairwise <= 2 r``: pairs are scanned
    only when those bounds cannot decide, and the scan stops at the first pair too far apart.
    """
    batch, count = positions.shape[0], positions.shape[1]
    limit_sq = threshold_m * threshold_m
    for env in numba.prange(batch):
        cx = 0.0
        cy = 0.0
        for i in range(count):
            cx += positions[env, i, 0]
            cy += positions[env, i, 1]
        cx /= count
        cy /= count
        radius_sq = 0.0
        for i in range(count):
            dx = positions[env, i, 0] - cx
            dy = positions[env, i, 1] - cy
            radius_sq = max(radius_sq, dx * dx + dy * dy)
        if radius_sq > limit_sq:
            above[env] = True
            continue
        if 4.0 * radius_sq <= limit_sq:
            above[env] = False
            continue
        found = False
        for i in range(count):
            xi = positions[env, i, 0]
            yi = positions[env, i, 1]
            for j in range(i + 1, count):
                dx = xi - positions[env, j, 0]
                dy = yi - positions[env, j, 1]
                if dx * dx + dy * dy > limit_sq:
                    found = True
                    break
            if found:
                break
        above[env] = found


def _lists_connected(neighbour_index: np.ndarray, reached: np.ndarray, connected: np.ndarray) -> None:
    """``connected[b]``: is every robot of environment b reachable from robot 0 over the padded
    neighbour lists ``(B, N, K)`` (-1 ends a list)? Breadth-first search; ``reached`` ``(B, N)`` scratch."""
    batch, count, slots = neighbour_index.shape
    for env in numba.prange(batch):
        for i in range(count):
            reached[env, i] = -1
        reached[env, 0] = 0  # reached[env, :found] is the queue, in order of discovery
        queue = np.empty(count, dtype=np.int64)
        queue[0] = 0
        head, tail = 0, 1
        while head < tail:
            i = queue[head]
            head += 1
            for k in range(slots):
                j = neighbour_index[env, i, k]
                if j < 0:
                    break
                if reached[env, j] < 0:
                    reached[env, j] = 0
                    queue[tail] = j
                    tail += 1
        connected[env] = tail == count


# Robots (rows) per call from which the multi-threaded variant is used (environment variable
# SWARM_PARALLEL_MIN_ROBOTS overrides it; threads only pay off on otherwise idle cores).
PARALLEL_MIN_ROBOTS = int(os.environ.get("SWARM_PARALLEL_MIN_ROBOTS", 50_000))


def _named(function, suffix: str):
    """``function`` (same code, globals and defaults) under the qualified name ``function`` + ``suffix``."""
    copy = types.FunctionType(
        function.__code__,
        function.__globals__,
        function.__name__ + suffix,
        function.__defaults__,
        function.__closure__,
    )
    copy.__qualname__ = function.__qualname__ + suffix
    copy.__doc__, copy.__module__ = function.__doc__, function.__module__
    return copy


def jit_serial_and_parallel(function, **options) -> tuple[Callable[..., None], Callable[..., None]]:
    """``function`` compiled by numba twice, serial and with ``parallel=True``, both cached on disk.

    Each variant is compiled under its own qualified name: numba's disk cache names an entry by the
    function's qualified name, first line and argument types, not by the compile options, so two
    variants of one function would share an entry and the second one called would load the first
    one's machine code (the parallel variant then ran on one thread: ``tests/test_kernels_threads.py``).
    Typed as plain callables: numba's Dispatcher declares a narrower ``__call__`` than the kernel.
    """
    serial = numba.njit(cache=True, **options)(_named(function, "_serial"))
    parallel = numba.njit(cache=True, parallel=True, **options)(_named(function, "_parallel"))
    return serial, parallel


def _in_chunks(serial, function):
    """The multi-threaded variant of a ``fastmath`` kernel: the compiled ``serial`` itself on contiguous
    chunks of axis 0 (robots, or environments) of every array argument, one chunk per thread task.

    Compiled with ``parallel=True`` instead, a fastmath kernel gets other floating-point contractions
    than its serial twin and results a few ulps apart; run this way, threads never change a bit.
    Not cached on disk (generated code): a process compiles it on its first threaded call.
    """
    parameters = inspect.signature(function).parameters
    sliced = [
        name for name, parameter in parameters.items() if parameter.annotation in ("np.ndarray", np.ndarray)
    ]
    call = ", ".join(f"{name}[first:last]" if name in sliced else name for name in parameters)
    source = (
        f"def {function.__name__}_in_chunks({', '.join(parameters)}):\n"
        f"    rows = {sliced[0]}.shape[0]\n"
        "    chunks = min(rows, 4 * numba.get_num_threads())\n"
        "    for chunk in numba.prange(chunks):\n"
        "        first = chunk * rows // chunks\n"
        "        last = (chunk + 1) * rows // chunks\n"
        f"        serial({call})\n"
    )
    namespace = {"numba": numba, "serial": serial}
    exec(source, namespace)  # the source is built above from the kernel's own parameter names
    return numba.njit(parallel=True)(namespace[f"{function.__name__}_in_chunks"])


def _serial_and_parallel(function):
    # fastmath lets LLVM reassociate and vectorize (about 30% faster here); results stay within
    # rounding of the numpy reference (tests/test_kinematic.py) and are deterministic, and the same
    # bits on any number of threads (``_in_chunks``).
    serial = numba.njit(cache=True, fastmath=True)(_named(function, "_serial"))
    parallel = _in_chunks(serial, function)

    def dispatch(*args):
        rows = args[0].shape[0] * (args[0].shape[1] if args[0].ndim == 3 else 1)
        return (parallel if rows >= PARALLEL_MIN_ROBOTS else serial)(*args)

    dispatch.__doc__ = function.__doc__
    dispatch.__name__ = function.__name__.lstrip("_")
    return dispatch


advance_unicycles = _serial_and_parallel(_advance_unicycles)
delayed_consensus = _serial_and_parallel(_delayed_consensus)
dense_to_lists = _serial_and_parallel(_dense_to_lists)
disk_degrees = _serial_and_parallel(_disk_degrees)
disk_lists = _serial_and_parallel(_disk_lists)
diameter_above = _serial_and_parallel(_diameter_above)
lists_connected = _serial_and_parallel(_lists_connected)
