"""The cost of the flood tables' merge (``swarm.sim.coverage_controllers._merge_tables``) per tick.

Every ``lloyd_flood``, ``lloyd_predict`` and ``lloyd_gnn`` robot merges, each tick, its own table with
the table of every neighbour it heard: per entry, the least age and that entry's fields. On a complete
graph of 100 that is 99 tables of 100 entries a robot a tick, and it was most of a sweep's time there.
``_merge_tables`` takes the ages first, branch-free over the entries, then copies the fields; the
reference is the plain loop it replaced (a branch per entry and sender, the fields copied on every
improvement), compiled the same way. Both run here, in this one invocation, on the same inboxes, and
their tables are checked equal bit for bit.

Per N in ``--sizes`` and graph (``complete``: every other robot heard; ``cycle``: the two neighbours),
``--batch`` environments of ``lloyd_predict``'s tables (5 fields an entry) whose ages are a flood's after
a few ticks (1 to 6 hops, some entries still unknown). Best of ``--repeats`` calls; ratios side by side,
so a busy machine changes little.

    python bench/bench_coverage_merge.py [--sizes 12 50 100] [--batch 50] [--repeats 5]
        [--out DIR | --update-results] [--quiet]

Writes ``coverage_merge.md`` and ``coverage_merge.json`` (with the load average before and after).
"""

from __future__ import annotations

import argparse
import os

import numba
import numpy as np
from _output import add_output_arguments, best_time_s, output_dir, progress, write_kernel_result

from swarm.sim.coverage_controllers import _merge_tables

FIELDS = 5  # lloyd_predict's entry: age + 1, x, y, target x, target y


@numba.njit(cache=True)
def plain_merge(inbox, index, positions, fields, memory):  # pragma: no cover (numba)
    """The merge as first written: a branch per entry and sender, the fields copied on each improvement."""
    batch, count, slots = index.shape[0], index.shape[1], index.shape[2]
    for b in range(batch):
        for i in range(count):
            for e in range(count):
                age = inbox[b, i, e * fields]
                memory[b, i, e, 0] = age + 1.0 if age > 0.0 else 0.0
                for f in range(1, fields):
                    memory[b, i, e, f] = inbox[b, i, e * fields + f]
            memory[b, i, i, 0] = 1.0
            memory[b, i, i, 1] = positions[b, i, 0]
            memory[b, i, i, 2] = positions[b, i, 1]
            for slot in range(slots):
                sender = index[b, i, slot]
                if sender < 0:
                    continue
                for e in range(count):
                    theirs = inbox[b, sender, e * fields]
                    if theirs <= 0.0:
                        continue
                    age = theirs + 1.0
                    if memory[b, i, e, 0] == 0.0 or age < memory[b, i, e, 0]:
                        memory[b, i, e, 0] = age
                        for f in range(1, fields):
                            memory[b, i, e, f] = inbox[b, sender, e * fields + f]


def inputs(count: int, batch: int, graph: str, rng: np.random.Generator):
    """``(inbox, index, positions)``: flood tables with ages of 1-6 hops (a fifth unknown) and the
    senders each robot heard on ``graph``."""
    ages = rng.integers(1, 7, (batch, count, count)).astype(float)
    ages[rng.random(ages.shape) < 0.2] = 0.0
    inbox = rng.normal(size=(batch, count, count * FIELDS))
    inbox[..., ::FIELDS] = ages
    robots = np.arange(count)
    if graph == "complete":
        heard = np.stack([np.delete(robots, i) for i in range(count)])
    else:
        heard = np.stack([(robots - 1) % count, (robots + 1) % count], axis=1)
    index = np.ascontiguousarray(np.broadcast_to(heard, (batch, *heard.shape)))
    return inbox, index, rng.normal(size=(batch, count, 2))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[12, 50, 100], help="swarm sizes N")
    parser.add_argument("--batch", type=int, default=50, help="environments a call (a sweep's chunk)")
    parser.add_argument("--repeats", type=int, default=5, help="timed calls per measurement (best)")
    parser.add_argument("--seed", type=int, default=0)
    add_output_arguments(parser)
    args = parser.parse_args(argv)
    if min(args.sizes) < 3 or args.batch < 1 or args.repeats < 1:
        parser.error("--sizes >= 3, --batch and --repeats >= 1")
    out_dir = output_dir(args)
    rng = np.random.default_rng(args.seed)
    load_before = os.getloadavg()
    rows = []
    for count in progress(args.sizes, args, desc="sizes"):
        for graph in ("complete", "cycle"):
            inbox, index, positions = inputs(count, args.batch, graph, rng)
            plain = np.empty((args.batch, count, count, FIELDS))
            merged = np.empty_like(plain)
            tables = (inbox, index, positions, FIELDS)
            plain_s = best_time_s(lambda t=tables, out=plain: plain_merge(*t, out), args.repeats)
            merged_s = best_time_s(lambda t=tables, out=merged: _merge_tables(*t, out), args.repeats)
            rows.append(
                {
                    "robots": count,
                    "graph": graph,
                    "batch": args.batch,
                    "plain_ms": 1e3 * plain_s,
                    "merge_ms": 1e3 * merged_s,
                    "speedup": plain_s / merged_s,
                    "same_bits": bool(np.array_equal(plain, merged)),
                }
            )
    caption = (
        f"Flood tables' merge per tick: `_merge_tables` against the plain loop, {args.batch} environments,"
        f" {FIELDS} fields an entry; best of {args.repeats} calls, ms per call, one thread."
    )
    columns = [
        ("N", "{robots}"),
        ("graph", "{graph}"),
        ("plain loop", "{plain_ms:.2f}"),
        ("`_merge_tables`", "{merge_ms:.2f}"),
        ("speed-up", "{speedup:.1f}x"),
        ("same bits", "{same_bits}"),
    ]
    return write_kernel_result(out_dir, "coverage_merge", __file__, argv, load_before, rows, caption, columns)


if __name__ == "__main__":
    raise SystemExit(main())
