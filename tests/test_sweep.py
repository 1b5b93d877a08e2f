"""Sweeps in the batched simulator: no start beats the lower bound, 1/lambda2 scaling, outputs."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from swarm.cli import main
from swarm.core import graphs, metrics
from swarm.core.robot import RobotParams
from swarm.scenarios.sweep import SweepConfig, connecting_radius, converge_batch, run_cell, summarize_cell
from swarm.sim.controllers import LocalConsensus
from swarm.sim.kinematic import KinematicSim


@pytest.mark.parametrize("topology", ["complete", "cycle", "line", "star", "random", "disk"])
@pytest.mark.parametrize("controller", ["local_consensus", "centralized"])
def test_no_start_beats_the_lower_bound(topology, controller):
    config = SweepConfig(seeds=40, sizes=[8], max_duration_s=400.0, hold_s=2.0, seed=11)
    cell = run_cell(config, topology, 8, controller)
    times, lower = cell["times_s"], cell["lower_bound_s"]
    assert not np.isnan(times).any(), f"{topology}/{controller}: some starts did not converge"
    assert np.all(times >= lower), f"beat the bound: {np.min(times - lower)}"
    if controller == "centralized" and topology != "disk":
        # the other side: the bound is nearly attained (the centralized controller heads for the
        # enclosing circle's centre at full speed), so a bound too small, or zero, fails here
        assert np.all(lower > 0) and np.min(times / lower) < 1.1, np.min(times / lower)


def test_lower_bound_equals_the_hand_computed_value():
    """Two robots D apart: R_mec = D / 2; an equilateral triangle of side s: R_mec = s / sqrt(3)
    (hand-computed, not from the enclosing-circle code); bound = (R_mec - threshold / sqrt(3)) / v_max."""
    v, threshold = 0.5, 0.2
    two = np.array([[0.0, 0.0], [3.0, 0.0]])
    assert metrics.lower_bound_s(two, threshold, v) == pytest.approx((1.5 - threshold / 3**0.5) / v)
    s = 2.0
    triangle = np.array([[0.0, 0.0], [s, 0.0], [s / 2, s * 3**0.5 / 2]]) + 7.0
    assert metrics.lower_bound_s(triangle, threshold, v) == pytest.approx(
        (s / 3**0.5 - threshold / 3**0.5) / v
    )
    assert metrics.lower_bound_s(two, 10.0, v) == 0.0  # already within the threshold


def test_convergence_time_matches_a_full_trajectory():
    """The early-exit bookkeeping gives the same time as metrics.convergence_time on the whole run."""
    robot = RobotParams()
    poses = np.random.default_rng(4).uniform(-2, 2, size=(5, 6, 3))
    adjacency = graphs.cycle(6)
    fast = converge_batch(
        KinematicSim(robot, LocalConsensus(robot), 0.05, poses, adjacency=adjacency),
        threshold_m=0.2,
        max_duration_s=60.0,
        hold_s=60.0,
    )
    trajectory = KinematicSim(robot, LocalConsensus(robot), 0.05, poses, adjacency=adjacency).rollout(1200)
    values = metrics.max_pairwise(trajectory[..., :2]).T  # (B, T)
    expected = metrics.convergence_time(np.arange(1201) * 0.05, values, 0.2)
    np.testing.assert_allclose(fast, expected)


def test_local_consensus_time_follows_inverse_lambda2():
    """Linear consensus decays like exp(-K lambda2 t): t x lambda2 stays roughly constant for lines
    and cycles while lambda2 itself falls by more than 10x (N^2 slow-down)."""
    config = SweepConfig(seeds=24, max_duration_s=3000.0, hold_s=2.0, controllers=["local_consensus"])
    products = []
    for topology in ("cycle", "line"):
        rows = [summarize_cell(run_cell(config, topology, count, "local_consensus")) for count in (8, 24)]
        assert rows[0]["median_lambda2"] > 8 * rows[1]["median_lambda2"]
        assert rows[1]["median_time_s"] > 4 * rows[0]["median_time_s"]
        products += [row["median_time_x_lambda2"] for row in rows]
    assert max(products) / min(products) < 3.0, products


def test_connecting_radius_connects_every_start():
    positions = np.random.default_rng(2).uniform(-3, 3, size=(10, 9, 2))
    radius = connecting_radius(positions)
    assert all(graphs.is_connected(graphs.disk(start, radius)) for start in positions)
    assert not all(graphs.is_connected(graphs.disk(start, radius * 0.98)) for start in positions)


@pytest.mark.slow
def test_sweep_command_writes_tables_and_plots(tmp_path):
    out = tmp_path / "sweep"
    code = main(
        [
            "sweep",
            "--topologies",
            "cycle",
            "random",
            "--sizes",
            "6",
            "--seeds",
            "10",
            "--quiet",
            "--out",
            str(out),
        ]
    )
    assert code == 0
    for name in (
        "sweep.csv",
        "sweep.md",
        "cells/cycle_6_centralized.npz",
        "convergence_time.png",
        "ratio_to_lower_bound.png",
    ):
        assert (out / name).is_file(), name
    rows = list(csv.DictReader((out / "sweep.csv").read_text().splitlines()))
    assert {(row["topology"], row["controller"]) for row in rows} == {
        ("cycle", "local_consensus"),
        ("cycle", "centralized"),
        ("random", "local_consensus"),
        ("random", "centralized"),
    }
    assert all(float(row["success_rate"]) == 1.0 for row in rows)
    # a second run reuses the cached cells: a cell whose saved times are changed on disk shows the
    # changed times (a sweep that ignored its cache would recompute the original ones)
    table = (out / "sweep.md").read_text()
    cell_file = out / "cells" / "cycle_6_local_consensus.npz"
    with np.load(cell_file) as saved:
        arrays = {name: saved[name] for name in saved.files}
    arrays["times_s"] = np.full_like(arrays["times_s"], 123.45)
    np.savez_compressed(cell_file, **arrays)
    assert (
        main(
            [
                "sweep",
                "--topologies",
                "cycle",
                "random",
                "--sizes",
                "6",
                "--seeds",
                "10",
                "--quiet",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    changed = (out / "sweep.md").read_text()
    cycle_rows = [line for line in changed.splitlines() if line.startswith("| cycle | 6 | local_consensus")]
    assert len(cycle_rows) == 1 and "| 123.45 |" in cycle_rows[0], cycle_rows
    others = [line for line in changed.splitlines() if not line.startswith("| cycle | 6 | local_consensus")]
    assert others == [
        line for line in table.splitlines() if not line.startswith("| cycle | 6 | local_consensus")
    ]


def test_sweep_bad_input_is_one_line_and_exit_2(tmp_path, capsys):
    config = tmp_path / "bad.yaml"
    config.write_text("seeds: 10\nnot_a_field: 3\n")
    assert main(["sweep", "--config", str(config), "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "not_a_field: unknown key" in err and str(config) in err
    assert main(["sweep", "--topologies", "hypercube", "--out", str(tmp_path / "y")]) == 2
    assert "unknown topology 'hypercube'" in capsys.readouterr().err
    assert not (tmp_path / "x").exists() and not (tmp_path / "y").exists()
