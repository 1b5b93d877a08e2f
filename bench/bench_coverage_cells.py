"""The cost of the coverage kinds' cells (``swarm.sim.coverage_controllers.cell_sums``) per tick.

Every decentralized coverage kind computes, each tick, each robot's Voronoi cell among the robots it
knows: its mass and first moments on the quadrature grid. ``cell_sums`` tests only the grid rows the
robot's half-planes can reach and, per point, only the others that could be nearer. The reference is
the definition itself, compiled the same way: every point against every known other (the kernel
before that change). Both run here, in this one invocation, on the same inputs, and their sums are
checked equal bit for bit.

Per N in ``--sizes`` (the sweep's square and grid: ``swarm.core.tasks.coverage.sweep_section``),
``--batch`` environments, every robot knowing every other (``lloyd_flood``'s view after the diameter),
in two states: ``start`` (the sweep's deployment from one corner) and ``spread`` (the reference
configuration, each environment's robots moved by up to 5 cm: the state most ticks of a run are near).
Timed: the definition and ``cell_sums`` on one numba thread, and ``cell_sums`` threaded
(``--threads``); best of ``--repeats``; ratios side by side, so a busy machine changes little.

    python bench/bench_coverage_cells.py [--sizes 12 24 50 100] [--batch 50] [--repeats 5] [--threads 2]
        [--out DIR | --update-results] [--quiet]

Writes ``coverage_cells.md`` and ``coverage_cells.json`` (with the load average before and after).
"""

from __future__ import annotations

import argparse
import os

import numba
import numpy as np
from _output import add_output_arguments, best_time_s, output_dir, progress, write_kernel_result

from swarm.core.tasks import coverage
from swarm.sim import coverage_controllers


@numba.njit(cache=True)
def definition_sums(own, others, valid, points, weights, radius_sq, out):  # pragma: no cover (numba)
    """Each point against every valid other: the cell's definition, in the points' order."""
    for b in range(own.shape[0]):
        for i in range(own.shape[1]):
            px, py = own[b, i, 0], own[b, i, 1]
            mass, moment_x, moment_y = 0.0, 0.0, 0.0
            for g in range(points.shape[0]):
                qx, qy = points[g, 0], points[g, 1]
                dx, dy = qx - px, qy - py
                mine = dx * dx + dy * dy
                if mine > radius_sq:
                    continue
                inside = True
                for k in range(others.shape[2]):
                    if valid[b, i, k]:
                        ex, ey = qx - others[b, i, k, 0], qy - others[b, i, k, 1]
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


def states(count: int, batch: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """``(B, N, 2)`` positions: the sweep's corner deployment, and the reference spread jittered."""
    section = coverage.sweep_section(count)
    start = coverage.sweep_starts(rng, batch, count)[..., :2]
    spread = coverage.reference(section, count)[1][None] + rng.uniform(-0.05, 0.05, (batch, count, 2))
    return {"start": np.ascontiguousarray(start), "spread": np.ascontiguousarray(spread)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[12, 24, 50, 100], help="swarm sizes N")
    parser.add_argument("--batch", type=int, default=50, help="environments a call (a sweep's chunk)")
    parser.add_argument("--repeats", type=int, default=5, help="timed calls per measurement (best)")
    parser.add_argument("--threads", type=int, default=2, help="numba threads of the threaded run")
    parser.add_argument("--seed", type=int, default=0)
    add_output_arguments(parser)
    args = parser.parse_args(argv)
    if min(args.sizes) < 2 or args.batch < 1 or args.repeats < 1 or args.threads < 1:
        parser.error("--sizes >= 2, --batch, --repeats and --threads >= 1")
    out_dir = output_dir(args)
    rng = np.random.default_rng(args.seed)
    load_before = os.getloadavg()
    rows = []
    for count in progress(args.sizes, args, desc="sizes"):
        points, weights = coverage.sweep_section(count).quadrature()
        for state, own in states(count, args.batch, rng).items():
            others = np.ascontiguousarray(np.broadcast_to(own[:, None], (args.batch, count, count, 2)))
            valid = np.ascontiguousarray(np.broadcast_to(~np.eye(count, dtype=bool), others.shape[:3]))
            plain, pruned = np.empty((args.batch, count, 3)), np.empty((args.batch, count, 3))

            def run_definition(
                plain=plain, own=own, others=others, valid=valid, points=points, weights=weights
            ):
                definition_sums(own, others, valid, points, weights, np.inf, plain)

            def run_cells(pruned=pruned, own=own, others=others, valid=valid, points=points, weights=weights):
                coverage_controllers.cell_sums(own, others, valid, points, weights, np.inf, pruned)

            numba.set_num_threads(1)
            definition_s = best_time_s(run_definition, args.repeats)
            saved = coverage_controllers.PARALLEL_MIN_CELL_POINTS
            coverage_controllers.PARALLEL_MIN_CELL_POINTS = 1 << 62  # serial
            cells_s = best_time_s(run_cells, args.repeats)
            same_serial = bool(np.array_equal(plain, pruned))
            coverage_controllers.PARALLEL_MIN_CELL_POINTS = 0  # threaded
            numba.set_num_threads(min(args.threads, numba.config.NUMBA_NUM_THREADS))
            threaded_s = best_time_s(run_cells, args.repeats)
            coverage_controllers.PARALLEL_MIN_CELL_POINTS = saved
            rows.append(
                {
                    "robots": count,
                    "state": state,
                    "points": len(points),
                    "batch": args.batch,
                    "definition_ms": 1e3 * definition_s,
                    "cell_sums_ms": 1e3 * cells_s,
                    "cell_sums_threaded_ms": 1e3 * threaded_s,
                    "threads": numba.get_num_threads(),
                    "speedup": definition_s / cells_s,
                    "speedup_threaded": definition_s / threaded_s,
                    "same_bits": same_serial and bool(np.array_equal(plain, pruned)),
                }
            )
    caption = (
        "Coverage cells per tick: `cell_sums` against the definition (every point against every known\n"
        f"other), {args.batch} environments, every robot knowing every other; best of {args.repeats}"
        " calls, ms per call."
    )
    columns = [
        ("N", "{robots}"),
        ("state", "{state}"),
        ("grid points", "{points}"),
        ("definition", "{definition_ms:.1f}"),
        ("cell_sums, 1 thread", "{cell_sums_ms:.1f}"),
        ("threaded", "{cell_sums_threaded_ms:.1f} ({threads})"),
        ("speed-up 1 thread", "{speedup:.1f}x"),
        ("threaded", "{speedup_threaded:.1f}x"),
        ("same bits", "{same_bits}"),
    ]
    return write_kernel_result(out_dir, "coverage_cells", __file__, argv, load_before, rows, caption, columns)


if __name__ == "__main__":
    raise SystemExit(main())
