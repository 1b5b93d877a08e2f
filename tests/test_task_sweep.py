"""``swarm sweep --task``: every task with a sweep entry, measured the same way (swarm.scenarios.task_sweep).

The oracles are outside the code under test: the formation bound by brute force over every
assignment of 4 robots, the slots held read from the raw positions, the locational cost recomputed
from the quadrature with plain numpy, the starts compared across controllers, the exit codes from
cells whose success is known.
"""

from __future__ import annotations

import csv
import itertools
import json
import math
from pathlib import Path

import numpy as np
import pytest

from swarm.core.tasks import registry
from swarm.scenarios import task_sweep
from swarm.scenarios.blas import blas_kernel
from swarm.scenarios.scenario import ScenarioError
from swarm.scenarios.task_sweep import TaskSweepConfig

SWEPT = task_sweep.sweep_tasks()


def _small(task: str, **more) -> TaskSweepConfig:
    settings = {"sizes": [4], "seeds": 3, "topologies": ["cycle", "disk"], "duration_s": 20.0, **more}
    return TaskSweepConfig(task=task).with_overrides(settings)


def test_formation_and_coverage_are_swept_and_rendezvous_has_its_own():
    assert set(SWEPT) == {"formation", "coverage"}
    assert registry.get("rendezvous").sweep is None


@pytest.mark.slow
@pytest.mark.parametrize("task", SWEPT)
def test_every_swept_task_gives_every_controller_the_same_seeded_starts(task, tmp_path):
    """The registry contract: one row per cell, every controller of a cell on the same starts, the same
    seed giving the same results, central kinds left out of lossy cells."""
    config = _small(task, packet_losses=[0.0, 0.5])
    rows = task_sweep.run_task_sweep(config, tmp_path / "a", progress=False)
    task_entry = registry.get(task)
    controllers = [*task_entry.experts, *task_entry.baselines, *task_entry.learned]
    expected = {(t, c, 0.0) for t in config.topologies for c in controllers}
    expected |= {(t, c, 0.5) for t in config.topologies for c in controllers if not registry_central(c)}
    assert {(r["topology"], r["controller"], r["packet_loss"]) for r in rows} == expected
    for row in rows:
        assert row["starts"] == 3 and 0.0 <= row["success_rate"] <= 1.0
    assert (tmp_path / "a" / "sweep.png").stat().st_size > 0
    assert "| topology | N | loss | controller |" in (tmp_path / "a" / "sweep.md").read_text()
    again = task_sweep.run_task_sweep(config, tmp_path / "b", progress=False)
    assert again == rows
    for cell in (tmp_path / "a" / "cells").iterdir():
        assert cell.read_text() == (tmp_path / "b" / "cells" / cell.name).read_text()
    # the same starts for each controller: every start's metric at time 0 (a function of the start alone)
    for topology in config.topologies:
        initial = [
            [start["initial_metric"] for start in json.loads(cell.read_text())["starts"]]
            for cell in sorted((tmp_path / "a" / "cells").glob(f"{topology}-N4-*.json"))
        ]
        assert len(initial) == len(expected) // len(config.topologies)
        assert all(values == initial[0] for values in initial), initial


def registry_central(controller: str) -> bool:
    from swarm.sim.controller_kinds import controller_kind

    return controller_kind(controller).central


def _brute_bottleneck(points: np.ndarray, slots: np.ndarray) -> float:
    return min(
        max(float(np.hypot(*(points[i] - slots[j]))) for i, j in enumerate(order))
        for order in itertools.permutations(range(len(slots)))
    )


