"""Consensus as an RL task: B environments x N robots stepping together in ``KinematicSim``.

This is the engine behind every environment in ``swarm.rl``: ``ConsensusVectorEnv`` (numpy arrays in
and out, auto-reset, for fast on-policy training), the thesis's single-agent Gymnasium env
(``swarm.rl.consensus_env``, one environment whose robot 0 learns) and the PettingZoo env
(``swarm.rl.consensus_v0``, one environment whose every robot is an agent). Thesis appendices C-D,
with its errors fixed (docs/design.md).

Episode. N robots start uniformly at random in the box ``swarm.core.initial_poses.box_for(N)`` (4 m x 4 m
for the thesis's 6) with a minimum separation and uniform headings, on the ``topology`` graph
(``random``: a connected G(N, p) redrawn every episode). Learning robots apply their action; the
others (``learners="first"``: robots 1..N-1) run ``others``: local consensus on the graph (eq. 3.1
with last tick's neighbour points, ``swarm.sim.controllers.LocalConsensus``) or the centralized expert.
Same robot model, saturation and integration as every engine (``KinematicSim`` kernels).

Information timing (docs/design.md). At tick k robot i observes what ``swarm.sim.features`` computes from its
own pose at tick k and the messages ``[p_j, M_j]`` its neighbours broadcast at tick k-1, in its own
frame (``frame="robot"``): ``[Mx, My, Phix, Phiy]`` for K = ``hops`` = 2 (thesis appendix C), ``2K``
numbers in general. On an episode's first tick nobody has heard anybody: the observation is zero
and experts hold still, exactly as in ``KinematicSim`` and the distributed runtime. Every robot,
learner or expert, broadcasts the same message, so learners may sit anywhere in the graph.

Actions of a learning robot, in its own frame (x forward, y left; ``frame="world"``: world axes):

- ``continuous``: ``a`` in ``[-1, 1]^2``, wished point velocity ``v_max a``;
- ``discrete`` (thesis, "up/down/left/right"): 0 forward, 1 backward, 2 left, 3 right, times ``v_max``.

The wish is saturated as every controller's is (``swarm.sim.features.saturate_local_velocity``: one
factor on both wheels, ``|ux| + (d/l)|uy| <= v_max``; sideways the point moves at most
``v_max l/d``) and held for ``action_repeat`` control ticks (the decision period ``dt``).

Reward, shared by all learners, per step (units m s)::

    r = -dt * mean_{i in learners} |x_i - c_{-i}|  +  success_bonus * terminated

``x`` the axle positions after the step, ``c_{-i}`` the centroid of the robots other than i: minus
the time integral of the learners' distance to the rest of the swarm, so a policy earns most by
reaching the others fast and staying there. Terminated: consensus, ``max_pairwise <= threshold_m``
(docs/design.md metric) after the step. Truncated: ``time_limit_s`` of simulated time without consensus.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, replace
from typing import Literal

import numpy as np
from gymnasium import spaces

from swarm.core import topologies
from swarm.core.experts import complete_consensus_velocity
from swarm.core.initial_poses import box_for, random_poses
from swarm.core.metrics import max_pairwise
from swarm.core.robot import RobotParams, controlled_point, rotate
from swarm.sim import kernels
from swarm.sim.features import FeatureSpec, batched_features, messages, saturate_local_velocity
from swarm.sim.kinematic import KinematicSim
from swarm.sim.links import Links

# Discrete actions: unit point velocities (forward "up", backward "down", left, right) in the action frame.
DISCRETE_ACTIONS = np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]])


@dataclass(frozen=True)
class ConsensusConfig:
    """One consensus task. Defaults: the multi-agent form (every robot learns, continuous actions)."""

    robots: int = 6
    topology: str = "cycle"  # complete | cycle | line | star | random (connected G(N, p), new every episode)
    random_p: float = 0.5
    learners: str = "all"  # "all": every robot is an agent; "first": robot 0 learns, the others run `others`
    others: str = "local_consensus"  # or "centralized": the law of the robots that do not learn
    gain: float = 1.0  # K of eq. 3.1 for the experts (1/s)
    actions: str = "continuous"  # or "discrete" (4 unit point velocities, the thesis's up/down/left/right)
    frame: str = "robot"  # frame of observations and actions: "robot" (thesis eq. 3.2-3.3, fixed) or "world"
    hops: int = 2  # K: observation [M, Phi2, ..., PhiK] (2K numbers; K = 2 is the thesis's)
    normaliser: Literal["degree", "n_minus_1"] = "degree"  # "n_minus_1": the thesis's, needs N
    v_max_mps: float = 0.5
    control_period_s: float = 0.05
    action_repeat: int = 1  # control ticks per environment step
    time_limit_s: float = 10.0
    threshold_m: float = 0.2  # consensus: max_pairwise <= threshold
    min_separation_m: float = 0.4
    success_bonus: float = 1.0

    def __post_init__(self) -> None:
        choices = {
            "topology": topologies.kinds(grid=True, fixed=True),
            "learners": ("all", "first"),
            "others": ("local_consensus", "centralized"),
            "actions": ("continuous", "discrete"),
            "frame": ("robot", "world"),
        }
        for name, allowed in choices.items():
            if getattr(self, name) not in allowed:
                raise ValueError(f"{name} must be one of {allowed}, got {getattr(self, name)!r}")
        if self.robots < 2:
            raise ValueError(f"robots must be >= 2, got {self.robots}")
        if self.action_repeat < 1 or self.max_steps < 1:
            raise ValueError("action_repeat and the time limit must allow at least one step")
        FeatureSpec(self.hops, "m", self.normaliser)  # validates hops and normaliser

    @property
    def step_s(self) -> float:
        """Simulated seconds per environment step."""
        return self.action_repeat * self.control_period_s

    @property
    def max_steps(self) -> int:
        return math.ceil(self.time_limit_s / self.step_s - 1e-9)

    @property
    def robot(self) -> RobotParams:
        """BubbleRob-like defaults (``swarm.core.robot``) with this task's wheel-speed limit."""
        return RobotParams(v_max_mps=self.v_max_mps)

    @property
    def learner_count(self) -> int:
        return self.robots if self.learners == "all" else 1

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict, base: ConsensusConfig | None = None) -> ConsensusConfig:
        known = {item.name for item in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(f"unknown environment option {unknown[0]!r}; known: {sorted(known)}")
        return replace(base or cls(), **data)


def observation_space(config: ConsensusConfig) -> spaces.Box:
    """Features are averages of differences of controlled points, which stay within ``v_max * time_limit``
    (plus the offset l) of the start box, so each coordinate is bounded by twice that reach."""
    reach_m = box_for(config.robots)[1] + config.v_max_mps * config.time_limit_s + config.robot.offset_m
    return spaces.Box(-2 * reach_m, 2 * reach_m, shape=(2 * config.hops,), dtype=np.float32)


def action_space(config: ConsensusConfig) -> spaces.Space:
    if config.actions == "discrete":
        return spaces.Discrete(len(DISCRETE_ACTIONS))
    return spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)


