"""PPO fine-tuning of the gated graph-filter GNN for fast consensus under the speed limit.

Reads top to bottom: hyperparameters (one dataclass, ``PPOConfig``), the batched torch swarm (the
environment), the policy and the critic, evaluation, the shaped reward and GAE, the PPO loss, and
the loop in labelled phases (learning rates, rollout, advantages, update, logs and checkpoints),
then the export to the torch-free policy file
(``swarm.sim.policy``, the same exporter as behavioural cloning). Run:
``swarm train --algo ppo --out runs/ppo`` (``--preset gpu`` for the long run,
``--config FILE``: YAML with any ``PPOConfig`` field).

Why not Stable-Baselines3: every robot of a swarm acts at the same tick from the messages its
neighbours sent at the last one, all robots share one policy (parameter sharing), the swarm size
and graph change from episode to episode (padded batches with a robot mask), and the critic sees
the whole swarm (centralized training, decentralized execution). SB3's PPO assumes one observation,
one action and one value per environment; flattening the swarm into one fixed-size action breaks
parameter sharing and varying N, and one SB3 environment per robot breaks the simultaneous
stepping and the team value. So this is a CleanRL-style PPO loop in torch (clipped surrogate, GAE,
value loss, entropy bonus, gradient clipping, linear learning-rate annealing).

**Policy (decentralized execution).** The GNN of ``swarm.learn.models.gnn`` (``GatedGraphFilter``),
initialised from a behavioural-cloning policy file (``init_policy``, default
``models/gnn_graph_filter.npz``). Robot i's observation is its robot-frame features ``(K, 2)``
(``swarm.sim.features``): its own pose of tick k and the messages ``[p_j, Phi1_j..Phi(K-1)_j]`` its
neighbours broadcast at tick k-1, so hop-h information is h ticks old (docs/design.md). Gaussian policy
with a learned state-free log-std, shared by all robots (``Actor``):

- ``action_space="velocity"`` (default): the action is the robot-frame point velocity,
  ``a ~ Normal(sat(GNN(x_i)), std^2)``; the robot applies ``sat(a)``, the wheel-speed saturation of
  every engine and agent (``|ux| + (d/l)|uy| <= v_max``, both wheels scaled by one factor);
- ``"hop_logits"``: the action is the GNN's K hop-weight logits, ``a ~ Normal(gate(x_i), std^2)``;
  the robot applies ``sat(G sum_k w_k(a) f_k)``: the noise explores where to head (which
  neighbourhood average) instead of jittering the velocity for one 0.05 s tick.

Either way the deterministic action is ``sat(GNN(x))``, exactly what ``swarm.sim.policy`` runs.

**Critic (centralized training).** ``V(s)`` from the whole swarm: each robot's rotation-invariant
hop features and distance to the centroid (an MLP per robot, mean- and max-pooled over the
robots), the swarm's ``max_pairwise`` and spread, N and the graph kind. It is used only in training.

**Reward**, shared by all robots, per control tick of ``dt`` seconds (units: seconds)::

    r_t = -dt + shaping * (gamma * Phi(s_{t+1}) - Phi(s_t)),     Phi(s) = -max_pairwise(s) / (2 v_max)

and the episode terminates at consensus, ``max_pairwise <= threshold_m`` (``Phi`` of the terminal
state is 0). Without shaping the undiscounted return is minus the convergence time; the shaping
is potential-based (Ng et al. 1999), so it leaves the optimal policy unchanged, and its potential
is minus a lower bound on the time still needed (the diameter shrinks at most ``2 v_max``), so the
shaped return is minus the time lost over that bound, and rewards reaching it fast step by step.
Episodes that reach ``max_episode_s`` without consensus are truncated (rare with the gated filter,
which converges on every connected graph, and logged); GAE (:func:`gae`) treats a time-out as
terminal by default, or bootstraps from the value of the state it stopped in
(``bootstrap_time_outs``).

**Episodes**: a graph kind drawn with the ``graphs`` weights (cycle, line, random-connected G(N, p)
with p = 1.5 ln N / N, complete, star), N uniform in ``sizes``, robots uniform in
``swarm.core.initial_poses.box_for(N)`` 0.4 m apart with uniform headings, all from the ``seed``.

**Selection**: every ``eval_every`` updates the deterministic policy runs from fixed starts (the
first ``eval_starts`` starts of ``swarm sweep`` for each of ``eval_cells``); the exported
``policy.npz`` is the iterate with the lowest mean over cells of log(median convergence time)
(first time at or under the threshold; the gated filter stays there), or the last one with
``export: last``. ``stop_after`` ends a run after that many updates with the schedule of ``updates``
(``time_limit_s`` does so by wall time, which a re-run cannot reproduce).

Outputs in ``out``: ``config.json``, ``log.csv`` (one row per update), ``eval.csv`` (one row per
evaluation), TensorBoard ``events.out.tfevents.*``, ``checkpoints/{last,best}.pt``,
``learning_curve.png`` and ``policy.npz``.
"""

from __future__ import annotations

import csv
import json
import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from swarm.core import topologies
from swarm.core.initial_poses import box_for, random_poses
from swarm.core.robot import RobotParams
from swarm.learn.models import build_model
from swarm.learn.models.base import mlp, saturate
from swarm.learn.models.gnn import GatedGraphFilter, hop_invariants
from swarm.learn.train import preset_with_overrides
from swarm.sim.features import FeatureSpec

GRAPH_KINDS = ("cycle", "line", "random", "complete", "star")
"""The kinds PPO trains on, in the order of the critic's one-hot graph-kind input (a trained critic
depends on it); each is built by ``swarm.core.topologies``."""


