"""Learnable delayed-aggregation graph filters (Tolstaya et al. 2019; Gama et al. 2020), shared by all robots.

Robot i diffuses the controlled points over its graph, one hop per tick, degree-normalised
(``swarm.sim.features``, ``phi_source="m"``): its hop-k aggregate is k ticks old, and
``f_k = Phi1 + ... + Phik`` is the robot-frame offset from its own point to the average point of
its k-hop neighbourhood (f_1 = M, eq. 3.4-3.5). Each robot's message is its point and its
hop-1..K-1 aggregates (``2K`` numbers); the model runs for any N and any graph.

``GatedGraphFilter`` (kind ``gnn``, the default) learns the filter taps as gains that depend on
the situation::

    z = invariants of (f_1..f_K)                  norms |f_k| and cosines between them
    (a, b_1..b_K) = MLP(z)                        hidden width, tanh
    G = g_min + (g_max - g_min) sigmoid(a)        total gain, 1/s
    w = w_1min e_1 + (1 - w_1min) softmax(b)      per-hop weights, a convex combination
    u = G sum_k w_k f_k                           robot-frame point velocity (then saturated)

so every robot heads for a learned convex combination of its neighbourhood averages. Built in:
``u(0) = 0`` (consensus is an equilibrium); rotation- and mirror-equivariance (z is invariant,
the f_k rotate with the frame); and, with ``g_max dt <= 1``, one tick never carries a robot past
its target point, a convex combination of (delayed) positions of the swarm, with a weight of at
least ``g_min dt w_1min`` on its neighbours: the convex-combination consensus with bounded delays
that converges on every connected graph (Blondel et al. 2005), whatever the weights learned.
The robot's saturation shortens ``u`` without turning it, so it keeps that property. Far from
consensus the learned G is large and the robot runs at full speed, like the expert.

``MLPGraphFilter`` (kind ``gnn_mlp``) is the plain filter with a readout MLP,
``u = readout(tanh(sum_k f_k W_k))``, odd (tanh, no biases: ``u(0) = 0``) and symmetrised about
the heading axis; it has none of the guarantees above (kept for comparison).
"""

from __future__ import annotations

import math

import torch
from torch import nn

from swarm.learn.models.base import ACTIVATIONS, PolicyModel, linears, mlp
from swarm.sim.features import FeatureSpec

MIRROR = (1.0, -1.0)
COSINE_EPS_M = 1e-3  # regularises the cosine of two near-zero offsets


def hop_invariants(f: torch.Tensor, scale_m: float) -> torch.Tensor:
    """``(..., K, 2)`` offsets -> ``(..., K + K(K-1)/2)``: ``|f_k| / scale`` and the cosines ``f_j . f_k``."""
    squared = (f * f).sum(-1) + COSINE_EPS_M**2
    norms = torch.sqrt(squared)
    rows, cols = torch.triu_indices(f.shape[-2], f.shape[-2], offset=1)
    dots = (f[..., rows, :] * f[..., cols, :]).sum(-1)
    cosines = dots / (norms[..., rows] * norms[..., cols])
    return torch.cat([norms / scale_m, cosines], dim=-1)


class GatedGraphFilter(PolicyModel):
    kind = "gnn"
    activation = "tanh"
    first_hop: torch.Tensor  # buffer

    def __init__(
        self,
        spec: FeatureSpec,
        hidden: int = 64,
        layers: int = 2,
        gain_min_per_s: float = 0.5,
        gain_max_per_s: float = 20.0,
        hop1_weight_min: float = 0.1,
        **scales: float,
    ):
        if spec.phi_source != "m" or spec.normaliser != "degree":
            raise ValueError("the graph filter diffuses the points: features need phi_source 'm', degree")
        super().__init__(spec, **scales)
        self.hidden, self.layers = hidden, layers
        self.gain_min_per_s, self.gain_max_per_s = gain_min_per_s, gain_max_per_s
        self.hop1_weight_min = hop1_weight_min
        k = spec.hops
        self.gates = linears([k + k * (k - 1) // 2] + [hidden] * layers + [1 + k])
        first = torch.zeros(k)
        first[0] = 1.0
        self.register_buffer("first_hop", first, persistent=False)

    def gains(self, f: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Total gain G (1/s) ``(...)`` and hop weights w ``(..., K)`` for the offsets ``f (..., K, 2)``."""
        out = mlp(self.gates, hop_invariants(f, self.feature_scale_m), torch.tanh)
        gain = self.gain_min_per_s + (self.gain_max_per_s - self.gain_min_per_s) * torch.sigmoid(out[..., 0])
        hop_weights = torch.softmax(out[..., 1:], dim=-1)
        return gain, self.hop1_weight_min * self.first_hop + (1 - self.hop1_weight_min) * hop_weights

    def forward(self, features_local_m: torch.Tensor) -> torch.Tensor:
        f = torch.cumsum(features_local_m, dim=-2)
        gain, weights = self.gains(f)
        return gain[..., None] * (weights[..., None] * f).sum(-2)

    def architecture(self) -> dict:
        return {
            **super().architecture(),
            "hidden": self.hidden,
            "layers": self.layers,
            "gain_min_per_s": self.gain_min_per_s,
            "gain_max_per_s": self.gain_max_per_s,
            "hop1_weight_min": self.hop1_weight_min,
        }


class MLPGraphFilter(PolicyModel):
    kind = "gnn_mlp"
    activation = "tanh"
    mirror: torch.Tensor  # buffer

    def __init__(
        self,
        spec: FeatureSpec,
        hidden: int = 64,
        readout: tuple[int, ...] | list[int] = (64,),
        odd: bool = True,
        symmetrize: bool = True,
        **scales: float,
    ):
        if spec.phi_source != "m":
            raise ValueError("the graph filter diffuses the points: features need phi_source 'm'")
        super().__init__(spec, **scales)
        self.hidden, self.readout_widths = hidden, list(readout)
        self.odd, self.symmetrize = odd, symmetrize
        bound = math.sqrt(6.0 / (2 * spec.hops + hidden))  # Xavier uniform over the K taps together
        self.hop_maps = nn.Parameter(torch.empty(spec.hops, 2, hidden).uniform_(-bound, bound))
        self.hop_bias = None if odd else nn.Parameter(torch.zeros(hidden))
        self.readout = linears([hidden, *self.readout_widths, 2], bias=not odd)
        self.register_buffer("mirror", torch.tensor(MIRROR), persistent=False)

    def _filter(self, x: torch.Tensor) -> torch.Tensor:
        act = ACTIVATIONS[self.activation]
        f = torch.cumsum(x, dim=-2)
        hidden = f.flatten(-2) @ self.hop_maps.flatten(0, 1)  # sum_k f_k W_k
        if self.hop_bias is not None:
            hidden = hidden + self.hop_bias
        return mlp(self.readout, act(hidden), act)

    def network(self, x: torch.Tensor) -> torch.Tensor:
        if not self.symmetrize:
            return self._filter(x)
        return 0.5 * (self._filter(x) + self._filter(x * self.mirror) * self.mirror)

    def architecture(self) -> dict:
        return {
            **super().architecture(),
            "hidden": self.hidden,
            "readout": self.readout_widths,
            "odd": self.odd,
            "symmetrize": self.symmetrize,
        }
