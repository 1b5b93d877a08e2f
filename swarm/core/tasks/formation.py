"""Formation with assignment (``task: formation``): N robots take N goal slots, one each.

The slots are public (every robot knows them): a circle, a grid, a line or an explicit list
(:class:`SlotsSpec`). Success: every slot holds exactly one robot's axle within ``tolerance_m``, held
``hold_s`` (2 s) to the end of the run. With ``tolerance_m`` under half the smallest slot spacing (the
schema requires it) a robot is within tolerance of at most one slot, so success at time t is
exactly ``bottleneck(x(t), slots) <= tolerance_m``: the metric is the bottleneck assignment distance
of the current axle positions (:func:`bottleneck_distance`).

Assignment (:func:`capt_assignment`): the bottleneck-optimal assignment (least largest distance),
ties broken by the least sum of squared distances, as in CAPT (Turpin, Michael and Kumar 2014,
whose sum-of-squares assignment makes synchronized straight lines collision-free).

Lower bound (:func:`lower_bound_s`): ``max(0, B* - tolerance) / v_max``, ``B*`` the bottleneck
distance of the initial axle positions. Proof: at a time t of success the slots within tolerance
define a bijection pi with ``|x_i(t) - s_pi(i)| <= tol``; axles move no faster than ``v_max``
(``v = (vL + vR) / 2``), so ``|x_i(0) - s_pi(i)| <= tol + v_max t`` for every i, and
``B* <= max_i |x_i(0) - s_pi(i)| <= tol + v_max t``. It is exact for holonomic points starting on
the lines to their slots: the bottleneck robot drives straight at ``v_max``.

Translation-free variant (``translation_free: true``): the slots may be placed anywhere, shifted by one
translation t. Success: one placement ``s + t`` holds exactly one axle per slot within tolerance, from
some time to the end, held ``hold_s``; t is :func:`best_translation` of the final frame (a placement that
moves while it holds is not the rule: a formation sits still). The least distance is
``B_tf(x) = min_t bottleneck(x, s + t)``; for a fixed assignment pi the best t is the centre of the
minimum enclosing circle of the differences ``x_i - s_pi(i)`` and ``B_tf`` its radius, minimized over
pi. :func:`best_translation` alternates the two steps (bottleneck assignment, enclosing circle) from the
mean difference: a translation that achieves its value, so an upper bound of ``B_tf`` (and the placement
the controllers drive to). The bound: ``max(0, LB - tolerance) / v_max`` with ``LB <= B_tf(x(0))``
(:func:`translation_free_lower_bound`), by the same argument with t fixed at the success time's witness:
``B_tf(x(0)) <= bottleneck(x(0), s + t) <= tol + v_max T``. ``LB`` is rigorous but not exact:
``g(t) = max(max_i min_j |x_i - s_j - t|, max_j min_i |x_i - s_j - t|)`` is at most
``bottleneck(x, s + t)`` (every robot is matched to some slot and every slot to some robot) and, like it,
1-Lipschitz in t; any t with ``bottleneck <= U`` (U the upper bound) lies within U of some ``x_0 - s_j``,
so the least g on a grid of spacing h over those discs, less ``h / sqrt 2``, bounds ``B_tf`` from below.
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
from pydantic import Field, model_validator

from swarm.core.initial_poses import box_for, random_poses
from swarm.core.tasks.registry import StrictSection, SweepCells, Task, register, settle_time


class CircleSlots(StrictSection):
    """N slots evenly on a circle: slot k at ``centre + r (cos(phase + 2 pi k / N), sin(...))``."""

    radius_m: float = Field(gt=0)
    centre: tuple[float, float] = (0.0, 0.0)
    phase_rad: float = 0.0


class GridSlots(StrictSection):
    """Row-major grid of ``columns`` per row (the last row may be short), centred on ``centre``."""

    spacing_m: float = Field(gt=0)
    columns: int | None = Field(None, ge=1, description="None: ceil(sqrt(N))")
    centre: tuple[float, float] = (0.0, 0.0)


class LineSlots(StrictSection):
    """N slots on a segment, ``spacing_m`` apart, centred on ``centre``, at ``angle_rad`` to the x axis."""

    spacing_m: float = Field(gt=0)
    centre: tuple[float, float] = (0.0, 0.0)
    angle_rad: float = 0.0


class SlotsSpec(StrictSection):
    """Exactly one of ``circle``, ``grid``, ``line`` and ``points`` (an explicit list of N [x, y])."""

    circle: CircleSlots | None = None
    grid: GridSlots | None = None
    line: LineSlots | None = None
    points: list[tuple[float, float]] | None = None

    @model_validator(mode="after")
    def _exactly_one(self) -> SlotsSpec:
        given = [name for name in ("circle", "grid", "line", "points") if getattr(self, name) is not None]
        if len(given) != 1:
            raise ValueError(
                f"give exactly one of 'circle', 'grid', 'line' and 'points', got {given or 'none'}"
            )
        return self

    def positions(self, count: int) -> np.ndarray:
        """``(count, 2)`` slot positions; ValueError when an explicit list has another length."""
        if self.points is not None:
            if len(self.points) != count:
                raise ValueError(f"points has {len(self.points)} slots but robots.count is {count}")
            return np.array(self.points, dtype=np.float64)
        if self.circle is not None:
            spec = self.circle
            angle = spec.phase_rad + 2.0 * np.pi * np.arange(count) / count
            return np.stack(
                [
                    spec.centre[0] + spec.radius_m * np.cos(angle),
                    spec.centre[1] + spec.radius_m * np.sin(angle),
                ],
                axis=-1,
            )
        if self.grid is not None:
            grid = self.grid
            columns = grid.columns or math.ceil(math.sqrt(count))
            rows = math.ceil(count / columns)
            k = np.arange(count)
            x = (k % columns - (columns - 1) / 2.0) * grid.spacing_m + grid.centre[0]
            y = ((rows - 1) / 2.0 - k // columns) * grid.spacing_m + grid.centre[1]
            return np.stack([x, y], axis=-1)
        line = self.line
        assert line is not None  # exactly one is given
        along = (np.arange(count) - (count - 1) / 2.0) * line.spacing_m
        return np.stack(
            [
                line.centre[0] + along * math.cos(line.angle_rad),
                line.centre[1] + along * math.sin(line.angle_rad),
            ],
            axis=-1,
        )


class FormationSection(StrictSection):
    """``task: {kind: formation, slots: {...}, tolerance_m: 0.1, hold_s: 2.0}``."""

    kind: Literal["formation"] = "formation"
    slots: SlotsSpec
    translation_free: bool = Field(False, description="the slots may be shifted anywhere (one translation)")
    tolerance_m: float = Field(0.1, gt=0, description="a slot holds a robot whose axle is this close")
    hold_s: float = Field(2.0, ge=0, description="success must hold this long, to the end of the run")

    def slot_positions(self, count: int) -> np.ndarray:
        return self.slots.positions(count)


def smallest_spacing_m(slots: np.ndarray) -> float:
    """The smallest distance between two slots (inf for one slot)."""
    if len(slots) < 2:
        return math.inf
    gaps = np.sqrt(((slots[:, None] - slots[None]) ** 2).sum(-1))
    return float(gaps[~np.eye(len(slots), dtype=bool)].min())


def distances(positions: np.ndarray, slots: np.ndarray) -> np.ndarray:
    """``(K, M)`` Euclidean distances from K positions to M slots."""
    delta = np.asarray(positions, dtype=np.float64)[:, None, :] - np.asarray(slots, dtype=np.float64)[None]
    return np.sqrt((delta * delta).sum(-1))


def _feasible(allowed: np.ndarray) -> bool:
    """Does the 0/1 matrix ``allowed (K, M)``, K <= M, hold a matching covering every row?"""
    from scipy.optimize import linear_sum_assignment

    cost = np.where(allowed, 0.0, 1.0)
    rows, cols = linear_sum_assignment(cost)
    return bool(cost[rows, cols].sum() == 0.0)


def capt_assignment(positions: np.ndarray, slots: np.ndarray, at_least_m: float | None = None) -> np.ndarray:
    """``(K,)`` slot index of each of K <= M positions: least bottleneck (largest distance), ties by
    least sum of squared distances (CAPT). Bottleneck by bisection over the sorted distinct distances
    (each a perfect-matching test, ``scipy.optimize.linear_sum_assignment`` on 0/1 costs), then the
    least sum of squares among assignments using only distances at or under it.

    ``at_least_m``: a known lower bound on the bottleneck (that of a subset of ``positions`` to the same
    slots: restricting an assignment to a subset never raises its largest distance). The search then
    starts there and gallops upward, which is what makes ``capt_flood``'s re-assignment, one more robot
    known at a time, cheap; the result is the same with or without it."""
    return assignment_of_distances(distances(positions, slots), at_least_m)


def assignment_of_distances(dist: np.ndarray, at_least_m: float | None = None) -> np.ndarray:
    """:func:`capt_assignment` of the ``(K, M)`` position-to-slot distances ``dist`` (rows of a matrix
    computed once, as ``capt_flood`` takes those of the robots a robot knows)."""
    from scipy.optimize import linear_sum_assignment

    if dist.shape[0] > dist.shape[1]:
        raise ValueError(f"more robots ({dist.shape[0]}) than slots ({dist.shape[1]})")
    if dist.shape[0] == 0:
        return np.zeros(0, dtype=np.int64)
    levels = np.unique(dist)
    low, high = 0, len(levels) - 1  # levels[high] is always feasible
    if at_least_m is not None:
        low = min(int(np.searchsorted(levels, at_least_m)), high)  # levels[:low] are all infeasible
        probe, step = low, 1
        while probe < high and not _feasible(dist <= levels[probe]):
            low, probe, step = probe + 1, min(probe + step, high), 2 * step
        high = probe
    while low < high:
        middle = (low + high) // 2
        if _feasible(dist <= levels[middle]):
            high = middle
        else:
            low = middle + 1
    bottleneck = levels[low]
    squared = dist * dist
    cost = np.where(dist <= bottleneck, squared, squared.max() * dist.size + 1.0)
    rows, cols = linear_sum_assignment(cost)
    assignment = np.empty(dist.shape[0], dtype=np.int64)
    assignment[rows] = cols
    return assignment


def bottleneck_distance(positions: np.ndarray, slots: np.ndarray) -> float:
    """``min over bijections pi of max_i |x_i - s_pi(i)|`` (m)."""
    assignment = capt_assignment(positions, slots)
    return float(distances(positions, slots)[np.arange(len(assignment)), assignment].max(initial=0.0))


def best_translation(positions: np.ndarray, slots: np.ndarray, rounds: int = 32) -> tuple[np.ndarray, float]:
    """``(t (2,), value)``: a translation of the slots and the bottleneck distance it achieves, from the
    mean difference by alternating the CAPT assignment and the enclosing circle of the differences
    (module docstring); stops when a round no longer lowers the value. K <= M positions."""
    from swarm.core.metrics import minimum_enclosing_circle

    positions = np.asarray(positions, dtype=np.float64)
    slots = np.asarray(slots, dtype=np.float64)
    shift = positions.mean(axis=0) - slots.mean(axis=0)
    value = bottleneck_distance(positions, slots + shift)
    for _ in range(rounds):
        assignment = capt_assignment(positions, slots + shift)
        centre, radius = minimum_enclosing_circle(positions - slots[assignment])
        if not radius < value - 1e-12:
            break
        shift, value = np.asarray(centre, dtype=np.float64), bottleneck_distance(positions, slots + centre)
    return shift, float(value)


def placed_slots(section: FormationSection, positions: np.ndarray, slots: np.ndarray) -> np.ndarray:
    """The slots the robots at ``positions`` (the starts, or those a robot knows) drive to: ``slots``, or
    for a translation-free formation ``slots + t`` with t from :func:`best_translation`."""
    if not section.translation_free:
        return slots
    return slots + best_translation(positions, slots)[0]


def translation_free_lower_bound(positions: np.ndarray, slots: np.ndarray, cells: int = 24) -> float:
    """A rigorous lower bound of ``min_t bottleneck(x, s + t)`` (module docstring): the least g over a grid
    of ``cells`` per disc diameter, less half the grid's diagonal."""
    positions = np.asarray(positions, dtype=np.float64)
    slots = np.asarray(slots, dtype=np.float64)
    _, upper = best_translation(positions, slots)
    if upper == 0.0:
        return 0.0
    spacing = 2.0 * upper / cells
    offsets = (np.arange(cells + 1) - cells / 2) * spacing
    disc = np.stack(np.meshgrid(offsets, offsets), -1).reshape(-1, 2)
    disc = disc[(disc * disc).sum(-1) <= (upper + spacing) ** 2]
    least = math.inf
    for centre in positions[0] - slots:  # t within `upper` of x_0 - s_j for some j
        shifts = centre + disc  # (P, 2)
        delta = positions[None, :, None, :] - slots[None, None, :, :] - shifts[:, None, None, :]
        gaps = np.sqrt((delta * delta).sum(-1))  # (P, K robots, M slots)
        g = np.maximum(gaps.min(axis=2).max(axis=1), gaps.min(axis=1).max(axis=1))
        least = min(least, float(g.min()))
    return max(0.0, least - spacing / math.sqrt(2.0))


