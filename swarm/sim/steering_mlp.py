"""A learned steering readout: a small tanh MLP from a robot's features to its point velocity (numpy).

The learned task controllers (``capt_gnn``: ``swarm.sim.formation_gnn``; ``lloyd_gnn``:
``swarm.sim.coverage_gnn``) keep a hand-built message and aggregation (a flood) and learn only this
readout. Each has features ``f`` whose first three are, in the robot's own frame, the unit direction
to the target its aggregation computed and the gate ``min(rho / (v_max T), 1)`` (``rho`` the distance
to it). The MLP ``g`` (tanh between layers, 3 outputs ``(a, b, c)``) gives the point velocity::

    u_local = v_max min(rho_n, 1) s (a, b) / |(a, b)|,   s = 1, or clip(c, 0, 1) ("imitated" speed)   (1)

The gate makes the command vanish on the target at every scale (the experts' ``drive_toward_velocity``
has the same factor); ``(a, b)`` is the direction, reversal included. The robot's wheels saturate (1)
as every controller's do.

Policy file: ``.npz`` with ``format`` (the controller's ``FORMAT``), ``layers`` (their count),
``w<k>``/``b<k>`` and ``meta`` (JSON: the training configuration and data; ``meta["speed"]`` chooses
``s``).
"""

from __future__ import annotations

import io
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from swarm.core.robot import RobotParams


class PolicyFileError(ValueError):
    """A file that is not a policy of the expected kind (names the reason)."""


@dataclass(frozen=True)
class SteeringMlp:
    """The MLP ``g`` of eq. (1): ``weights[k] (in, out)``, ``biases[k] (out,)``; tanh between layers.

    A learned controller subclasses it with its file ``FORMAT``, its ``FEATURES`` (names, in order) and
    ``KIND`` (the controller kind, for error messages)."""

    weights: tuple[np.ndarray, ...]
    biases: tuple[np.ndarray, ...]
    meta: dict = field(default_factory=dict)

    FORMAT: ClassVar[str] = ""
    FEATURES: ClassVar[tuple[str, ...]] = ()
    KIND: ClassVar[str] = ""

    @classmethod
    def load(cls, source: str | Path | bytes):
        """From a policy file's path or bytes; :class:`PolicyFileError` naming what is wrong."""
        try:
            data = np.load(io.BytesIO(source) if isinstance(source, bytes) else source, allow_pickle=False)
        except (OSError, ValueError) as error:
            raise PolicyFileError(f"not a policy file ({error})") from None
        with data:
            found = str(data["format"]) if "format" in data.files else None
            if found != cls.FORMAT:
                raise PolicyFileError(f"format {found!r}, expected {cls.FORMAT!r} (a {cls.KIND} policy)")
            layers = int(data["layers"])
            weights = tuple(np.asarray(data[f"w{k}"], dtype=np.float64) for k in range(layers))
            biases = tuple(np.asarray(data[f"b{k}"], dtype=np.float64) for k in range(layers))
            meta = json.loads(str(data["meta"]))
        if weights[0].shape[0] != len(cls.FEATURES) or weights[-1].shape[1] != 3:
            raise PolicyFileError(
                f"layer shapes {[w.shape for w in weights]}: want {len(cls.FEATURES)} in, 3 out"
            )
        return cls(weights, biases, meta)

    def save(self, path: Path) -> None:
        arrays: dict[str, Any] = {
            "format": self.FORMAT,
            "layers": len(self.weights),
            "meta": json.dumps(self.meta),
        }
        arrays |= {f"w{k}": w for k, w in enumerate(self.weights)} | {
            f"b{k}": b for k, b in enumerate(self.biases)
        }
        np.savez(path, **arrays)

    def __call__(self, features: np.ndarray) -> np.ndarray:
        """``g(f)``: ``(..., len(FEATURES)) -> (..., 3)``."""
        hidden = np.asarray(features, dtype=np.float64)
        for k, (weight, bias) in enumerate(zip(self.weights, self.biases, strict=True)):
            hidden = hidden @ weight + bias
            if k < len(self.weights) - 1:
                hidden = np.tanh(hidden)
        return hidden


def target_features(
    poses: np.ndarray, targets: np.ndarray, robot: RobotParams, control_period_s: float
) -> tuple[np.ndarray, np.ndarray]:
    """Eq. (1)'s first three features ``(..., 3)`` (unit direction to the target in the robot's frame,
    the gate) and the gate ``min(rho_n, 1)`` ``(...)``, from poses ``(..., 3)`` and targets ``(..., 2)``."""
    theta = poses[..., 2]
    cos, sin = np.cos(theta), np.sin(theta)
    delta = targets - poses[..., :2]
    local_x = cos * delta[..., 0] + sin * delta[..., 1]
    local_y = -sin * delta[..., 0] + cos * delta[..., 1]
    rho = np.sqrt(local_x * local_x + local_y * local_y)
    safe = np.where(rho > 0.0, rho, 1.0)
    gate = np.minimum(rho / (robot.v_max_mps * control_period_s), 1.0)
    return np.stack([local_x / safe, local_y / safe, gate], axis=-1), gate


def local_command(
    weights: SteeringMlp, features: np.ndarray, gate: np.ndarray, v_max_mps: float
) -> np.ndarray:
    """Eq. (1): ``u_local = v_max min(rho_n, 1) s (a, b) / |(a, b)|`` ``(..., 2)``, before the wheels
    saturate (a zero direction ``(a, b)`` gives no command)."""
    output = weights(features)
    direction = output[..., :2]
    norm = np.sqrt((direction * direction).sum(-1))
    unit = direction / np.where(norm > 0.0, norm, 1.0)[..., None]
    speed = np.clip(output[..., 2], 0.0, 1.0) if weights.meta.get("speed") == "imitated" else 1.0
    return (v_max_mps * gate * speed)[..., None] * unit


def to_world(poses: np.ndarray, u_local: np.ndarray) -> np.ndarray:
    """The robot-frame point velocity in the world frame."""
    cos, sin = np.cos(poses[..., 2]), np.sin(poses[..., 2])
    return np.stack(
        [cos * u_local[..., 0] - sin * u_local[..., 1], sin * u_local[..., 0] + cos * u_local[..., 1]], -1
    )
