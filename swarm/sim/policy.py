"""Torch-free inference of an exported policy file: what a robot agent runs (numpy only).

The file is one ``.npz`` (``numpy.savez``, no pickles): every weight under its torch
``state_dict`` name as float32, plus ``__metadata__``, UTF-8 JSON bytes::

    {"format": "gnn-swarm-policy", "format_version": 1,
     "model": {"kind": "model1" | "model2" | "two_branch" | "gnn" | "gnn_mlp" | "gnn_flood",
               "activation", widths...},
     "features": {"hops": K, "phi_source": "m" | "output", "normaliser": "degree" | "n_minus_1"},
     (no features for gnn_flood)
     "feature_scale_m": 1.0, "output_scale_mps": 0.5,
     "robot": {RobotParams fields}, "training": {free-form provenance}}

The network maps robot-frame features ``x / feature_scale_m`` (``swarm.sim.features``) to a
robot-frame point velocity ``output_scale_mps * y`` (the gated ``gnn`` outputs m/s itself:
``G sum_k w_k f_k``, see ``swarm.learn.models.gnn``); the robot saturates it (eq. 2.3-2.4 and
``swarm.core.robot.saturate_wheels``) and rotates it to the world frame.

``Policy`` is a batched controller (``swarm.sim.controllers``), so ``KinematicSim`` runs it, and has
the per-robot ``act_one`` that a robot agent runs with the messages it actually heard.

Kind ``gnn_flood`` (``swarm.learn.models.flood``, the recurrent max-flooding GNN) loads as
:class:`FloodPolicy`: it has no hop features but a memory, which is also its message. Per robot
(``act_one``) the object keeps that robot's memory, so each robot needs its own instance
(``FloodPolicy.fresh``); batched (``act``) the memory is the robot's own last message, which the
engine hands back in the inbox, so the batched form is stateless.
"""

from __future__ import annotations

import io
import json
import math
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from swarm.core.robot import (
    RobotParams,
    controlled_point,
    largest_wheel_speed_local,
    rotate,
    wheel_speed_scale,
)
from swarm.sim import flood_readout
from swarm.sim.features import (
    FeatureSpec,
    batched_features,
    messages,
    robot_features,
    saturate_local_velocity,
)

if TYPE_CHECKING:  # swarm.sim.links compiles numba kernels; an agent host has only numpy
    from swarm.sim.links import Links

FORMAT = "gnn-swarm-policy"
FORMAT_VERSION = 1
METADATA_KEY = "__metadata__"
MIRROR = np.array([1.0, -1.0])  # reflection about the robot's heading axis, in its own frame
COSINE_EPS_M = 1e-3  # as swarm.learn.models.gnn
FLOOD_KIND = "gnn_flood"

_ACTIVATIONS: dict[str, Callable[[np.ndarray], np.ndarray]] = {
    "relu": lambda x: np.maximum(x, 0.0),
    "tanh": np.tanh,
}


class PolicyFormatError(ValueError):
    """A policy file that cannot be read; the message says why."""


def _layers(arrays: dict[str, np.ndarray], prefix: str) -> list[tuple[np.ndarray, np.ndarray | None]]:
    layers: list[tuple[np.ndarray, np.ndarray | None]] = []
    while f"{prefix}.{len(layers)}.weight" in arrays:
        index = len(layers)
        layers.append((arrays[f"{prefix}.{index}.weight"], arrays.get(f"{prefix}.{index}.bias")))
    if not layers:
        raise PolicyFormatError(f"no weights named {prefix}.0.weight")
    return layers


def _mlp(layers, x: np.ndarray, activation, final_activation: bool = False) -> np.ndarray:
    for index, (weight, bias) in enumerate(layers):
        x = x @ weight.T
        if bias is not None:
            x = x + bias
        if final_activation or index < len(layers) - 1:
            x = activation(x)
    return x


def _mlp_t(layers, x: np.ndarray) -> np.ndarray:
    """``_mlp`` with tanh and pre-transposed weights."""
    for index, (weight_t, bias) in enumerate(layers):
        x = x @ weight_t
        if bias is not None:
            x = x + bias
        if index < len(layers) - 1:
            x = np.tanh(x)
    return x


