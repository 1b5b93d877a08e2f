"""Reinforcement-learning environments and DQN (swarm.rl): API compliance, seeding, locality, parity."""

from __future__ import annotations

import json
import warnings

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from pettingzoo.test import api_test, parallel_api_test, parallel_seed_test

from swarm.core import graphs
from swarm.rl import ENV_ID, consensus_v0
from swarm.rl.consensus_env import ConsensusEnv
from swarm.rl.vector_env import ConsensusConfig, ConsensusVectorEnv
from swarm.sim.controllers import LocalConsensus
from swarm.sim.features import batched_features, saturate_local_velocity
from swarm.sim.kinematic import KinematicSim


@pytest.fixture(autouse=True)
def _quiet_space_warnings():
    with warnings.catch_warnings():
        # the first observation is zero by design: nothing has been heard yet
        warnings.filterwarnings("ignore", message=".*all zeros.*")
        yield


# --- API compliance ---------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "overrides",
    [{}, {"actions": "continuous"}, {"frame": "world", "topology": "random"}, {"others": "centralized"}],
)
def test_gymnasium_env_checker(overrides):
    env = gymnasium.make(ENV_ID, **overrides)
    assert env.spec.id == ENV_ID
    check_env(env.unwrapped, skip_render_check=True)
    continuous = overrides.get("actions") == "continuous"
    assert env.action_space == (
        gymnasium.spaces.Box(-1, 1, (2,)) if continuous else gymnasium.spaces.Discrete(4)
    )
    assert env.observation_space.shape == (4,)  # [Mx, My, Phix, Phiy]


@pytest.mark.parametrize("overrides", [{}, {"actions": "discrete", "topology": "random", "robots": 4}])
def test_pettingzoo_parallel_api(overrides):
    parallel_api_test(consensus_v0.parallel_env(**overrides), num_cycles=250)
    parallel_seed_test(lambda: consensus_v0.parallel_env(**overrides))


def test_pettingzoo_aec_api():
    api_test(consensus_v0.env(robots=4), num_cycles=30)


def test_config_rejects_bad_options():
    with pytest.raises(ValueError, match="topology"):
        ConsensusConfig(topology="mesh")
    with pytest.raises(ValueError, match="unknown environment option"):
        gymnasium.make(ENV_ID, nope=1)


# --- seeding -----------------------------------------------------------------------------------------
def _rollout(env: gymnasium.Env, seed: int, steps: int) -> list[tuple]:
    actions = np.random.default_rng(99).integers(0, 4, steps)
    obs, _ = env.reset(seed=seed)
    rows = [(obs.copy(),)]
    for action in actions:
        obs, reward, terminated, truncated, info = env.step(int(action))
        rows.append((obs.copy(), reward, terminated, truncated, info["max_pairwise"]))
        if terminated or truncated:
            obs, _ = env.reset()
            rows.append((obs.copy(),))
    return rows


def _same(a: list[tuple], b: list[tuple]) -> bool:
    return len(a) == len(b) and all(
        len(x) == len(y) and all(np.array_equal(u, v) for u, v in zip(x, y, strict=True))
        for x, y in zip(a, b, strict=True)
    )


def test_same_seed_same_trajectory():
    env = ConsensusEnv(time_limit_s=2.0)  # 10 steps per episode: the rollout crosses episode boundaries
    first, again = _rollout(env, 3, 40), _rollout(ConsensusEnv(time_limit_s=2.0), 3, 40)
    assert _same(first, again)
    assert not _same(first, _rollout(env, 4, 40))


def test_discrete_actions_are_robot_frame_point_velocities():
    env = ConsensusEnv(action_repeat=1)
    env.reset(seed=0)
    pose = env.core.sim.poses[0, 0].copy()
    env.step(0)  # forward: the axle moves along the heading at (nearly) v_max
    moved = env.core.sim.poses[0, 0, :2] - pose[:2]
    heading = np.array([np.cos(pose[2]), np.sin(pose[2])])
    assert moved @ heading == pytest.approx(env.config.v_max_mps * env.config.step_s, rel=1e-6)


