"""Many actors on one learner: ingest with rho, chunks lost, and the weight broadcast's latency to
N subscribers, for N emulated actors behind one router or behind the far router of a mesh.

Processes, all started with `spawn` (forking after zenoh is initialised hangs), on 127.0.0.1:

  routers    `common.transport.zenoh_backend.run_router` on free ports. Topology 'router': one,
             for everyone. 'mesh': router A (the learner's) and router B connected to it (the
             actors'), configured by deploy/zenoh/router-mesh-{a,b}.json5 where present
  actors     N emulated actors (bench/support/scale_procs.py): each one Zenoh session replaying valid
             TransitionChunks (own key, own seq, congestion control BLOCK) at --rate chunks/s
             and acking every weights version with the time.time() it arrived. No simulator,
             no policy, not a process each: up to --per-process share one OS process
  this one   the learner (bench/support/scale_learner.py): a real `LearnerService` whose `ingest()`
             (bounded inbox, strict decode, sequence gaps, insert with rho) runs in a loop with
             no training, publishing a Weights message of the real policy every
             --broadcast-every s, --broadcasts times

For each topology and each N (--actors), two phases of --warmup then at least --seconds (longer
until the broadcasts are out), with `learner.rho_at=actor`:

  rho_learner  the chunks carry no log mu_hat: the learner runs the discriminator at insert
               (Algorithm 1, lines 8-10); the weights carry the acting policy
  rho_actor    the chunks carry the actors' log mu_hat: the learner only forms tau / mu_hat;
               the weights also carry the discriminator (behaviour.*), as actors would need

Figures per phase: transitions/s inserted in the measured window (and offered), and per second
spent inside `ingest()` with the chunks per call this load gives (a light load gives small
batches, which cost more per transition than the full ones of a saturated learner); over the whole
phase (warm-up and drain too) chunks lost (the learner's seq gaps), chunks missing (sent, never
received), inbox drops and rejects; the weight latency from publish to arrival at each
subscriber (p50/p99 over every broadcast x subscriber) and to the last of the N (p50/p99 over
broadcasts); CPU seconds and resident MB of the learner (this process, which also paces the
phases), the routers and the actor processes. Per N they are summed or pooled over both phases.
With --memory-minutes M, the largest N then runs M minutes more per topology (rho where
--memory-rho says, the learner by default; weights every --broadcast-every s), router and
learner RSS sampled every --memory-every s: first, last and max (is memory flat?). `meets_target` per N: no chunk lost,
missing or dropped and p99 <= 100 ms (DESIGN.md asks it of N = 256).

Usage: python bench/scale.py [--actors 1 16 64 256] [--topology router mesh] [--rate 1]
       [--seconds 10] [--warmup 2] [--broadcasts 20] [--broadcast-every 0.5] [--per-process 32]
       [--memory-minutes 0] [--memory-every 10] [--memory-rho learner|actor]
       [hydra overrides, e.g. learner.ingest_batch=16; learner.weights_dtype=float16 broadcasts
       half the bytes, uint8 about a quarter]
The last line printed is one JSON object: {"router": {N: figures}, "mesh": {N: ...}, "memory":
{topology: ...} (with --memory-minutes), "params": {...}}; one line per N goes to stderr as it ends.
"""

from __future__ import annotations

import argparse
import functools
import json
import logging
import multiprocessing as mp
import os
import sys
import tempfile
import time
from pathlib import Path

# run as a script, bench/ comes first on sys.path: the repository root goes there instead, so
# that `bench.support.scale_procs` imports here and in the spawned processes that inherit it
_HERE = Path(__file__).resolve().parent
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != _HERE]
sys.path.insert(0, str(_HERE.parent))

from bench.support.acks import Latencies  # noqa: E402
from bench.support.scale_learner import Learner  # noqa: E402
from bench.support.scale_procs import (  # noqa: E402
    MESH_CONFIGS,
    TOPOLOGIES,
    actor_name,
    start_fleet,
    start_topology,
    stop_all,
)
from bench.support.transport_procs import episode_payloads  # noqa: E402
from bench.support.transport_summary import learner_parameters  # noqa: E402
from bench.transport import compose  # noqa: E402

