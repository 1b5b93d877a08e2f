"""The thesis's features M and Phi (eq. 3.4-3.7) and their K-hop generalisation, in each robot's frame.

Timing (docs/design.md, "Information timing"): at tick k robot i knows its
own pose at tick k and the message each neighbour j broadcast at tick k-1. With ``c_i`` the
normaliser and ``sum_j`` over the neighbours robot i heard:

- ``M_i(k)     = (1/c_i) sum_j (p_j(k-1) - p_i(k))``           (eq. 3.4-3.5; neighbours' points are
  one tick old, as in ``swarm.sim.controllers.LocalConsensus``)
- ``Phi1_i(k)  = M_i(k)`` and ``Phih_i(k) = (1/c_i) sum_j Phi(h-1)_j(k-1)`` for h = 2..K: hop-h
  information, h ticks old. ``Phi2`` is the thesis's Phi (eq. 3.6-3.7, with its index fixed:
  ``Mx_j``, not ``Mx_i``) for ``phi_source="m"``.
- ``phi_source="output"``: the thesis's other variant, ``Phi_i(k) = (1/c_i) sum_j u_j(k-1)``, the
  point velocity each neighbour applied last tick (K = 2 only).

Normaliser ``c_i``: ``"degree"`` (default) counts the neighbours heard this tick (a robot that heard
nobody has zero features); ``"n_minus_1"`` is the thesis's ``N - 1`` (needs the swarm size).

Messages carry world-frame vectors (every robot knows its pose in the common world frame): for
``phi_source="m"`` robot j sends ``[p_j, Phi1_j, ..., Phi(K-1)_j]`` (``2K`` numbers), for
``"output"`` ``[p_j, u_j]``. Features are rotated into the receiver's frame with ``R(theta)^T``
(``swarm.core.robot.world_to_local``) and returned as ``(..., K, 2)``: row h-1 is ``Phih``.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING, Literal

import numpy as np

from swarm.core.robot import RobotParams, largest_wheel_speed_local, wheel_speed_scale, world_to_local

if TYPE_CHECKING:  # swarm.sim.links compiles numba kernels; an agent host has only numpy
    from swarm.sim.links import Links


@dataclass(frozen=True)
class FeatureSpec:
    """Which features a policy sees: ``hops`` K (1: M only, thesis Model 1; 2: M and Phi)."""

    hops: int = 2
    phi_source: Literal["m", "output"] = "m"
    normaliser: Literal["degree", "n_minus_1"] = "degree"

    def __post_init__(self) -> None:
        if self.hops < 1:
            raise ValueError(f"hops must be >= 1, got {self.hops}")
        if self.phi_source not in ("m", "output"):
            raise ValueError(f"phi_source must be 'm' or 'output', got {self.phi_source!r}")
        if self.phi_source == "output" and self.hops != 2:
            raise ValueError("phi_source 'output' is the thesis's Phi: it needs hops = 2")
        if self.normaliser not in ("degree", "n_minus_1"):
            raise ValueError(f"normaliser must be 'degree' or 'n_minus_1', got {self.normaliser!r}")

    @property
    def message_dim(self) -> int:
        """Numbers per broadcast message: own point plus K-1 hop aggregates (or the last output)."""
        return 2 * self.hops

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> FeatureSpec:
        return cls(**data)


def saturate_local_velocity(u_local: np.ndarray, robot: RobotParams) -> np.ndarray:
    """The point velocity a robot actually applies for a wished robot-frame ``u_local``.

    Same arithmetic as ``swarm.core.robot.local_point_velocity_to_wheels``: ``v = ux``, ``w = uy / l``,
    wheels ``v -+ d w``, both scaled by one factor so that ``max |wheel| <= v_max``; in the robot
    frame that is ``|ux| + (d / l) |uy| <= v_max`` (a diamond), and ``u`` keeps its direction.
    """
    largest = largest_wheel_speed_local(u_local[..., 0], u_local[..., 1], robot.half_axle_m, robot.offset_m)
    return u_local * wheel_speed_scale(largest, robot.v_max_mps)[..., None]


def gather_sums(inbox: np.ndarray, heard: Links) -> tuple[np.ndarray, np.ndarray]:
    """``sum_j heard_ij inbox_j`` ``(B, N, D)`` and the weight heard ``(B, N)``."""
    batch, count, slots = heard.index.shape
    if slots == 0:
        return np.zeros((batch, count, inbox.shape[-1])), np.zeros((batch, count))
    rows = np.arange(batch)[:, None, None]
    gathered = inbox[rows, np.maximum(heard.index, 0)]  # (B, N, S, D); pads have weight 0
    return np.einsum("bns,bnsd->bnd", heard.weight, gathered), heard.weight.sum(axis=-1)


def _normalise(sums: np.ndarray, heard_weight: np.ndarray, spec: FeatureSpec, robot_count: int) -> np.ndarray:
    """``sums / c_i``; zero where the robot heard nobody."""
    if spec.normaliser == "n_minus_1":
        norm = np.full_like(heard_weight, max(robot_count - 1, 1), dtype=np.float64)
    else:
        norm = heard_weight
    inverse = np.where(heard_weight > 0, 1.0 / np.where(norm > 0, norm, 1.0), 0.0)
    return sums * inverse[..., None]


def world_features(
    points: np.ndarray, sums: np.ndarray, heard_weight: np.ndarray, spec: FeatureSpec, robot_count: int
) -> np.ndarray:
    """World-frame ``[Phi1 = M, Phi2, ..., PhiK]`` ``(..., K, 2)`` from the summed neighbour messages.

    ``sum_j (p_j - p_i) = sum_j p_j - (weight heard) p_i``, so M needs only the sums.
    """
    relative = sums.copy()
    relative[..., :2] -= heard_weight[..., None] * points
    normalised = _normalise(relative, heard_weight, spec, robot_count)
    return normalised.reshape(*normalised.shape[:-1], spec.hops, 2)


def messages(points: np.ndarray, phi_world: np.ndarray, u_world: np.ndarray, spec: FeatureSpec) -> np.ndarray:
    """Each robot's broadcast ``(..., 2K)``: ``[p, Phi1..Phi(K-1)]`` (``"m"``) or ``[p, u]``."""
    if spec.phi_source == "output":
        return np.concatenate([points, u_world], axis=-1)
    hops = phi_world[..., : spec.hops - 1, :].reshape(*points.shape[:-1], 2 * (spec.hops - 1))
    return np.concatenate([points, hops], axis=-1)


