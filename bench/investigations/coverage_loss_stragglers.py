"""Coverage under packet loss: are the starts that fail the success rule slow, or stuck?

In the committed loss sweeps (``coverage-loss-*``) 0.1-2% of a cell's starts never hold ``H / H_ref
<= 1.05`` for 2 s before the run ends, though the same starts without loss all do
(``coverage-1000-*``). This reruns every chunk of a cell that holds such a start, the same starts and
the same packet losses (chunk ``c`` draws them from seed ``c``, as ``swarm sweep`` does), for
``--duration-s`` instead of the sweep's run, and says of each such start what it does after the
sweep's end:

- **held later**: it holds the rule, at the time given (slow);
- **stopped above**: ``H / H_ref`` is above 1.05 and changed by less than ``--still-ratio`` over the
  last 10 s (its robots' largest move in those 10 s is given beside it): a fixed point of Lloyd's map
  on the grid, the kind the loss-free cells' few failures are, which no longer run moves it out of;
- **moving**: neither, at the end of the longer run.

The rerun first checks it reproduced the sweep: every start of the chunk must give the committed
``H / H_ref`` at the sweep's end time, to 1e-9 (a chunk with a failing start never stopped early, so
every start of it has its committed end there). The same start's final ``H / H_ref`` without
loss is read from ``--no-loss`` (a sweep directory with the loss-free cells) when given. A cell run on
another BLAS kernel than this process's is refused: set ``OPENBLAS_CORETYPE`` as the error says
(``swarm/scenarios/blas.py``).

    OPENBLAS_CORETYPE=SkylakeX python bench/investigations/coverage_loss_stragglers.py \\
        --sweep docs/results/tasks/coverage-loss-1000 --cells cycle-N24-lloyd_gnn-loss0.2 \\
        cycle-N50-lloyd_gnn-loss0.5 cycle-N50-lloyd_predict-loss0.5 --duration-s 180 \\
        --no-loss docs/results/tasks/coverage-1000-24 docs/results/tasks/coverage-1000-50 \\
        --out bench/results/coverage_loss_stragglers.md
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from swarm.core.tasks import coverage
from swarm.core.tasks.registry import settle_time
from swarm.scenarios.blas import blas_kernel, coretype_setting
from swarm.scenarios.task_sweep import TaskSweepConfig, cell_chunks, cell_file_name, cell_starts, run_chunk

CELL_NAME = re.compile(r"^(?P<topology>[a-z_]+)-N(?P<count>\d+)-(?P<controller>\w+?)-loss(?P<loss>[0-9.]+)$")
STILL_WINDOW_S = 10.0
MOVER_M = 0.1
"""A robot whose position in the last ``STILL_WINDOW_S`` strayed more than this from its last one moves."""


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sweep", type=Path, required=True, help="a coverage loss sweep's --out")
    parser.add_argument(
        "--cells", nargs="+", required=True, help="cell names: topology-N<count>-<kind>-loss<p>"
    )
    parser.add_argument("--duration-s", type=float, default=300.0, help="the longer run, s")
    parser.add_argument(
        "--still-ratio", type=float, default=1e-4, help="'stopped': H/H_ref changes less in 10 s"
    )
    parser.add_argument(
        "--no-loss", nargs="*", type=Path, default=[], help="sweep dirs of the loss-free cells"
    )
    parser.add_argument(
        "--starts", nargs="*", type=int, help="of the failing starts, only these (default: all)"
    )
    parser.add_argument(
        "--out", type=Path, required=True, help="markdown file written (and a .png beside it)"
    )
    args = parser.parse_args(argv)

    # -- inputs: the sweep's settings and the cells asked, every name checked before any run
    config_path = args.sweep / "sweep_config.json"
    if not config_path.is_file():
        print(f"error: {config_path}: no such file (--sweep must be a sweep's --out)", file=sys.stderr)
        return 2
    config = TaskSweepConfig.from_mapping(json.loads(config_path.read_text()), str(config_path))
    if config.task != "coverage":
        print(f"error: {config_path}: task: {config.task}, not coverage", file=sys.stderr)
        return 2
    cells = []
    for name in args.cells:
        match = CELL_NAME.match(name)
        path = args.sweep / "cells" / f"{name}.json"
        if match is None or not path.is_file():
            print(f"error: --cells: {name}: no such cell in {args.sweep / 'cells'}", file=sys.stderr)
            return 2
        record = json.loads(path.read_text())
        if record.get("blas", blas_kernel()) != blas_kernel():  # a learned kind's rounding is the kernel's
            print(
                f"error: {path}: ran on {record['blas']}, this process on {blas_kernel()}:"
                f" set {coretype_setting(record['blas'])} (swarm/scenarios/blas.py)",
                file=sys.stderr,
            )
            return 2
        cells.append((name, match, record))

    series: list[tuple[str, int, np.ndarray, np.ndarray]] = []  # (cell, start, times, H / H_ref) to draw
    lines = [
        f"# Coverage under loss: the starts that fail the success rule, run {args.duration_s:g} s",
        "",
        f"Sweep `{args.sweep}`; each chunk with a failing start rerun with the same starts and losses"
        f" (`bench/investigations/coverage_loss_stragglers.py`). 'stopped': H/H_ref changed by less than"
        f" {args.still_ratio:g} in the last {STILL_WINDOW_S:g} s.",
        "",
    ]
    for name, match, record in cells:
        topology, count = match["topology"], int(match["count"])
        controller, loss = match["controller"], float(match["loss"])
        failing = [index for index, start in enumerate(record["starts"]) if not start["converged"]]
        asked = failing if args.starts is None else [index for index in failing if index in args.starts]
        sweep_end_s = config.run_duration_s
        longer = replace(config, duration_s=args.duration_s)
        section = config.cells.section(count)
        tolerance = section.tolerance
        poses, adjacency = cell_starts(config, topology, count)
        no_loss = _no_loss_finals(args.no_loss, topology, count, controller)
        print(f"{name}: {len(failing)} of {len(record['starts'])} starts fail", flush=True)

        # -- rerun each chunk holding a failing start; check it reproduces the sweep; read the failing ones
        rows: list[dict] = []
        for loss_seed, chunk in enumerate(cell_chunks(config, len(poses))):
            places = {index: place for place, index in enumerate(chunk.tolist())}
            in_chunk = [index for index in asked if index in places]
            if not in_chunk:
                continue
            chunk_adjacency = None if adjacency is None else adjacency[chunk]
            times_s, positions = run_chunk(
                longer, section, controller, poses[chunk], chunk_adjacency, loss, loss_seed
            )
            end = int(np.flatnonzero(np.isclose(times_s, sweep_end_s))[0])
            for index, place in places.items():  # no early stop in this chunk: each start ended there
                reran = coverage.ratio_series(positions[end : end + 1, place], section)[0]
                if abs(reran - record["starts"][index]["final_metric"]) > 1e-9:
                    print(f"error: {name} start {index}: the sweep is not reproduced", file=sys.stderr)
                    return 1
            for index in in_chunk:
                row = _straggler(times_s, positions[:, places[index]], section, end, args.still_ratio)
                row["start"] = index
                row["no_loss"] = None if no_loss is None else no_loss[index]
                rows.append(row)
                series.append((name, index, times_s, row.pop("ratio")))
            print(f"  chunk {loss_seed}: {len(in_chunk)} failing start(s) read", flush=True)

        # -- the cell's table
        verdicts = [row["verdict"].split(" ")[0] for row in rows]
        lines += [
            f"## {name}",
            "",
            f"{len(failing)} of {len(record['starts'])} starts fail in the sweep's {sweep_end_s:g} s:"
            f" of the {len(rows)} rerun, {verdicts.count('held')} hold the rule later,"
            f" {verdicts.count('stopped')} stopped above 1.05,"
            f" {verdicts.count('moving')} still moving at {args.duration_s:g} s.",
            "",
            f"| start | H/H_ref at {sweep_end_s:g} s | at {args.duration_s:g} s | first within (s) |"
            " no loss, end | H/H_ref range, last 10 s | largest move, last 10 s (m) | robots moving > 0.1 m |"
            " verdict |",
            "|---|---|---|---|---|---|---|---|---|",
        ]
        for row in rows:
            first = "never" if row["first_within_s"] is None else f"{row['first_within_s']:g}"
            no_loss_text = "" if row["no_loss"] is None else f"{row['no_loss']:.3f}"
            lines.append(
                f"| {row['start']} | {row['at_sweep_end']:.4f} | {row['at_end']:.4f} | {first}"
                f" | {no_loss_text} | {row['drift']:.1e} | {row['still_m']:.2g} | {row['movers']}"
                f" | {row['verdict']} |"
            )
        lines.append("")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text("\n".join(lines))
    _plot(series, config.run_duration_s, 1.0 + tolerance, args.out.with_suffix(".png"))
    print(f"wrote {args.out} and {args.out.with_suffix('.png')}")
    return 0


def _straggler(
    times_s: np.ndarray,
    positions: np.ndarray,
    section: coverage.CoverageSection,
    end: int,
    still_ratio: float,
) -> dict:
    """One failing start's longer run: ``H / H_ref`` at the sweep's end (frame ``end``) and at the end,
    the first sample within the tolerance, the largest move of a robot over the last 10 s, and the
    verdict."""
    ratio = coverage.ratio_series(positions, section)
    within = ratio <= 1.0 + section.tolerance
    settle_s = settle_time(times_s, within, section.hold_s)
    window = times_s >= times_s[-1] - STILL_WINDOW_S
    window_positions = positions[window]
    moves_m = np.max(np.linalg.norm(window_positions - window_positions[-1], axis=-1), axis=0)  # (N,)
    moved_m = float(np.max(moves_m))
    drift = float(np.ptp(ratio[window]))
    if settle_s is not None:
        verdict = f"held later, from {settle_s:g} s"
    elif drift < still_ratio:
        verdict = "stopped above 1.05"
    else:
        verdict = "moving"
    first = np.flatnonzero(within)
    return {
        "at_sweep_end": float(ratio[end]),
        "at_end": float(ratio[-1]),
        "first_within_s": float(times_s[first[0]]) if len(first) else None,
        "still_m": moved_m,
        "movers": int(np.sum(moves_m > MOVER_M)),
        "drift": drift,
        "verdict": verdict,
        "ratio": ratio,
    }


def _plot(
    series: list[tuple[str, int, np.ndarray, np.ndarray]], sweep_end_s: float, threshold: float, path: Path
) -> None:
    """``H / H_ref`` against time of every start rerun, one panel per cell, with the success line and
    the sweep's end."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cells = list(dict.fromkeys(cell for cell, *_ in series))
    figure, panels = plt.subplots(len(cells), 1, figsize=(7.0, 2.6 * len(cells)), squeeze=False)
    for panel, cell in zip(panels[:, 0], cells, strict=True):
        for name, start, times_s, ratio in series:
            if name == cell:
                panel.plot(times_s, ratio, linewidth=0.8, label=f"start {start}")
        panel.axhline(threshold, color="black", linestyle="--", linewidth=0.8)
        panel.axvline(sweep_end_s, color="grey", linestyle=":", linewidth=0.8)
        panel.set_ylim(0.98, 1.15)
        panel.set_title(cell, fontsize=9)
        panel.set_ylabel("H / H_ref")
        if len(panel.get_lines()) <= 12:
            panel.legend(fontsize=6, ncol=4, loc="upper right")
    panels[-1, 0].set_xlabel("time (s); dashed: 1.05, dotted: the sweep's end")
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)


def _no_loss_finals(
    directories: list[Path], topology: str, count: int, controller: str
) -> list[float] | None:
    """Each start's final ``H / H_ref`` in the loss-free cell of the same kind, when a directory has it."""
    for directory in directories:
        path = directory / "cells" / cell_file_name(topology, count, controller, 0.0)
        if path.is_file():
            return [start["final_metric"] for start in json.loads(path.read_text())["starts"]]
    return None


if __name__ == "__main__":
    sys.exit(main())
