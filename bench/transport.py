"""Actor -> learner transitions/s over Zenoh against raw Zenoh pub/sub of the same bytes, in
the same run; and the latency of a weight broadcast to 1 and 4 actors.

Processes, all started with `spawn` (forking after zenoh is initialised hangs), on 127.0.0.1:

  router     `common.transport.zenoh_backend.run_router` on a free port
  producer   a synthetic actor: one episode of valid TransitionChunks (random frames, the last
             chunk truncated at 1200 steps) encoded once; every put copies a payload, writes the
             chunk's seq and episode into it and publishes it with congestion control BLOCK on
             gvf/<run>/transitions/<actor>
  actors     for the weight broadcast: `actors.acting.Acting` (the acting policy of
             `common.networks.make_policy`) behind a subscription to gvf/<run>-weights/weights,
             acking every decoded and loaded version
  this one   the learner: a real `LearnerService`, whose `ingest()` (the transport's bounded
             inbox, strict wire decode, sequence gaps, `chunks_to_transitions`, insert) runs in a
             loop with nothing else to do

Phases, repeated --repeats times, each --warmup seconds then --seconds measured (the first
ingest phase also warms up until the replay has been filled once: its pages are faulted in):

  raw              the producer flat out into a subscriber on the learner's own session whose
                   callback only counts (on gvf/<run>-raw/..., which the learner does not hear)
  ingest           `ingest()` with `core.add` = `replay.extend(compact(batch, rho=1))`: decode and
                   insert into the replay storage, rho precomputed. The producer is paced: it
                   stays within --window chunks of the next seq the learner expects (published
                   after every ingest), so the learner's inbox never overflows and the producer
                   and router do not take from the learner's 2 cores what it would then drop
  ingest_flat_out  the same with the producer flat out, as an actor fleet faster than the learner
                   would be: the inbox overflows, and dropped chunks are counted
  ingest_rho       paced, `core.add` unchanged: `LearningCore.add` computes rho with the behaviour
                   network first (the learner's real insert cost)
  ingest_actor_rho paced, `core.add` unchanged, the chunks carrying the actors' log mu_hat
                   (`learner.rho_at=actor`): the learner only computes tau and combines

`transitions_per_s` is the paced ingest; `ratio` = transitions_per_s / raw_zenoh_per_s (medians
over rounds; `ratio_per_repeat` pairs the phases of each round). Rates count only transitions
that entered the replay; chunks lost on the network (sent - received), dropped by the full inbox
or rejected by the decoder are counted. Each ingest phase also gives the learner's time per chunk
in decode (msgpack + strict checks), convert (`chunks_to_transitions`) and insert (`core.add`).

The weight broadcast is timed with time.time() (CLOCK_REALTIME: one clock for every process of
this machine): publish -> every actor has decoded and loaded it (median and p90 over
--broadcasts); the round trip to the acks is given too. Actors are idle meanwhile.

Usage: python bench/transport.py [--seconds 2] [--warmup 0.5] [--repeats 3] [--broadcasts 20]
       [--window 256] [--profile] [hydra overrides, e.g. learner.ingest_batch=16]
The last line printed is one JSON object.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import multiprocessing as mp
import sys
import tempfile
import time
from pathlib import Path

# run as a script, bench/ comes first on sys.path: the repository root goes there instead, so
# that `bench.support.transport_procs` imports here and in the spawned processes that inherit it
_HERE = Path(__file__).resolve().parent
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != _HERE]
sys.path.insert(0, str(_HERE.parent))


from bench.support.transport_procs import (  # noqa: E402
    ACTOR,
    Producer,
    ack_key,
    broadcast_latency,
    credit_key,
    start_router,
    stop_process,
    wait_all,
    weights_actor_main,
)
from bench.support.transport_summary import summarize  # noqa: E402
from common import wire  # noqa: E402
from common.keys import Keys  # noqa: E402

RAW_SUFFIX, WEIGHTS_SUFFIX = "-raw", "-weights"
FILL_TIMEOUT_S = 60.0
"""Longest the first ingest phase's warm-up waits for the replay to be full once."""


