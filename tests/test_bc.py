"""Behavioural cloning end to end: collect, train (both presets), export, CLI, and a gnn scenario run."""

from __future__ import annotations

import csv
import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from swarm.cli import main
from swarm.learn.data import collect, collect_config
from swarm.learn.train.bc import make_config, train
from swarm.learn.train.evaluate import compare, local_consensus
from swarm.sim.policy import load_policy


def quiet(config):
    return replace(config, progress=False)


@pytest.fixture(scope="module")
def small_data(tmp_path_factory):
    path = tmp_path_factory.mktemp("data") / "bc.npz"
    collect(collect_config(samples=20_000, sizes=(4, 6), hops=3, seed=1), progress=False).save(path)
    return path


@pytest.mark.slow
def test_default_recipe_trains_and_exports(small_data, tmp_path):
    config = make_config("default", {"data": str(small_data), "out": str(tmp_path / "run"), "epochs": 3})
    policy_path = train(quiet(config))
    run = tmp_path / "run"
    for name in ("log.csv", "curve.png", "config.json", "checkpoints/best.pt", "checkpoints/last.pt"):
        assert (run / name).is_file(), name
    rows = list(csv.DictReader((run / "log.csv").read_text().splitlines()))
    assert len(rows) == 3 and float(rows[-1]["train_loss"]) < float(rows[0]["train_loss"])
    policy = load_policy(policy_path)
    assert policy.kind == "gnn" and policy.spec.hops == 3
    assert policy.metadata["training"]["algo"] == "bc"


@pytest.mark.slow
def test_thesis_preset_and_seeding(small_data, tmp_path):
    overrides = {"data": str(small_data), "epochs": 1, "batch_size": 256}
    first = train(quiet(make_config("thesis", {**overrides, "out": str(tmp_path / "a")})))
    second = train(quiet(make_config("thesis", {**overrides, "out": str(tmp_path / "b")})))
    a, b = load_policy(first), load_policy(second)
    assert a.kind == "two_branch" and a.spec.hops == 2
    features = np.random.default_rng(0).normal(size=(50, 2, 2))
    np.testing.assert_array_equal(a.forward(features), b.forward(features))
    saved = torch.load(tmp_path / "a" / "checkpoints" / "last.pt", weights_only=False)
    assert saved["bc_config"]["optimizer"] == "sgd" and saved["bc_config"]["lr"] == 0.01


def test_bad_options(small_data):
    with pytest.raises(ValueError, match="unknown bc option"):
        make_config("default", {"data": str(small_data), "learning_rate": 1})
    with pytest.raises(ValueError, match="no such file"):
        make_config("default", {"data": "missing.npz"})


@pytest.mark.slow
def test_cli_collect_train_and_run_a_gnn_scenario(tmp_path, capsys):
    data = tmp_path / "bc.npz"
    assert (
        main(["collect", "--samples", "8000", "--sizes", "5", "--hops", "2", "--out", str(data), "--quiet"])
        == 0
    )
    config = tmp_path / "bc.yaml"
    config.write_text(yaml.safe_dump({"data": str(data), "epochs": 2, "progress": False}))
    assert main(["train", "--algo", "bc", "--config", str(config), "--out", str(tmp_path / "run")]) == 0
    model = tmp_path / "run" / "policy.npz"
    assert model.is_file()
    out = tmp_path / "gnn-run"
    status = main(
        [
            "run",
            "scenarios/thesis/cycle-local_consensus.yaml",
            "--controller",
            "gnn",
            "--model",
            str(model),
            "--duration",
            "3",
            "--out",
            str(out),
            "--quiet",
        ]
    )
    assert status in (0, 1)  # ran (whether 3 s sufficed is not the point here)
    outcome = json.loads((out / "metrics.json").read_text())
    assert outcome["controller"] == "gnn" and outcome["initial_metric"] > outcome["final_metric"]
    assert (
        main(["run", "scenarios/thesis/cycle-local_consensus.yaml", "--model", "no-such.npz", "--quiet"]) == 2
    )
    assert "model file not found" in capsys.readouterr().err


def test_shipped_model_beats_local_consensus_on_sparse_graphs():
    """models/gnn_bc.npz (default recipe, N <= 12): every start converges, never slower than local
    consensus on the complete graph, faster on the line (simulated seconds, same starts)."""
    model = Path(__file__).resolve().parent.parent / "models" / "gnn_bc.npz"
    controllers = {"lc": local_consensus, "gnn": lambda robot, count: load_policy(model, robot, count)}
    rows = {
        (row["topology"], row["controller"]): row
        for row in compare(controllers, ["complete", "line"], [8], seeds=8, max_duration_s=300.0)
    }
    assert all(row["success_rate"] == 1.0 for row in rows.values())
    assert rows["complete", "gnn"]["median_ratio_to_first"] <= 1.05
    assert rows["line", "gnn"]["median_ratio_to_first"] < 0.7
