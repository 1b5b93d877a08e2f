"""``swarm.rl.formation_v0``: the formation task as a PettingZoo environment.

Oracles from outside the environment: PettingZoo's own checkers; the bottleneck distance by brute force
over every assignment, from the global state; the slots held and the neighbours heard read from the
global state and the graph.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from swarm.rl import formation_v0


@pytest.mark.parametrize(
    "overrides", [{"robots": 4, "topology": "line"}, {"robots": 5, "topology": "complete"}]
)
def test_the_formation_env_passes_pettingzoos_checks(overrides):
    from pettingzoo.test import api_test, parallel_api_test, parallel_seed_test

    parallel_api_test(formation_v0.parallel_env(**overrides), num_cycles=100)
    parallel_seed_test(lambda: formation_v0.parallel_env(**overrides))
    api_test(formation_v0.env(**overrides), num_cycles=20)


def _bottleneck(axles: np.ndarray, slots: np.ndarray) -> float:
    return min(
        max(float(np.hypot(*(axles[i] - slots[j]))) for i, j in enumerate(order))
        for order in itertools.permutations(range(len(slots)))
    )


def test_the_experts_episode_fills_every_slot_and_its_return_telescopes():
    """The ``capt`` expert's episode on a line of 5: the return is (B_0 - B_end) / step plus the bonus, B
    by brute force here; it ends with one axle per slot, no sooner than the lower bound; each robot's
    neighbour slots hold its line neighbours' axles of one tick before, and nothing at the start."""
    env = formation_v0.parallel_env(robots=5, topology="line", action_repeat=1)
    observations, infos = env.reset(seed=4)
    slots, count = env.slots, 5
    base = 4 + 2 * count

    def axles() -> np.ndarray:
        return env.state().reshape(count, 4)[:, :2].astype(np.float64)

    first, total, previous = _bottleneck(axles(), slots), 0.0, axles()
    assert infos["robot_0"]["bottleneck_m"] == pytest.approx(first, rel=1e-6)
    assert all(not obs[base:].any() for obs in observations.values())  # nothing heard at tick 0
    for i in range(count):  # the public slots, relative to the robot's own axle
        seen = observations[f"robot_{i}"][4:base].reshape(count, 2)
        assert np.allclose(seen, (slots - previous[i]) / env.scale_m, atol=1e-5)
    while env.agents:
        observations, rewards, terminations, truncations, infos = env.step(env.expert_actions())
        total += rewards["robot_0"]
        now = axles()
        for i in range(count):
            heard = observations[f"robot_{i}"][base:].reshape(count - 1, 3)
            neighbours = [j for j in (i - 1, i + 1) if 0 <= j < count]
            assert np.allclose(
                heard[: len(neighbours), :2], (previous[neighbours] - now[i]) / env.scale_m, atol=1e-5
            )
            assert heard[: len(neighbours), 2].tolist() == [1.0] * len(neighbours)
            assert not heard[len(neighbours) :].any()
        previous = now
    assert terminations["robot_0"] and not truncations["robot_0"]
    gaps = np.linalg.norm(axles()[:, None] - slots[None], axis=-1)
    assert np.all((gaps <= env.section.tolerance_m).sum(axis=0) == 1)
    assert infos["robot_0"]["time_s"] >= infos["robot_0"]["lower_bound_s"]
    assert total == pytest.approx((first - _bottleneck(axles(), slots)) / env.step_m + 10.0, rel=1e-4)


def test_standing_still_earns_nothing_and_is_truncated():
    env = formation_v0.parallel_env(robots=3, topology="cycle", time_limit_s=1.0)
    env.reset(seed=0)
    still = {agent: np.zeros(2, dtype=np.float32) for agent in env.agents}
    steps, total = 0, 0.0
    while env.agents:
        _, rewards, terminations, truncations, _ = env.step(still)
        steps, total = steps + 1, total + rewards["robot_0"]
    assert steps == 10 and total == 0.0 and truncations["robot_0"] and not terminations["robot_0"]
