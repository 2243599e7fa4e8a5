"""Smoke test of bench/nstep.py: a tiny run whose last line is the JSON result with both rates
present and positive. No timing assertions."""

import math

from tests.helpers import run_bench


def test_bench_nstep_prints_both_rates_as_json():
    result = run_bench("nstep", ["--rounds", "1", "--per-round", "2", "--threads", "1"], timeout=180)
    for key in ("updates_per_s_1_step", "updates_per_s_5_step", "ratio"):
        assert isinstance(result[key], float) and math.isfinite(result[key]) and result[key] > 0, key
    assert result["n_step"] == 5 and isinstance(result["meets_limit"], bool)