LATENCY_P99_TARGET_MS = 100.0
"""DESIGN.md: 256 emulated actors on one learner, 0 chunks lost, weight latency p99 <= 100 ms."""
FRAME_SHAPE = (64, 128)
PHASES = {"rho_learner": False, "rho_actor": True}
"""Phase -> whether the chunks carry log mu_hat."""


def run_case(learner: Learner, ctx, actor_cfg, n: int, args, memory_minutes: float) -> tuple[dict, dict | None]:
    """N actors: both phases, then the memory run if asked; the actors are stopped at the end."""
    cfg = learner.cfg
    names = [actor_name(n, i) for i in range(n)]
    groups = start_fleet(
        ctx, actor_cfg, cfg.run, n, args.per_process, cfg.actor.chunk_len, FRAME_SHAPE, args.rate, learner.acks
    )
    try:
        learner.join(groups, names)
        shared = dict(groups=groups, names=names, rate=args.rate, warmup=args.warmup, every=args.broadcast_every)
        phases = {
            phase: learner.phase(**shared, log_mu=log_mu, seconds=args.seconds, broadcasts=args.broadcasts)
            for phase, log_mu in PHASES.items()
        }
        memory = None
        if memory_minutes > 0:
            memory = learner.phase(
                **shared,
                log_mu=args.memory_rho == "actor",
                seconds=memory_minutes * 60,
                broadcasts=None,
                sample_every=args.memory_every,
            )
    finally:
        for g in groups:
            g.quit()
        stop_all([g.process for g in groups], timeout=30)
    return summarize_case(n, len(groups), phases), memory and summarize_memory(memory, memory_minutes)


def summarize_case(n: int, processes: int, phases: dict) -> dict:
    each = functools.reduce(Latencies.merge, [p.pop("_latencies") for p in phases.values()])
    totals = {k: sum(p[k] for p in phases.values()) for k in ("chunks_lost", "chunks_missing", "inbox_dropped")}
    p99 = each.percentile(99)
    return {
        "actors": n,
        "processes": processes,
        **{f"transitions_per_s_{name}": p["transitions_per_s"] for name, p in phases.items()},
        **{f"ingest_per_busy_s_{name}": p["ingest_per_busy_s"] for name, p in phases.items()},
        **totals,
        "rejected": sum(p["rejected"] for p in phases.values()),
        "weights_latency_p50_ms": each.percentile(50),
        "weights_latency_p99_ms": p99,
        "weights_acks": each.count,
        "weights_missed": sum(p["weights_missed"] for p in phases.values()),
        "meets_target": not any(totals.values()) and p99 is not None and p99 <= LATENCY_P99_TARGET_MS,
        "phases": phases,
    }


