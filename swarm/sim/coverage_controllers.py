"""Batched controllers of the coverage task (``swarm.core.tasks.coverage``).

Every kind drives each axle at full speed toward a target (``swarm.core.experts.drive_toward_velocity``:
the whole way in one control period when closer than ``v_max T``, so near a fixed point a tick is one
step of Lloyd's map; the baselines' ``step_fraction`` option goes that fraction of the way instead).
The kinds differ in what the target is computed from:

- ``lloyd`` (:class:`LloydExpert`, centralized): the centroid of the robot's Voronoi cell among all
  robots' current positions (Lloyd's map, ``swarm.core.tasks.coverage.lloyd_centroids``, but with a
  boundary point in every cell it is nearest to, as below).
- ``lloyd_local`` (:class:`LloydLocal`, decentralized; Cortes, Martinez, Karatas and Bullo 2004): the
  centroid of its cell among itself and the neighbours it heard this tick (their positions of last
  tick: the message is the sender's axle ``(x, y)``), cut to the disc of ``cell_radius_m`` around it when
  that is set (the limited-range cell of Cortes, Martinez and Bullo 2005: with ``cell_radius_m`` half a
  disk graph's radius the cut cell lies inside the true Voronoi cell).
- ``lloyd_flood`` (:class:`LloydFlood`, decentralized): every robot floods the freshest position it knows
  of every robot with its age in hops (message ``N x (age + 1, x, y)``, 0: unknown; the merge keeps the
  least age, the robot's own memory first on ties), and takes the centroid of its cell among every robot
  it knows. After graph-diameter ticks it knows everyone, a robot h hops away as of h ticks ago; its
  Voronoi neighbours are near it and mostly few hops away, so its cell is nearly the expert's.
- ``lloyd_predict`` (:class:`LloydPredict`, decentralized): ``lloyd_flood`` whose table also carries each
  robot's target (message ``N x (age + 1, x, y, target x, target y)``: the target it computed at that
  position). A robot places every robot it knows where it would be after driving straight toward that
  target at ``v_max`` for the entry's age (:func:`swarm.sim.coverage_onboard.predicted_positions`), and
  takes its cell among those points. A position one tick old is where a neighbour *was*; near the end
  every robot moves the whole way to its centroid in one tick, so on dense graphs the prediction is
  what closes the gap to the expert (``bench/results/coverage_prediction.md``).

The cells of the decentralized kinds are computed by one numba kernel (:func:`cell_sums`, on threads
for large batches); the robots' on-board forms (``swarm.sim.coverage_onboard``) compute them with
numpy masks, to rounding.
A point on a cell's boundary (equidistant) belongs to every robot it is nearest to.
"""

from __future__ import annotations

import math
import os

import numba
import numpy as np

from swarm.core.robot import RobotParams
from swarm.core.tasks.coverage import CoverageSection
from swarm.sim import kernels
from swarm.sim.coverage_gnn import CoverageGnnWeights, coverage_features, region_scale_m
from swarm.sim.coverage_onboard import HORIZON_TICKS, CoverageDrive
from swarm.sim.links import Links
from swarm.sim.steering_mlp import local_command, to_world

PRUNE_RELATIVE = 1.0 + 1e-6
PRUNE_ABSOLUTE_M2 = 1e-12
"""The margin of :func:`cell_sums`'s scan over the others: an other ``d`` from the robot is compared with
a point ``r`` from it while ``d^2 <= 4 r^2 PRUNE_RELATIVE + PRUNE_ABSOLUTE_M2``. Beyond, ``d > 2 r (1 +
5e-7)``, so the other is more than ``r (1 + 1e-6)`` from the point: farther, by a margin rounding never
crosses."""

ROW_SLACK = 1e-12
"""The margin of :func:`cell_sums`'s window on a grid row, relative to the squared lengths involved,
``2 (extent^2 + |a|^2) >= (extent + |a|)^2`` for an other at ``a`` from the robot and the region within
``extent`` of it (about 50 times the rounding of the distances it stands for): a window only picks the
points to test, so a wide one costs time, never a bit."""