class _MixedController:
    """Batched controller (``swarm.sim.controllers`` protocol): learners apply the wish set in ``wish``,
    the others the expert; everyone broadcasts ``[p, Phi1..Phi(K-1)]`` (``swarm.sim.features.messages``)."""

    centralized = False

    def __init__(self, config: ConsensusConfig, robot: RobotParams, spec: FeatureSpec):
        self.config, self.robot, self.spec = config, robot, spec
        self.message_dim = spec.message_dim
        self.learners = np.arange(config.learner_count)
        self.wish = np.zeros((0, config.learner_count, 2))  # (B, L, 2) in the action frame, m/s

    def act(
        self, poses: np.ndarray, points: np.ndarray, inbox: np.ndarray, heard: Links
    ) -> tuple[np.ndarray, np.ndarray]:
        _, phi_world = batched_features(poses, points, inbox, heard, self.spec)
        u_world = np.zeros_like(points)
        if self.config.learner_count < self.config.robots:
            if self.config.others == "centralized":
                u_world = complete_consensus_velocity(points, self.config.gain)
            else:
                neighbour_points = np.ascontiguousarray(inbox[..., :2])
                kernels.delayed_consensus(
                    points, neighbour_points, heard.index, heard.weight, self.config.gain, u_world
                )
        theta = poses[:, self.learners, 2]
        if self.config.frame == "robot":
            u_world[:, self.learners] = rotate(saturate_local_velocity(self.wish, self.robot), theta)
        else:  # saturation is a property of the robot: apply it in the robot's frame
            local = rotate(self.wish, -theta)
            u_world[:, self.learners] = rotate(saturate_local_velocity(local, self.robot), theta)
        return u_world, messages(points, phi_world, u_world, self.spec)


