"""What the imitation of the learned task controllers (``capt_gnn``, ``lloyd_gnn``) shares: the torch
form of ``swarm.sim.steering_mlp``'s MLP, eq. (1)'s polar loss, the fit and the DAgger loop
(:func:`dagger`); each task's module has its configuration, episodes and closed-loop check.

The loss: ``1 - cos`` of the angle between the direction ``(a, b)`` and the label's (rows with a label
of length 0 add nothing), plus, where the speed is imitated, the squared error of ``clip(c, 0, 1)``
against the label's speed (its length over ``v_max min(rho_n, 1)``, at most 1). The third feature is
always the gate ``min(rho_n, 1)``. With ``weighted`` the ``1 - cos`` of a row counts in proportion to
``gate * |label|``: at the command's fixed speed ``v = v_max gate`` the squared velocity error is
``|u - u*|^2 = v^2 + |u*|^2 - 2 v |u*| cos``, so that weighting minimises it; unweighted, a row whose
label is a millimetre's move (a robot at its fixed point) pulls the direction as hard as one at full
speed.
"""

from __future__ import annotations

import csv
import json
import logging
import time
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np
import torch

from swarm.sim.steering_mlp import SteeringMlp

log = logging.getLogger(__name__)


class Mlp(torch.nn.Module):
    """``inputs -> hidden -> hidden -> 3``, tanh between layers (``SteeringMlp``'s form)."""

    def __init__(self, inputs: int, hidden: int):
        super().__init__()
        self.linears: list[torch.nn.Linear] = [
            torch.nn.Linear(inputs, hidden),
            torch.nn.Linear(hidden, hidden),
            torch.nn.Linear(hidden, 3),
        ]
        self.layers = torch.nn.ModuleList(self.linears)
        with torch.no_grad():  # the speed starts at half (a clipped output at 0 or 1 passes no gradient)
            self.linears[-1].bias[2] = 0.5

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        hidden = features
        for k, layer in enumerate(self.linears):
            hidden = layer(hidden)
            if k < len(self.linears) - 1:
                hidden = torch.tanh(hidden)
        return hidden

    def export(self, weights_class: type[SteeringMlp], meta: dict):
        return weights_class(
            tuple(layer.weight.detach().double().numpy().T.copy() for layer in self.linears),
            tuple(layer.bias.detach().double().numpy().copy() for layer in self.linears),
            meta,
        )


def polar_loss(
    features: torch.Tensor,
    output: torch.Tensor,
    labels: torch.Tensor,
    imitate_speed: bool = True,
    weighted: bool = False,
) -> torch.Tensor:
    """Eq. (1)'s speed and direction against the label's (module docstring); labels in units of v_max."""
    gate = features[:, 2]
    length = labels.norm(dim=-1)
    speed_label = torch.where(gate > 0, length / torch.clamp(gate, min=1e-9), torch.zeros_like(length))
    speed_loss = (torch.clamp(output[:, 2], 0.0, 1.0) - torch.clamp(speed_label, max=1.0)) ** 2
    cosine = (output[:, :2] * labels).sum(-1) / (output[:, :2].norm(dim=-1) * length + 1e-9)
    moving = (length > 1e-9).float()
    if weighted:  # the squared velocity error's share that the direction decides (module docstring)
        weight = gate * length * moving
        direction_loss = (weight * (1.0 - cosine)).sum() / torch.clamp(weight.sum(), min=1e-9)
        return (speed_loss.mean() if imitate_speed else 0.0) + direction_loss
    return ((speed_loss if imitate_speed else 0.0) + moving * (1.0 - cosine)).mean()


def fit(
    model: Mlp,
    optimiser,
    features: np.ndarray,
    labels: np.ndarray,
    *,
    steps: int,
    batch_rows: int,
    v_max_mps: float,
    imitate_speed: bool,
    rng: np.random.Generator,
    weighted: bool = False,
) -> float:
    """``steps`` Adam steps on minibatches of ``batch_rows`` rows drawn with ``rng``; the mean loss."""
    x = torch.from_numpy(features).float()
    y = torch.from_numpy(labels / v_max_mps).float()
    total = 0.0
    for _ in range(steps):
        rows = torch.from_numpy(rng.integers(0, len(x), batch_rows))
        loss = polar_loss(x[rows], model(x[rows]), y[rows], imitate_speed, weighted)
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
        total += float(loss.detach())
    return total / max(steps, 1)