def test_reward_and_termination_at_consensus():
    env = ConsensusEnv()
    env.reset(seed=0)
    for robot in range(env.config.robots):  # everyone within 5 cm of the origin: consensus after one step
        env.core.set_pose(0, robot, [0.01 * robot, 0.0, 0.0])
    _, reward, terminated, truncated, info = env.step(1)
    assert terminated and not truncated and info["is_success"] and info["max_pairwise"] <= 0.2
    positions = env.core.sim.poses[0, :, :2]
    distance = np.linalg.norm(positions[0] - positions[1:].mean(axis=0))
    assert reward == pytest.approx(env.config.success_bonus - env.config.step_s * distance, rel=1e-5)


def test_truncation_at_time_limit():
    env = ConsensusEnv(time_limit_s=1.0)  # 5 steps of 0.2 s; random starts are far from consensus
    env.reset(seed=1)
    ends = [env.step(2)[2:4] for _ in range(5)]
    assert ends == [(False, False)] * 4 + [(False, True)]


# --- locality and timing -----------------------------------------------------------------------------
def _line_env(learners: str) -> ConsensusVectorEnv:
    config = ConsensusConfig(topology="line", learners=learners, time_limit_s=100.0)
    env = ConsensusVectorEnv(1, config)
    env.reset(seed=5)
    return env


def _robot0_observations(learners: str, perturbed: int | None, ticks: int = 12) -> np.ndarray:
    """Robot 0's observation at ticks k, k+1, ... after robot ``perturbed`` is moved at tick k = 3."""
    env = _line_env(learners)
    actions = np.random.default_rng(0).uniform(-1, 1, (1, env.num_agents, 2))  # held: blind to observations
    for _ in range(3):
        env.step(actions)
    if perturbed is not None:
        pose = env.sim.poses[0, perturbed].copy()
        env.set_pose(0, perturbed, pose + np.array([0.3, -0.2, 0.5]))
    rows = [env.observe()[0, 0]]
    for _ in range(ticks):
        rows.append(env.step(actions)[0][0, 0])
    return np.array(rows)


@pytest.mark.parametrize("learners", ["all", "first"])
def test_observation_depends_on_nobody_elses_current_pose(learners):
    base = _robot0_observations(learners, None, ticks=0)
    for robot in range(1, 6):  # neighbour or not: at tick k robot 0 knows only messages of tick k-1
        assert np.array_equal(_robot0_observations(learners, robot, ticks=0), base)
    assert not np.array_equal(_robot0_observations(learners, 0, ticks=0), base)  # its own pose it knows


@pytest.mark.parametrize("learners", ["all", "first"])
def test_information_travels_one_hop_per_tick(learners):
    """Line 0-1-2-3-4-5: a robot h hops from robot 0 moved at tick k cannot change robot 0's observation
    before tick k + h (messages carry one hop per tick; so does motion, for experts reacting to them)."""
    base = _robot0_observations(learners, None)
    for hops in range(1, 6):
        changed = np.flatnonzero(np.any(_robot0_observations(learners, hops) != base, axis=1))
        first = changed[0] if len(changed) else None
        if hops <= 2:  # M sees neighbours one tick late, Phi (K = 2) second neighbours two ticks late
            assert first == hops, (hops, first)
        elif learners == "all":  # observation-blind learners: nothing carries information further
            assert first is None, (hops, first)
        else:  # experts react to what they heard and move: slower, but it does arrive
            assert first is not None and first >= hops, (hops, first)


# --- batched form ------------------------------------------------------------------------------------
def test_vector_env_equals_single_envs():
    count, seed, steps = 3, 11, 25
    overrides = {"time_limit_s": 1.0}  # 5-step episodes: auto-reset (vector) against reset() (single)
    vector = ConsensusVectorEnv(count, ConsensusEnv(**overrides).config)
    singles = [ConsensusEnv(**overrides) for _ in range(count)]
    actions = np.random.default_rng(0).integers(0, 4, (steps, count))
    obs, _ = vector.reset(seed=seed)
    for b, env in enumerate(singles):
        np.testing.assert_allclose(obs[b, 0], env.reset(seed=seed + b)[0], rtol=0, atol=1e-9)
    for t in range(steps):
        obs, reward, terminated, truncated, _ = vector.step(actions[t][:, None])
        for b, env in enumerate(singles):
            single_obs, single_reward, single_terminated, single_truncated, _ = env.step(int(actions[t, b]))
            assert (terminated[b], truncated[b]) == (single_terminated, single_truncated)
            assert reward[b] == pytest.approx(single_reward, abs=1e-6)
            if single_terminated or single_truncated:
                single_obs, _ = env.reset()
            np.testing.assert_allclose(obs[b, 0], single_obs, rtol=0, atol=1e-9)
    assert vector.steps.max() < steps  # episodes did restart