class _RestartableSim(KinematicSim):
    """``KinematicSim`` whose environments restart one by one: new poses, new graph, nothing heard yet.

    The only place in ``swarm.rl`` that touches the simulator's private state (its fixed links and
    the links last tick's messages went over, read by ``heard``); ``tests/test_rl.py`` pins the behaviour.
    """

    def __init__(self, robot, controller, control_period_s, initial_poses, adjacency):
        batch, count, _ = initial_poses.shape
        self._adjacency = np.array(np.broadcast_to(adjacency, (batch, count, count)))
        super().__init__(robot, controller, control_period_s, initial_poses, adjacency=self._adjacency)

    @property
    def heard(self) -> Links:
        """Who heard whom with the messages now in ``inbox`` (the graph of the last tick)."""
        return self._sent_over

    def restart(self, envs: np.ndarray, poses: np.ndarray, adjacency: np.ndarray | None = None) -> None:
        """Environments ``envs`` (indices) start over from ``poses (E, N, 3)`` (``KinematicSim.restart``)
        on ``adjacency (E, N, N)`` (None: the graph they had)."""
        super().restart(envs, poses)
        if adjacency is not None and not np.array_equal(self._adjacency[envs], adjacency):
            self._adjacency[envs] = adjacency
            self._fixed_links = Links.from_dense(self._adjacency)


