"""Smoke test of bench/transport.py: a tiny run end to end (router, producer, learner, actors);
its last line is the JSON result with every figure present and positive. No timing assertions."""

import math

import pytest

from tests.helpers import run_bench

TINY = [
    "--seconds",
    "0.3",
    "--warmup",
    "0.1",
    "--repeats",
    "1",
    "--broadcasts",
    "2",
    "--window",
    "32",
    "scale.buffer_size=1000",
    "learner.ingest_batch=8",
]
POSITIVE = [
    "transitions_per_s",
    "raw_zenoh_per_s",
    "ratio",
    "transitions_per_s_with_rho",
    "transitions_per_s_flat_out",
    "transitions_per_s_with_actor_rho",
    "weights_payload_bytes",
    "weights_latency_ms_1",
    "weights_latency_p90_ms_1",
    "weights_latency_ms_4",
    "weights_latency_p90_ms_4",
]


def test_bench_transport_prints_its_figures_as_json():
    pytest.importorskip("zenoh")
    result = run_bench("transport", TINY, timeout=180)
    for key in POSITIVE:
        assert isinstance(result[key], (int, float)) and math.isfinite(result[key]) and result[key] > 0, key
    assert isinstance(result["meets_ratio_target"], bool) and isinstance(result["meets_50k_goal"], bool)
    assert result["weights_missed_1"] == result["weights_missed_4"] == 0
    assert result["params"]["repeats"] == 1 and len(result["rounds"]) == 1
    # a paced producer never overruns the learner's inbox, and loopback loses nothing
    paced = result["rounds"][0]["ingest"]
    assert paced["inbox_dropped"] == 0 and paced["network_lost"] == 0 and paced["rejected"] == 0
    assert paced["inserted_chunks"] == paced["sent"] > 0
    actor_rho = result["rounds"][0]["ingest_actor_rho"]  # chunks with log_mu pass the checks
    assert actor_rho["rejected"] == 0 and actor_rho["inserted_chunks"] == actor_rho["sent"] > 0
    assert isinstance(result["meets_actor_rho_target"], bool)
