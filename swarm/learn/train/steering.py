"""The fit shared by the imitation of the learned task controllers (``capt_gnn``, ``lloyd_gnn``): the
torch form of ``swarm.sim.steering_mlp``'s MLP and eq. (1)'s polar loss.

The loss: ``1 - cos`` of the angle between the direction ``(a, b)`` and the label's (rows with a label
of length 0 add nothing), plus, where the speed is imitated, the squared error of ``clip(c, 0, 1)``
against the label's speed (its length over ``v_max min(rho_n, 1)``, at most 1). The third feature is
always the gate ``min(rho_n, 1)``.
"""

from __future__ import annotations

import numpy as np
import torch

from swarm.sim.steering_mlp import SteeringMlp


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
    features: torch.Tensor, output: torch.Tensor, labels: torch.Tensor, imitate_speed: bool = True
) -> torch.Tensor:
    """Eq. (1)'s speed and direction against the label's (module docstring); labels in units of v_max."""
    gate = features[:, 2]
    length = labels.norm(dim=-1)
    speed_label = torch.where(gate > 0, length / torch.clamp(gate, min=1e-9), torch.zeros_like(length))
    speed_loss = (torch.clamp(output[:, 2], 0.0, 1.0) - torch.clamp(speed_label, max=1.0)) ** 2
    cosine = (output[:, :2] * labels).sum(-1) / (output[:, :2].norm(dim=-1) * length + 1e-9)
    moving = (length > 1e-9).float()
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
) -> float:
    """``steps`` Adam steps on minibatches of ``batch_rows`` rows drawn with ``rng``; the mean loss."""
    x = torch.from_numpy(features).float()
    y = torch.from_numpy(labels / v_max_mps).float()
    total = 0.0
    for _ in range(steps):
        rows = torch.from_numpy(rng.integers(0, len(x), batch_rows))
        loss = polar_loss(x[rows], model(x[rows]), y[rows], imitate_speed)
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
        total += float(loss.detach())
    return total / max(steps, 1)
