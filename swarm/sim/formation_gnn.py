"""The learned formation controller ``capt_gnn``: ``capt_flood``'s messages, a learned steering (numpy).

Information and aggregation are ``capt_flood``'s (``swarm.sim.formation_controllers``): every robot
floods the initial axle positions it knows (``N x (known, x, y)``, a union: the max-aggregation GNN
layer of ``capt_flood``, idempotent under loss and repetition) and, each time that set grows, computes
the CAPT assignment of the robots it knows to all N slots. From that a robot has, in its own frame:

- ``r``: the vector from its axle to its provisional slot; ``rho = |r|``, ``rho_n = rho / (v_max T)``;
- ``sync = d_i0 / D_0`` (at most 1): its own start-to-slot distance over the largest among the robots
  it knows, the time-synchronization factor of the expert (in the holonomic limit ``d_i(t) / D(t)``
  is constant, so the robot can compute the expert's speed ratio from the starts alone);
- ``known``: the fraction of the N robots it knows (1 once the flood has reached it from everyone).

Features ``f = (r_x / rho, r_y / rho, min(rho_n, 1), sync, known)`` and a tanh MLP ``g`` (2 hidden
layers, 3 outputs ``(a, b, c)``) give the robot-frame point velocity in polar form::

    u_local = v_max min(rho_n, 1) clip(c, 0, 1) (a, b) / |(a, b)|                          (1)

The gate ``min(rho_n, 1)`` makes the command vanish on the slot at every scale (the expert's law
``u = r min(v_max q / rho, 1 / T)`` has the same factor). ``(a, b)`` is the direction, reversal
included (``swarm.core.experts.drive_toward_velocity`` steers the axle backward when the slot is
behind), and ``clip(c, 0, 1)`` the speed: the expert's ``q = d_i / D`` where the robot knows everyone
(clipped, not squashed: a sigmoid fitted to the bottleneck robot's full speed stays under it, 3.5%
slower on the complete graph of 100 where everyone is known at once).
Where it does not yet, imitation (``swarm.learn.train.formation``) fits the expert's speed and its
direction separately: a Cartesian output fitted to commands toward a slot the robot cannot know yet
is their average, shorter than any of them (measured: 3-5% slower than ``capt_flood`` at N <= 12).
The robot's wheels saturate (1) as every controller's do.

Policy file: ``.npz`` with ``format`` (``FORMAT``), ``layers`` (their count), ``w<k>``/``b<k>`` and
``meta`` (JSON: the training configuration and data). The batched form
(``swarm.sim.formation_controllers.CaptGnn``) and the per-robot one (:class:`OnboardCaptGnn`, here:
numpy only, what the agents import) share :func:`local_command`.
"""

from __future__ import annotations

import io
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from swarm.core.robot import RobotParams
from swarm.core.tasks.formation import FormationSection
from swarm.sim.formation_onboard import OnboardCaptFlood

FORMAT = "formation_gnn/1"
FEATURES = ("dir_x", "dir_y", "near", "sync", "known")
DEFAULT_MODEL_NAME = "formation/capt_gnn.npz"
"""The shipped policy, below ``<project root>/models`` (``swarm train --algo formation``; its own folder:
``models/*.npz`` are rendezvous policies)."""


class FormationPolicyError(ValueError):
    """A file that is not a formation GNN policy (names the reason)."""


