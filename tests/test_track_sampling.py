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
