"""``PoseWindow``: which pose ticks an agent believes (swarm/runtime/ticks.py, eq. 1).

The oracle is the rule as the docs state it, written out here tick by tick: before its first pose an
agent believes tick 0 only; a newer tick within k + 1 + margin + floor(elapsed / step) of the newest
accepted one is accepted; one beyond it only once a second pose within its own window confirms it;
``RECOVER_AFTER`` old poses one tick apart become the clock again.
"""

from __future__ import annotations

import pytest

from swarm.runtime.ticks import ACCEPT, CANDIDATE, OLD, RECOVER_AFTER, PoseWindow

STEP_S = 0.05


def test_before_its_first_pose_an_agent_believes_tick_zero_only():
    window = PoseWindow(STEP_S)
    assert window.limit(0.0) == 0 and window.limit(1e6) == 0  # no time makes a later tick believable
    assert window.offer(7, 0.0) == CANDIDATE  # a restarted agent's first pose: held, not believed
    assert window.tick == -1 and window.limit(0.0) == 0  # messages dated after 0 are still future
    assert window.offer(7, 0.001) == CANDIDATE  # the same tick again confirms nothing
    assert window.tick == -1 and window.future == 1


def test_tick_zero_needs_no_confirmation():
    window = PoseWindow(STEP_S)
    assert window.offer(0, 0.0) == ACCEPT and window.tick == 0


def test_a_restarted_agent_follows_once_a_second_pose_confirms_its_first():
    window = PoseWindow(STEP_S)
    assert window.offer(500, 0.0) == CANDIDATE
    assert window.offer(501, 0.01) == ACCEPT and window.tick == 501
    assert window.confirmed == 1 and window.future == 0


def test_the_window_is_k_plus_two_plus_the_elapsed_steps():
    window = PoseWindow(STEP_S)
    window.offer(0, 0.0)
    assert window.offer(10, 0.0) == CANDIDATE  # beyond 0 + 2: held
    assert window.tick == 0
    fresh = PoseWindow(STEP_S)
    fresh.offer(0, 0.0)
    assert fresh.limit(0.0) == 2 and fresh.limit(0.049) == 2 and fresh.limit(0.05) == 3
    assert fresh.limit(1.0) == 22
    assert fresh.offer(2, 0.0) == ACCEPT and fresh.offer(5, 0.0) == CANDIDATE


def test_one_pose_far_ahead_never_moves_the_clock():
    window = PoseWindow(STEP_S)
    window.offer(0, 0.0)
    assert window.offer(10**6, 0.001) == CANDIDATE
    assert window.offer(1, 0.002) == ACCEPT  # the genuine next pose supersedes it
    assert window.tick == 1 and window.future == 1 and window.confirmed == 0
    for tick in range(2, 10):
        assert window.offer(tick, 0.002 + tick * 1e-3) == ACCEPT


def test_two_forged_poses_a_tick_apart_confirm_each_other_and_the_window_recovers():
    """The attack that the run key stops before the window (here: no run key): the jump is followed,
    the genuine poses look old, and after RECOVER_AFTER of them one tick apart they are the clock."""
    window = PoseWindow(STEP_S)
    for tick in range(21):
        window.offer(tick, tick * 1e-3)
    assert window.offer(10**6, 0.03) == CANDIDATE
    assert window.offer(10**6 + 1, 0.031) == ACCEPT  # confirmed: the window follows the forgery
    verdicts = [window.offer(tick, 0.032 + tick * 1e-3) for tick in range(21, 21 + RECOVER_AFTER + 3)]
    assert verdicts == [OLD] * (RECOVER_AFTER - 1) + [ACCEPT] * 4
    assert window.recovered == 1 and window.tick == 20 + RECOVER_AFTER + 3


def test_a_burst_walking_the_window_freezes_for_at_most_recover_after_ticks():
    window = PoseWindow(STEP_S)
    for tick in range(21):
        window.offer(tick, 0.0)
    accepted = [window.offer(20 + k, 0.0) for k in range(2, 82, 2)]  # each +2 of the last: the walk
    assert accepted == [ACCEPT] * 40 and window.tick == 100
    verdicts = [window.offer(tick, 0.0) for tick in range(21, 30)]
    assert verdicts[: RECOVER_AFTER - 1] == [OLD] * (RECOVER_AFTER - 1)
    assert verdicts[RECOVER_AFTER - 1 :] == [ACCEPT] * (len(verdicts) - RECOVER_AFTER + 1)


@pytest.mark.parametrize("replayed", [[5, 5, 5], [5, 3, 4], [7, 6, 5]])
def test_replays_that_do_not_advance_one_by_one_never_rewind_the_clock(replayed):
    window = PoseWindow(STEP_S)
    for tick in range(11):
        window.offer(tick, 0.0)
    assert [window.offer(tick, 0.0) for tick in replayed] == [OLD] * 3
    assert window.tick == 10 and window.recovered == 0


def test_close_counts_a_pending_candidate_as_future():
    window = PoseWindow(STEP_S)
    window.offer(0, 0.0)
    window.offer(10**6, 0.0)
    window.close()
    assert window.future == 1 and window.candidate is None