def dagger(
    config: Any,
    *,
    weights_class: type[SteeringMlp],
    meta: dict,
    episode: Callable[[Any, Any, float, str, int, np.random.Generator], tuple[np.ndarray, np.ndarray]],
    closed_loop: Callable[[Any, Any, int], float],
    score: str,
    references: tuple[str, ...],
    imitate_speed: bool,
    weighted: bool = False,
) -> Path:
    """DAgger imitation of a task's expert by its learned steering (``capt_gnn``, ``lloyd_gnn``).

    ``config`` (the algorithm's dataclass) gives ``out``, ``seed``, ``counts``, ``graphs``,
    ``iterations``, ``beta_decay``, ``hidden``, ``learning_rate``, ``steps``, ``batch_rows``,
    ``v_max_mps`` and ``progress``. Iteration 0 lets the expert drive everywhere, iteration i >= 1 in a
    share ``beta_decay ** i`` of the environments (``episode(config, weights, beta, graph, N, rng)``:
    rows of features and the expert's labels); every row so far is fitted (:func:`fit`), and each
    iterate checked by ``closed_loop(config, weights, seed)`` (lower is better; logged as ``score``,
    beside each kind of ``references`` on the same starts). The best iterate is ``<out>/policy.npz``;
    the log is ``<out>/log.csv``; ``weighted``: :func:`polar_loss`'s. Seeded: numpy and torch from
    ``seed``, torch on one thread."""
    out = Path(config.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "config.json").write_text(json.dumps(asdict(config), indent=2) + "\n")
    torch.manual_seed(config.seed)
    torch.set_num_threads(1)
    rng = np.random.default_rng(config.seed)
    model = Mlp(len(weights_class.FEATURES), config.hidden)
    optimiser = torch.optim.Adam(model.parameters(), lr=config.learning_rate)
    features: list[np.ndarray] = []
    labels: list[np.ndarray] = []
    best: tuple[float, Any] | None = None
    rows_log = []
    started_s = time.perf_counter()
    baselines = {kind: closed_loop(config, kind, config.seed + 1000) for kind in references}  # same starts
    for iteration in range(config.iterations):
        weights = model.export(weights_class, meta)
        beta = 1.0 if iteration == 0 else config.beta_decay**iteration
        # -- episodes: the expert or the learner drives, the expert labels every state
        for count in config.counts:
            for topology in config.graphs:
                new_features, new_labels = episode(config, weights, beta, topology, count, rng)
                features.append(new_features)
                labels.append(new_labels)
        all_features, all_labels = np.concatenate(features), np.concatenate(labels)
        # -- fit every row so far
        loss = fit(
            model,
            optimiser,
            all_features,
            all_labels,
            steps=config.steps,
            batch_rows=config.batch_rows,
            v_max_mps=config.v_max_mps,
            imitate_speed=imitate_speed,
            rng=rng,
            weighted=weighted,
        )
        # -- closed-loop check
        weights = model.export(weights_class, meta | {"iteration": iteration, "rows": len(all_features)})
        value = closed_loop(config, weights, config.seed + 1000)
        rows_log.append(
            {"iteration": iteration, "beta": beta, "rows": len(all_features), "loss": loss, score: value}
            | {f"{kind}_{score}": baseline for kind, baseline in baselines.items()}
            | {"elapsed_s": round(time.perf_counter() - started_s, 1)}
        )
        if config.progress:
            log.info("%s", json.dumps(rows_log[-1]))
        if best is None or value < best[0]:
            best = (value, weights)
    assert best is not None
    with (out / "log.csv").open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(rows_log[0]))
        writer.writeheader()
        writer.writerows(rows_log)
    path = out / "policy.npz"
    best[1].save(path)
    return path
