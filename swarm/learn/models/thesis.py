"""The thesis's three MLPs (chapter 3.2, appendices A and B), ReLU, biases, robot-frame in and out.

- ``Model1`` (appendix A, "2-4-2"): ``M -> U``.
- ``Model2`` (appendix B, "4-8-2"): ``[M, Phi] -> U``.
- ``TwoBranch`` (Fig. 3.1, the final "ensembled" model): M and Phi in separate branches
  (the thesis "decoupled the two inputs"), concatenated into a small linear head. The figure gives
  no widths: each branch is 2 -> ``branch_width`` with ReLU, the head ``2 branch_width -> 2``.

Features ``M`` and ``Phi`` are eq. 3.4-3.7 (``swarm.sim.features``, hops 1 and 2).
"""

from __future__ import annotations

import torch

from swarm.learn.models.base import ACTIVATIONS, PolicyModel, linears, mlp
from swarm.sim.features import FeatureSpec


class Model1(PolicyModel):
    kind = "model1"

    def __init__(self, spec: FeatureSpec, hidden: int = 4, **scales: float):
        super().__init__(spec, **scales)
        self.hidden = hidden
        self.net = linears([2, hidden, 2])

    def network(self, x: torch.Tensor) -> torch.Tensor:
        return mlp(self.net, x[..., 0, :], ACTIVATIONS[self.activation])

    def architecture(self) -> dict:
        return {**super().architecture(), "hidden": self.hidden}


class Model2(PolicyModel):
    kind = "model2"

    def __init__(self, spec: FeatureSpec, hidden: int = 8, **scales: float):
        if spec.hops < 2:
            raise ValueError("model2 needs M and Phi: features with hops >= 2")
        super().__init__(spec, **scales)
        self.hidden = hidden
        self.net = linears([4, hidden, 2])

    def network(self, x: torch.Tensor) -> torch.Tensor:
        return mlp(self.net, x[..., :2, :].flatten(-2), ACTIVATIONS[self.activation])

    def architecture(self) -> dict:
        return {**super().architecture(), "hidden": self.hidden}


class TwoBranch(PolicyModel):
    kind = "two_branch"

    def __init__(self, spec: FeatureSpec, branch_width: int = 4, **scales: float):
        if spec.hops < 2:
            raise ValueError("two_branch needs M and Phi: features with hops >= 2")
        super().__init__(spec, **scales)
        self.branch_width = branch_width
        self.m_branch = linears([2, branch_width])
        self.phi_branch = linears([2, branch_width])
        self.head = linears([2 * branch_width, 2])

    def network(self, x: torch.Tensor) -> torch.Tensor:
        act = ACTIVATIONS[self.activation]
        m = mlp(self.m_branch, x[..., 0, :], act, final_activation=True)
        phi = mlp(self.phi_branch, x[..., 1, :], act, final_activation=True)
        return mlp(self.head, torch.cat([m, phi], dim=-1), act)

    def architecture(self) -> dict:
        return {**super().architecture(), "branch_width": self.branch_width}