def sync_ratio(starts: np.ndarray, assigned: np.ndarray, own: int) -> float:
    """``d_own / max_j d_j`` of the start-to-slot distances ``d`` of an assignment (0 when all are 0):
    the expert's time-synchronized speed over ``v_max`` (constant along straight lines)."""
    distance = np.sqrt(((assigned - starts) ** 2).sum(-1))
    largest = distance.max()
    return float(distance[own] / largest) if largest > 0.0 else 0.0


def lower_bound_s(
    initial_positions: np.ndarray,
    section: FormationSection,
    v_max_mps: float,
    threshold_m: float | None = None,
) -> float:
    """``max(0, B* - tolerance) / v_max`` (module docstring: the proof); translation free, ``B*`` replaced
    by a rigorous lower bound of ``min_t bottleneck`` (:func:`translation_free_lower_bound`)."""
    slots = section.slot_positions(len(initial_positions))
    if section.translation_free:
        least = translation_free_lower_bound(initial_positions, slots)
    else:
        least = bottleneck_distance(initial_positions, slots)
    return max(0.0, least - section.tolerance_m) / v_max_mps


def occupied(positions: np.ndarray, slots: np.ndarray, tolerance_m: float) -> np.ndarray:
    """``(...)`` bool: every slot holds exactly one of the positions ``(..., N, 2)`` within tolerance
    (N robots, N slots; assumes ``tolerance_m`` under half the slot spacing, so that it equals
    ``bottleneck <= tolerance``). O(N^2) per configuration, batched."""
    positions = np.asarray(positions, dtype=np.float64)
    delta = positions[..., :, None, :] - slots
    dist = np.sqrt((delta * delta).sum(-1))  # (..., N robots, N slots)
    within = dist <= tolerance_m
    return np.all(within.sum(axis=-2) == 1, axis=-1) & np.all(within.sum(axis=-1) == 1, axis=-1)


