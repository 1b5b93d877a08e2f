"""Torch policy models: the thesis's MLPs and the delayed-aggregation graph-filter GNN.

``build_model(config)`` rebuilds a model from ``model.config()`` (what checkpoints store);
``model.export(path, robot)`` writes the one-file policy that ``swarm.sim.policy`` runs without torch.
"""

from __future__ import annotations

from pathlib import Path

import torch

from swarm.learn.models.base import PolicyModel, TorchController
from swarm.learn.models.flood import KIND as FLOOD_KIND
from swarm.learn.models.flood import FloodGNN, build_flood
from swarm.learn.models.gnn import GatedGraphFilter, MLPGraphFilter
from swarm.learn.models.thesis import Model1, Model2, TwoBranch
from swarm.sim.features import FeatureSpec

MODELS: dict[str, type[PolicyModel]] = {
    "model1": Model1,
    "model2": Model2,
    "two_branch": TwoBranch,
    "gnn": GatedGraphFilter,
    "gnn_mlp": MLPGraphFilter,
}

__all__ = [
    "MODELS",
    "FloodGNN",
    "GatedGraphFilter",
    "MLPGraphFilter",
    "Model1",
    "Model2",
    "PolicyModel",
    "TorchController",
    "TwoBranch",
    "build_model",
    "load_checkpoint",
]


def build_model(config: dict) -> PolicyModel | FloodGNN:
    """A fresh model from ``{"model": {"kind", ...architecture}, "features", "feature_scale_m",
    "output_scale_mps"}`` (``PolicyModel.config()``; ``gnn_flood``: ``FloodGNN.config()``)."""
    if config["model"]["kind"] == FLOOD_KIND:
        return build_flood(config)
    architecture = dict(config["model"])
    kind = architecture.pop("kind")
    if kind not in MODELS:
        raise ValueError(f"unknown model kind {kind!r}; choose one of {sorted(MODELS)}")
    architecture.pop("activation", None)
    scales = {key: config[key] for key in ("feature_scale_m", "output_scale_mps") if key in config}
    return MODELS[kind](FeatureSpec.from_dict(config["features"]), **architecture, **scales)


def load_checkpoint(path: str | Path) -> tuple[PolicyModel | FloodGNN, dict]:
    """A model and the checkpoint dictionary saved by ``swarm.learn.train``."""
    checkpoint = torch.load(path, map_location="cpu", weights_only=False)
    model = build_model(checkpoint["model_config"])
    model.load_state_dict(checkpoint["model"])
    return model, checkpoint
