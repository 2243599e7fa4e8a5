"""Smoke test of bench/scale.py: 1 and 4 emulated actors (two to a process) behind one router and
behind the far router of a mesh, then a 3-second memory run with rho at the actors; the last line
is the JSON result with every figure present and positive, nothing lost under BLOCK at this low
rate, and every broadcast acked. No timing assertions."""

import json
import math

import pytest

from tests.helpers import run_bench

TINY = [
    "--actors",
    "1",
    "4",
    "--topology",
    "router",
    "mesh",
    "--seconds",
    "1",
    "--warmup",
    "0.3",
    "--broadcasts",
    "3",
    "--broadcast-every",
    "0.3",
    "--rate",
    "2",
    "--per-process",
    "2",
    "--memory-minutes",
    "0.05",
    "--memory-every",
    "0.5",
    "--memory-rho",
    "actor",
    "scale.buffer_size=1000",
    "learner.ingest_batch=8",
]
POSITIVE = [
    "transitions_per_s_rho_learner",
    "transitions_per_s_rho_actor",
    "ingest_per_busy_s_rho_learner",
    "ingest_per_busy_s_rho_actor",
    "weights_latency_p50_ms",
    "weights_latency_p99_ms",
    "weights_acks",
]
PHASE_POSITIVE = [
    "transitions_per_s",
    "offered_transitions_per_s",
    "chunks_per_ingest",
    "chunks_sent",
    "weights_latency_p50_ms",
    "weights_latency_p99_ms",
    "weights_all_p50_ms",
    "weights_all_p99_ms",
]


def positive(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) and x > 0


def test_bench_scale_prints_its_figures_as_json():
    pytest.importorskip("zenoh")
    result = run_bench("scale", TINY, timeout=600)
    for topology in ("router", "mesh"):
        for n, case in result[topology].items():
            print(f"scale {topology} N={n}:", json.dumps({k: v for k, v in case.items() if k != "phases"}))
    assert result["params"]["actors"] == [1, 4] and result["params"]["topology"] == ["router", "mesh"]
    assert result["params"]["mesh_configs"]  # the mesh ran with deploy/zenoh/router-mesh-{a,b}.json5
    for topology in ("router", "mesh"):
        for n in (1, 4):
            case = result[topology][str(n)]
            where = f"{topology} N={n}"
            assert case["actors"] == n and case["processes"] == (n + 1) // 2, where
            for key in POSITIVE:
                assert positive(case[key]), (where, key, case[key])
            # BLOCK at 2 chunks/s per actor on loopback: every chunk arrives and enters the replay
            assert case["chunks_lost"] == case["chunks_missing"] == case["inbox_dropped"] == 0, where
            assert case["rejected"] == 0 and case["weights_missed"] == 0, where
            assert isinstance(case["meets_target"], bool), where
            for name, phase in case["phases"].items():
                for key in PHASE_POSITIVE:
                    assert positive(phase[key]), (where, name, key, phase[key])
                assert phase["chunks_inserted"] == phase["chunks_received"] == phase["chunks_sent"], (where, name)
                assert phase["broadcasts"] == 3 and phase["weights_acks"] == 3 * n, (where, name)
                routers = ["router"] if topology == "router" else ["router_a", "router_b"]
                for role in ["learner", "actors", *routers]:
                    # CPU is read in clock ticks: a router may spend less than one in a short phase
                    cpu = phase["cpu_s"][role]
                    assert math.isfinite(cpu) and cpu >= 0 and positive(phase["rss_mb"][role]), (where, name, role)
                assert positive(phase["cpu_s"]["learner"]), (where, name)
        # the memory run of the largest N, with the chunks carrying log mu_hat as asked
        memory = result["memory"][topology]
        assert memory["actors"] == 4 and memory["rho_at"] == "actor" and memory["samples"] >= 2, topology
        assert memory["chunks_lost"] == memory["chunks_missing"] == memory["inbox_dropped"] == 0, topology
        assert all(positive(r["max_mb"]) for r in memory["rss"].values()), topology
        for r in memory["rss"].values():
            assert len(r["series_mb"]) == memory["samples"] and max(r["series_mb"]) == round(r["max_mb"], 1), topology