INNER_SLACK = 1e-9
"""The margin of the inner window on a grid row (:func:`_row_window`), relative to the same squared
lengths as ``ROW_SLACK``: a point of the row whose offset from the robot lies in it is inside every
half-plane by more than a million times the rounding of the exact test, so it is the cell's without
that test; only the points between the two windows (none, or one at either end, on most rows) are
tested one by one."""


GROUPS = 64
"""The groups of :func:`_nearest_first`: the others on the robot's spot, then one per multiple of the
nearest other's squared distance up to ``GROUPS`` of them, the last taking every farther other."""


@numba.njit(cache=True)
def _nearest_first(gap_sq: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(order, floor_sq)``: the indices of ``gap_sq`` (squared distances) in groups, nearest group
    first, group ``j`` the values in ``[j s, (j + 1) s)`` for ``s`` the least positive value (0: the
    zeros; the last group unbounded), in index order within a group; and per entry of ``order`` a lower
    bound of its group's values, non-decreasing. A scan that stops at the first ``floor_sq`` beyond
    its reach has passed every entry within the reach. A counting sort, linear in the others: at N =
    100 a full sort of them was a third of a cell's cost."""
    known = gap_sq.shape[0]
    step = math.inf
    for k in range(known):
        if gap_sq[k] > 0.0:
            step = min(step, gap_sq[k])
    group = np.empty(known, np.int64)
    starts = np.zeros(GROUPS + 2, np.int64)
    for k in range(known):
        group[k] = int(min(gap_sq[k] / step, GROUPS)) if step < math.inf else 0
        starts[group[k] + 1] += 1
    for j in range(GROUPS + 1):
        starts[j + 1] += starts[j]
    order = np.empty(known, np.int64)
    floor_sq = np.empty(known)
    for k in range(known):
        j = group[k]
        order[starts[j]] = k
        floor_sq[starts[j]] = j * step * (1.0 - 1e-9) if j > 0 else 0.0  # below group j's values
        starts[j] += 1
    return order, floor_sq


@numba.njit(cache=True)
def _row_window(
    up: float,
    px: float,
    py: float,
    gap_sq: np.ndarray,
    floor_sq: np.ndarray,
    near_x: np.ndarray,
    near_y: np.ndarray,
    extent_sq: float,
    radius_sq: float,
) -> tuple[float, float, float, float]:
    """``(low, high, inner_low, inner_high)``. ``low`` to ``high``: the x where the grid row ``up`` above
    the robot at ``(px, py)`` can meet its cell: the intersection of the disc and of the half-planes
    ``2 (x - px) ax + 2 up ay <= |a|^2 + slack`` of the others at ``a`` from the robot (in
    :func:`_nearest_first`'s groups); ``low > high``: nowhere. An other more than twice as far from the
    robot as every point of the window so far cuts none of it (triangle inequality): the scan skips it,
    and ends at the first group all of whose others are that far. ``inner_low`` to ``inner_high``: the
    offsets ``x - px`` inside every scanned half-plane by the margin ``INNER_SLACK`` (offsets, so that
    no rounding of coordinates far from the origin enters), a part of the window whose points are the
    cell's (the disc aside, which the caller tests)."""
    low, high = -math.inf, math.inf
    inner_low, inner_high = -math.inf, math.inf
    if radius_sq < math.inf:
        room = radius_sq * (1.0 + 1e-9) + 1e-12 - up * up
        if room < 0.0:
            return math.inf, -math.inf, math.inf, -math.inf
        low, high = px - math.sqrt(room) - 1e-9, px + math.sqrt(room) + 1e-9
    for k in range(gap_sq.shape[0]):
        if high < math.inf and low > -math.inf:
            farthest_sq = max((low - px) ** 2, (high - px) ** 2) + up * up
            reach_sq = 4.0 * farthest_sq * PRUNE_RELATIVE + PRUNE_ABSOLUTE_M2
            if floor_sq[k] > reach_sq:
                break
            if gap_sq[k] > reach_sq:
                continue
        ax, ay = near_x[k] - px, near_y[k] - py
        span_sq = 2.0 * (extent_sq + gap_sq[k])
        limit = gap_sq[k] - 2.0 * up * ay + (ROW_SLACK * span_sq + 1e-300)
        strict = gap_sq[k] - 2.0 * up * ay - (INNER_SLACK * span_sq + 1e-300)
        if ax > 0.0:
            high = min(high, px + limit / (2.0 * ax))
            inner_high = min(inner_high, strict / (2.0 * ax))
        elif ax < 0.0:
            low = max(low, px + limit / (2.0 * ax))
            inner_low = max(inner_low, strict / (2.0 * ax))
        else:
            if limit < 0.0:
                return math.inf, -math.inf, math.inf, -math.inf
            if strict < 0.0:
                inner_low, inner_high = math.inf, -math.inf
        if low > high:
            return low, high, math.inf, -math.inf
    return low, high, inner_low, inner_high


def _cell_sums(
    own: np.ndarray,
    others: np.ndarray,
    valid: np.ndarray,
    points: np.ndarray,
    xs: np.ndarray,
    row_start: np.ndarray,
    rows_ascending: bool,
    weights: np.ndarray,
    radius_sq: float,
    out: np.ndarray,
) -> None:
    batch, count = own.shape[0], own.shape[1]
    slots = others.shape[2]
    rows = row_start.shape[0] - 1
    row_y = np.empty(rows)
    for r in range(rows):
        row_y[r] = points[row_start[r], 1]
    low_x, high_x = points[:, 0].min(), points[:, 0].max()
    low_y, high_y = points[:, 1].min(), points[:, 1].max()
    for row in numba.prange(batch * count):  # one robot's cell a row: rows share nothing
        b, i = row // count, row % count
        px, py = own[b, i, 0], own[b, i, 1]
        extent = max(abs(low_x - px), abs(high_x - px)) + max(abs(low_y - py), abs(high_y - py))
        # the valid others, in groups nearest first
        known = 0
        for k in range(slots):
            known += valid[b, i, k]
        gap_sq = np.empty(known)
        near_x = np.empty(known)
        near_y = np.empty(known)
        m = 0
        for k in range(slots):
            if valid[b, i, k]:
                near_x[m], near_y[m] = others[b, i, k, 0], others[b, i, k, 1]
                gap_sq[m] = (near_x[m] - px) ** 2 + (near_y[m] - py) ** 2
                m += 1
        order, floor_sq = _nearest_first(gap_sq)
        gap_sq, near_x, near_y = gap_sq[order], near_x[order], near_y[order]
        # each row's window; rows sorted by y: the rows that meet the (convex) cell are one run around
        # the robot's y, so the scan goes outward from it and stops at the first row met by none
        low = np.full(rows, math.inf)
        high = np.full(rows, -math.inf)
        inner_low = np.full(rows, math.inf)
        inner_high = np.full(rows, -math.inf)
        if rows_ascending:
            middle = np.searchsorted(row_y, py)
            first, last = middle, middle
            for r in range(middle, rows):
                low[r], high[r], inner_low[r], inner_high[r] = _row_window(
                    row_y[r] - py, px, py, gap_sq, floor_sq, near_x, near_y, extent * extent, radius_sq
                )
                last = r + 1
                if low[r] > high[r]:
                    break
            for r in range(middle - 1, -1, -1):
                low[r], high[r], inner_low[r], inner_high[r] = _row_window(
                    row_y[r] - py, px, py, gap_sq, floor_sq, near_x, near_y, extent * extent, radius_sq
                )
                first = r
                if low[r] > high[r]:
                    break
        else:
            first, last = 0, rows
            for r in range(rows):
                low[r], high[r], inner_low[r], inner_high[r] = _row_window(
                    row_y[r] - py, px, py, gap_sq, floor_sq, near_x, near_y, extent * extent, radius_sq
                )
        mass, moment_x, moment_y = 0.0, 0.0, 0.0
        for r in range(first, last):  # in the points' order: the sums are the plain loop's, bit for bit
            if low[r] > high[r]:
                continue
            start, stop = row_start[r], row_start[r + 1]
            widen = 1e-9 * (1.0 + abs(low[r]) + abs(high[r])) if high[r] - low[r] < math.inf else 0.0
            begin = start + np.searchsorted(xs[start:stop], low[r] - widen)
            end = start + np.searchsorted(xs[start:stop], high[r] + widen, side="right")
            for g in range(begin, end):  # the exact test: no valid other strictly nearer
                qx, qy = points[g, 0], points[g, 1]
                dx, dy = qx - px, qy - py
                mine = dx * dx + dy * dy
                if mine > radius_sq:
                    continue
                inside = True
                if not inner_low[r] <= dx <= inner_high[r]:  # near the cell's edge: the exact test
                    reach_sq = 4.0 * mine * PRUNE_RELATIVE + PRUNE_ABSOLUTE_M2
                    for k in range(known):
                        if floor_sq[k] > reach_sq:
                            break
                        if gap_sq[k] > reach_sq:
                            continue
                        ex, ey = qx - near_x[k], qy - near_y[k]
                        if ex * ex + ey * ey < mine:
                            inside = False
                            break
                if inside:
                    mass += weights[g]
                    moment_x += weights[g] * qx
                    moment_y += weights[g] * qy
        out[b, i, 0] = mass
        out[b, i, 1] = moment_x
        out[b, i, 2] = moment_y


_cell_sums_serial, _cell_sums_parallel = kernels.jit_serial_and_parallel(_cell_sums)

PARALLEL_MIN_CELL_POINTS = int(os.environ.get("SWARM_PARALLEL_MIN_CELL_POINTS", 1_000_000))
"""Robots' cells times quadrature points from which :func:`cell_sums` runs on numba's threads
(``SWARM_PARALLEL_MIN_CELL_POINTS`` overrides it). A cell costs about as much as thousands of robots of
the kinematic kernels (``PARALLEL_MIN_ROBOTS``), so threads pay off far sooner: on two idle cores, two
threads make a sweep chunk's cells 1.9-2.1x faster from N = 12 on (``bench/results/coverage_cells.md``).
On busy cores they cost: run several sweeps at once with ``NUMBA_NUM_THREADS=1``. Threads never change
a bit (each cell is summed by one thread, in the serial order)."""


def point_rows(points: np.ndarray) -> np.ndarray:
    """``(R + 1,)`` where each row of ``points (G, 2)`` starts: a row is a run of points of one y with x
    increasing (the quadrature's grid lines; any other order only makes more, shorter rows)."""
    same_row = (points[1:, 1] == points[:-1, 1]) & (points[1:, 0] > points[:-1, 0])
    return np.concatenate([[0], np.flatnonzero(~same_row) + 1, [len(points)]]).astype(np.int64)


def cell_sums(
    own: np.ndarray,
    others: np.ndarray,
    valid: np.ndarray,
    points: np.ndarray,
    weights: np.ndarray,
    radius_sq: float,
    out: np.ndarray,
) -> None:
    """``out (B, N, 3)``: mass and first moments ``(M, M x, M y)`` of robot i's cell, the quadrature
    points at most ``sqrt(radius_sq)`` from ``own (B, N, 2)`` and no farther from it than from any
    ``others[b, i, k]`` with ``valid[b, i, k]`` (``(B, N, K, 2)``, ``(B, N, K)``), summed in the points'
    order.

    A point is the cell's when no other is nearer; which points and others are compared is narrowed
    exactly (the margins ``ROW_SLACK``, ``INNER_SLACK``, ``PRUNE_*``): per grid row
    (:func:`point_rows`), the window where the row meets the intersection of the robot's half-planes;
    the points well inside it are the cell's untested, and the others, near its ends, are tested against
    the others within twice their distance to the robot. Compiled, on threads from
    ``PARALLEL_MIN_CELL_POINTS``."""
    if len(points) == 0:
        out[...] = 0.0
        return
    work = own.shape[0] * own.shape[1] * points.shape[0]
    kernel = _cell_sums_parallel if work >= PARALLEL_MIN_CELL_POINTS else _cell_sums_serial
    xs = np.ascontiguousarray(points[:, 0])
    row_start = point_rows(points)
    row_y = points[row_start[:-1], 1]
    rows_ascending = bool(np.all(row_y[1:] > row_y[:-1]))
    kernel(own, others, valid, points, xs, row_start, rows_ascending, weights, radius_sq, out)


@numba.njit(cache=True)
def _merge_tables(
    inbox: np.ndarray, index: np.ndarray, positions: np.ndarray, fields: int, memory: np.ndarray
) -> None:
    """``memory (B, N, N, fields)``: :meth:`LloydFlood.merge` from ``inbox (B, >= N, N fields)``, the
    heard senders ``index (B, N, S)`` (-1: none) and ``positions (B, N, 2)``.

    Per robot, first the age of every entry and where it comes from: its own table aged by one (itself
    at age 1), then each heard sender in slot order, taken where its age plus one is less or the entry
    unknown; then the fields are copied from there. The ages' pass is branch-free over entries, which
    on a complete graph of 100 (99 senders a robot) is most of a sweep's time."""
    batch, count, slots = index.shape[0], index.shape[1], index.shape[2]
    ages = np.empty((inbox.shape[1], count))  # every sender's ages, contiguous
    best = np.empty(count)
    source = np.empty(count, np.int64)
    for b in range(batch):
        for sender in range(inbox.shape[1]):
            for e in range(count):
                ages[sender, e] = inbox[b, sender, e * fields]
        for i in range(count):
            for e in range(count):
                age = ages[i, e]
                best[e] = age + 1.0 if age > 0.0 else 0.0
                source[e] = i
            best[i] = 1.0
            for slot in range(slots):
                sender = index[b, i, slot]
                if sender < 0:
                    continue
                for e in range(count):
                    theirs = ages[sender, e]
                    age = theirs + 1.0
                    # taken where known, and younger or the entry unknown (`not <=`: NaN as the plain loop)
                    take = not theirs <= 0.0 and (best[e] == 0.0 or age < best[e])
                    best[e] = age if take else best[e]
                    source[e] = sender if take else source[e]
            for e in range(count):
                memory[b, i, e, 0] = best[e]
                for f in range(1, fields):
                    memory[b, i, e, f] = inbox[b, source[e], e * fields + f]
            memory[b, i, i, 1] = positions[b, i, 0]
            memory[b, i, i, 2] = positions[b, i, 1]


@numba.njit(cache=True)
def _predicted_positions(table: np.ndarray, step_m: float, horizon_ticks: float, out: np.ndarray) -> None:
    """``out (B, N, N, 2)``: :func:`swarm.sim.coverage_onboard.predicted_positions` of ``table (B, N, N,
    5)``, the same operations in the same order (its twin, bit for bit)."""
    for b in range(table.shape[0]):
        for i in range(table.shape[1]):
            for e in range(table.shape[2]):
                ticks_old = min(max(table[b, i, e, 0] - 1.0, 0.0), horizon_ticks)
                toward_x = table[b, i, e, 3] - table[b, i, e, 1]
                toward_y = table[b, i, e, 4] - table[b, i, e, 2]
                gap_m = math.sqrt(toward_x * toward_x + toward_y * toward_y)
                reach_m = min(gap_m, ticks_old * step_m)
                scale = reach_m / gap_m if gap_m > 0.0 else 0.0
                out[b, i, e, 0] = table[b, i, e, 1] + toward_x * scale
                out[b, i, e, 1] = table[b, i, e, 2] + toward_y * scale


def centroid_targets(sums: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    """``(..., 2)`` each cell's centroid ``(M x, M y) / M``, ``fallback`` where the cell has no mass."""
    mass = sums[..., 0:1]
    return np.where(mass > 0.0, sums[..., 1:] / np.where(mass > 0.0, mass, 1.0), fallback)


class _Coverage(CoverageDrive):
    centralized = False

    def sums(
        self, own: np.ndarray, others: np.ndarray, valid: np.ndarray, radius_m: float | None
    ) -> np.ndarray:
        """``(B, N, 3)``: every cell's mass and first moments (:func:`cell_sums`)."""
        sums = np.empty((*own.shape[:2], 3))
        radius_sq = math.inf if radius_m is None else float(radius_m) ** 2
        cell_sums(
            np.ascontiguousarray(own),
            np.ascontiguousarray(others),
            np.ascontiguousarray(valid),
            self.points,
            self.weights,
            radius_sq,
            sums,
        )
        return sums

    def cells(
        self, own: np.ndarray, others: np.ndarray, valid: np.ndarray, radius_m: float | None
    ) -> np.ndarray:
        """``(B, N, 2)``: every cell's centroid (the density's where a cell holds no mass)."""
        return centroid_targets(self.sums(own, others, valid, radius_m), self.fallback)


class LloydExpert(_Coverage):
    """``lloyd``: the centralized coverage expert (module docstring)."""

    message_dim = 0
    centralized = True

    def velocity(self, poses: np.ndarray) -> np.ndarray:
        """``(B, N, 2)``: every axle at full speed toward its true Voronoi cell's centroid."""
        batch, count = poses.shape[:2]
        others = np.broadcast_to(poses[:, None, :, :2], (batch, count, count, 2))
        valid = np.broadcast_to(~np.eye(count, dtype=bool), (batch, count, count))
        return self.drive(poses, self.cells(poses[..., :2], others, valid, None))

    def act(
        self, poses: np.ndarray, points: np.ndarray, inbox: np.ndarray, heard: Links
    ) -> tuple[np.ndarray, np.ndarray]:
        return self.velocity(poses), inbox


class LloydLocal(_Coverage):
    """``lloyd_local``: Lloyd over the heard neighbours (module docstring)."""

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

    def act(
        self, poses: np.ndarray, points: np.ndarray, inbox: np.ndarray, heard: Links
    ) -> tuple[np.ndarray, np.ndarray]:
        batch = poses.shape[0]
        valid = heard.index >= 0  # (B, N, S)
        envs = np.arange(batch)[:, None, None]
        others = inbox[envs, np.where(valid, heard.index, 0), :2]  # (B, N, S, 2)
        targets = self.cells(poses[..., :2], others, valid, self.cell_radius_m)
        return self.drive(poses, targets), np.ascontiguousarray(poses[..., :2])


class LloydFlood(_Coverage):
    """``lloyd_flood``: Lloyd over every robot's freshest flooded position (module docstring)."""

    def __init__(
        self,
        robot: RobotParams,
        control_period_s: float,
        section: CoverageSection,
        robot_count: int,
        reverse: bool = True,
        step_fraction: float = 1.0,
    ):
        super().__init__(robot, control_period_s, section, reverse, step_fraction)
        self.count = int(robot_count)
        self.message_dim = self.fields * self.count
        self._targets = np.zeros((0, self.count, 2))
        self._mass = np.zeros((0, self.count))

    fields = 3
    """Floats an entry of the table: ``age + 1, x, y``."""

    def merge(self, poses: np.ndarray, inbox: np.ndarray, heard: Links) -> np.ndarray:
        """``(B, N, N, fields)`` robot i's table of tick k: its own of k-1 (``inbox[:, i]``) one hop
        older, its own position fresh, and each heard neighbour's entries one hop older where strictly
        fresher (slot order; the robot's own table first)."""
        batch, count, fields = poses.shape[0], poses.shape[1], self.fields
        memory = np.empty((batch, count, count, fields))
        index = np.ascontiguousarray(heard.index, dtype=np.int64)
        _merge_tables(
            np.ascontiguousarray(inbox), index, np.ascontiguousarray(poses[..., :2]), fields, memory
        )
        return memory

    def update_targets(self, poses: np.ndarray, inbox: np.ndarray, heard: Links) -> np.ndarray:
        """Merge and take every robot's cell among those it knows: sets ``_targets (B, N, 2)`` and
        ``_mass (B, N)`` (each cell's) and returns the tables ``(B, N, N, 3)``."""
        count = poses.shape[1]
        memory = self.merge(poses, inbox, heard)
        valid = memory[..., 0] > 0.0
        valid[:, np.arange(count), np.arange(count)] = False  # itself is `own`
        sums = self.sums(poses[..., :2], self.known_positions(memory), valid, None)
        self._targets = centroid_targets(sums, self.fallback)
        self._mass = sums[..., 0]
        return memory

    def known_positions(self, memory: np.ndarray) -> np.ndarray:
        """``(B, N, N, 2)`` where each robot places the robots in its table: where they were sent from."""
        return memory[..., 1:3]

    def act(
        self, poses: np.ndarray, points: np.ndarray, inbox: np.ndarray, heard: Links
    ) -> tuple[np.ndarray, np.ndarray]:
        batch, count = poses.shape[:2]
        memory = self.update_targets(poses, inbox, heard)
        return self.drive(poses, self._targets), memory.reshape(batch, count, self.fields * count)


class LloydPredict(LloydFlood):
    """``lloyd_predict``: ``lloyd_flood`` with each robot's target flooded beside its position, and the
    known robots placed where their targets take them in their entries' age (module docstring)."""

    fields = 5
    """Floats an entry of the table: ``age + 1, x, y, target x, target y``."""

    def __init__(
        self,
        robot: RobotParams,
        control_period_s: float,
        section: CoverageSection,
        robot_count: int,
        reverse: bool = True,
        horizon_ticks: float = HORIZON_TICKS,
        step_fraction: float = 1.0,
    ):
        super().__init__(robot, control_period_s, section, robot_count, reverse, step_fraction)
        self.horizon_ticks = float(horizon_ticks)  # math.inf: not capped

    def known_positions(self, memory: np.ndarray) -> np.ndarray:
        """``(B, N, N, 2)``: every entry where its target takes it in the entry's age, at most
        ``horizon_ticks`` of it (:func:`swarm.sim.coverage_onboard.predicted_positions`)."""
        positions = np.empty((*memory.shape[:3], 2))
        step_m = self.robot.v_max_mps * self.control_period_s
        _predicted_positions(np.ascontiguousarray(memory), step_m, self.horizon_ticks, positions)
        return positions

    def update_targets(self, poses: np.ndarray, inbox: np.ndarray, heard: Links) -> np.ndarray:
        """``lloyd_flood``'s, among the predicted positions; each robot's own entry carries the target it
        computes, sent beside the position it was computed at."""
        memory = super().update_targets(poses, inbox, heard)
        own = np.arange(poses.shape[1])
        memory[:, own, own, 3:5] = self._targets
        return memory


class LloydGnn(LloydPredict):
    """``lloyd_gnn``, batched: ``lloyd_predict``'s flood and cells (over the horizon its policy file
    names), a learned steering (``swarm.sim.coverage_gnn``)."""

    def __init__(
        self,
        robot: RobotParams,
        control_period_s: float,
        section: CoverageSection,
        robot_count: int,
        weights: CoverageGnnWeights,
        reverse: bool = True,
    ):
        super().__init__(robot, control_period_s, section, robot_count, reverse, weights.horizon_ticks)
        self.policy = weights  # (self.weights are the quadrature's)
        self.scale_m = region_scale_m(self.points)
        self.last_features: np.ndarray | None = None  # (B, N, 8) of the last tick (training reads it)

    def features(self, poses: np.ndarray, memory: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The readout's features ``(B, N, F)`` and gate ``(B, N)`` after :meth:`update_targets`
        (``swarm.sim.coverage_gnn.coverage_features``)."""
        batch, count = poses.shape[:2]
        own = np.broadcast_to(np.eye(count, dtype=bool), (batch, count, count))
        return coverage_features(
            poses,
            self._targets,
            memory,
            own,
            self._mass,
            self.fallback,
            self.scale_m,
            self.robot,
            self.control_period_s,
        )

    def act(
        self, poses: np.ndarray, points: np.ndarray, inbox: np.ndarray, heard: Links
    ) -> tuple[np.ndarray, np.ndarray]:
        batch, count = poses.shape[:2]
        memory = self.update_targets(poses, inbox, heard)
        features, gate = self.features(poses, memory)
        self.last_features = features
        u_local = local_command(self.policy, features, gate, self.robot.v_max_mps)
        return to_world(poses, u_local), memory.reshape(batch, count, self.fields * count)