@dataclass(frozen=True)
class PPOConfig:
    out: str = "runs/ppo"
    seed: int = 0
    init_policy: str | None = "models/gnn_graph_filter.npz"  # BC policy file to start from (None: fresh GNN)
    hops: int = 8  # fresh GNN only
    device: str = "cpu"  # "cpu", "cuda" or "auto"
    threads: int = 1  # torch intra-op threads on the CPU
    # environment (kinematic unicycles, docs/design.md timing), the same robot and limits as swarm sweep
    graphs: dict = field(
        default_factory=lambda: {"cycle": 0.3, "line": 0.3, "random": 0.15, "complete": 0.1, "star": 0.15}
    )
    sizes: tuple[int, int] = (6, 24)  # N uniform in [min, max]
    v_max_mps: float = 0.5
    control_period_s: float = 0.05
    threshold_m: float = 0.2
    min_separation_m: float = 0.4
    max_episode_s: float = 120.0
    shaping: float = 1.0  # weight of the potential-based term (0: reward is -dt per tick)
    # a time-out (max_episode_s) ends the episode; False: as if terminal (how models/gnn_ppo.npz was
    # trained), True: GAE bootstraps from the value of the state it stopped in
    bootstrap_time_outs: bool = False
    # PPO
    num_envs: int = 64
    rollout_steps: int = 64
    updates: int = 50
    gamma: float = 0.995
    gae_lambda: float = 0.95
    epochs: int = 4
    minibatches: int = 4
    clip: float = 0.2
    clip_value: bool = False
    entropy_coef: float = 0.0
    value_coef: float = 0.5
    max_grad_norm: float = 0.5
    lr: float = 1e-4  # policy (the pretrained GNN: small steps)
    critic_lr: float = 1e-3
    # "linear": anneal both learning rates to 0 over `updates`; "adaptive": scale the policy's by 1.5 after
    # an update whose approx KL was under target_kl / 1.5 (down when over 1.5 target_kl), within
    # [lr / 30, 30 lr] (the adaptive schedule of rl_games), the critic's fixed
    lr_schedule: str = "linear"
    target_kl: float = 0.02
    action_space: str = "velocity"  # or "hop_logits" (see Actor)
    init_std: float = 0.05  # exploration noise: m/s on the velocity, or on the hop logits
    learn_std: bool = True
    critic_hidden: int = 64
    critic_warmup_updates: int = 2  # first updates fit only the critic (the policy stays the BC one)
    # evaluation of the deterministic policy during training, and checkpoints
    eval_every: int = 5
    eval_cells: tuple[tuple[str, int], ...] = (("cycle", 20), ("line", 20), ("random", 20), ("complete", 20))
    eval_starts: int = 64
    eval_max_s: float = 200.0
    checkpoint_every: int = 10
    # stop after this many updates (the schedule still spans `updates`), or after this wall time (not
    # reproducible: depends on the machine); then evaluate and export
    stop_after: int | None = None
    time_limit_s: float | None = None
    export: str = "best"  # "best": the best iterate on the eval cells; "last": the final one
    progress: bool = True
    tensorboard: bool = True


PRESETS: dict[str, PPOConfig] = {
    "default": PPOConfig(),
    # for one GPU: 1024 swarms x 64 ticks per update (not yet run on a GPU: no GPU was lent when
    # models/gnn_ppo.npz was trained on a CPU, docs/results/rl/ppo/stage*.yaml)
    "gpu": PPOConfig(
        device="auto", num_envs=1024, rollout_steps=64, updates=150, eval_every=10, eval_starts=128
    ),
    # seconds on a laptop CPU: tests and smoke runs
    "tiny": PPOConfig(
        num_envs=4,
        rollout_steps=16,
        updates=2,
        sizes=(4, 8),
        epochs=2,
        minibatches=2,
        critic_warmup_updates=0,
        eval_every=2,
        eval_cells=(("cycle", 6),),
        eval_starts=4,
        eval_max_s=20.0,
        checkpoint_every=1,
        progress=False,
        tensorboard=False,
    ),
}


def make_config(preset: str = "default", overrides: dict | None = None) -> PPOConfig:
    overrides = dict(overrides or {})
    if "eval_cells" in overrides:
        overrides["eval_cells"] = [(str(t), int(n)) for t, n in overrides["eval_cells"]]
    config = preset_with_overrides("ppo", PRESETS, preset, overrides, tuple_fields=("sizes", "eval_cells"))
    unknown = sorted(set(config.graphs) - set(GRAPH_KINDS))
    if unknown:
        raise ValueError(f"graphs: unknown graph kind {unknown[0]!r}; choose from {list(GRAPH_KINDS)}")
    if not config.graphs or min(config.graphs.values()) < 0 or sum(config.graphs.values()) <= 0:
        raise ValueError("graphs: weights must be non-negative and not all zero")
    if len(config.sizes) != 2 or not 2 <= config.sizes[0] <= config.sizes[1]:
        raise ValueError(f"sizes: need [min, max] with 2 <= min <= max, got {list(config.sizes)}")
    if config.export not in ("best", "last"):
        raise ValueError(f"export: must be 'best' or 'last', got {config.export!r}")
    if config.lr_schedule not in ("linear", "adaptive"):
        raise ValueError(f"lr_schedule: must be 'linear' or 'adaptive', got {config.lr_schedule!r}")
    if config.action_space not in ("velocity", "hop_logits"):
        raise ValueError(f"action_space: must be 'velocity' or 'hop_logits', got {config.action_space!r}")
    if config.init_policy is not None and not Path(config.init_policy).is_file():
        raise ValueError(f"init_policy: no such policy file {config.init_policy}")
    if config.num_envs * config.rollout_steps % config.minibatches:
        raise ValueError("minibatches must divide num_envs * rollout_steps")
    return config


def resolve_device(name: str) -> torch.device:
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(name)


# -- the environment: B swarms of up to n_max robots, padded, stepped together in torch --------------


