"""What every torch policy model shares: feature/output scaling, export, and the controller forms.

A model maps robot-frame features ``(..., K, 2)`` in metres (``swarm.sim.features``) to the wished
robot-frame velocity of the controlled point in m/s: ``output_scale_mps * network(x / feature_scale_m)``.
The robot then saturates it (``swarm.sim.features.saturate_local_velocity``) and rotates it to the world.
"""

from __future__ import annotations

from collections.abc import Callable
from itertools import pairwise
from pathlib import Path

import numpy as np
import torch
from torch import nn

from swarm.core.robot import RobotParams
from swarm.sim.features import FeatureSpec
from swarm.sim.policy import FeatureController, save_policy

ACTIVATIONS: dict[str, Callable[[torch.Tensor], torch.Tensor]] = {
    "relu": nn.functional.relu,
    "tanh": torch.tanh,
}


def mlp(layers: nn.ModuleList, x: torch.Tensor, activation, final_activation: bool = False) -> torch.Tensor:
    """Linear layers with ``activation`` between them (and after the last one if asked)."""
    for index, layer in enumerate(layers):
        x = layer(x)
        if final_activation or index < len(layers) - 1:
            x = activation(x)
    return x


def saturate(u_local: torch.Tensor, robot: RobotParams) -> torch.Tensor:
    """Torch twin of ``swarm.sim.features.saturate_local_velocity`` (``|ux| + (d/l)|uy| <= v_max``)."""
    largest = u_local[..., 0].abs() + (robot.half_axle_m / robot.offset_m) * u_local[..., 1].abs()
    return u_local * torch.clamp(robot.v_max_mps / largest.clamp_min(1e-12), max=1.0)[..., None]


def linears(widths: list[int], bias: bool = True) -> nn.ModuleList:
    return nn.ModuleList(nn.Linear(a, b, bias=bias) for a, b in pairwise(widths))


class PolicyModel(nn.Module):
    """Base class: subclasses set ``kind`` and implement ``network`` and ``architecture``."""

    kind: str = ""
    activation: str = "relu"

    def __init__(self, spec: FeatureSpec, feature_scale_m: float = 1.0, output_scale_mps: float = 0.5):
        super().__init__()
        self.spec = spec
        self.feature_scale_m = float(feature_scale_m)
        self.output_scale_mps = float(output_scale_mps)

    def network(self, x: torch.Tensor) -> torch.Tensor:
        """Scaled features ``(..., K, 2)`` -> normalised robot-frame output ``(..., 2)``."""
        raise NotImplementedError

    def architecture(self) -> dict:
        """Everything ``swarm.learn.models.build_model`` and ``swarm.sim.policy`` need besides the weights."""
        return {"kind": self.kind, "activation": self.activation}

    def forward(self, features_local_m: torch.Tensor) -> torch.Tensor:
        return self.output_scale_mps * self.network(features_local_m / self.feature_scale_m)

    def config(self) -> dict:
        return {
            "model": self.architecture(),
            "features": self.spec.to_dict(),
            "feature_scale_m": self.feature_scale_m,
            "output_scale_mps": self.output_scale_mps,
        }

    def export(self, path: str | Path, robot: RobotParams, training: dict | None = None) -> Path:
        """Write the one-file policy that ``swarm.sim.policy.Policy`` runs with numpy alone."""
        arrays = {name: value.detach().cpu().numpy() for name, value in self.state_dict().items()}
        metadata = {**self.config(), "robot": robot.model_dump(), "training": training or {}}
        return save_policy(path, metadata, arrays)

    def controller(self, robot: RobotParams, robot_count: int = 0) -> TorchController:
        """This model as a batched and per-robot controller (runs in ``KinematicSim``)."""
        return TorchController(self, robot, robot_count)


class TorchController(FeatureController):
    """``swarm.sim.policy.FeatureController`` with the torch model as ``forward`` (in the model's dtype)."""

    def __init__(self, model: PolicyModel, robot: RobotParams, robot_count: int = 0):
        super().__init__(model.spec, robot, robot_count)
        self.model = model

    def forward(self, features_local: np.ndarray) -> np.ndarray:
        dtype = next(self.model.parameters()).dtype
        with torch.no_grad():
            return self.model(torch.as_tensor(np.asarray(features_local), dtype=dtype)).double().numpy()
