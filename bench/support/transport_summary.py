"""The JSON result of bench/transport.py: medians over rounds, ratios against raw Zenoh and the
targets, loss counts, broadcast latency and the parameters of the run (a helper module)."""

from __future__ import annotations

import os
import statistics

TARGET_RATIO, GOAL_TRANSITIONS_PER_S = 0.5, 50_000.0
ACTOR_RHO_GOAL, ACTOR_RHO_RATIO = 40_000.0, 0.8


def learner_parameters(cfg) -> dict:
    """The learner's settings every ingest benchmark reports beside its figures."""
    return {
        "ingest_batch": cfg.learner.ingest_batch,
        "inbox_chunks": cfg.learner.inbox_chunks,
        "buffer_size": cfg.scale.buffer_size,
        "scale": cfg.scale.name,
        "agent": cfg.agent.name,
        "torch_threads": cfg.learner.torch_threads,
    }


def median(values: list[float]) -> float:
    return float(statistics.median(values)) if values else float("nan")


def summarize(
    rounds: list[dict],
    latency: dict[int, dict],
    args,
    cfg,
    chunk_bytes: int,
    weights_bytes: int,
    encode_ms: float,
    wall_s: float,
) -> dict:
    """The JSON result: medians over rounds, ratios, loss counts, broadcast latency, parameters."""

    def med(phase: str) -> float | None:
        values = [r[phase]["transitions_per_s"] for r in rounds if phase in r]
        return round(median(values), 1) if values else None

    def total(key: str) -> int:
        return int(sum(r[p][key] for r in rounds for p in r if p.startswith("ingest")))

    def ratio(a: float | None, b: float | None) -> float | None:
        return round(a / b, 4) if a is not None and b else None

    tps, raw = med("ingest"), med("raw")
    result = {
        "transitions_per_s": tps,
        "raw_zenoh_per_s": raw,
        "ratio": ratio(tps, raw),
        "transitions_per_s_with_rho": med("ingest_rho"),
        "ratio_with_rho": ratio(med("ingest_rho"), raw),
        "transitions_per_s_flat_out": med("ingest_flat_out"),
        "ratio_flat_out": ratio(med("ingest_flat_out"), raw),
        "ratio_per_repeat": [ratio(r["ingest"]["transitions_per_s"], r["raw"]["transitions_per_s"]) for r in rounds],
        "meets_ratio_target": tps / raw >= TARGET_RATIO,
        "meets_50k_goal": tps >= GOAL_TRANSITIONS_PER_S,
        "meets_50k_goal_with_rho": None if med("ingest_rho") is None else med("ingest_rho") >= GOAL_TRANSITIONS_PER_S,
        # rho where it scales: the actors send log mu_hat; target >= 40,000/s or >= 0.8x no rho
        "transitions_per_s_with_actor_rho": med("ingest_actor_rho"),
        "actor_rho_to_no_rho": ratio(med("ingest_actor_rho"), tps),
        "learner_rho_to_no_rho": ratio(med("ingest_rho"), tps),
        "meets_actor_rho_target": None
        if med("ingest_actor_rho") is None
        else (med("ingest_actor_rho") >= ACTOR_RHO_GOAL or med("ingest_actor_rho") >= ACTOR_RHO_RATIO * tps),
        "chunks_sent": total("sent"),
        "chunks_inserted": total("inserted_chunks"),
        "chunks_inbox_dropped": total("inbox_dropped"),
        "chunks_network_lost": total("network_lost"),
        "chunks_rejected": total("rejected"),
        "raw_chunks_lost": int(sum(r["raw"]["lost"] for r in rounds)),
        "weights_payload_bytes": weights_bytes,
        "weights_encode_ms": round(encode_ms, 3),
    }
    for n, lat in latency.items():
        result[f"weights_latency_ms_{n}"] = round(lat["median_ms"], 3)
        result[f"weights_latency_p90_ms_{n}"] = round(lat["p90_ms"], 3)
        result[f"weights_received_ms_{n}"] = round(lat["received_median_ms"], 3)
        result[f"weights_rtt_ms_{n}"] = round(lat["rtt_median_ms"], 3)
        result[f"weights_broadcasts_{n}"] = lat["broadcasts"]
        result[f"weights_missed_{n}"] = lat["missed"]
    result["rounds"] = [
        {phase: {k: round(v, 3) if isinstance(v, float) else v for k, v in r.items()} for phase, r in rnd.items()}
        for rnd in rounds
    ]
    result["params"] = {
        "seconds": args.seconds,
        "warmup": args.warmup,
        "repeats": args.repeats,
        "window": args.window,
        "broadcasts": args.broadcasts,
        "actors": args.actors,
        "chunk_len": cfg.actor.chunk_len,
        "frame_shape": [64, 128],
        "chunk_bytes": chunk_bytes,
        **learner_parameters(cfg),
        "cpus": os.cpu_count(),
        "overrides": args.overrides,
        "wall_s": round(wall_s, 1),
    }
    return result
