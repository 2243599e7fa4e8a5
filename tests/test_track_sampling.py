"""Priority track sampling follows P(i) = exp(-n_i/kappa) / sum_j exp(-n_j/kappa), kappa = mean n."""

import math

import numpy as np
import pytest

from actors.track_sampling import PriorityTrackSampler


def test_initial_probabilities_are_equal():
    s = PriorityTrackSampler(["a", "b", "c", "d"])
    np.testing.assert_allclose(s.probabilities(), 0.25)


def test_probabilities_match_the_paper_formula():
    s = PriorityTrackSampler(["a", "b", "c"])
    for name, n in [("a", 100), ("b", 400), ("c-r", 1000)]:
        s.record(name, n)
    kappa = (100 + 400 + 1000) / 3
    expected = np.exp(-np.array([100, 400, 1000]) / kappa)
    np.testing.assert_allclose(s.probabilities(), expected / expected.sum())


def test_sampling_frequencies_follow_the_probabilities():
    s = PriorityTrackSampler(["short", "long"], np.random.default_rng(0))
    s.update({"short": 50, "long": 1200})
    p_short = s.probabilities()[0]
    draws = [s.sample() for _ in range(20000)]
    freq = draws.count("short") / len(draws)
    assert p_short == pytest.approx(math.exp(-50 / 625) / (math.exp(-50 / 625) + math.exp(-1200 / 625)))
    assert abs(freq - p_short) < 4 * math.sqrt(p_short * (1 - p_short) / len(draws))


def test_global_table_replaces_local_counts_and_ignores_unknown_roads():
    s = PriorityTrackSampler(["a", "b"])
    s.record("a", 10)
    s.update({"a": 300, "b": 20, "elsewhere": 5})
    assert s.table() == {"a": 300.0, "b": 20.0}


def test_empty_track_list_is_refused():
    with pytest.raises(ValueError, match="at least one"):
        PriorityTrackSampler([])


def test_the_draw_after_an_episode_uses_that_episodes_steps():
    """The actor's env records the finished episode before it draws the car's next road."""
    from actors.actor import make_env
    from common.config.run import RunConfig

    cfg = RunConfig()
    cfg.actor.num_envs = 1
    sampler = PriorityTrackSampler(["brook"], np.random.default_rng(0))
    seen = []  # the sampler's table at each draw
    draw = sampler.sample
    sampler.sample = lambda: (seen.append(dict(sampler.table())), draw())[1]
    env = make_env(cfg, sampler)
    env.reset(seed=0)
    steps = 0
    while len(seen) < 2:  # full left lock: off the road within a few seconds
        _, _, term, trunc, info = env.step(np.array([[1.0, 1.0]], np.float32))
        steps += 1
        assert steps < 1200
    assert term[0] and seen[0] == {"brook": 0.0}
    assert seen[1] == {"brook": float(info["final_info"]["steps"][0])} == {"brook": float(steps)}