def test_pettingzoo_env_equals_vector_env():
    parallel = consensus_v0.parallel_env(topology="random")
    vector = ConsensusVectorEnv(1, parallel.config)
    observations, _ = parallel.reset(seed=7)
    obs, _ = vector.reset(seed=7)
    rng = np.random.default_rng(1)
    for _ in range(20):
        actions = rng.uniform(-1, 1, (6, 2)).astype(np.float32)
        obs, reward, *_ = vector.step(actions[None])
        observations, rewards, *_ = parallel.step(dict(zip(parallel.possible_agents, actions, strict=True)))
        assert np.array_equal(np.stack(list(observations.values())), obs[0])
        assert rewards["robot_3"] == reward[0]


def test_local_consensus_policy_reproduces_kinematic_sim():
    """Every robot an agent acting on its observation with eq. 3.1 (``u = K deg M``, saturated) moves the
    swarm exactly as ``KinematicSim`` with ``LocalConsensus``: same robot model, saturation and timing."""
    config = ConsensusConfig(topology="cycle", time_limit_s=100.0, gain=1.0)
    env = ConsensusVectorEnv(4, config, autoreset=False)
    obs, _ = env.reset(seed=2)
    sim = KinematicSim(
        env.robot,
        LocalConsensus(env.robot, config.gain),
        config.control_period_s,
        env.sim.poses.copy(),
        adjacency=graphs.cycle(config.robots),
    )
    degree = graphs.cycle(config.robots).sum(axis=1)[None, :, None]
    for _ in range(200):
        features, _ = batched_features(env.sim.poses, env.sim.points, env.sim.inbox, env.sim.heard, env.spec)
        np.testing.assert_allclose(features[..., 0, :], obs[..., :2], atol=1e-5)  # M, the observation
        wish = saturate_local_velocity(config.gain * degree * features[..., 0, :], env.robot)
        obs, *_ = env.step(wish / env.robot.v_max_mps)
        sim.step()
    np.testing.assert_allclose(env.sim.poses, sim.poses, rtol=0, atol=1e-9)


# --- DQN ---------------------------------------------------------------------------------------------
@pytest.mark.slow
def test_tiny_dqn_training_writes_its_outputs(tmp_path):
    from swarm.cli import main
    from swarm.rl import dqn

    config = tmp_path / "dqn.yaml"
    config.write_text(
        "total_timesteps: 1000\nlearning_starts: 200\neval_every: 500\n"
        "eval_episodes: 20\neval_episodes_during: 10\nenv: {robots: 5}\n"
    )
    out = tmp_path / "run"
    arguments = ["train", "--algo", "dqn", "--preset", "tiny", "--config", str(config), "--out", str(out)]
    assert main(arguments) == 0
    assert (out / "model.zip").is_file()
    for name in ("eval.json", "eval_curve.csv", "monitor.csv", "progress.csv", "learning_curve.png"):
        assert (out / name).stat().st_size > 0, name
    assert list(out.glob("events.out.tfevents.*")) and list((out / "checkpoints").glob("*.zip"))
    summary = json.loads((out / "eval.json").read_text())
    assert set(summary["results"]) == {"dqn_greedy", "random", "toward_neighbours"}
    assert summary["results"]["random"]["episodes"] == 20 and summary["env"]["robots"] == 5
    with pytest.raises(ValueError, match="unknown dqn option"):
        dqn.make_config("default", {"learning_rat": 1.0})
    assert main(["train", "--algo", "dqn", "--config", str(tmp_path / "missing.yaml")]) == 2