@dataclass(frozen=True)
class FormationGnnWeights:
    """The MLP ``g`` of eq. (1): ``weights[k] (in, out)``, ``biases[k] (out,)``; tanh between layers."""

    weights: tuple[np.ndarray, ...]
    biases: tuple[np.ndarray, ...]
    meta: dict = field(default_factory=dict)

    @classmethod
    def load(cls, source: str | Path | bytes) -> FormationGnnWeights:
        """From a policy file's path or bytes; :class:`FormationPolicyError` naming what is wrong."""
        try:
            data = np.load(io.BytesIO(source) if isinstance(source, bytes) else source, allow_pickle=False)
        except (OSError, ValueError) as error:
            raise FormationPolicyError(f"not a policy file ({error})") from None
        with data:
            found = str(data["format"]) if "format" in data.files else None
            if found != FORMAT:
                raise FormationPolicyError(f"format {found!r}, expected {FORMAT!r} (a capt_gnn policy)")
            layers = int(data["layers"])
            weights = tuple(np.asarray(data[f"w{k}"], dtype=np.float64) for k in range(layers))
            biases = tuple(np.asarray(data[f"b{k}"], dtype=np.float64) for k in range(layers))
            meta = json.loads(str(data["meta"]))
        if weights[0].shape[0] != len(FEATURES) or weights[-1].shape[1] != 3:
            raise FormationPolicyError(
                f"layer shapes {[w.shape for w in weights]}: want {len(FEATURES)} in, 3 out"
            )
        return cls(weights, biases, meta)

    def save(self, path: Path) -> None:
        arrays: dict[str, Any] = {
            "format": FORMAT,
            "layers": len(self.weights),
            "meta": json.dumps(self.meta),
        }
        arrays |= {f"w{k}": w for k, w in enumerate(self.weights)} | {
            f"b{k}": b for k, b in enumerate(self.biases)
        }
        np.savez(path, **arrays)

    def __call__(self, features: np.ndarray) -> np.ndarray:
        """``g(f)``: ``(..., 5) -> (..., 3)``."""
        hidden = np.asarray(features, dtype=np.float64)
        for k, (weight, bias) in enumerate(zip(self.weights, self.biases, strict=True)):
            hidden = hidden @ weight + bias
            if k < len(self.weights) - 1:
                hidden = np.tanh(hidden)
        return hidden


def steering_features(
    poses: np.ndarray,
    targets: np.ndarray,
    sync: np.ndarray,
    known: np.ndarray,
    robot: RobotParams,
    control_period_s: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Eq. (1)'s features ``(..., 5)`` and gate ``min(rho_n, 1)`` ``(...)`` from poses ``(..., 3)``, the
    provisional slots ``(..., 2)`` and the ``sync`` and ``known`` fractions ``(...)``."""
    theta = poses[..., 2]
    cos, sin = np.cos(theta), np.sin(theta)
    delta = targets - poses[..., :2]
    local_x = cos * delta[..., 0] + sin * delta[..., 1]
    local_y = -sin * delta[..., 0] + cos * delta[..., 1]
    rho = np.sqrt(local_x * local_x + local_y * local_y)
    safe = np.where(rho > 0.0, rho, 1.0)
    gate = np.minimum(rho / (robot.v_max_mps * control_period_s), 1.0)
    features = np.stack([local_x / safe, local_y / safe, gate, sync, known], axis=-1)
    return features, gate


def local_command(
    weights: FormationGnnWeights, features: np.ndarray, gate: np.ndarray, v_max_mps: float
) -> np.ndarray:
    """Eq. (1): ``u_local = v_max min(rho_n, 1) clip(c, 0, 1) (a, b) / |(a, b)|`` ``(..., 2)``, before the
    wheels saturate (a zero direction ``(a, b)`` gives no command)."""
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


class OnboardCaptGnn(OnboardCaptFlood):
    """``capt_gnn`` for robot ``robot_id`` (``swarm.sim.onboard``'s protocol; numpy only)."""

    def __init__(
        self,
        robot: RobotParams,
        control_period_s: float,
        section: FormationSection,
        robot_count: int,
        robot_id: int,
        weights: FormationGnnWeights,
        reverse: bool = True,
    ):
        super().__init__(robot, control_period_s, section, robot_count, robot_id, reverse)
        self.weights = weights

    def act_one(
        self, pose: np.ndarray, neighbour_messages: np.ndarray, weights: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        pose = np.asarray(pose, dtype=np.float64)
        memory = self.update_target(pose, neighbour_messages)
        features, gate = steering_features(
            pose,
            self._target,
            np.float64(self._sync),
            np.float64(self._known_fraction),
            self.robot,
            self.control_period_s,
        )
        u_local = local_command(self.weights, features, gate, self.robot.v_max_mps)
        return to_world(pose, u_local), memory.reshape(-1).copy()