class ConsensusVectorEnv:
    """B consensus environments stepping together; numpy in, numpy out.

    ``reset(seed)`` -> ``obs (B, L, 2K)`` float32, info. ``step(actions)`` with ``actions (B, L, 2)``
    (continuous) or ``(B, L)`` integers (discrete) -> ``obs, reward (B,), terminated (B,),
    truncated (B,), info``; L is the number of learning robots (N, or 1 for ``learners="first"``).
    With ``autoreset`` (default) a finished environment restarts within the same step: its ``obs``
    row is the new episode's first observation; on such a step ``info`` also holds ``final_obs``,
    ``episode_return``, ``episode_length`` and ``is_success`` (rows valid where ``terminated | truncated``).

    Environment b draws its episodes from its own generator, seeded ``seed + b``: it replays exactly
    the episodes of a single environment reset with ``seed + b``.
    """

    def __init__(self, num_envs: int, config: ConsensusConfig | None = None, autoreset: bool = True):
        self.config = config = config or ConsensusConfig()
        self.num_envs = int(num_envs)
        self.autoreset = autoreset
        self.robot = config.robot
        self.spec = FeatureSpec(config.hops, "m", config.normaliser)
        self.num_agents = config.learner_count
        self.single_observation_space = observation_space(config)
        self.single_action_space = action_space(config)
        self.controller = _MixedController(config, self.robot, self.spec)
        self.box_m = box_for(config.robots)
        self.rngs: list[np.random.Generator] = []
        self._sim: _RestartableSim | None = None
        self.steps = np.zeros(self.num_envs, dtype=np.int64)
        self.returns = np.zeros(self.num_envs)

    @property
    def sim(self) -> _RestartableSim:
        """The batched simulator (after the first ``reset``)."""
        if self._sim is None:
            raise RuntimeError("call reset() first")
        return self._sim

    # --- episodes -------------------------------------------------------------------------------
    def _draw(self, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """One episode's start: poses ``(N, 3)`` and graph ``(N, N)``."""
        config = self.config
        poses = random_poses(rng, 1, config.robots, self.box_m, self.box_m, config.min_separation_m)[0]
        adjacency = topologies.draw(config.topology, config.robots, rng, p=config.random_p)
        assert adjacency is not None  # ConsensusConfig.check: a fixed kind
        return poses, adjacency

    def reset(
        self, seed: int | None = None, rngs: list[np.random.Generator] | None = None
    ) -> tuple[np.ndarray, dict]:
        """Start every environment over. ``rngs`` (one generator per environment) overrides ``seed``."""
        if rngs is not None:
            self.rngs = list(rngs)
        elif seed is not None or not self.rngs:
            self.rngs = [
                np.random.default_rng(None if seed is None else seed + b) for b in range(self.num_envs)
            ]
        if len(self.rngs) != self.num_envs:
            raise ValueError(f"need {self.num_envs} generators, got {len(self.rngs)}")
        starts = [self._draw(rng) for rng in self.rngs]
        poses = np.stack([start[0] for start in starts])
        adjacency = np.stack([start[1] for start in starts])
        self.controller.wish = np.zeros((self.num_envs, self.num_agents, 2))
        self._sim = _RestartableSim(
            self.robot, self.controller, self.config.control_period_s, poses, adjacency
        )
        self.steps[:] = 0
        self.returns[:] = 0.0
        return self.observe(), {"max_pairwise": max_pairwise(poses[..., :2])}

    def _restart(self, envs: np.ndarray) -> None:
        starts = [self._draw(self.rngs[b]) for b in envs]
        self.sim.restart(envs, np.stack([s[0] for s in starts]), np.stack([s[1] for s in starts]))
        self.steps[envs] = 0
        self.returns[envs] = 0.0

    # --- observation, action, reward -------------------------------------------------------------
    def observe(self) -> np.ndarray:
        """Every learner's observation at the current tick ``(B, L, 2K)`` float32 (see the module doc)."""
        sim = self.sim
        local, world = batched_features(sim.poses, sim.points, sim.inbox, sim.heard, self.spec)
        features = local if self.config.frame == "robot" else world
        learners = features[:, : self.num_agents]
        return learners.reshape(self.num_envs, self.num_agents, -1).astype(np.float32)

    def wish_from_actions(self, actions: np.ndarray) -> np.ndarray:
        """Actions -> wished point velocities ``(B, L, 2)`` in the action frame (m/s, before saturation)."""
        if self.config.actions == "discrete":
            actions = np.asarray(actions, dtype=np.int64).reshape(self.num_envs, self.num_agents)
            return self.robot.v_max_mps * DISCRETE_ACTIONS[actions]
        actions = np.asarray(actions, dtype=np.float64).reshape(self.num_envs, self.num_agents, 2)
        return self.robot.v_max_mps * np.clip(actions, -1.0, 1.0)

    def distance_to_others(self, positions: np.ndarray) -> np.ndarray:
        """``(B,)`` mean over learners of the distance from robot i to the centroid of the others (m)."""
        count = positions.shape[1]
        learners = positions[:, : self.num_agents]
        others_centroid = (positions.sum(axis=1, keepdims=True) - learners) / (count - 1)
        return np.linalg.norm(learners - others_centroid, axis=-1).mean(axis=-1)

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict]:
        config, sim = self.config, self.sim
        self.controller.wish = self.wish_from_actions(actions)
        for _ in range(config.action_repeat):
            sim.step()
        positions = sim.poses[..., :2]
        spread_m = max_pairwise(positions)
        terminated = spread_m <= config.threshold_m
        self.steps += 1
        truncated = ~terminated & (self.steps >= config.max_steps)
        reward = -config.step_s * self.distance_to_others(positions) + config.success_bonus * terminated
        self.returns += reward
        info = {"max_pairwise": spread_m, "time_s": self.steps * config.step_s}
        obs = self.observe()
        done = np.flatnonzero(terminated | truncated)
        if self.autoreset and len(done):
            info.update(
                final_obs=obs.copy(),
                episode_return=self.returns.copy(),
                episode_length=self.steps.copy(),
                is_success=terminated.copy(),
            )
            self._restart(done)
            obs[done] = self.observe()[done]
        return obs, reward.astype(np.float32), terminated, truncated, info

    # --- for tests and perturbation studies ------------------------------------------------------
    def set_pose(self, env: int, robot: int, pose: np.ndarray) -> None:
        """Move one robot instantly (its messages already sent are unchanged)."""
        pose = np.asarray(pose, dtype=np.float64)
        self.sim.poses[env, robot] = pose
        self.sim.headings[env, robot] = np.cos(pose[2]), np.sin(pose[2])
        self.sim.points[env, robot] = controlled_point(pose, self.robot.offset_m)

    def adjacency(self) -> np.ndarray:
        """The current graph of every environment ``(B, N, N)``."""
        return self.sim.adjacency()