# --- the learner side -----------------------------------------------------------------------


def raw_phase(session, run: str, producer: Producer, warmup: float, seconds: float, chunk_len: int) -> dict:
    """Raw Zenoh: the same payloads into a subscriber whose callback only counts."""
    import zenoh

    count = [0]

    def on_sample(_sample) -> None:
        count[0] += 1

    sub = session.declare_subscriber(Keys(run).all_transitions, zenoh.handlers.Callback(on_sample, indirect=False))
    try:
        producer.start(run, 0)
        deadline = time.monotonic() + 30.0
        while count[0] == 0:
            if time.monotonic() > deadline:
                raise RuntimeError("no chunk reached the raw subscriber in 30 s")
            time.sleep(0.001)
        time.sleep(warmup)
        c0, t0 = count[0], time.perf_counter()
        time.sleep(seconds)
        c1, t1 = count[0], time.perf_counter()
        sent = producer.stop()
        settle(lambda: count[0])
        received = count[0]
    finally:
        sub.undeclare()
    chunks_per_s = (c1 - c0) / (t1 - t0)
    return {
        "transitions_per_s": chunks_per_s * chunk_len,
        "chunks_per_s": chunks_per_s,
        "sent": sent,
        "received": received,
        "lost": sent - received,
    }


def settle(counter, quiet: float = 0.3, timeout: float = 10.0) -> None:
    """Wait until `counter()` stops changing for `quiet` seconds (what was in flight arrived)."""
    last, since, deadline = counter(), time.monotonic(), time.monotonic() + timeout
    while time.monotonic() - since < quiet and time.monotonic() < deadline:
        time.sleep(0.02)
        if (now := counter()) != last:
            last, since = now, time.monotonic()


@contextlib.contextmanager
def stage_times(service):
    """Seconds the learner's ingest spends in each stage, by timing the calls it makes:
    decode (msgpack + strict checks), convert (`chunks_to_transitions`), insert (`core.add`)."""
    import learner.ingestor as learner_ingestor

    totals = dict.fromkeys(("decode", "convert", "insert"), 0.0)

    def timed(stage: str, fn):
        def call(*a, **kw):
            t = time.perf_counter()
            try:
                return fn(*a, **kw)
            finally:
                totals[stage] += time.perf_counter() - t

        return call

    rejects, core = service.intake.rejects, service.core
    saved = (rejects.decode, learner_ingestor.chunks_to_transitions, core.add)
    rejects.decode = timed("decode", saved[0])
    learner_ingestor.chunks_to_transitions = timed("convert", saved[1])
    core.add = timed("insert", saved[2])
    try:
        yield totals
    finally:
        del rejects.decode  # back to the class's method
        learner_ingestor.chunks_to_transitions, core.add = saved[1], saved[2]


