"""``bench/investigations/coverage_loss_stragglers.py``: its rerun of a sweep's chunks reproduces the
sweep's own cells (the oracle: the cell files ``swarm sweep`` wrote), and it refuses a cell it cannot
reproduce."""

from __future__ import annotations

import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "bench" / "investigations"))

import coverage_loss_stragglers as stragglers

from swarm.scenarios import task_sweep
from swarm.scenarios.task_sweep import TaskSweepConfig


def _lossy_sweep(out: Path) -> None:
    """A sweep too short for any start to hold the rule: every start is a straggler, in two chunks."""
    config = TaskSweepConfig(task="coverage").with_overrides(
        {
            "topologies": ["cycle"],
            "sizes": [4],
            "seeds": 3,
            "chunk_starts": 2,
            "controllers": ["lloyd_flood"],
            "packet_losses": [0.5],
            "duration_s": 1.0,
        }
    )
    task_sweep.run_task_sweep(config, out, progress=False)


def test_the_rerun_reproduces_the_sweep_and_reads_every_failing_start(tmp_path, capsys):
    sweep = tmp_path / "sweep"
    _lossy_sweep(sweep)
    cell = json.loads((sweep / "cells" / "cycle-N4-lloyd_flood-loss0.5.json").read_text())
    assert not any(start["converged"] for start in cell["starts"])
    out = tmp_path / "stragglers.md"
    argv = [
        "--sweep",
        str(sweep),
        "--cells",
        "cycle-N4-lloyd_flood-loss0.5",
        "--duration-s",
        "30",
        "--out",
        str(out),
    ]
    assert stragglers.main(argv) == 0
    text = out.read_text()
    rows = [line for line in text.splitlines() if line.startswith("| ") and not line.startswith("| start")]
    assert [int(row.split("|")[1]) for row in rows] == [0, 1, 2]
    for row, start in zip(rows, cell["starts"], strict=True):
        assert f"| {start['final_metric']:.4f} |" in row  # H/H_ref at the sweep's end: the cell's own
    assert "3 of 3 starts fail" in text
    assert out.with_suffix(".png").stat().st_size > 0
    assert stragglers.main([*argv, "--starts", "1"]) == 0  # one start asked: its chunk only, its row only
    rows = [
        line for line in out.read_text().splitlines() if line.startswith("| 1 |") or line.startswith("| 0 |")
    ]
    assert [row.split("|")[1].strip() for row in rows] == ["1"]
    # a cell whose numbers the rerun does not give back (as from other code or another kernel): refused
    cell["starts"][2]["final_metric"] += 1e-6
    (sweep / "cells" / "cycle-N4-lloyd_flood-loss0.5.json").write_text(json.dumps(cell))
    assert stragglers.main(argv) == 1
    assert "start 2: the sweep is not reproduced" in capsys.readouterr().err


def test_bad_input_exits_2_naming_it(tmp_path, capsys):
    sweep = tmp_path / "sweep"
    _lossy_sweep(sweep)
    out = tmp_path / "stragglers.md"
    assert stragglers.main(["--sweep", str(tmp_path), "--cells", "x", "--out", str(out)]) == 2
    assert "sweep_config.json: no such file" in capsys.readouterr().err
    assert (
        stragglers.main(["--sweep", str(sweep), "--cells", "cycle-N5-lloyd_flood-loss0.5", "--out", str(out)])
        == 2
    )
    assert "cycle-N5-lloyd_flood-loss0.5: no such cell" in capsys.readouterr().err
    assert not out.exists()
