"""bench/task_paired.py: the paired comparison of a task sweep's controllers, on cell files whose
values the test wrote (the oracle is what was generated) and on a real sweep's cells."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "bench"))

import task_paired

from swarm.scenarios import task_sweep


def _write_sweep(root: Path, times: dict[str, list[float | None]]) -> Path:
    """A coverage sweep's --out with one cycle cell per controller, ``first_within_s`` as given."""
    (root / "cells").mkdir(parents=True)
    (root / "sweep_config.json").write_text(json.dumps({"task": "coverage"}))
    for kind, values in times.items():
        starts = [
            {"converged": v is not None, **({"first_within_s": v} if v is not None else {})} for v in values
        ]
        cell = {"topology": "cycle", "robots": 5, "controller": kind, "packet_loss": 0.0, "starts": starts}
        (root / "cells" / f"cycle-N5-{kind}-loss0.json").write_text(json.dumps(cell))
    return root


def test_a_shift_by_a_constant_is_found_and_a_failed_start_is_slower(tmp_path, capsys):
    rng = np.random.default_rng(3)
    other = rng.uniform(5.0, 20.0, 400).round(3)
    mine = other - 0.5
    sweep = _write_sweep(
        tmp_path / "s",
        {"a": [*mine, None], "b": [*other, 30.0], "c": [*other, None]},  # the last start: a never got there
    )
    out = tmp_path / "paired.md"
    argv = [str(sweep), "--kind", "a", "--against", "b", "c", "--column", "first_within_s", "--out", str(out)]
    assert task_paired.main(argv) == 0
    rows = task_paired.compare(sweep / "cells", "a", ["b", "c"], "first_within_s", 500, 0)
    against_b, against_c = rows
    starts = len(other) + 1
    assert against_b["starts"] == starts
    assert against_b["faster"] == len(other) / starts and against_b["slower"] == 1 / starts
    assert against_c["equal"] == 1 / starts  # both never got there: equal, not faster
    assert np.isclose(against_b["ratio"], np.median((other - 0.5) / other))
    # every resample draws the same starts for both: a shift of 0.5 s on all but one start
    assert abs(against_b["difference"] + 0.5) < 0.1 and against_b["high"] < 0
    assert "| cycle | 5 | 0% | `b` | 401 |" in out.read_text()
    assert (tmp_path / "paired.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"  # the plot beside it
    assert task_paired.plot(rows, "a", "first_within_s", tmp_path / "again.png") == 2  # both differences


def test_a_controller_that_never_got_there_reads_never_not_nan(tmp_path):
    """A stalled baseline (``lloyd_local`` on a cycle): its median is no time, and no number is made up."""
    times = np.random.default_rng(2).uniform(5.0, 20.0, 50).round(3)
    sweep = _write_sweep(tmp_path / "s", {"a": [*times], "stalled": [None] * len(times)})
    out = tmp_path / "paired.md"
    argv = [
        str(sweep),
        "--kind",
        "a",
        "--against",
        "stalled",
        "--column",
        "first_within_s",
        "--out",
        str(out),
    ]
    assert task_paired.main(argv) == 0
    row = next(line for line in out.read_text().splitlines() if "`stalled`" in line)
    cells = [cell.strip() for cell in row.strip("|").split("|")]
    assert cells[5:8] == [f"{np.median(times):.3f}", "never", "-"]
    assert cells[8] == "100% / 0% / 0%" and cells[9] == "-"
    assert "nan" not in out.read_text() and "inf" not in out.read_text()
    rows = task_paired.compare(sweep / "cells", "a", ["stalled"], "first_within_s", 100, 0)
    assert task_paired.plot(rows, "a", "first_within_s", tmp_path / "p.png") == 0  # named, not drawn


def test_rows_come_in_the_order_of_n_and_loss_as_numbers(tmp_path):
    """The cells of N = 6, 12 and 100 (whose file names sort 100, 12, 6) at two losses: rows go by topology,
    then N and loss as numbers."""
    cells = tmp_path / "s" / "cells"
    cells.mkdir(parents=True)
    (tmp_path / "s" / "sweep_config.json").write_text(json.dumps({"task": "coverage"}))
    for topology in ("line", "cycle"):
        for count in (100, 6, 12):
            for loss in (0.5, 0.2):
                for kind in ("a", "b"):
                    starts = [{"converged": True, "first_within_s": float(count)}]
                    cell = {"topology": topology, "robots": count, "controller": kind, "packet_loss": loss}
                    name = f"{topology}-N{count}-{kind}-loss{loss:g}.json"
                    (cells / name).write_text(json.dumps({**cell, "starts": starts}))
    rows = task_paired.compare(cells, "a", ["b"], "first_within_s", 10, 0)
    order = [(row["topology"], row["robots"], row["packet_loss"]) for row in rows]
    assert order == [(g, n, loss) for g in ("cycle", "line") for n in (6, 12, 100) for loss in (0.2, 0.5)]


def test_a_controller_against_itself_differs_by_nothing():
    values = np.random.default_rng(1).uniform(1.0, 2.0, 300)
    row = task_paired.paired_row(values, values.copy(), 200, 0)
    assert row["difference"] == row["low"] == row["high"] == 0.0
    assert row["equal"] == 1.0 and row["ratio"] == 1.0


def test_a_real_sweeps_cells_are_compared_start_by_start(tmp_path):
    """The shares agree with the cell files read directly."""
    config = task_sweep.TaskSweepConfig(task="coverage").with_overrides(
        {
            "topologies": ["cycle"],
            "sizes": [5],
            "seeds": 6,
            "controllers": ["lloyd", "lloyd_flood"],
            "duration_s": 8.0,
        }
    )
    task_sweep.run_task_sweep(config, tmp_path / "s", progress=False)
    [row] = task_paired.compare(tmp_path / "s" / "cells", "lloyd_flood", ["lloyd"], "ratio_at_s.5", 100, 0)
    cells = {
        kind: json.loads((tmp_path / "s" / "cells" / f"cycle-N5-{kind}-loss0.json").read_text())["starts"]
        for kind in ("lloyd", "lloyd_flood")
    }
    expert = np.array([start["ratio_at_s"]["5"] for start in cells["lloyd"]])
    flood = np.array([start["ratio_at_s"]["5"] for start in cells["lloyd_flood"]])
    assert row["starts"] == 6
    assert row["faster"] == np.mean(flood < expert) and row["slower"] == np.mean(flood > expert)
    assert row["median"] == np.median(flood) and row["other_median"] == np.median(expert)


def test_bad_input_exits_2_and_names_it(tmp_path, capsys):
    assert task_paired.main([str(tmp_path), "--kind", "a", "--against", "b"]) == 2
    assert "not a task sweep's --out" in capsys.readouterr().err
    sweep = _write_sweep(tmp_path / "s", {"a": [1.0, 2.0], "b": [1.0]})
    assert task_paired.main([str(sweep), "--kind", "a", "--against", "b", "--column", "first_within_s"]) == 2
    assert "1 starts, cycle-N5-a-loss0.json has 2" in capsys.readouterr().err
    assert task_paired.main([str(sweep), "--kind", "z", "--against", "b"]) == 2
    assert "no cell of z beside b" in capsys.readouterr().err