def ingest_phase(
    service,
    producer: Producer,
    warmup: float,
    seconds: float,
    credit=None,
    window: int = 0,
    profiler=None,
    log_mu: bool = False,
) -> dict:
    """The learner's real ingest loop for warmup + seconds, then drain what is left.

    With `credit` (a publisher) and `window` > 0 the producer is paced: after every ingest the
    learner publishes the next seq it expects, and the producer stays within `window` chunks.
    """
    inbox, counters, seq = service.chunks_in, service.intake.counters, service.intake.seq

    def state() -> dict:
        return {
            "received": inbox.received,
            "dropped": inbox.dropped,
            "rejected": service.intake.rejects.total,
            "chunks": counters["chunks"],
        }

    before = state()

    def ingest() -> int:
        n = service.ingest()
        if credit is not None:
            credit.put(str(seq.expected.get(ACTOR, 0)).encode())
        if n == 0:
            time.sleep(0.005)  # the learner's own idle wait when nothing arrived
        return n

    producer.start(service.keys.run, window if credit is not None else 0, log_mu)
    deadline = time.monotonic() + 30.0
    while ingest() == 0:
        if time.monotonic() > deadline:
            raise RuntimeError("no chunk reached the learner in 30 s")
    start, replay = time.perf_counter(), service.core.replay
    # steady state: the replay's storage has been written once (first writes fault its pages in)
    while time.perf_counter() - start < warmup or (
        len(replay) < replay.capacity and time.perf_counter() - start < FILL_TIMEOUT_S
    ):
        ingest()
    if profiler is not None:
        profiler.enable()
    with stage_times(service) as stages:
        t0, i0, c0 = time.perf_counter(), counters["inserted"], counters["chunks"]
        # the window closes at the first batch to end after `seconds` (at least one batch inside)
        while (t1 := time.perf_counter()) - t0 < seconds or counters["inserted"] == i0:
            ingest()
        i1, chunks = counters["inserted"], counters["chunks"] - c0
    if profiler is not None:
        profiler.disable()
    sent = producer.stop()
    settle(lambda: inbox.received)
    while len(inbox):
        ingest()
    rate = (i1 - i0) / (t1 - t0)
    d = {k: v - before[k] for k, v in state().items()}
    return {
        "transitions_per_s": rate,
        "chunks_per_s": rate / service.cfg.actor.chunk_len,
        "sent": sent,
        "received": d["received"],
        "inserted_chunks": d["chunks"],
        "inbox_dropped": d["dropped"],
        "network_lost": sent - d["received"],
        "rejected": d["rejected"],
        # where the learner's time went, per chunk inserted in the window (the rest: waiting,
        # draining the inbox, sequence bookkeeping, and the zenoh thread's share of the GIL)
        **{f"{k}_ms_per_chunk": v * 1e3 / chunks for k, v in stages.items()},
        "window_ms_per_chunk": (t1 - t0) * 1e3 / chunks,
    }


def use_precomputed_rho(core) -> None:
    """`core.add` without the behaviour network: the batch goes into the replay with rho = 1."""
    import torch

    from learner.replay import compact

    def add(transitions) -> None:
        core.replay.extend(compact(transitions, torch.ones(transitions.shape[0], 1)))

    core.add = add


# --- wiring ---------------------------------------------------------------------------------