def batched_features(
    poses: np.ndarray, points: np.ndarray, inbox: np.ndarray, heard: Links, spec: FeatureSpec
) -> tuple[np.ndarray, np.ndarray]:
    """Robot-frame features ``(B, N, K, 2)`` and world-frame ``Phi`` ``(B, N, K, 2)`` (for the messages)."""
    sums, heard_weight = gather_sums(inbox, heard)
    phi_world = world_features(points, sums, heard_weight, spec, poses.shape[1])
    return world_to_local(phi_world, poses[..., None, 2]), phi_world


def robot_features(
    pose: np.ndarray,
    point: np.ndarray,
    neighbour_messages: np.ndarray,
    spec: FeatureSpec,
    robot_count: int = 0,
    weights: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """One robot's features ``(K, 2)`` and world ``Phi`` ``(K, 2)`` from the ``(m, 2K)`` messages it heard,
    each weighted by its link's weight ``w_ij`` (``weights (m,)``; None: every link 1), as
    :func:`gather_sums` weights them: ``sum_j w_ij m_j`` and ``c_i = sum_j w_ij``.

    ``robot_count`` is needed only by the ``n_minus_1`` normaliser.
    """
    if spec.normaliser == "n_minus_1" and robot_count < 2:
        raise ValueError("the n_minus_1 normaliser needs robot_count (the swarm size N)")
    neighbour_messages = np.asarray(neighbour_messages, dtype=np.float64).reshape(-1, spec.message_dim)
    if weights is None:
        sums = neighbour_messages.sum(axis=0)
        heard_weight = np.asarray(float(len(neighbour_messages)))
    else:
        link_weights = np.asarray(weights, dtype=np.float64).reshape(-1)
        sums = (link_weights[:, None] * neighbour_messages).sum(axis=0)
        heard_weight = np.asarray(link_weights.sum())
    phi_world = world_features(np.asarray(point, dtype=np.float64), sums, heard_weight, spec, robot_count)
    return world_to_local(phi_world, np.asarray(pose)[2]), phi_world
