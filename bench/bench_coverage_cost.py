"""The cost of the coverage metric (``swarm.core.tasks.coverage.locational_cost``) over a run's frames.

Every coverage start of a sweep ends with ``H`` at each sampled frame (every 5 ticks: 241 frames of a
60-s run), each frame every quadrature point against every robot. At N = 100 on 2 cores this was about
a third of a sweep cell's time. ``locational_cost`` takes each block of points' minimum over the few
robots that can be nearest to it (since 2026-12-07; before, over every robot into preallocated
buffers, 1.75x as fast as the reference); the reference is the plain expression, every robot against
every point with a temporary array per operation (the form every coverage cell committed before
2026-12-07 was computed with). Both run here, in this one
invocation, on the same frames, and their costs are checked equal bit for bit.

Per N in ``--sizes`` (the sweep's square and grid: ``swarm.core.tasks.coverage.sweep_section``),
``--frames`` frames of the sweep's corner deployment moved toward the reference configuration (a run's
frames, from the start to the spread). Best of ``--repeats`` calls; ratios side by side, so a busy
machine changes little.

    python bench/bench_coverage_cost.py [--sizes 12 24 50 100] [--frames 241] [--repeats 3]
        [--out DIR | --update-results] [--quiet]

Writes ``coverage_cost.md`` and ``coverage_cost.json`` (with the load average before and after).
"""

from __future__ import annotations

import argparse
import os

import numpy as np
from _output import add_output_arguments, best_time_s, output_dir, progress, write_kernel_result

from swarm.core.tasks import coverage


def plain_locational_cost(positions: np.ndarray, points: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """H as the expression reads (a temporary per operation), in the same chunks of frames."""
    flat = positions.reshape(-1, *positions.shape[-2:])
    cost = np.empty(len(flat))
    for start in range(0, len(flat), coverage.FRAMES_PER_CHUNK):
        chunk = flat[start : start + coverage.FRAMES_PER_CHUNK]
        nearest = np.full((len(chunk), len(points)), np.inf)
        for robot in range(chunk.shape[1]):
            dx, dy = points[None, :, 0] - chunk[:, robot, 0:1], points[None, :, 1] - chunk[:, robot, 1:2]
            nearest = np.minimum(nearest, dx * dx + dy * dy)
        cost[start : start + len(chunk)] = nearest @ weights
    return cost.reshape(positions.shape[:-2])


def frames(count: int, frame_count: int, rng: np.random.Generator) -> np.ndarray:
    """``(F, N, 2)``: the sweep's corner start moved in a straight line to the reference spread."""
    section = coverage.sweep_section(count)
    start = coverage.sweep_starts(rng, 1, count)[0, :, :2]
    spread = coverage.reference(section, count)[1]
    share = np.linspace(0.0, 1.0, frame_count)[:, None, None]
    return np.ascontiguousarray((1.0 - share) * start + share * spread)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[12, 24, 50, 100], help="swarm sizes N")
    parser.add_argument("--frames", type=int, default=241, help="frames a call (a 60-s start: 241)")
    parser.add_argument("--repeats", type=int, default=3, help="timed calls per measurement (best)")
    parser.add_argument("--seed", type=int, default=0)
    add_output_arguments(parser)
    args = parser.parse_args(argv)
    if min(args.sizes) < 1 or args.frames < 1 or args.repeats < 1:
        parser.error("--sizes, --frames and --repeats must be at least 1")
    out_dir = output_dir(args)
    rng = np.random.default_rng(args.seed)
    load_before = os.getloadavg()
    rows = []
    for count in progress(args.sizes, args, desc="sizes"):
        points, weights = coverage.sweep_section(count).quadrature()
        positions = frames(count, args.frames, rng)
        plain = plain_locational_cost(positions, points, weights)
        pruned = coverage.locational_cost(positions, points, weights)
        plain_s = best_time_s(
            lambda p=positions, q=points, w=weights: plain_locational_cost(p, q, w), args.repeats
        )
        pruned_s = best_time_s(
            lambda p=positions, q=points, w=weights: coverage.locational_cost(p, q, w), args.repeats
        )
        rows.append(
            {
                "robots": count,
                "points": len(points),
                "frames": args.frames,
                "plain_ms": 1e3 * plain_s,
                "locational_cost_ms": 1e3 * pruned_s,
                "speedup": plain_s / pruned_s,
                "same_bits": bool(np.array_equal(plain, pruned)),
            }
        )
    caption = (
        f"Coverage metric over {args.frames} frames (one 60-s start): `locational_cost` (blocks of points,"
        " a few robots each) against the plain expression (a temporary per operation); best of"
        f" {args.repeats} calls, ms per call."
    )
    columns = [
        ("N", "{robots}"),
        ("grid points", "{points}"),
        ("plain", "{plain_ms:.1f}"),
        ("locational_cost", "{locational_cost_ms:.1f}"),
        ("speed-up", "{speedup:.2f}x"),
        ("same bits", "{same_bits}"),
    ]
    return write_kernel_result(out_dir, "coverage_cost", __file__, argv, load_before, rows, caption, columns)


if __name__ == "__main__":
    raise SystemExit(main())
