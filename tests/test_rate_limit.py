"""The learner's rate limit on hand-made counts (learner.rate_limit)."""

import pytest

from learner.rate_limit import RateLimiter


def test_no_update_is_owed_before_the_warm_up_then_one_per_batch_over_ratio():
    r = RateLimiter(batch_size=64, samples_per_insert=8)  # one update per 8 inserted transitions
    assert r.per_update == 8
    assert r.owed(inserted=999, ready=False) == 0 and r.ready_at is None
    assert r.owed(inserted=1000, ready=True) == 1 and r.ready_at == 1000  # the first one at once
    r.done = 1
    assert r.owed(inserted=1007, ready=True) == 0
    assert r.owed(inserted=1008, ready=True) == 1
    assert r.owed(inserted=1100, ready=True) == 1 + (100 - 8) // 8
    r.done = 20  # more done than the data allows is never negative
    assert r.owed(inserted=1100, ready=True) == 0


def test_a_ratio_above_the_batch_owes_several_updates_per_transition():
    r = RateLimiter(batch_size=32, samples_per_insert=64)
    assert r.per_update == 0.5
    r.owed(inserted=64, ready=True)
    r.done = 1
    assert r.owed(inserted=74, ready=True) == 1 + (10 - 0.5) // 0.5


def test_pause_above_the_limit_and_resume_only_within_half_of_it():
    r = RateLimiter(batch_size=64, samples_per_insert=8, max_owed_updates=10)  # limit 80 transitions
    assert not r.should_pause(80)
    assert r.should_pause(81)
    assert r.should_pause(41)  # hysteresis: still more than half the limit
    assert not r.should_pause(40)
    assert not r.should_pause(79)


def test_data_ahead_counts_the_replay_before_the_warm_up_and_the_surplus_after():
    r = RateLimiter(batch_size=64, samples_per_insert=8, max_owed_updates=10)
    assert r.ahead(inserted=0, waiting=32, replay=900, warmup=1000) == -68  # a resumed learner: its replay
    r.owed(inserted=1000, ready=True)
    r.done = 5
    assert r.ahead(inserted=1100, waiting=32, replay=1100, warmup=1000) == 100 - 40 + 32


def test_never_pauses_when_the_limit_is_off_and_refuses_bad_ratios():
    assert not RateLimiter(64, 8, max_owed_updates=0).should_pause(1e9)
    with pytest.raises(ValueError, match="learner.samples_per_insert"):
        RateLimiter(64, 0)
    with pytest.raises(ValueError, match="learner.max_owed_updates"):
        RateLimiter(64, 8, max_owed_updates=-1)