class TorchSwarm:
    """Unicycles with the information timing of docs/design.md, as ``swarm.sim.kinematic.KinematicSim`` (same
    features, saturation and exact unicycle step), batched in torch so a GPU can run thousands of
    swarms. Swarm b has ``count[b]`` robots in slots ``0..count-1``; the other slots are masked out
    (no links, not in the metric). At tick k each robot sees its pose of tick k and the messages its
    neighbours sent at tick k-1 over the graph of tick k-1; on a swarm's first tick it heard nobody.
    """

    def __init__(self, batch: int, n_max: int, hops: int, robot: RobotParams, dt_s: float, device, dtype):
        self.batch, self.n_max, self.hops, self.robot, self.dt_s = batch, n_max, hops, robot, dt_s
        self.device, self.dtype = device, dtype
        zeros = lambda *shape: torch.zeros(*shape, device=device, dtype=dtype)  # noqa: E731
        self.positions = zeros(batch, n_max, 2)  # axle centres, m
        self.theta = zeros(batch, n_max)
        self.adjacency = zeros(batch, n_max, n_max)
        self.heard = zeros(batch, n_max, n_max)  # graph the inbox was sent over (tick k-1)
        self.inbox = zeros(batch, n_max, 2 * hops)
        self.valid = torch.zeros(batch, n_max, dtype=torch.bool, device=device)
        self.count = torch.zeros(batch, dtype=torch.long, device=device)
        self.kind = torch.zeros(batch, dtype=torch.long, device=device)
        self.ticks = torch.zeros(batch, dtype=torch.long, device=device)

    def load(self, envs: list[int], poses: list[np.ndarray], adjacency: list[np.ndarray], kinds: list[int]):
        """Start swarms ``envs`` from ``poses (N, 3)`` on ``adjacency (N, N)``."""
        for env, pose, links, kind in zip(envs, poses, adjacency, kinds, strict=True):
            count = len(pose)
            padded_pose = np.zeros((self.n_max, 3))
            padded_pose[:count] = pose
            padded_links = np.zeros((self.n_max, self.n_max))
            padded_links[:count, :count] = links
            pose_t = torch.as_tensor(padded_pose, device=self.device, dtype=self.dtype)
            self.positions[env] = pose_t[:, :2]
            self.theta[env] = pose_t[:, 2]
            self.adjacency[env] = torch.as_tensor(padded_links, device=self.device, dtype=self.dtype)
            self.valid[env] = torch.arange(self.n_max, device=self.device) < count
            self.count[env] = count
            self.kind[env] = kind
        index = torch.as_tensor(envs, device=self.device, dtype=torch.long)
        self.heard[index] = 0.0
        self.inbox[index] = 0.0
        self.ticks[index] = 0

    def points(self) -> torch.Tensor:
        """Controlled points ``(B, N, 2)``, ``l`` ahead of the axle."""
        heading = torch.stack([torch.cos(self.theta), torch.sin(self.theta)], dim=-1)
        return self.positions + self.robot.offset_m * heading

    def observe(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Robot-frame features ``(B, N, K, 2)``, world-frame ``Phi (B, N, K, 2)`` and the points."""
        points = self.points()
        sums = self.heard @ self.inbox  # sum_j heard_ij m_j(k-1)
        degree = self.heard.sum(-1)
        relative = torch.cat([sums[..., :2] - degree[..., None] * points, sums[..., 2:]], dim=-1)
        inverse = torch.where(degree > 0, 1.0 / degree.clamp_min(1.0), torch.zeros_like(degree))
        phi_world = (relative * inverse[..., None]).reshape(self.batch, self.n_max, self.hops, 2)
        c, s = torch.cos(self.theta)[..., None], torch.sin(self.theta)[..., None]
        local = torch.stack(
            [c * phi_world[..., 0] + s * phi_world[..., 1], -s * phi_world[..., 0] + c * phi_world[..., 1]],
            dim=-1,
        )
        return local, phi_world, points

    def step(self, u_local: torch.Tensor, phi_world: torch.Tensor, points: torch.Tensor) -> None:
        """Apply robot-frame point velocities ``(B, N, 2)`` (saturated here again, which is idempotent)
        for one control period; broadcast this tick's messages."""
        robot, dt = self.robot, self.dt_s
        self.inbox = torch.cat([points, phi_world[:, :, : self.hops - 1].flatten(-2)], dim=-1)
        self.heard = self.adjacency.clone()
        v, w = u_local[..., 0], u_local[..., 1] / robot.offset_m
        largest = v.abs() + robot.half_axle_m * w.abs()  # max(|v - d w|, |v + d w|)
        scale = torch.clamp(robot.v_max_mps / largest.clamp_min(1e-12), max=1.0)
        v, w = v * scale, w * scale
        half = 0.5 * w * dt
        small = half.abs() < 1e-4
        sinc = torch.where(small, 1.0 - half * half / 6.0, torch.sin(half) / torch.where(small, 1.0, half))
        chord = v * dt * sinc
        middle = self.theta + half
        self.positions = self.positions + chord[..., None] * torch.stack(
            [torch.cos(middle), torch.sin(middle)], -1
        )
        self.theta = torch.remainder(self.theta + 2.0 * half + math.pi, 2.0 * math.pi) - math.pi
        self.positions = torch.where(self.valid[..., None], self.positions, torch.zeros_like(self.positions))
        self.ticks += 1

    def max_pairwise(self) -> torch.Tensor:
        """Largest distance between two robots of each swarm ``(B,)`` (axle centres, docs/design.md)."""
        distance = torch.cdist(self.positions, self.positions)
        both = self.valid[:, :, None] & self.valid[:, None, :]
        return torch.where(both, distance, torch.zeros_like(distance)).amax(dim=(-2, -1))

    def spread(self) -> torch.Tensor:
        """RMS distance to the centroid ``(B,)``."""
        count = self.count.to(self.dtype)
        centroid = (self.positions * self.valid[..., None]).sum(1) / count[:, None]
        squared = ((self.positions - centroid[:, None]) ** 2).sum(-1) * self.valid
        return torch.sqrt(squared.sum(-1) / count)


class EpisodeSampler:
    """Seeded random episodes: graph kind, N, start poses and graph."""

    def __init__(self, config: PPOConfig, rng: np.random.Generator):
        self.config, self.rng = config, rng
        self.kinds = [kind for kind in GRAPH_KINDS if config.graphs.get(kind, 0) > 0]
        weights = np.array([config.graphs[kind] for kind in self.kinds], dtype=float)
        self.weights = weights / weights.sum()

    def draw(self) -> tuple[np.ndarray, np.ndarray, int]:
        kind = self.kinds[self.rng.choice(len(self.kinds), p=self.weights)]
        count = int(self.rng.integers(self.config.sizes[0], self.config.sizes[1] + 1))
        box = box_for(count)
        poses = random_poses(self.rng, 1, count, box, box, self.config.min_separation_m)[0]
        adjacency = topologies.draw(kind, count, self.rng)  # random: p = topologies.default_edge_probability
        assert adjacency is not None  # GRAPH_KINDS are fixed graphs
        return poses, adjacency, GRAPH_KINDS.index(kind)

    def start(self, env: TorchSwarm, envs: list[int]) -> None:
        """New episodes in swarms ``envs`` of ``env``."""
        drawn = [self.draw() for _ in envs]
        env.load(envs, [d[0] for d in drawn], [d[1] for d in drawn], [d[2] for d in drawn])


# -- policy and critic ----------------------------------------------------------------------------


def load_gnn(config: PPOConfig, robot: RobotParams) -> GatedGraphFilter:
    """The GNN to fine-tune: the ``init_policy`` file's model and weights, or a fresh one."""
    if config.init_policy is None:
        return GatedGraphFilter(FeatureSpec(hops=config.hops), gain_min_per_s=20.0, gain_max_per_s=20.0)
    with np.load(config.init_policy, allow_pickle=False) as file:
        metadata = json.loads(file["__metadata__"].tobytes().decode("utf-8"))
        state = {name: torch.from_numpy(file[name]) for name in file.files if name != "__metadata__"}
    if metadata["model"]["kind"] != "gnn":
        raise ValueError(
            f"init_policy: PPO fine-tunes the gated GNN (kind 'gnn'), not {metadata['model']['kind']!r}"
        )
    model = build_model(metadata)
    assert isinstance(model, GatedGraphFilter)  # kind 'gnn'
    model.load_state_dict(state)
    return model


class Actor(nn.Module):
    """The shared GNN as the mean of a Gaussian policy, per robot.

    ``action_space="velocity"``: the action is the robot-frame point velocity, mean ``sat(GNN(x))``;
    the robot applies ``sat(action)``. ``"hop_logits"``: the action is the GNN's K hop-weight logits
    (the gate's output), mean what the gate computes; the robot applies ``sat(G sum_k w_k(action) f_k)``
    (``swarm.learn.models.gnn``), so the noise explores where to head rather than jittering the velocity.
    Either way the deterministic action is ``sat(GNN(x))``, exactly what ``swarm.sim.policy`` runs.
    """

    def __init__(
        self, gnn: GatedGraphFilter, robot: RobotParams, init_std: float, learn_std: bool, action_space: str
    ):
        super().__init__()
        self.gnn, self.robot, self.action_space = gnn, robot, action_space
        self.action_dim = 2 if action_space == "velocity" else gnn.spec.hops
        log_std = torch.full((self.action_dim,), math.log(init_std))
        self.log_std = nn.Parameter(log_std, requires_grad=learn_std)

    def _gate(self, features_local: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Total gain G ``(...)``, hop logits ``(..., K)`` and offsets ``f (..., K, 2)``."""
        gnn = self.gnn
        f = torch.cumsum(features_local, dim=-2)
        out = mlp(gnn.gates, hop_invariants(f, gnn.feature_scale_m), torch.tanh)
        gain = gnn.gain_min_per_s + (gnn.gain_max_per_s - gnn.gain_min_per_s) * torch.sigmoid(out[..., 0])
        return gain, out[..., 1:], f

    def mean(self, features_local: torch.Tensor) -> torch.Tensor:
        """``sat(GNN(x))``: the deterministic action as applied, what ``swarm.sim.policy`` runs."""
        return saturate(self.gnn(features_local), self.robot)

    def action_mean(self, features_local: torch.Tensor) -> torch.Tensor:
        if self.action_space == "velocity":
            return self.mean(features_local)
        return self._gate(features_local)[1]

    def apply(self, features_local: torch.Tensor, action: torch.Tensor) -> torch.Tensor:  # type: ignore[override]
        """The robot-frame point velocity a robot applies for ``action`` (saturated)."""
        if self.action_space == "velocity":
            return saturate(action, self.robot)
        gain, _, f = self._gate(features_local)
        floor = self.gnn.hop1_weight_min
        weights = floor * self.gnn.first_hop + (1 - floor) * torch.softmax(action, dim=-1)
        return saturate(gain[..., None] * (weights[..., None] * f).sum(-2), self.robot)

    def distribution(self, features_local: torch.Tensor) -> torch.distributions.Normal:
        return torch.distributions.Normal(self.action_mean(features_local), self.log_std.exp())


class Critic(nn.Module):
    """Centralized ``V(s)``: per-robot invariants, pooled over the swarm, plus global summaries."""

    GLOBAL = 4 + len(GRAPH_KINDS)

    def __init__(self, hops: int, hidden: int, scale_m: float):
        super().__init__()
        self.scale_m = scale_m
        per_robot = hops + hops * (hops - 1) // 2 + 2
        self.encoder = nn.Sequential(
            nn.Linear(per_robot, hidden), nn.Tanh(), nn.Linear(hidden, hidden), nn.Tanh()
        )
        self.head = nn.Sequential(
            nn.Linear(2 * hidden + self.GLOBAL, hidden), nn.Tanh(), nn.Linear(hidden, hidden), nn.Tanh(),
            nn.Linear(hidden, 1),
        )  # fmt: skip

    def forward(self, robots: torch.Tensor, valid: torch.Tensor, summary: torch.Tensor) -> torch.Tensor:
        hidden = self.encoder(robots)
        mask = valid[..., None].to(hidden.dtype)
        mean = (hidden * mask).sum(-2) / mask.sum(-2).clamp_min(1.0)
        largest = torch.where(valid[..., None], hidden, torch.full_like(hidden, -1.0)).amax(-2)
        return self.head(torch.cat([mean, largest, summary], dim=-1)).squeeze(-1)


def critic_inputs(
    env: TorchSwarm, features_local: torch.Tensor, scale_m: float, n_max: int
) -> tuple[torch.Tensor, torch.Tensor]:
    """Per-robot ``(B, N, D)`` (hop invariants, distance to centroid, degree) and global ``(B, G)``."""
    count = env.count.to(env.dtype)
    centroid = (env.positions * env.valid[..., None]).sum(1) / count[:, None]
    to_centroid = (env.positions - centroid[:, None]).norm(dim=-1, keepdim=True) / scale_m
    degree = env.adjacency.sum(-1, keepdim=True) / n_max
    robots = torch.cat([hop_invariants(torch.cumsum(features_local, -2), scale_m), to_centroid, degree], -1)
    kinds = nn.functional.one_hot(env.kind, len(GRAPH_KINDS)).to(env.dtype)
    summary = torch.stack(
        [
            env.max_pairwise() / scale_m,
            env.spread() / scale_m,
            count / n_max,
            torch.log(env.max_pairwise().clamp_min(1e-3)),
        ],
        dim=-1,
    )
    return robots, torch.cat([summary, kinds], -1)


# -- evaluation -------------------------------------------------------------------------------------


def evaluate(actor: Actor, config: PPOConfig, robot: RobotParams, device, dtype) -> dict[str, float | None]:
    """Median first time at ``max_pairwise <= threshold`` of the deterministic policy per eval cell,
    from the first ``eval_starts`` starts of ``swarm sweep`` (None: not every start converged)."""
    from swarm.scenarios.sweep import SweepConfig, cell_starts

    sweep = SweepConfig(
        seeds=max(1000, config.eval_starts),
        first_starts=config.eval_starts,
        threshold_m=config.threshold_m,
        v_max_mps=config.v_max_mps,
        control_period_s=config.control_period_s,
    )
    result: dict[str, float | None] = {}
    for topology, count in config.eval_cells:
        poses, adjacency, _ = cell_starts(sweep, topology, count)
        assert adjacency is not None  # fixed graphs only
        env = TorchSwarm(
            len(poses), count, actor.gnn.spec.hops, robot, config.control_period_s, device, dtype
        )
        env.load(list(range(len(poses))), list(poses), list(adjacency), [0] * len(poses))
        times = torch.full((len(poses),), math.nan, dtype=torch.float64)
        for tick in range(round(config.eval_max_s / config.control_period_s) + 1):
            reached = (env.max_pairwise() <= config.threshold_m).cpu()
            fresh = reached & times.isnan()
            times[fresh] = tick * config.control_period_s
            if not times.isnan().any():
                break
            features, phi_world, points = env.observe()
            with torch.no_grad():
                env.step(actor.mean(features), phi_world, points)
        ok = ~times.isnan()
        result[f"{topology}{count}_median_s"] = float(times[ok].median()) if ok.all() else None
    return result


def eval_score(row: dict) -> float:
    """Mean log median time over the eval cells (inf when a cell did not always converge)."""
    values = [value for key, value in row.items() if key.endswith("_median_s")]
    if any(value is None for value in values):
        return math.inf
    return float(np.mean(np.log(values)))


# -- reward and advantages -------------------------------------------------------------------------


def potential(diameter_m: torch.Tensor, v_max_mps: float) -> torch.Tensor:
    """``Phi(s) = -max_pairwise(s) / (2 v_max)`` (s): minus a lower bound on the time consensus still
    needs, since the diameter shrinks at most ``2 v_max``."""
    return -diameter_m / (2 * v_max_mps)


def shaped_reward(
    before: torch.Tensor,
    after: torch.Tensor,
    terminated: torch.Tensor,
    dt_s: float,
    gamma: float,
    shaping: float,
) -> tuple[torch.Tensor, torch.Tensor]:
    """``r_t = -dt + shaping * (gamma * Phi(s_{t+1}) - Phi(s_t))`` with ``Phi`` of a terminal state 0
    (Ng et al. 1999); ``before``, ``after``: the potentials of s_t and s_{t+1}. Returns the reward
    and ``Phi(s_{t+1})`` as used (0 where terminated)."""
    after = torch.where(terminated, torch.zeros_like(after), after)
    return -dt_s + shaping * (gamma * after - before), after


def gae(
    rewards: torch.Tensor,
    values: torch.Tensor,
    next_value: torch.Tensor,
    terminated: torch.Tensor,
    truncated: torch.Tensor,
    final_values: torch.Tensor,
    gamma: float,
    gae_lambda: float,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Generalized advantage estimation (Schulman et al. 2016) over a rollout of ``T`` steps of ``B``
    environments, every argument ``(T, B)`` but ``next_value (B)``, the value of the state after the
    last step. An episode ends after step t when ``terminated[t]`` (no future: bootstrap 0) or
    ``truncated[t]`` (a time-out: bootstrap ``final_values[t]``, the value of the state it stopped
    in, before the reset; zeros treat a time-out as terminal). The recursion
    ``A_t = delta_t + gamma lambda (1 - ended_t) A_{t+1}`` with
    ``delta_t = r_t + gamma V_boot(t) - V(s_t)`` never crosses an episode's end. Returns the
    advantages and the value targets ``A + V``."""
    steps = rewards.shape[0]
    ended = torch.maximum(terminated, truncated)
    advantages = torch.zeros_like(rewards)
    last = torch.zeros_like(next_value)
    for t in reversed(range(steps)):
        following = next_value if t == steps - 1 else values[t + 1]
        alive = 1.0 - ended[t]
        bootstrap = following * alive + final_values[t] * truncated[t]
        delta = rewards[t] + gamma * bootstrap - values[t]
        last = delta + gamma * gae_lambda * alive * last
        advantages[t] = last
    return advantages, advantages + values


# -- the loop ---------------------------------------------------------------------------------------


def plot_curve(log_rows: list[dict], eval_rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(15, 4), dpi=110)
    steps = [row["env_steps"] for row in log_rows]
    axes[0].plot(steps, [row["episode_return"] for row in log_rows], label="shaped return")
    axes[0].plot(steps, [-row["episode_time_s"] for row in log_rows], label="- episode time (s)")
    axes[0].set(xlabel="swarm ticks", ylabel="per episode (mean of the update)", title="training episodes")
    axes[0].legend(fontsize=7)
    axes[1].plot(steps, [row["policy_std"] for row in log_rows], label="policy std")
    axes[1].plot(steps, [row["approx_kl"] for row in log_rows], label="approx KL")
    axes[1].plot(steps, [row["clip_fraction"] for row in log_rows], label="clip fraction")
    axes[1].set(xlabel="swarm ticks", yscale="log", title="PPO statistics")
    axes[1].legend(fontsize=7)
    for key in eval_rows[0] if eval_rows else []:
        if key.endswith("_median_s"):
            values = [row[key] if row[key] is not None else np.nan for row in eval_rows]
            axes[2].plot([row["env_steps"] for row in eval_rows], values, marker="o", label=key[:-9])
    axes[2].set(
        xlabel="swarm ticks", ylabel="median convergence time (s)", title="deterministic policy, fixed starts"
    )
    axes[2].legend(fontsize=7)
    for ax in axes:
        ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def write_csv(path: Path, rows: list[dict]) -> None:
    with open(path, "w", newline="") as file:
        writer = csv.DictWriter(file, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


def anneal_lr(
    optimizer: torch.optim.Optimizer, config: PPOConfig, update: int, last_kl: float | None
) -> None:
    """``linear``: both learning rates from their base to 0 over ``updates``; ``adaptive``: the
    policy's by 1.5 after an update whose approx KL left ``[target_kl / 1.5, 1.5 target_kl]``."""
    if config.lr_schedule == "linear":
        for group, base in zip(optimizer.param_groups, (config.lr, config.critic_lr), strict=True):
            group["lr"] = base * (1.0 - (update - 1) / config.updates)
    elif last_kl is not None and update > config.critic_warmup_updates + 1:
        group = optimizer.param_groups[0]
        if last_kl < config.target_kl / 1.5:
            group["lr"] = min(group["lr"] * 1.5, 30 * config.lr)
        elif last_kl > config.target_kl * 1.5:
            group["lr"] = max(group["lr"] / 1.5, config.lr / 30)


def ppo_loss(
    actor: Actor,
    critic: Critic,
    batch: dict[str, torch.Tensor],
    advantages: torch.Tensor,
    returns: torch.Tensor,
    config: PPOConfig,
    train_policy: bool,
) -> tuple[torch.Tensor, dict[str, float]]:
    """One minibatch: the clipped surrogate over the robots that exist (padding skipped), the value
    loss (optionally clipped) and the entropy bonus of the state-free Gaussian."""
    valid = batch["valid"]
    adv = (advantages - advantages.mean()) / (advantages.std() + 1e-8)
    value = critic(batch["critic_robots"], valid, batch["critic_summary"])
    if config.clip_value:
        old = batch["values"]
        clipped = old + (value - old).clamp(-config.clip, config.clip)
        value_loss = 0.5 * torch.max((value - returns) ** 2, (clipped - returns) ** 2)
    else:
        value_loss = 0.5 * (value - returns) ** 2
    value_loss = value_loss.mean()
    loss = config.value_coef * value_loss
    stats = {"value_loss": float(value_loss.detach())}
    if train_policy:
        dist = actor.distribution(batch["features"][valid])
        logp = dist.log_prob(batch["actions"][valid]).sum(-1)
        log_ratio = logp - batch["logp"][valid]
        ratio = log_ratio.exp()
        robot_adv = adv[:, None].expand_as(valid)[valid]
        surrogate = torch.max(-robot_adv * ratio, -robot_adv * ratio.clamp(1 - config.clip, 1 + config.clip))
        policy_loss = surrogate.mean()
        entropy = actor.log_std.sum() + math.log(2 * math.pi * math.e)  # per robot, state-free
        loss = loss + policy_loss - config.entropy_coef * entropy
        with torch.no_grad():
            kl = ((ratio - 1) - log_ratio).mean()
            clipped_share = ((ratio - 1).abs() > config.clip).to(ratio.dtype).mean()
        stats.update(
            policy_loss=float(policy_loss.detach()), approx_kl=float(kl), clip_fraction=float(clipped_share)
        )
    return loss, stats


def make_checkpoint(
    gnn: GatedGraphFilter,
    actor: Actor,
    critic: Critic,
    optimizer: torch.optim.Optimizer,
    update: int,
    config: PPOConfig,
) -> dict:
    return {
        "model_config": gnn.config(),
        "model": gnn.state_dict(),
        "actor": actor.state_dict(),
        "critic": critic.state_dict(),
        "optimizer": optimizer.state_dict(),
        "update": update,
        "ppo_config": asdict(config),
    }


def evaluate_and_log(
    actor: Actor,
    config: PPOConfig,
    robot: RobotParams,
    device,
    dtype,
    update: int,
    env_steps: int,
    eval_rows: list[dict],
    out: Path,
    writer,
) -> float:
    """Evaluate the deterministic policy, append its row to ``eval.csv`` (and TensorBoard); its score."""
    row: dict[str, Any] = {"update": update, "env_steps": env_steps}
    row.update(evaluate(actor, config, robot, device, dtype))
    row["score"] = eval_score(row)
    eval_rows.append(row)
    write_csv(out / "eval.csv", eval_rows)
    if writer is not None:
        for key, value in row.items():
            if key.endswith("_median_s") and value is not None:
                writer.add_scalar(f"eval/{key}", value, env_steps)
    return row["score"]


def train(config: PPOConfig) -> Path:
    """Fine-tune with PPO; returns the exported policy file (the best iterate on the eval cells)."""
    # -- setup: seeds, models, optimizer, environment, rollout buffers, logs ----------------------------
    out = Path(config.out)
    (out / "checkpoints").mkdir(parents=True, exist_ok=True)
    (out / "config.json").write_text(json.dumps(asdict(config), indent=2) + "\n")
    device = resolve_device(config.device)
    dtype = torch.float32
    torch.manual_seed(config.seed)
    torch.set_num_threads(config.threads)
    rng = np.random.default_rng(config.seed)
    noise = torch.Generator(device=device).manual_seed(config.seed)
    shuffle = torch.Generator().manual_seed(config.seed + 1)
    robot = RobotParams(v_max_mps=config.v_max_mps)

    gnn = load_gnn(config, robot)
    hops, scale_m = gnn.spec.hops, gnn.feature_scale_m
    actor = Actor(gnn, robot, config.init_std, config.learn_std, config.action_space).to(device)
    critic = Critic(hops, config.critic_hidden, scale_m).to(device)
    actor_params = [p for p in actor.parameters() if p.requires_grad]
    optimizer = torch.optim.Adam(
        [{"params": actor_params, "lr": config.lr}, {"params": critic.parameters(), "lr": config.critic_lr}],
        eps=1e-5,
    )

    B, T, n_max, dt = config.num_envs, config.rollout_steps, config.sizes[1], config.control_period_s
    env = TorchSwarm(B, n_max, hops, robot, dt, device, dtype)
    sampler = EpisodeSampler(config, rng)
    sampler.start(env, list(range(B)))
    max_ticks = round(config.max_episode_s / dt)
    per_robot_dim = hops + hops * (hops - 1) // 2 + 2
    zeros = lambda *shape, kind=dtype: torch.zeros(*shape, device=device, dtype=kind)  # noqa: E731
    buffers = {
        "features": zeros(T, B, n_max, hops, 2),
        "actions": zeros(T, B, n_max, actor.action_dim),
        "logp": zeros(T, B, n_max),
        "valid": zeros(T, B, n_max, kind=torch.bool),
        "critic_robots": zeros(T, B, n_max, per_robot_dim),
        "critic_summary": zeros(T, B, Critic.GLOBAL),
        "values": zeros(T, B),
        "rewards": zeros(T, B),
        "terminated": zeros(T, B),
        "truncated": zeros(T, B),
        "final_values": zeros(T, B),  # value of the state a time-out stopped in (bootstrap_time_outs)
    }
    writer = None
    if config.tensorboard:
        from torch.utils.tensorboard import SummaryWriter

        writer = SummaryWriter(str(out))
    bar = None
    if config.progress:
        from tqdm import tqdm

        bar = tqdm(total=config.updates, unit="update", desc="ppo")
    log_rows: list[dict] = []
    eval_rows: list[dict] = []
    best_score, best_update = math.inf, -1
    started = time.perf_counter()
    env_steps = 0
    phi = potential(env.max_pairwise(), config.v_max_mps)
    episode_return = zeros(B)

    def evaluate_now(update: int) -> None:  # evaluate; keep the best iterate's checkpoint
        nonlocal best_score, best_update
        score = evaluate_and_log(
            actor, config, robot, device, dtype, update, env_steps, eval_rows, out, writer
        )
        if score < best_score:
            best_score, best_update = score, update
            torch.save(
                make_checkpoint(gnn, actor, critic, optimizer, update, config),
                out / "checkpoints" / "best.pt",
            )

    evaluate_now(0)
    update = 0
    for update in range(1, config.updates + 1):
        # -- 1. learning rates ----------------------------------------------------------------------
        anneal_lr(optimizer, config, update, log_rows[-1]["approx_kl"] if log_rows else None)

        # -- 2. rollout: T ticks of B swarms, every robot sampling its action -------------------------
        finished_times, finished_returns, truncated = [], [], 0
        for t in range(T):
            features, phi_world, points = env.observe()
            robots, summary = critic_inputs(env, features, scale_m, n_max)
            with torch.no_grad():
                mean = actor.action_mean(features)
                std = actor.log_std.exp()
                actions = mean + std * torch.randn(mean.shape, generator=noise, device=device, dtype=dtype)
                logp = torch.distributions.Normal(mean, std).log_prob(actions).sum(-1)
                value = critic(robots, env.valid, summary)
            buffers["features"][t] = features
            buffers["actions"][t] = actions
            buffers["logp"][t] = logp
            buffers["valid"][t] = env.valid
            buffers["critic_robots"][t] = robots
            buffers["critic_summary"][t] = summary
            buffers["values"][t] = value
            with torch.no_grad():
                env.step(actor.apply(features, actions), phi_world, points)
            diameter = env.max_pairwise()
            terminated = diameter <= config.threshold_m
            out_of_ticks = env.ticks >= max_ticks
            time_out = out_of_ticks & ~terminated
            reward, _ = shaped_reward(
                phi, potential(diameter, config.v_max_mps), terminated, dt, config.gamma, config.shaping
            )
            buffers["rewards"][t] = reward
            buffers["terminated"][t] = terminated.to(dtype)
            buffers["truncated"][t] = time_out.to(dtype)
            if config.bootstrap_time_outs and bool(time_out.any()):
                features_end, _, _ = env.observe()
                robots_end, summary_end = critic_inputs(env, features_end, scale_m, n_max)
                with torch.no_grad():
                    final = critic(robots_end, env.valid, summary_end)
                buffers["final_values"][t] = torch.where(time_out, final, torch.zeros_like(final))
            else:
                buffers["final_values"][t] = 0.0
            episode_return += reward
            env_steps += B
            done = terminated | time_out
            ended = done.nonzero().flatten().tolist()
            if ended:
                ticks = env.ticks[ended].cpu().numpy()
                finished_times.extend((ticks * dt).tolist())
                finished_returns.extend(episode_return[ended].cpu().tolist())
                truncated += int(out_of_ticks[ended].sum())
                episode_return[ended] = 0.0
                sampler.start(env, ended)
            phi = potential(env.max_pairwise(), config.v_max_mps)

        # -- 3. advantages (GAE, time-outs cut the recursion) ---------------------------------------
        with torch.no_grad():
            features, _, _ = env.observe()
            robots, summary = critic_inputs(env, features, scale_m, n_max)
            next_value = critic(robots, env.valid, summary)
            advantages, returns = gae(
                buffers["rewards"],
                buffers["values"],
                next_value,
                buffers["terminated"],
                buffers["truncated"],
                buffers["final_values"],
                config.gamma,
                config.gae_lambda,
            )

        # -- 4. PPO update: epochs x minibatches of (tick, swarm) samples --------------------------
        flat = {key: value.reshape(T * B, *value.shape[2:]) for key, value in buffers.items()}
        flat_adv, flat_ret = advantages.reshape(-1), returns.reshape(-1)
        train_policy = update > config.critic_warmup_updates
        stats: dict[str, list[float]] = {
            key: [] for key in ("policy_loss", "value_loss", "approx_kl", "clip_fraction")
        }
        size = T * B // config.minibatches
        for _ in range(config.epochs):
            order = torch.randperm(T * B, generator=shuffle).to(device)
            for start in range(0, T * B, size):
                index = order[start : start + size]
                batch = {key: value[index] for key, value in flat.items()}
                loss, minibatch = ppo_loss(
                    actor, critic, batch, flat_adv[index], flat_ret[index], config, train_policy
                )
                for key, value in minibatch.items():
                    stats[key].append(value)
                optimizer.zero_grad(set_to_none=True)
                loss.backward()
                nn.utils.clip_grad_norm_(actor_params, config.max_grad_norm)
                nn.utils.clip_grad_norm_(critic.parameters(), config.max_grad_norm)
                optimizer.step()

        # -- 5. logs, checkpoints, evaluation, stop --------------------------------------------------
        explained = 1.0 - float((flat_ret - flat["values"]).var() / (flat_ret.var() + 1e-12))
        row = {
            "update": update,
            "env_steps": env_steps,
            "episodes": len(finished_times),
            "truncated": truncated,
            "episode_time_s": float(np.mean(finished_times)) if finished_times else math.nan,
            "episode_return": float(np.mean(finished_returns)) if finished_returns else math.nan,
            "mean_reward": float(buffers["rewards"].mean()),
            "policy_loss": float(np.mean(stats["policy_loss"])) if stats["policy_loss"] else 0.0,
            "value_loss": float(np.mean(stats["value_loss"])),
            "approx_kl": float(np.mean(stats["approx_kl"])) if stats["approx_kl"] else 0.0,
            "clip_fraction": float(np.mean(stats["clip_fraction"])) if stats["clip_fraction"] else 0.0,
            "explained_variance": explained,
            "policy_std": float(actor.log_std.detach().exp().mean()),
            "lr": optimizer.param_groups[0]["lr"],
            "time_s": round(time.perf_counter() - started, 2),
        }
        log_rows.append(row)
        write_csv(out / "log.csv", log_rows)
        if writer is not None:
            for key, value in row.items():
                if key not in ("update", "env_steps") and not (
                    isinstance(value, float) and math.isnan(value)
                ):
                    writer.add_scalar(f"train/{key}", value, env_steps)
        if update % config.checkpoint_every == 0 or update == config.updates:
            torch.save(
                make_checkpoint(gnn, actor, critic, optimizer, update, config),
                out / "checkpoints" / "last.pt",
            )
        if update % config.eval_every == 0 or update == config.updates:
            evaluate_now(update)
        out_of_time = (
            config.time_limit_s is not None and time.perf_counter() - started > config.time_limit_s
        ) or (config.stop_after is not None and update >= config.stop_after)
        if out_of_time and update % config.eval_every != 0 and update != config.updates:
            evaluate_now(update)
        if bar is not None:
            bar.update()
            last_eval = eval_rows[-1]
            bar.set_postfix_str(
                f"ep {row['episode_time_s']:.1f}s kl {row['approx_kl']:.1e} eval "
                + " ".join(f"{k[:-9]}={v:.2f}" for k, v in last_eval.items() if k.endswith("_median_s") and v)
            )
        if out_of_time:
            break
    if bar is not None:
        bar.close()
    if writer is not None:
        writer.close()
    plot_curve(log_rows, eval_rows, out / "learning_curve.png")

    # -- export the chosen iterate ------------------------------------------------------------------
    if config.export == "last":
        torch.save(
            make_checkpoint(gnn, actor, critic, optimizer, update, config), out / "checkpoints" / "last.pt"
        )
        best_update = update
    chosen = "best" if config.export == "best" else "last"
    best = torch.load(out / "checkpoints" / f"{chosen}.pt", map_location="cpu", weights_only=False)
    gnn.load_state_dict(best["model"])
    gnn.to("cpu")
    training = {
        "algo": "ppo",
        "config": asdict(config),
        "chosen_update": best_update,
        "eval": eval_rows,
        "train_time_s": round(time.perf_counter() - started, 1),
        "init_policy": config.init_policy,
    }
    return gnn.export(out / "policy.npz", robot, training)