def conflicts(positions: np.ndarray, slots: np.ndarray) -> int:
    """Robots whose nearest slot is also the nearest slot of a robot before them (0: every robot
    nearest to its own slot)."""
    nearest = distances(positions, slots).argmin(axis=1)
    return int(len(nearest) - len(np.unique(nearest)))


def judged_slots(positions: np.ndarray, section: FormationSection) -> np.ndarray:
    """The slots a run ``(T, N, 2)`` is judged against: the section's, or translation free, the section's
    shifted by the best translation of the final frame (one placement, held: the success rule)."""
    positions = np.asarray(positions, dtype=np.float64)
    slots = section.slot_positions(positions.shape[1])
    return placed_slots(section, positions[-1], slots)


def bottleneck_series(positions: np.ndarray, section: FormationSection) -> np.ndarray:
    """``(T,)`` the bottleneck distance of each frame of ``positions (T, N, 2)`` to the judged slots (m)."""
    slots = judged_slots(positions, section)
    return np.array([bottleneck_distance(frame, slots) for frame in positions])


def outcome(times_s: np.ndarray, positions: np.ndarray, section: FormationSection, v_max_mps: float) -> dict:
    """The task's results from the axle positions ``(T, N, 2)``: success (``converged``), its time,
    the bound and their ratio, the metric (bottleneck distance) at the start and the end, the
    expert's assignment of the start and the conflicts at the end."""
    positions = np.asarray(positions, dtype=np.float64)
    count = positions.shape[1]
    slots = judged_slots(positions, section)
    ok = occupied(positions, slots, section.tolerance_m)
    time_s = settle_time(times_s, ok, section.hold_s)
    bound = lower_bound_s(positions[0], section, v_max_mps)
    return {
        "metric": "bottleneck",
        "threshold": section.tolerance_m,
        "converged": time_s is not None,
        "convergence_time_s": time_s,
        "hold_s": section.hold_s,
        "initial_metric": (
            best_translation(positions[0], slots)[1]
            if section.translation_free
            else bottleneck_distance(positions[0], slots)
        ),
        "final_metric": bottleneck_distance(positions[-1], slots),
        "lower_bound_s": bound,
        "ratio_to_lower_bound": time_s / bound if time_s is not None and bound > 0 else None,
        "assignment": capt_assignment(positions[0], slots).tolist(),
        "conflicts": conflicts(positions[-1], slots),
        "slots": slots.tolist(),
        "translation_m": (slots - section.slot_positions(count))[0].tolist(),
    }