@pytest.mark.slow
def test_formation_cells_against_the_brute_force_bound_and_the_raw_positions():
    config = _small("formation", topologies=["cycle"], seeds=4)
    section = config.cells.section(4)
    slots = section.slot_positions(4)
    poses, adjacency = task_sweep.cell_starts(config, "cycle", 4)
    for controller in ("capt", "capt_flood"):
        times, positions = task_sweep.run_chunk(config, section, controller, poses, adjacency, 0.0, 0)
        assert times[-1] < config.run_duration_s  # every start held its slots: the run stopped early
        for b in range(len(poses)):
            outcome = registry.get("formation").outcome(times, positions[:, b], section, 0.5)
            bound = max(0.0, _brute_bottleneck(poses[b, :, :2], slots) - section.tolerance_m) / 0.5
            assert outcome["lower_bound_s"] == pytest.approx(bound, rel=1e-9)
            assert outcome["converged"] and outcome["ratio_to_lower_bound"] >= 1.0
            # from the settle time on, each slot has exactly one axle within tolerance, for hold_s
            settled = times >= outcome["convergence_time_s"] - 1e-9
            assert times[-1] - outcome["convergence_time_s"] >= section.hold_s - 1e-9
            gaps = np.linalg.norm(positions[settled, b][:, :, None] - slots[None, None], axis=-1)
            assert np.all((gaps <= section.tolerance_m).sum(axis=1) == 1)
            assert np.all((gaps <= section.tolerance_m).sum(axis=2) == 1)
            before = positions[~settled, b]
            if len(before):  # the frame before the settle time did not hold
                gaps = np.linalg.norm(before[-1][:, None] - slots[None], axis=-1)
                assert not np.all((gaps <= section.tolerance_m).sum(axis=0) == 1)


@pytest.mark.slow
def test_coverage_cells_report_the_cost_recomputed_from_the_quadrature():
    config = _small("coverage", topologies=["line"], duration_s=10.0)
    section = config.cells.section(4)
    points, weights = section.quadrature()
    poses, adjacency = task_sweep.cell_starts(config, "line", 4)
    times, positions = task_sweep.run_chunk(config, section, "lloyd", poses, adjacency, 0.0, 0)
    assert math.isclose(times[-1], 10.0) and len(times) == 10.0 / 0.05 / 5 + 1  # every 5th tick
    reference = registry.get("coverage").reference(section, 4)
    for b in range(len(poses)):
        final = positions[-1, b]
        cost = sum(
            w * min(float(np.sum((q - p) ** 2)) for p in final) for q, w in zip(points, weights, strict=True)
        )
        outcome = registry.get("coverage").outcome(times, positions[:, b], section, 0.5)
        assert outcome["final_metric"] == pytest.approx(cost / reference, rel=1e-9)


