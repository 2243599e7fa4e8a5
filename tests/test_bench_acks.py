"""bench/support/acks.py: the scale benchmark's weight-ack bookkeeping in constant memory."""

import numpy as np

from bench.support.acks import BIN_MS, SPAN_MS, Acks, Latencies


def test_histogram_percentiles_match_the_exact_ones_to_a_bin():
    values = np.random.default_rng(0).gamma(2.0, 30.0, 5_000)
    lat = Latencies()
    for v in values:
        lat.add(float(v))
    for p in (50, 90, 99):
        exact = float(np.percentile(values, p, method="inverted_cdf"))
        assert abs(lat.percentile(p) - exact) <= BIN_MS
    assert lat.count == 5_000 and Latencies().percentile(99) is None


def test_latencies_beyond_the_span_are_kept_exactly_and_merge_adds_up():
    a, b = Latencies(), Latencies()
    for v in (1.0, 2.0, 3.0):
        a.add(v)
    b.add(SPAN_MS + 500.0)
    merged = a.merge(b)
    assert merged.count == 4 and merged.percentile(100) == SPAN_MS + 500.0
    assert abs(merged.percentile(50) - 2.0) <= BIN_MS


def test_acks_turn_into_latencies_forget_complete_versions_and_count_the_missed():
    acks = Acks(["a", "b", "c"])
    acks.published(1, 100.0)
    acks.published(2, 101.0)
    for name, arrived in (("a", 100.010), ("b", 100.020), ("c", 100.050), ("a", 100.900)):
        acks.add(name, 1, arrived)  # the repeated ack of a is ignored
    acks.add("a", 2, 101.030)
    acks.add("z", 7, 0.0)  # a version this phase never published
    assert 1 not in acks.pending and acks.waiting
    acks.close()
    assert acks.each.count == 4 and acks.to_all.count == 1 and acks.missed == 2
    assert abs(acks.to_all.percentile(50) - 50.0) <= BIN_MS
    assert abs(acks.each.percentile(100) - 50.0) <= BIN_MS and not acks.waiting