def sweep_section(count: int) -> FormationSection:
    """A sweep cell's slots: a circle with neighbours 0.5 m apart (radius at least 1 m), tolerance 0.1 m,
    held 2 s (``bench/formation.py``'s cells)."""
    radius_m = max(1.0, count * 0.5 / (2.0 * math.pi))
    return FormationSection(
        slots=SlotsSpec(circle=CircleSlots(radius_m=radius_m)), tolerance_m=0.1, hold_s=2.0
    )


def sweep_starts(rng: np.random.Generator, number: int, count: int) -> np.ndarray:
    """Uniform starts in the rendezvous sweep's box (``box_for``), 0.4 m apart."""
    box = box_for(count)
    return random_poses(rng, number, count, box, box)


def sweep_held(positions: np.ndarray, section: FormationSection) -> np.ndarray:
    """``(B,)``: every slot of the section (fixed slots) holds one axle within tolerance now."""
    return occupied(positions, section.slot_positions(positions.shape[1]), section.tolerance_m)


FORMATION = register(
    Task(
        name="formation",
        summary="take the N goal slots, one robot each (bottleneck assignment)",
        section=FormationSection,
        knows="its own pose, the public slot list and what its heard neighbours sent last tick",
        experts=("capt",),
        baselines=("capt_flood",),
        learned=("capt_gnn",),
        metric="bottleneck: least largest axle-to-slot distance over assignments",
        success="every slot holds exactly one axle within tolerance_m, held hold_s to the end",
        bound="lower_bound",
        bound_s=lower_bound_s,
        reward="swarm.rl.formation_v0:FormationParallelEnv.step",
        plot="swarm.scenarios.task_report:formation_pictures",
        outcome=outcome,
        series=bottleneck_series,
        sweep=SweepCells(
            section=sweep_section,
            starts=sweep_starts,
            duration_s=120.0,
            columns=("ratio_to_lower_bound", "convergence_time_s", "final_metric", "conflicts"),
            held=sweep_held,
        ),
    )
)