def test_the_sweep_command_runs_a_task_and_exits_1_where_a_cell_fails(tmp_path, capsys):
    from swarm.cli import main

    out = tmp_path / "formation"
    argv = ["sweep", "--task", "formation", "--sizes", "4", "--seeds", "2", "--topologies", "complete"]
    assert main([*argv, "--out", str(out), "--quiet"]) == 0
    assert "sweep formation: 3 cells" in capsys.readouterr().out
    cells = sorted(path.name for path in (out / "cells").iterdir())
    expected = [
        "complete-N4-capt-loss0.json",
        "complete-N4-capt_flood-loss0.json",
        "complete-N4-capt_gnn-loss0.json",
    ]
    assert cells == expected  # the expert, the baseline and the learned GNN
    assert all(json.loads((out / "cells" / c).read_text())["starts"][0]["converged"] for c in cells)
    # each cell names the BLAS kernel it ran on, and the table counts them
    assert {json.loads((out / "cells" / c).read_text())["blas"] for c in cells} == {blas_kernel()}
    assert (
        f"BLAS kernel of the cells' matrix products (cells): {blas_kernel()} (3)."
        in (out / "sweep.md").read_text()
    )
    # --resume reads the cells it has (a marker written into one survives) and runs the missing ones
    marked = out / "cells" / expected[1]
    data = json.loads(marked.read_text())
    data["marker"] = True
    marked.write_text(json.dumps(data))
    (out / "cells" / expected[2]).unlink()
    assert main([*argv, "--out", str(out), "--quiet", "--resume"]) == 0
    assert json.loads(marked.read_text())["marker"] and (out / "cells" / expected[2]).is_file()
    # ... only from a sweep of the same settings: 3 seeds where it has 2 is bad input, nothing written
    before = {p.name: p.read_bytes() for p in (out / "cells").iterdir()}
    argv3 = [*argv[:5], "--seeds", "3", "--topologies", "complete", "--out", str(out), "--quiet", "--resume"]
    assert main(argv3) == 2
    assert "--resume" in capsys.readouterr().err
    assert {p.name: p.read_bytes() for p in (out / "cells").iterdir()} == before
    # lloyd_local on a line stalls far above the reference (docs/tasks.md): success 0, exit 1
    argv = ["sweep", "--task", "coverage", "--controllers", "lloyd_local", "--topologies", "line"]
    argv += ["--sizes", "6", "--seeds", "2", "--max-duration", "5", "--out", str(tmp_path / "c"), "--quiet"]
    assert main(argv) == 1
    assert "not always met: line N=6 lloyd_local: 0.0%" in capsys.readouterr().out
    # a cell that succeeds, then its tables with another kind's not run yet: exit 1 (incomplete), the
    # missing cell named, and not run
    argv = ["sweep", "--task", "coverage", "--controllers", "lloyd", "--topologies", "line", "--sizes", "6"]
    argv += ["--seeds", "2", "--max-duration", "30", "--out", str(tmp_path / "d"), "--quiet"]
    assert main(argv) == 0
    capsys.readouterr()
    assert main([*argv[:5], "lloyd_flood", *argv[5:], "--tables-only"]) == 1
    said = capsys.readouterr().out
    assert "incomplete: 1 cells of these lists not run yet (line-N6-lloyd_flood-loss0.json)" in said
    assert "not always met" not in said
    assert not (tmp_path / "d" / "cells" / "line-N6-lloyd_flood-loss0.json").exists()


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--task", "nope"], "task: 'nope' is not swept; choose from formation, coverage"),
        (["--task", "formation", "--controllers", "mec_flood"], "'mec_flood' does not do task formation"),
        (["--task", "formation", "--gain", "2"], "--gain: a rendezvous sweep setting"),
        (["--task", "formation", "--model", "m.npz"], "model: m.npz: no such policy file"),
        (
            ["--task", "formation", "--controllers", "capt", "--model", "models/formation/capt_gnn.npz"],
            "model: none of the controllers takes one (the task's learned kinds: capt_gnn)",
        ),
        (["--task", "coverage", "--topologies", "wheel"], "topologies: unknown topology 'wheel'"),
        (["--tables-only"], "--tables-only: a task sweep setting"),
        (["--task", "coverage", "--tables-only"], "--tables-only: no "),
    ],
)
def test_bad_task_sweeps_exit_2_and_say_why(argv, message, tmp_path, capsys):
    from swarm.cli import main

    assert main(["sweep", *argv, "--out", str(tmp_path / "out")]) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_a_task_sweep_config_names_its_file_and_key(tmp_path, capsys):
    from swarm.cli import main

    config = tmp_path / "cells.yaml"
    config.write_text("task: formation\nsizes: [4]\nthreshold_m: 0.2\n")
    assert main(["sweep", "--config", str(config), "--out", str(tmp_path / "out")]) == 2
    assert f"{config}: threshold_m: unknown key of a task sweep" in capsys.readouterr().err


