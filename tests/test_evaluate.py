"""Tests for ``swarm evaluate`` (swarm.scenarios.evaluate on swarm.scenarios.sweep), DAgger
(swarm.learn.train.dagger) and the shipped default model of controller ``gnn`` (models/gnn_default.npz)."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from swarm.cli import main
from swarm.learn.data import collect, collect_config
from swarm.learn.train import dagger
from swarm.scenarios import scenario as scenario_module
from swarm.scenarios.evaluate import CONTROLLER_ORDER
from swarm.scenarios.scenario import resolve_model_path
from swarm.scenarios.sweep import SweepConfig, connected, run_cell
from swarm.sim.policy import load_policy

PROJECT_ROOT = Path(__file__).resolve().parent.parent
DEFAULT_MODEL = PROJECT_ROOT / "models" / "gnn_default.npz"


@pytest.mark.slow
def test_evaluate_tiny_grid_shares_cells_with_sweep(tmp_path, capsys):
    sweep_dir, out = tmp_path / "sweep", tmp_path / "eval"
    assert (
        main(
            [
                "sweep",
                "--topologies",
                "cycle",
                "--sizes",
                "4",
                "--seeds",
                "6",
                "--out",
                str(sweep_dir),
                "--quiet",
            ]
        )
        == 0
    )
    grid = [
        "--topologies",
        "cycle",
        "disk",
        "--sizes",
        "4",
        "--seeds",
        "6",
        "--curve-sizes",
        "4",
        "--curve-starts",
        "3",
    ]
    assert (
        main(["evaluate", str(DEFAULT_MODEL), *grid, "--reuse", str(sweep_dir), "--out", str(out), "--quiet"])
        == 0
    )
    for name in ("evaluation.csv", "evaluation.md", "max_pairwise_N4.png", "ratio_to_lower_bound.png"):
        assert (out / name).is_file(), name
    rows = {(r["topology"], r["controller"]): r for r in csv.DictReader((out / "evaluation.csv").open())}
    assert len(rows) == 2 * len(CONTROLLER_ORDER)  # the model beside every baseline, on both graphs
    assert float(rows["cycle", "mec_flood"]["median_ratio_to_lower_bound"]) < float(
        rows["cycle", "local_consensus"]["median_ratio_to_lower_bound"]
    )
    assert float(rows["cycle", "local_consensus"]["median_ratio_to_local_consensus"]) == 1.0
    assert float(rows["cycle", "gnn"]["median_ratio_to_local_consensus"]) < 1.0  # faster on the cycle
    assert rows["disk", "gnn"]["disconnected_rate"] != "" and rows["cycle", "gnn"]["disconnected_rate"] == ""
    cells = sorted(path.name for path in (out / "cells").iterdir())
    # the cycle's local-consensus and centralized cells were read from the sweep, not rerun
    assert "cycle_4_local_consensus.npz" not in cells and "cycle_4_centralized.npz" not in cells
    assert "cycle_4_mec_flood.npz" in cells  # not in that sweep: run here
    assert any(name.startswith("cycle_4_gnn-") for name in cells)  # the model's cell, named by its hash

    # --limit cuts cached full cells to their first starts; the model's cell runs on those starts
    limited = tmp_path / "limited"
    argv = [
        "evaluate",
        str(DEFAULT_MODEL),
        "--topologies",
        "cycle",
        "--sizes",
        "4",
        "--seeds",
        "6",
        "--limit",
        "4:3",
    ]
    argv += ["--curve-sizes", "9", "--reuse", str(out), str(sweep_dir), "--out", str(limited), "--quiet"]
    assert main(argv) == 0
    first = {r["controller"]: r for r in csv.DictReader((limited / "evaluation.csv").open())}
    assert {r["starts"] for r in first.values()} == {"3"}
    assert not (limited / "cells").exists()  # every cell cut from the cached full ones
    full = np.load(next((out / "cells").glob("cycle_4_gnn-*.npz")))["times_s"]
    config = SweepConfig(seeds=6, first_starts=3, controllers=["gnn"], model=str(DEFAULT_MODEL))
    np.testing.assert_allclose(run_cell(config, "cycle", 4, "gnn")["times_s"], full[:3])  # same starts
    # a limit for one topology leaves the others whole
    argv[argv.index("4:3")] = "disk:4:3"
    argv[argv.index("--topologies") + 1 : argv.index("--topologies") + 2] = ["cycle", "disk"]
    argv[argv.index(str(limited))] = str(tmp_path / "per_topology")
    assert main(argv) == 0
    rows = list(csv.DictReader((tmp_path / "per_topology" / "evaluation.csv").open()))
    assert {(r["topology"], r["starts"]) for r in rows} == {("cycle", "6"), ("disk", "3")}
    assert main(["evaluate", str(tmp_path / "none.npz"), "--out", str(tmp_path / "x")]) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1


def test_disconnection_is_recorded_on_disk_graphs():
    two_pairs = np.zeros((1, 4, 4))
    two_pairs[0, 0, 1] = two_pairs[0, 1, 0] = two_pairs[0, 2, 3] = two_pairs[0, 3, 2] = 1
    chain = np.zeros((1, 4, 4))
    for i in range(3):
        chain[0, i, i + 1] = chain[0, i + 1, i] = 1
    assert connected(np.concatenate([two_pairs, chain])).tolist() == [False, True]
    # a radius just under the connecting one disconnects every start at once
    cell = run_cell(SweepConfig(seeds=4, disk_radius_m=0.3, max_duration_s=5.0), "disk", 6, "local_consensus")
    assert cell["disconnected"].all()


@pytest.mark.slow
def test_dagger_tiny_run_writes_outputs_and_a_loadable_policy(tmp_path):
    data = collect(collect_config(samples=3000, graphs=("cycle",), sizes=(4,)), progress=False).save(
        tmp_path / "d.npz"
    )
    config = tmp_path / "dagger.yaml"
    config.write_text(
        yaml.safe_dump(
            {
                "iterations": 1,
                "samples_per_iteration": 2000,
                "bc": {"epochs": 1, "batch_size": 512},
                "eval_seeds": 2,
                "eval_cells": [["cycle", 4]],
                "eval_max_duration_s": 60,
                "progress": False,
            }
        )
    )
    out = tmp_path / "dagger"
    argv = ["train", "--algo", "dagger", "--data", str(data), "--config", str(config), "--out", str(out)]
    assert main(argv) == 0
    log = list(csv.DictReader((out / "log.csv").open()))
    assert [row["iteration"] for row in log] == ["0", "1"] and float(log[1]["beta"]) == 0.5
    assert int(log[1]["samples"]) == 5000  # aggregated: 3000 expert + 2000 from the mixture
    for name in ("curve.png", "data.npz", "iter_1/checkpoints/last.pt", "iter_1/policy.npz"):
        assert (out / name).is_file(), name
    policy = load_policy(out / "policy.npz")
    assert policy.metadata["training"]["algo"] == "dagger"
    u, message = policy.act_one(np.array([0.0, 0.0, 0.3]), np.ones((2, policy.message_dim)))
    assert np.isfinite(u).all() and message.shape == (policy.message_dim,)
    assert dagger.make_config("default", {"data": str(data)}).iterations >= 1


def test_gnn_without_model_runs_the_shipped_default(tmp_path):
    assert resolve_model_path(None) == DEFAULT_MODEL
    source = PROJECT_ROOT / "scenarios" / "thesis" / "cycle-gnn.yaml"
    assert "model" not in yaml.safe_load(source.read_text())["controller"]
    out = tmp_path / "run"
    assert (
        main(["run", str(source), "--engine", "kinematic", "--duration", "5.5", "--out", str(out), "--quiet"])
        == 0
    )
    assert json.loads((out / "metrics.json").read_text())["controller"] == "gnn"


def test_missing_default_model_is_one_line_and_exit_2(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(scenario_module, "DEFAULT_MODEL_NAME", "no_such_model.npz")
    source = PROJECT_ROOT / "scenarios" / "thesis" / "cycle-gnn.yaml"
    assert main(["run", str(source), "--engine", "kinematic", "--out", str(tmp_path / "r"), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "default model" in err[0] and "no_such_model.npz" in err[0]