class FeatureController:
    """The controller protocol around any ``forward(features_local) -> u_local``: features from the
    messages heard (``swarm.sim.features``), the robot's saturation, robot to world frame, next message.
    ``Policy`` runs it with numpy; ``swarm.learn.models`` runs the same with a torch model."""

    centralized = False

    def __init__(self, spec: FeatureSpec, robot: RobotParams, robot_count: int = 0):
        self.spec = spec
        self.robot = robot
        self.robot_count = robot_count
        self.message_dim = spec.message_dim

    def forward(self, features_local: np.ndarray) -> np.ndarray:
        """Robot-frame features ``(..., K, 2)`` in metres -> wished robot-frame point velocity (m/s)."""
        raise NotImplementedError

    def act(
        self, poses: np.ndarray, points: np.ndarray, inbox: np.ndarray, heard: Links
    ) -> tuple[np.ndarray, np.ndarray]:
        """Batched: ``(B, N, 3)`` poses, ``(B, N, 2)`` points, last tick's ``(B, N, D)`` messages."""
        features_local, phi_world = batched_features(poses, points, inbox, heard, self.spec)
        u_local = saturate_local_velocity(self.forward(features_local), self.robot)
        u_world = rotate(u_local, poses[..., 2])
        u_world[heard.heard_count() <= 0] = 0.0  # a robot that heard nobody holds still
        return u_world, messages(points, phi_world, u_world, self.spec)

    def act_one(
        self,
        pose: np.ndarray,
        neighbour_messages: np.ndarray,
        robot_count: int | None = None,
        weights: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """One robot: pose ``(3,)`` and the ``(m, D)`` messages it heard (over links of ``weights (m,)``;
        None: every link 1) -> ``u_world (2,)``, message."""
        pose = np.asarray(pose, dtype=np.float64)
        point = controlled_point(pose, self.robot.offset_m)
        count = self.robot_count if robot_count is None else robot_count
        features_local, phi_world = robot_features(pose, point, neighbour_messages, self.spec, count, weights)
        u_local = saturate_local_velocity(self.forward(features_local), self.robot)
        u_world = rotate(u_local, pose[2])
        if np.size(neighbour_messages) == 0:  # heard nobody: holds still, as the batched ``act``
            u_world = np.zeros_like(u_world)
        return u_world, messages(point, phi_world, u_world, self.spec)


class Policy(FeatureController):
    """An exported model, run with numpy. ``robot`` overrides the robot parameters in the file
    (the controlled point and the saturation); ``robot_count`` is needed by the ``n_minus_1``
    normaliser in ``act_one``."""

    def __init__(
        self,
        metadata: dict,
        arrays: dict[str, np.ndarray],
        robot: RobotParams | None = None,
        robot_count: int = 0,
    ):
        if metadata.get("format") != FORMAT:
            raise PolicyFormatError(f"not a policy file (format {metadata.get('format')!r})")
        if metadata.get("format_version") != FORMAT_VERSION:
            raise PolicyFormatError(
                f"policy format version {metadata.get('format_version')!r}, this code reads {FORMAT_VERSION}"
            )
        robot = robot if robot is not None else RobotParams(**metadata["robot"])
        super().__init__(FeatureSpec.from_dict(metadata["features"]), robot, robot_count)
        self.metadata = metadata
        self.model = metadata["model"]
        self.kind = self.model["kind"]
        self.feature_scale_m = float(metadata["feature_scale_m"])
        self.output_scale_mps = float(metadata["output_scale_mps"])
        self._activation = _ACTIVATIONS[self.model["activation"]]
        arrays = {name: np.asarray(value, dtype=np.float64) for name, value in arrays.items()}
        if self.kind in ("model1", "model2"):
            self._net = _layers(arrays, "net")
        elif self.kind == "two_branch":
            self._m_branch = _layers(arrays, "m_branch")
            self._phi_branch = _layers(arrays, "phi_branch")
            self._head = _layers(arrays, "head")
        elif self.kind == "gnn":
            self._gates = [(w.T.copy(), b) for w, b in _layers(arrays, "gates")]  # x @ w^T, precomputed
            self._pairs = np.triu_indices(self.spec.hops, k=1)
        elif self.kind == "gnn_mlp":
            self._hop_maps = arrays["hop_maps"]
            self._hop_bias = arrays.get("hop_bias")
            self._readout = _layers(arrays, "readout")
            if self._hop_maps.shape[0] != self.spec.hops:
                raise PolicyFormatError(
                    f"hop_maps has {self._hop_maps.shape[0]} hops, features {self.spec.hops}"
                )
        else:
            raise PolicyFormatError(f"unknown model kind {self.kind!r}")

    @classmethod
    def load(
        cls,
        source: str | Path | bytes,
        robot: RobotParams | None = None,
        robot_count: int = 0,
        control_period_s: float | None = None,
    ) -> Policy | FloodPolicy:
        """From a file path or from the file's bytes (an agent receives the file over the network).
        Anything that is not a readable policy file raises :class:`PolicyFormatError` with the reason.
        ``control_period_s``: the period the policy runs at (a ``gnn_flood`` file with scaled steering
        reads it; None: the one it was trained at)."""
        try:
            if isinstance(source, bytes):
                head = source[:4]
            else:
                with Path(source).open("rb") as file:
                    head = file.read(4)
        except OSError as error:
            raise PolicyFormatError(f"cannot read policy file: {error.strerror or error}") from None
        if head != b"PK\x03\x04":  # an .npz file is a zip archive
            raise PolicyFormatError("not a policy file (not an .npz archive)")
        try:
            with np.load(
                io.BytesIO(source) if isinstance(source, bytes) else source, allow_pickle=False
            ) as file:
                arrays = {name: file[name] for name in file.files}
        except Exception as error:  # zipfile, zlib, numpy: a damaged or truncated archive raises many kinds
            raise PolicyFormatError(
                f"damaged or truncated policy file ({type(error).__name__}: {error})"
            ) from None
        if METADATA_KEY not in arrays:
            raise PolicyFormatError("policy file has no metadata (not a gnn-swarm policy)")
        try:
            metadata = json.loads(arrays.pop(METADATA_KEY).tobytes().decode("utf-8"))
            if not isinstance(metadata, dict):
                raise ValueError("metadata is not a mapping")
            if metadata.get("model", {}).get("kind") == FLOOD_KIND:
                return FloodPolicy(metadata, arrays, robot, robot_count, control_period_s)
            return cls(metadata, arrays, robot, robot_count)
        except PolicyFormatError:
            raise
        except Exception as error:  # foreign or damaged metadata and arrays: KeyError, TypeError, shapes
            raise PolicyFormatError(f"not a usable policy ({type(error).__name__}: {error})") from None

    def act_one(
        self,
        pose: np.ndarray,
        neighbour_messages: np.ndarray,
        robot_count: int | None = None,
        weights: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """``FeatureController.act_one``; for the gated filter on degree-normalised ``m`` features over
        links of weight 1, the same arithmetic in plain floats where numpy per call costs more than the
        work (a robot's tick)."""
        spec = self.spec
        unit_links = weights is None or bool(np.all(np.asarray(weights) == 1.0))
        if self.kind != "gnn" or spec.normaliser != "degree" or spec.phi_source != "m" or not unit_links:
            return super().act_one(pose, neighbour_messages, robot_count, weights)
        x, y, theta = float(pose[0]), float(pose[1]), float(pose[2])
        c, s = math.cos(theta), math.sin(theta)
        px, py = x + self.robot.offset_m * c, y + self.robot.offset_m * s
        heard = np.asarray(neighbour_messages, dtype=np.float64).reshape(-1, spec.message_dim)
        if len(heard):
            sums = heard.sum(axis=0)
            sums[0] -= len(heard) * px
            sums[1] -= len(heard) * py
            phi_world = (sums * (1.0 / len(heard))).reshape(spec.hops, 2)
        else:
            phi_world = np.zeros((spec.hops, 2))
        rotation = np.array([[c, -s], [s, c]])  # world -> robot frame: g @ R(theta)
        ux, uy = (float(v) for v in self._gated_one(np.cumsum(phi_world @ rotation, axis=0)))
        largest = largest_wheel_speed_local(ux, uy, self.robot.half_axle_m, self.robot.offset_m)
        scale = float(wheel_speed_scale(largest, self.robot.v_max_mps))
        ux, uy = ux * scale, uy * scale
        message = np.empty(spec.message_dim)
        message[0], message[1] = px, py
        message[2:] = phi_world[: spec.hops - 1].ravel()
        return np.array([c * ux - s * uy, s * ux + c * uy]), message

    # -- the network ---------------------------------------------------------------------------

    def forward(self, features_local: np.ndarray) -> np.ndarray:
        features_local = np.asarray(features_local, dtype=np.float64)
        if self.kind == "gnn":
            return self._gated(np.cumsum(features_local, axis=-2))
        return self.output_scale_mps * self._network(features_local / self.feature_scale_m)

    def _network(self, x: np.ndarray) -> np.ndarray:
        """Scaled robot-frame features ``(..., K, 2)`` -> normalised output ``(..., 2)``."""
        act = self._activation
        if self.kind == "model1":
            return _mlp(self._net, x[..., 0, :], act)
        if self.kind == "model2":
            return _mlp(self._net, x[..., :2, :].reshape(*x.shape[:-2], 4), act)
        if self.kind == "two_branch":
            m = _mlp(self._m_branch, x[..., 0, :], act, final_activation=True)
            phi = _mlp(self._phi_branch, x[..., 1, :], act, final_activation=True)
            return _mlp(self._head, np.concatenate([m, phi], axis=-1), act)
        if not self.model["symmetrize"]:
            return self._mlp_filter(x)
        return 0.5 * (self._mlp_filter(x) + self._mlp_filter(x * MIRROR) * MIRROR)

    def _mlp_filter(self, x: np.ndarray) -> np.ndarray:
        """``readout(tanh(sum_k f_k W_k))`` (``swarm.learn.models.gnn.MLPGraphFilter``)."""
        f = np.cumsum(x, axis=-2)
        hidden = f.reshape(*f.shape[:-2], -1) @ self._hop_maps.reshape(-1, self._hop_maps.shape[-1])
        if self._hop_bias is not None:
            hidden = hidden + self._hop_bias
        return _mlp(self._readout, self._activation(hidden), self._activation)

    def _gated_one(self, f: np.ndarray) -> np.ndarray:
        """``_gated`` for one robot's ``(K, 2)``, in fewer numpy calls (same formulas)."""
        gram = f @ f.T
        norms = np.sqrt(np.diagonal(gram) + COSINE_EPS_M**2)
        rows, cols = self._pairs
        cosines = (gram / np.outer(norms, norms))[rows, cols]
        x = np.concatenate([norms / self.feature_scale_m, cosines])
        for index, (weight_t, bias) in enumerate(self._gates):
            x = x @ weight_t if bias is None else x @ weight_t + bias
            if index < len(self._gates) - 1:
                x = np.tanh(x)
        out = x
        low, high = self.model["gain_min_per_s"], self.model["gain_max_per_s"]
        gain = low + (high - low) / (1.0 + math.exp(-float(out[0])))
        softmax = np.exp(out[1:] - out[1:].max())
        weights = (1.0 - self.model["hop1_weight_min"]) / softmax.sum() * softmax
        weights[0] += self.model["hop1_weight_min"]
        return gain * (weights @ f)

    def _gated(self, f: np.ndarray) -> np.ndarray:
        """``G(z) sum_k w_k(z) f_k`` (``swarm.learn.models.gnn.GatedGraphFilter``); f in metres."""
        norms = np.sqrt((f * f).sum(-1) + COSINE_EPS_M**2)
        rows, cols = self._pairs
        cosines = (f[..., rows, :] * f[..., cols, :]).sum(-1) / (norms[..., rows] * norms[..., cols])
        out = _mlp_t(self._gates, np.concatenate([norms / self.feature_scale_m, cosines], axis=-1))
        low, high = self.model["gain_min_per_s"], self.model["gain_max_per_s"]
        gain = low + (high - low) / (1.0 + np.exp(-out[..., 0]))
        logits = out[..., 1:] - out[..., 1:].max(axis=-1, keepdims=True)
        softmax = np.exp(logits) / np.exp(logits).sum(axis=-1, keepdims=True)
        weights = (1.0 - self.model["hop1_weight_min"]) * softmax
        weights[..., 0] += self.model["hop1_weight_min"]
        return gain[..., None] * (weights[..., None] * f).sum(-2)


def load_policy(
    source: str | Path | bytes,
    robot: RobotParams | None = None,
    robot_count: int = 0,
    control_period_s: float | None = None,
) -> Policy | FloodPolicy:
    return Policy.load(source, robot, robot_count, control_period_s)


def save_policy(path: str | Path, metadata: dict, arrays: dict[str, np.ndarray]) -> Path:
    """Write a policy file (the exporter in ``swarm.learn.models`` fills ``metadata`` and ``arrays``)."""
    metadata = {"format": FORMAT, "format_version": FORMAT_VERSION, **metadata}
    encoded = np.frombuffer(json.dumps(metadata, sort_keys=True).encode("utf-8"), dtype=np.uint8)
    payload: dict[str, Any] = {name: np.asarray(value, dtype=np.float32) for name, value in arrays.items()}
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as file:
        payload[METADATA_KEY] = encoded
        np.savez(file, **payload)
    return path


def _check_format(metadata: dict) -> None:
    if metadata.get("format") != FORMAT:
        raise PolicyFormatError(f"not a policy file (format {metadata.get('format')!r})")
    if metadata.get("format_version") != FORMAT_VERSION:
        raise PolicyFormatError(
            f"policy format version {metadata.get('format_version')!r}, this code reads {FORMAT_VERSION}"
        )


class FloodPolicy:
    """The recurrent max-flooding GNN (``swarm.learn.models.flood``, kind ``gnn_flood``) with numpy.

    Message of a robot: ``[h^+ (P), h^- (P), c_x, c_y, f]``: its memory, the target it computed from
    it (a function of the memory alone, which lets the batched kernel skip the readout while the
    memory does not change; neighbours ignore it) and a flag ``f`` that marks a real message (the
    engine's inbox starts as zeros): 1 while the robot has never heard a neighbour, 2 once it has
    (neighbours ignore it too). A robot holds still until it has heard a neighbour once; from then
    on it steers toward its memory's target whether or not it hears anybody in a tick (a lost tick
    leaves its memory as it was). Equations: ``swarm.learn.models.flood``.

    The steering's scales (:attr:`steering_scales`) come from the file (``metric`` steering: a distance
    cap and an output speed in metres and m/s, fixed at training) or from the robot it drives and the
    period it runs at (``scaled`` steering: distances in units of ``v_max T``, speeds in units of
    ``v_max``), ``swarm.learn.models.flood``.
    """

    centralized = False

    def __init__(
        self,
        metadata: dict,
        arrays: dict[str, np.ndarray],
        robot: RobotParams | None = None,
        robot_count: int = 0,
        control_period_s: float | None = None,
    ):
        _check_format(metadata)
        self.metadata = metadata
        self.model = metadata["model"]
        self.kind = self.model["kind"]
        self.robot = robot if robot is not None else RobotParams(**metadata["robot"])
        self.robot_count = robot_count
        self.output_scale_mps = float(metadata["output_scale_mps"])
        self.steering = self.model.get("steering", flood_readout.METRIC)
        if self.steering not in flood_readout.STEERING_FORMS:
            raise PolicyFormatError(
                f"gnn_flood steering {self.steering!r}, this code reads {flood_readout.STEERING_FORMS}"
            )
        trained_period_s = metadata.get("training", {}).get("config", {}).get("control_period_s", 0.05)
        self.control_period_s = float(trained_period_s if control_period_s is None else control_period_s)
        self.steering_scales = flood_readout.steering_scales(
            self.steering,
            float(self.model.get("rho_cap_m", 0.0)),
            self.output_scale_mps,
            self.robot.v_max_mps,
            self.control_period_s,
        )
        self._arrays = arrays
        arrays = {name: np.asarray(value, dtype=np.float64) for name, value in arrays.items()}
        try:
            self.projections = arrays["projections"]
            self._tau_share = float(np.exp(arrays["log_tau"]))
            self._steer = _layers(arrays, "steer")
        except KeyError as error:
            raise PolicyFormatError(f"gnn_flood policy lacks weights {error}") from None
        self.directions = int(self.model["directions"])
        if self.projections.shape != (self.directions, 2):
            raise PolicyFormatError(
                f"projections has shape {self.projections.shape}, expected ({self.directions}, 2)"
            )
        self.memory_dim = 2 * self.directions
        self.message_dim = self.memory_dim + 3
        self._norms = np.sqrt((self.projections**2).sum(-1))
        self._unit = self.projections / self._norms[:, None]
        self._steer_activation = _ACTIVATIONS[self.model["activation"]]
        self.reset()

    def fresh(self) -> FloodPolicy:
        """Another robot's instance of the same policy (own, empty memory)."""
        return FloodPolicy(self.metadata, self._arrays, self.robot, self.robot_count, self.control_period_s)

    def reset(self) -> None:
        """Forget the memory and that it has heard anybody (a robot that starts, or restarts, knows
        only what it sees from then on, and holds still until it hears a neighbour)."""
        self._memory: np.ndarray | None = None
        self._has_heard = False

    # -- the network, any leading shape ---------------------------------------------------------

    def own_values(self, axle_m: np.ndarray) -> np.ndarray:
        projected = axle_m @ self.projections.T
        return np.concatenate([projected, -projected], axis=-1)

    def target(self, memory: np.ndarray) -> np.ndarray:
        """World-frame target ``(..., 2)`` from the memory ``(..., 2P)``: the smoothed minimax centre,
        damped Newton steps from the least-squares centre (``swarm.learn.models.flood``)."""
        count, unit = self.directions, self._unit
        upper, lower = memory[..., :count] / self._norms, memory[..., count:] / self._norms
        support = np.concatenate([upper, lower], axis=-1)
        ux, uy = np.concatenate([unit[:, 0], -unit[:, 0]]), np.concatenate([unit[:, 1], -unit[:, 1]])
        width = (upper + lower).max(axis=-1) + 1e-9
        gram = unit.T @ unit
        middle = 0.5 * (upper - lower)
        bx, by = (middle * unit[:, 0]).sum(-1), (middle * unit[:, 1]).sum(-1)
        det = gram[0, 0] * gram[1, 1] - gram[0, 1] ** 2
        cx = (gram[1, 1] * bx - gram[0, 1] * by) / det
        cy = (gram[0, 0] * by - gram[0, 1] * bx) / det
        steps = self.model["newton_steps"]
        for step in range(steps):
            tau_start = flood_readout.TAU_START
            tau = width * (tau_start * (self._tau_share / tau_start) ** (step / max(steps - 1, 1)))
            slack = (support - cx[..., None] * ux - cy[..., None] * uy) / tau[..., None]
            weight = np.exp(slack - slack.max(axis=-1, keepdims=True))
            weight /= weight.sum(axis=-1, keepdims=True)
            gx, gy = (weight * ux).sum(-1), (weight * uy).sum(-1)
            hxx = ((weight * ux * ux).sum(-1) - gx * gx + flood_readout.HESSIAN_EPS) / tau
            hxy = ((weight * ux * uy).sum(-1) - gx * gy) / tau
            hyy = ((weight * uy * uy).sum(-1) - gy * gy + flood_readout.HESSIAN_EPS) / tau
            det = hxx * hyy - hxy * hxy
            dx, dy = (hyy * gx - hxy * gy) / det, (hxx * gy - hxy * gx) / det
            length = np.sqrt(dx * dx + dy * dy + 1e-30)
            damp = np.minimum(flood_readout.MAX_STEP * width / length, 1.0)
            cx, cy = cx + damp * dx, cy + damp * dy
        return np.stack([cx, cy], axis=-1)

    def steer_local(self, poses: np.ndarray, target: np.ndarray) -> np.ndarray:
        """Raw robot-frame point velocity ``(..., 2)`` (before the robot's saturation)."""
        c, s = np.cos(poses[..., 2]), np.sin(poses[..., 2])
        dx, dy = target[..., 0] - poses[..., 0], target[..., 1] - poses[..., 1]
        rx, ry = c * dx + s * dy, -s * dx + c * dy
        rho = np.sqrt(rx * rx + ry * ry + flood_readout.RHO_EPS_M**2)
        rho_unit_m, gate_m, output_mps = self.steering_scales
        features = np.stack([rx / rho, ry / rho, np.minimum(rho / rho_unit_m, 1.0)], axis=-1)
        u_local = output_mps * _mlp(self._steer, features, self._steer_activation)
        if gate_m > 0.0:  # scaled steering: the command vanishes on the target (swarm.learn.models.flood)
            u_local = u_local * np.minimum(rho / gate_m, 1.0)[..., None]
        return u_local

    def raw_step(
        self,
        poses: np.ndarray,
        memory: np.ndarray | None,
        inbox: np.ndarray,
        heard: np.ndarray,
        has_heard: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The numpy reference of the whole tick, dense: poses ``(B, N, 3)``, own memory ``(B, N, 2P)``
        or None, neighbours' last memories ``inbox (B, N, 2P)``, ``heard (B, N, N)`` bool, whether
        each robot has heard a neighbour at an earlier tick ``has_heard (B, N)`` bool (None: nobody
        has) -> raw ``u_local`` (zero where a robot has never heard anybody, this tick included), the
        new memory and the new ``has_heard``. Same as ``FloodGNN.step``."""
        values = self.own_values(poses[..., :2])
        if memory is not None:
            values = np.maximum(values, memory)
        if heard.any():
            masked = np.where(heard[..., None], inbox[:, None, :, :], -np.inf)
            values = np.maximum(values, masked.max(axis=2))
        moving = np.asarray(heard.any(axis=-1))
        if has_heard is not None:
            moving = moving | has_heard
        u_local = self.steer_local(poses, self.target(values))
        u_local[~moving] = 0.0
        return u_local, values, moving

    # -- the controller forms --------------------------------------------------------------------

    def act(
        self, poses: np.ndarray, points: np.ndarray, inbox: np.ndarray, heard: Links
    ) -> tuple[np.ndarray, np.ndarray]:
        """Batched (``swarm.sim.controllers``): the compiled kernel ``swarm.sim.flood_kernel`` (numba);
        ``KinematicSim`` calls that kernel itself, with what it may skip."""
        from swarm.sim import flood_kernel

        outputs = flood_kernel.act(self, poses, inbox, heard)
        return outputs.u_world, outputs.outbox

    def act_one(
        self,
        pose: np.ndarray,
        neighbour_messages: np.ndarray,
        robot_count: int | None = None,
        weights: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """One robot, with the memory this object keeps: pose ``(3,)``, the ``(m, 2P+1)`` messages it
        heard -> ``u_world (2,)``, its message. ``weights`` is unused: a max flood weighs no link (nor
        does the batched kernel)."""
        pose = np.asarray(pose, dtype=np.float64)
        heard = np.asarray(neighbour_messages, dtype=np.float64).reshape(-1, self.message_dim)
        values = self.own_values(pose[:2])
        if self._memory is not None:
            values = np.maximum(values, self._memory)
        if len(heard):
            values = np.maximum(values, heard[:, : self.memory_dim].max(axis=0))
        self._memory = values
        self._has_heard = self._has_heard or bool(len(heard))
        target = self.target(values)
        message = np.concatenate([values, target, [2.0 if self._has_heard else 1.0]])
        if not self._has_heard:  # it has never heard anybody: it holds still
            return np.zeros(2), message
        u_local = saturate_local_velocity(self.steer_local(pose, target), self.robot)
        return rotate(u_local, pose[2]), message