@pytest.mark.slow
def test_ctrl_c_keeps_the_finished_cells_and_exits_130(tmp_path):
    """Interrupted after its first cell, a task sweep writes the tables of the cells it finished."""
    import signal
    import subprocess
    import sys
    import time

    out = tmp_path / "sweep"
    command = [sys.executable, "-m", "swarm.cli", "sweep", "--task", "formation", "--topologies", "cycle"]
    command += ["--sizes", "4", "50", "100", "--seeds", "50", "--out", str(out), "--quiet"]
    run = subprocess.Popen(  # SIGINT as from a terminal, even when the suite runs in the background
        command,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        give_up = time.monotonic() + 300
        while not list((out / "cells").glob("*.json")) and time.monotonic() < give_up and run.poll() is None:
            time.sleep(0.05)
        finished = len(list((out / "cells").glob("*.json")))
        assert finished >= 1 and run.poll() is None
        run.send_signal(signal.SIGINT)
        _, stderr = run.communicate(timeout=120)
    finally:
        if run.poll() is None:
            run.kill()
    assert run.returncode == 130, stderr
    table = (out / "sweep.md").read_text()
    done = len(list((out / "cells").glob("*.json")))
    assert f"Interrupted after {done} of 9 cells." in table  # 3 sizes x capt, capt_flood, capt_gnn
    assert table.count("| cycle |") == done


def test_a_ctrl_c_between_a_cells_file_and_its_row_keeps_the_cell_in_the_tables(tmp_path, monkeypatch):
    """The window the signal test above hits by chance (once in CI): the cell's file is written and the
    interrupt lands before its row is made. Its file is on disk, so its row is in the tables."""
    summarize = task_sweep.summarize_cell
    calls = []

    def interrupted_once(cell, columns):
        calls.append(cell["controller"])
        if len(calls) == 2:  # the second cell: after its file, before its row
            raise KeyboardInterrupt
        return summarize(cell, columns)

    monkeypatch.setattr(task_sweep, "summarize_cell", interrupted_once)
    config = _small("formation", topologies=["cycle"], seeds=2)
    out = tmp_path / "sweep"
    with pytest.raises(KeyboardInterrupt):
        task_sweep.run_task_sweep(config, out, progress=False)
    cells = sorted(path.name for path in (out / "cells").iterdir())
    assert len(cells) == 2 and all(name.endswith(".json") for name in cells)  # no half-written file
    table = (out / "sweep.md").read_text()
    assert "Interrupted after 2 of 3 cells." in table
    with open(out / "sweep.csv") as file:
        assert sorted(row["controller"] for row in csv.DictReader(file)) == sorted(calls[:2])


@pytest.mark.parametrize("task", SWEPT)
def test_worker_processes_write_the_cells_one_process_writes(task, tmp_path):
    """``--workers``: chunks of every cell in several processes. The oracle is the one-process sweep:
    every cell file and both tables byte for byte, lossy cells included (chunk c draws its losses from
    seed c, so a chunk run under another seed or put back in another order shows)."""
    config = _small(task, seeds=5, chunk_starts=2, packet_losses=[0.0, 0.5])  # 3 chunks a cell
    one, two = tmp_path / "one", tmp_path / "two"
    task_sweep.run_task_sweep(config, one, progress=False)
    task_sweep.run_task_sweep(config, two, progress=False, workers=2)
    names = sorted(path.name for path in (one / "cells").iterdir())
    assert names == sorted(path.name for path in (two / "cells").iterdir())
    assert any("loss0.5" in name for name in names)
    for name in names:
        assert (one / "cells" / name).read_bytes() == (two / "cells" / name).read_bytes(), name
    for table in ("sweep.md", "sweep.csv", "sweep_config.json"):
        assert (one / table).read_bytes() == (two / table).read_bytes(), table


def test_a_sweep_run_in_parts_with_resume_writes_what_one_run_writes(tmp_path):
    """``--resume`` across parts that choose other graphs, sizes, controllers and losses (a long sweep
    run one graph at a time). The oracle is the sweep run at once: every cell file and both tables byte
    for byte; the last part runs only the cells no part ran (a marker written into a cell survives)."""
    whole = _small(
        "coverage", sizes=[4, 5], seeds=2, controllers=["lloyd_flood", "lloyd_gnn"], packet_losses=[0.0, 0.5]
    )
    once, parts = tmp_path / "once", tmp_path / "parts"
    task_sweep.run_task_sweep(whole, once, progress=False)
    first = whole.with_overrides({"topologies": ["disk"], "sizes": [5], "controllers": ["lloyd_gnn"]})
    task_sweep.run_task_sweep(first, parts, progress=False)
    second = whole.with_overrides({"topologies": ["cycle"], "packet_losses": [0.5]})
    task_sweep.run_task_sweep(second, parts, progress=False, resume=True, workers=2)
    marked = parts / "cells" / "disk-N5-lloyd_gnn-loss0.json"
    cell = json.loads(marked.read_text())
    marked.write_text(json.dumps({**cell, "marker": True}) + "\n")
    task_sweep.run_task_sweep(whole, parts, progress=False, resume=True)
    assert json.loads(marked.read_text())["marker"]  # read, not run again
    marked.write_text(json.dumps(cell) + "\n")
    names = sorted(path.name for path in (once / "cells").iterdir())
    assert names == sorted(path.name for path in (parts / "cells").iterdir())
    assert len(names) == 2 * 2 * 2 * 2  # cycle and disk, N = 4 and 5, two kinds, two losses
    for name in names:
        assert (once / "cells" / name).read_bytes() == (parts / "cells" / name).read_bytes(), name
    task_sweep.run_task_sweep(whole, parts, progress=False, resume=True)  # the tables of the true cells
    for table in ("sweep.md", "sweep.csv", "sweep_config.json"):
        assert (once / table).read_bytes() == (parts / table).read_bytes(), table
    # --tables-only: a narrower part's tables, then the whole's again from the cells, running none
    task_sweep.run_task_sweep(first, parts, progress=False, resume=True)
    assert (once / "sweep.md").read_bytes() != (parts / "sweep.md").read_bytes()
    stamps = {p.name: p.stat().st_mtime_ns for p in (parts / "cells").iterdir()}
    task_sweep.run_task_sweep(whole, parts, progress=False, tables_only=True, workers=2)
    assert {p.name: p.stat().st_mtime_ns for p in (parts / "cells").iterdir()} == stamps
    for table in ("sweep.md", "sweep.csv", "sweep_config.json"):
        assert (once / table).read_bytes() == (parts / table).read_bytes(), table
    # ... and with a cell missing: the tables of the other 15, a line naming it, and it is not run
    gone = parts / "cells" / "cycle-N4-lloyd_flood-loss0.json"
    kept = gone.read_bytes()
    gone.unlink()
    rows = task_sweep.run_task_sweep(whole, parts, progress=False, tables_only=True)
    assert not gone.exists()
    assert len(rows) == 15
    assert not any(
        row["topology"] == "cycle"
        and row["robots"] == 4
        and row["controller"] == "lloyd_flood"
        and row["packet_loss"] == 0.0
        for row in rows
    )
    assert (
        "Tables of 15 of the 16 cells of these lists; not run yet: cycle-N4-lloyd_flood-loss0.json"
        in (parts / "sweep.md").read_text()
    )
    # ... and with none of them there: refused, nothing written
    narrow = whole.with_overrides({"topologies": ["cycle"], "sizes": [4], "controllers": ["lloyd_flood"]})
    narrow = narrow.with_overrides({"packet_losses": [0.0]})
    tables = {name: (parts / name).read_bytes() for name in ("sweep.md", "sweep.csv", "sweep_config.json")}
    with pytest.raises(ScenarioError, match=r"holds none of the 1 cells of these lists"):
        task_sweep.run_task_sweep(narrow, parts, progress=False, tables_only=True)
    assert not gone.exists()
    assert {name: (parts / name).read_bytes() for name in tables} == tables
    gone.write_bytes(kept)
    # another setting than the lists: refused, nothing written
    before = {p.name: p.read_bytes() for p in (parts / "cells").iterdir()}
    with pytest.raises(ScenarioError, match="only the topologies, sizes, controllers and packet losses"):
        task_sweep.run_task_sweep(whole.with_overrides({"seeds": 3}), parts, progress=False, resume=True)
    assert {p.name: p.read_bytes() for p in (parts / "cells").iterdir()} == before
    # cells without the sweep_config.json that tells their settings (copied alone): refused, not run again
    (parts / "sweep_config.json").unlink()
    with pytest.raises(ScenarioError, match=r"no \S*sweep_config\.json to tell their settings"):
        task_sweep.run_task_sweep(whole, parts, progress=False, resume=True)
    assert {p.name: p.read_bytes() for p in (parts / "cells").iterdir()} == before


def test_resume_says_when_the_cells_there_ran_on_another_blas_kernel(tmp_path, caplog):
    """Cells written on another machine's BLAS kernel: a resume that runs new cells says so, naming the
    kernel, one such cell and the setting that matches it; a resume with nothing to run, or among cells
    of this process's kernel, says nothing. The oracle is the kernel written into the cell file."""
    config = _small("coverage", topologies=["cycle"], controllers=["lloyd_flood"])
    out = tmp_path / "out"
    task_sweep.run_task_sweep(config, out, progress=False)
    wider = config.with_overrides({"controllers": ["lloyd_flood", "lloyd_gnn"]})
    more = config.with_overrides({"controllers": ["lloyd_gnn"], "sizes": [5]})
    with caplog.at_level("WARNING", logger="swarm.scenarios.task_sweep"):
        task_sweep.run_task_sweep(wider, out, progress=False, resume=True)  # same kernel: silent
        assert caplog.records == []
        moved = out / "cells" / "cycle-N4-lloyd_flood-loss0.json"
        moved.write_text(json.dumps({**json.loads(moved.read_text()), "blas": "openblas Elsewhere"}) + "\n")
        task_sweep.run_task_sweep(wider, out, progress=False, resume=True)  # nothing to run: silent
        assert caplog.records == []
        task_sweep.run_task_sweep(more, out, progress=False, resume=True)
    (record,) = caplog.records
    message = record.getMessage()
    assert "1 of the cells" in message and "openblas Elsewhere" in message and moved.name in message
    assert f"this process on {blas_kernel()}" in message and "OPENBLAS_CORETYPE=Elsewhere" in message
    assert (out / "cells" / "cycle-N5-lloyd_gnn-loss0.json").is_file()  # said, and run


@pytest.mark.slow
def test_ctrl_c_in_worker_processes_keeps_the_finished_cells_and_leaves_no_worker(tmp_path):
    """``--workers 2`` interrupted after its first cell by a Ctrl-C as a terminal sends it (to the whole
    process group, workers included): exit 130, one line and no worker's traceback, the finished
    cells' tables, and every worker process (found from outside, by parent pid in /proc) gone."""
    import os
    import signal
    import subprocess
    import sys
    import time

    def children(pid: int) -> set[int]:
        found = set()
        for stat in Path("/proc").glob("[0-9]*/stat"):
            try:
                fields = stat.read_text().rsplit(")", 1)[1].split()
            except (OSError, IndexError):
                continue
            if int(fields[1]) == pid:
                found.add(int(stat.parent.name))
        return found

    out = tmp_path / "sweep"
    command = [sys.executable, "-m", "swarm.cli", "sweep", "--task", "formation", "--topologies", "cycle"]
    command += ["--sizes", "4", "50", "100", "--seeds", "100", "--workers", "2", "--out", str(out), "--quiet"]

    def own_group() -> None:  # a terminal's foreground group, even when the suite runs in the background
        os.setpgrp()
        signal.signal(signal.SIGINT, signal.SIG_DFL)

    run = subprocess.Popen(command, preexec_fn=own_group, stderr=subprocess.PIPE, text=True)
    workers: set[int] = set()
    try:
        give_up = time.monotonic() + 300
        while not list((out / "cells").glob("*.json")) and time.monotonic() < give_up and run.poll() is None:
            workers |= children(run.pid)
            time.sleep(0.05)
        workers |= children(run.pid)
        assert list((out / "cells").glob("*.json")) and run.poll() is None
        assert len(workers) >= 2  # the pool's processes (and the resource tracker)
        os.killpg(run.pid, signal.SIGINT)
        _, stderr = run.communicate(timeout=120)
    finally:
        if run.poll() is None:
            run.kill()
    assert run.returncode == 130, stderr
    assert stderr.strip() == "swarm sweep: interrupted", stderr
    table = (out / "sweep.md").read_text()
    done = len(list((out / "cells").glob("*.json")))
    assert f"Interrupted after {done} of 9 cells." in table
    assert table.count("| cycle |") == done
    give_up = time.monotonic() + 30
    while any(Path(f"/proc/{pid}").exists() for pid in workers) and time.monotonic() < give_up:
        time.sleep(0.1)
    alive = [pid for pid in workers if Path(f"/proc/{pid}").exists()]
    assert not alive, f"worker processes left running: {alive}"


def test_starts_that_cannot_be_drawn_are_refused_before_any_cell_runs(tmp_path, capsys):
    """A disk radius that connects no start of the last cell: exit 2 naming it, and no cell was run."""
    from swarm.cli import main

    config = tmp_path / "cells.yaml"
    config.write_text(
        "task: formation\ntopologies: [complete, disk]\nsizes: [4, 30]\nseeds: 1\ndisk_radius_m: 0.5\n"
    )
    out = tmp_path / "out"
    assert main(["sweep", "--config", str(config), "--out", str(out), "--quiet"]) == 2
    assert "disk_radius_m: 0.5 m connects too few starts of" in capsys.readouterr().err
    assert not list((out / "cells").glob("*.json"))


def _silent_formation_policy(path: Path) -> Path:
    """A capt_gnn policy whose direction output is 0: its robots never move."""
    from swarm.sim.formation_gnn import FEATURES, FormationGnnWeights

    FormationGnnWeights((np.zeros((len(FEATURES), 3)),), (np.zeros(3),)).save(path)
    return path


def test_evaluate_runs_a_task_policy_beside_the_experts_and_baselines(tmp_path, capsys):
    """``swarm evaluate`` of a formation policy: the task sweep's cells with the file given; the shipped
    policy fills every slot (exit 0), one that never moves fills none (exit 1, the cell named)."""
    from swarm.cli import main

    cells = ["--sizes", "4", "--seeds", "2", "--topologies", "line", "--quiet"]
    shipped = "models/formation/capt_gnn.npz"
    assert main(["evaluate", shipped, *cells, "--out", str(tmp_path / "a")]) == 0
    assert "evaluate formation: 3 cells" in capsys.readouterr().out
    rows = {row["controller"]: row for row in csv.DictReader((tmp_path / "a" / "sweep.csv").open())}
    assert sorted(rows) == ["capt", "capt_flood", "capt_gnn"]
    assert json.loads((tmp_path / "a" / "sweep_config.json").read_text())["model"] == shipped
    silent = str(_silent_formation_policy(tmp_path / "silent.npz"))
    # in two worker processes, which load the file given themselves
    assert main(["evaluate", silent, *cells, "--workers", "2", "--out", str(tmp_path / "b")]) == 1
    assert "model not always met: line N=4: 0.0%" in capsys.readouterr().out
    rows = {row["controller"]: row for row in csv.DictReader((tmp_path / "b" / "sweep.csv").open())}
    assert float(rows["capt_gnn"]["success_rate"]) == 0.0 and float(rows["capt_flood"]["success_rate"]) == 1.0
    # swarm sweep --task --model runs the same file
    argv = ["sweep", "--task", "formation", "--controllers", "capt_gnn", "--model", silent, *cells]
    assert main([*argv, "--out", str(tmp_path / "c")]) == 1


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--task", "coverage"], "--task coverage: models/formation/capt_gnn.npz is a formation policy"),
        (["--limit", "4:1"], "--limit: a rendezvous evaluation setting; a formation evaluation has none"),
        (["--topologies", "wheel"], "topologies: unknown topology 'wheel'"),
    ],
)
def test_bad_task_evaluations_exit_2_and_write_nothing(extra, message, tmp_path, capsys):
    from swarm.cli import main

    out = tmp_path / "out"
    assert main(["evaluate", "models/formation/capt_gnn.npz", *extra, "--out", str(out)]) == 2
    assert message in capsys.readouterr().err
    assert not out.exists()


def test_an_outdated_coverage_policy_is_refused_by_name_before_any_cell_runs(tmp_path, capsys):
    """A ``coverage_gnn/1`` file (``lloyd_gnn`` on ``lloyd_flood``'s cell, before the format changed):
    ``swarm evaluate`` names the file and both formats, exit 2, and writes nothing."""
    from swarm.cli import main
    from swarm.sim.coverage_gnn import FEATURES, CoverageGnnWeights

    class Outdated(CoverageGnnWeights):
        FORMAT = "coverage_gnn/1"

    path = tmp_path / "v1.npz"
    Outdated((np.zeros((len(FEATURES), 3)),), (np.zeros(3),)).save(path)
    out = tmp_path / "out"
    assert main(["evaluate", str(path), "--sizes", "4", "--seeds", "1", "--out", str(out)]) == 2
    assert f"{path}: format 'coverage_gnn/1', expected 'coverage_gnn/2'" in capsys.readouterr().err
    assert not out.exists()