def compose(overrides: list[str]):
    from common.cli import compose_run

    return compose_run(overrides)


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=2.0, help="measured seconds per phase")
    parser.add_argument("--warmup", type=float, default=0.5, help="unmeasured seconds before each phase")
    parser.add_argument("--repeats", type=int, default=3, help="rounds of every phase; medians are reported")
    parser.add_argument(
        "--window",
        type=int,
        default=256,
        help="chunks a paced producer may be ahead of the learner (< learner.inbox_chunks)",
    )
    parser.add_argument("--broadcasts", type=int, default=20, help="timed weight broadcasts per actor count")
    parser.add_argument("--actors", type=int, nargs="+", default=[1, 4], help="actor counts of the broadcast")
    parser.add_argument("--no-rho", action="store_true", help="skip the ingest+rho phases")
    parser.add_argument("--no-flat-out", action="store_true", help="skip the flat-out ingest phases")
    parser.add_argument("--profile", action="store_true", help="cProfile the paced ingest phases (to stderr)")
    parser.add_argument("overrides", nargs="*", help="hydra overrides of the run config, e.g. learner.ingest_batch=16")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, stream=sys.stderr)

    from common.networks import make_policy
    from common.transport.zenoh_backend import ZenohTransport
    from learner.service import LearnerService

    # rho_at=actor: the learner takes a chunk's log mu_hat where there is one (ingest_actor_rho)
    cfg = compose(["run=bench", "learner.device=cpu", "transport=local", "learner.rho_at=actor", *args.overrides])
    if not 0 < args.window < cfg.learner.inbox_chunks:
        parser.error(f"--window must be in 1..{cfg.learner.inbox_chunks - 1} (learner.inbox_chunks)")
    chunk_len, frame_shape = cfg.actor.chunk_len, (64, 128)
    raw_run = cfg.run + RAW_SUFFIX
    weights_run = cfg.run + WEIGHTS_SUFFIX
    ctx = mp.get_context("spawn")
    router_stop, actors_stop = ctx.Event(), ctx.Event()
    procs: list[mp.Process] = []
    producer = transport = service = None
    rounds: list[dict] = []
    latency: dict[int, dict] = {}
    tmp = tempfile.TemporaryDirectory(prefix="bench-transport-")
    started = time.perf_counter()
    try:
        tcfg, router = start_router(ctx, cfg.transport, router_stop)
        procs.append(router)
        cfg.transport = tcfg
        producer = Producer(ctx, tcfg, [cfg.run, raw_run], chunk_len, frame_shape)
        procs.append(producer.process)
        # max(--actors) actor processes; the first n subscribe for the broadcast to n actors
        joins, readies = [], []
        for i in range(max(args.actors)):
            joins.append(ctx.Event())
            readies.append(ctx.Event())
            p = ctx.Process(
                target=weights_actor_main,
                name=f"actor-{i}",
                daemon=True,
                args=(tcfg, weights_run, f"a{i}", cfg.agent, cfg.scale, cfg.actor, joins[i], readies[i], actors_stop),
            )
            p.start()
            procs.append(p)

        transport = ZenohTransport(tcfg)
        service = LearnerService(cfg, transport, run_dir=tmp.name)
        service.open()
        credit = transport.publisher(credit_key(cfg.run))
        real_add = service.core.add
        wait_all([producer.ready, *readies], "producer and actors")
        chunk_bytes = producer.results.get(timeout=10)

        profiler = None
        if args.profile:
            import cProfile

            profiler = cProfile.Profile()
        phase = dict(service=service, producer=producer, warmup=args.warmup, seconds=args.seconds)
        for _ in range(args.repeats):
            r = {"raw": raw_phase(transport.session, raw_run, producer, args.warmup, args.seconds, chunk_len)}
            use_precomputed_rho(service.core)
            r["ingest"] = ingest_phase(**phase, credit=credit, window=args.window, profiler=profiler)
            if not args.no_flat_out:
                r["ingest_flat_out"] = ingest_phase(**phase)
            if not args.no_rho:
                service.core.add = real_add
                r["ingest_rho"] = ingest_phase(**phase, credit=credit, window=args.window)
                r["ingest_actor_rho"] = ingest_phase(**phase, credit=credit, window=args.window, log_mu=True)
            rounds.append(r)
            print(json.dumps({k: round(v["transitions_per_s"]) for k, v in r.items()}), file=sys.stderr)
        if profiler is not None:
            import pstats

            pstats.Stats(profiler, stream=sys.stderr).sort_stats("tottime").print_stats(25)

        tensors = {k: v.detach().cpu().numpy() for k, v in make_policy(cfg.agent, cfg.scale).state_dict().items()}
        t_encode = time.perf_counter()
        weights_bytes = len(wire.encode(wire.Weights(0, tensors)))
        encode_ms = (time.perf_counter() - t_encode) * 1e3
        version = 0
        weights_out = transport.publisher(Keys(weights_run).weights)
        acks = transport.subscribe(ack_key(weights_run), capacity=256)
        for n in sorted(set(args.actors)):
            for join in joins[:n]:
                join.set()
            latency[n] = broadcast_latency(
                weights_out,
                acks,
                lambda v: wire.encode(wire.Weights(v, tensors)),
                [f"a{i}" for i in range(n)],
                args.broadcasts,
                version,
            )
            version = latency[n]["last_version"]
    finally:
        actors_stop.set()
        if producer is not None:
            producer.close()
        if service is not None:
            service.run_log.close()
        if transport is not None:
            transport.close()
        router_stop.set()
        for p in reversed(procs):  # the router last: the others close their sessions through it
            stop_process(p)
        tmp.cleanup()
    return summarize(rounds, latency, args, cfg, chunk_bytes, weights_bytes, encode_ms, time.perf_counter() - started)


if __name__ == "__main__":
    print(json.dumps(main()), flush=True)