def summarize_memory(m: dict, minutes: float) -> dict:
    each = m.pop("_latencies")
    samples = m.pop("rss_samples")
    rss = {
        role: {
            "first_mb": samples[0][role],
            "last_mb": samples[-1][role],
            "max_mb": max(s[role] for s in samples),
            "growth_mb": samples[-1][role] - samples[0][role],
            # a leak keeps growing after start-up; warm-up growth stops in the first half
            "second_half_growth_mb": samples[-1][role] - samples[len(samples) // 2][role],
            "series_mb": [round(s[role], 1) for s in samples],
        }
        for role in samples[0]
    }
    keep = ("transitions_per_s", "chunks_sent", "chunks_lost", "chunks_missing", "inbox_dropped", "rejected")
    return {
        "minutes": minutes,
        "samples": len(samples),
        "rss": rss,
        **{k: m[k] for k in keep},
        "weights_latency_p50_ms": each.percentile(50),
        "weights_latency_p99_ms": each.percentile(99),
        "weights_missed": m["weights_missed"],
        "cpu_s": m["cpu_s"],
    }


def rounded(x):
    if isinstance(x, float):
        return round(x, 3)
    if isinstance(x, dict):
        return {k: rounded(v) for k, v in x.items()}
    if isinstance(x, list):
        return [rounded(v) for v in x]
    return x


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--actors", type=int, nargs="+", default=[1, 16, 64, 256], help="emulated actor counts N")
    parser.add_argument("--topology", nargs="+", choices=TOPOLOGIES, default=list(TOPOLOGIES), help="router layouts")
    parser.add_argument("--rate", type=float, default=1.0, help="chunks/s each emulated actor sends")
    parser.add_argument("--seconds", type=float, default=10.0, help="measured seconds per phase (at least)")
    parser.add_argument("--warmup", type=float, default=2.0, help="unmeasured seconds before each phase")
    parser.add_argument("--broadcasts", type=int, default=20, help="timed weight broadcasts per phase")
    parser.add_argument("--broadcast-every", type=float, default=0.5, help="seconds between weight broadcasts")
    parser.add_argument("--per-process", type=int, default=32, help="emulated actors packed in one OS process")
    parser.add_argument("--memory-minutes", type=float, default=0.0, help="then run the largest N this long")
    parser.add_argument("--memory-every", type=float, default=10.0, help="seconds between RSS samples of that run")
    parser.add_argument("--memory-rho", choices=["learner", "actor"], default="learner", help="rho in that run")
    parser.add_argument("overrides", nargs="*", help="hydra overrides of the run config, e.g. learner.ingest_batch=16")
    args = parser.parse_args(argv)
    if min(args.actors) < 1 or args.rate <= 0 or args.per_process < 1 or args.broadcasts < 1:
        parser.error("--actors, --rate, --per-process and --broadcasts must be positive")
    logging.basicConfig(level=logging.WARNING, stream=sys.stderr)

    # rho_at=actor: the learner takes a chunk's log mu_hat where there is one, else runs g itself
    cfg = compose(["run=bench-scale", "learner.device=cpu", "transport=local", "learner.rho_at=actor", *args.overrides])
    chunk_bytes = {
        phase: len(episode_payloads(cfg.actor.chunk_len, FRAME_SHAPE, seed=1, log_mu=log_mu)[0][0])
        for phase, log_mu in PHASES.items()
    }
    ctx = mp.get_context("spawn")
    actors = sorted(set(args.actors))
    results: dict = {}
    memory: dict = {}
    weights_bytes: dict = {}
    started = time.perf_counter()
    for topology in args.topology:
        stop = ctx.Event()
        routers: dict = {}
        learner = None
        tmp = tempfile.TemporaryDirectory(prefix="bench-scale-")
        try:
            learner_cfg, actor_cfg, routers = start_topology(ctx, cfg.transport, topology, stop)
            learner = Learner(cfg, learner_cfg, routers, tmp.name)
            weights_bytes = {phase: len(learner.encoded(log_mu, version=0)) for phase, log_mu in PHASES.items()}
            results[topology] = {}
            for n in actors:
                minutes = args.memory_minutes if n == actors[-1] else 0.0
                case, mem = run_case(learner, ctx, actor_cfg, n, args, minutes)
                results[topology][str(n)] = case
                print(json.dumps({"topology": topology, **rounded(case)}), file=sys.stderr, flush=True)
                if mem is not None:
                    memory[topology] = {"actors": n, "rho_at": args.memory_rho, **mem}
        finally:
            if learner is not None:
                learner.close()
            stop.set()
            stop_all(list(routers.values()))
            tmp.cleanup()
    out = {**results}
    if memory:
        out["memory"] = memory
    out["params"] = {
        **{k: getattr(args, k) for k in ("actors", "topology", "rate", "seconds", "warmup", "broadcasts")},
        **{
            k: getattr(args, k)
            for k in ("broadcast_every", "per_process", "memory_minutes", "memory_every", "memory_rho")
        },
        "mesh_configs": all((MESH_CONFIGS / f"router-mesh-{s}.json5").exists() for s in "ab"),
        "chunk_len": cfg.actor.chunk_len,
        "chunk_bytes": chunk_bytes,
        "weights_payload_bytes": weights_bytes,
        "frame_shape": list(FRAME_SHAPE),
        **learner_parameters(cfg),
        "weights_dtype": cfg.learner.weights_dtype,
        "latency_p99_target_ms": LATENCY_P99_TARGET_MS,
        "cpus": os.cpu_count(),
        "overrides": args.overrides,
        "wall_s": time.perf_counter() - started,
    }
    return rounded(out)


if __name__ == "__main__":
    print(json.dumps(main()), flush=True)
