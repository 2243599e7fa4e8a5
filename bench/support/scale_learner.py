"""The learner side of bench/scale.py: a real `LearnerService` ingesting (no training) in this
process, publishing the Weights of each phase, collecting the emulated actors' acks, and reading
the figures of a phase (ingest, losses, weight latency, CPU and memory of every process)."""

from __future__ import annotations

import multiprocessing as mp
import os
import queue
import time
from collections import defaultdict

from bench.support.acks import Acks
from bench.support.scale_procs import usage
from common import wire
from common.wire_quant import for_broadcast

ACK_WAIT_S = 5.0
"""After the last broadcast of a phase, how long acks still count (later ones are missed)."""


class Learner:
    """The learner side of one topology: the service, the acks of every actor, the readings."""

    def __init__(self, cfg, tcfg, routers: dict, run_dir: str) -> None:
        from common.transport.zenoh_backend import ZenohTransport
        from learner.service import LearnerService

        self.cfg, self.routers = cfg, routers
        self.transport = ZenohTransport(tcfg)
        self.service = LearnerService(cfg, self.transport, run_dir=run_dir)
        self.service.open()
        self.acks = mp.get_context("spawn").Queue()
        self.version = 0
        # (tensors, quant) of each phase's Weights in the learner's broadcast precision
        # (learner.weights_dtype): the acting policy, and the discriminator where actors need it
        core = self.service.core
        self.tensors = {
            log_mu: for_broadcast(
                {k: v.detach().cpu().numpy() for k, v in core.broadcast_state_dict(with_behaviour=log_mu).items()},
                cfg.learner.weights_dtype,
            )
            for log_mu in (False, True)
        }

    def close(self) -> None:
        self.service.run_log.close()
        self.transport.close()

    def encoded(self, log_mu: bool, version: int) -> bytes:
        """The Weights payload of the phase with (True) or without the discriminator."""
        tensors, quant = self.tensors[log_mu]
        return wire.encode(wire.Weights(version, tensors, epoch=self.service.epoch, quant=quant))

    def publish(self, log_mu: bool) -> tuple[int, float]:
        """Encode and put the next Weights version; its version and time.time() just before the put."""
        self.version += 1
        payload = self.encoded(log_mu, self.version)
        at = time.time()
        self.service.weights_out.put(payload)
        return self.version, at

    def step(self) -> float:
        """One ingest; the seconds it took if it inserted anything (busy time), else 0 after a short idle wait."""
        t = time.perf_counter()
        if self.service.ingest():
            return time.perf_counter() - t
        time.sleep(0.005)  # the learner's own idle wait when nothing arrived
        return 0.0

    def take_acks(self, sink) -> None:
        """Hand every ack that came in to sink(name, version, arrival time.time())."""
        while True:
            try:
                batch = self.acks.get_nowait()
            except queue.Empty:
                return
            for name, version, arrived in batch:
                sink(name, version, arrived)

    def counters(self) -> dict:
        s = self.service
        return {
            "received": s.chunks_in.received,
            "dropped": s.chunks_in.dropped,
            "waited": s.chunks_in.waited,
            "inserted": s.intake.counters["inserted"],
            "chunks": s.intake.counters["chunks"],
            "lost": s.intake.seq.lost,
            "rejected": s.intake.rejects.total,
        }

    def readings(self, groups) -> dict:
        """(CPU s, RSS MB) of the learner, each router, and the actor processes together."""
        out = {"learner": usage(os.getpid())}
        out.update({name: usage(p.pid) for name, p in self.routers.items()})
        per_group = [usage(g.process.pid) for g in groups]
        out["actors"] = (sum(c for c, _ in per_group), sum(r for _, r in per_group))
        return out

    def settle(self, received: int, timeout: float = 10.0) -> None:
        """Ingest until the inbox has received `received` chunks in all and is empty (what was in
        flight is in), or `timeout` s: chunks still missing then are counted as such."""
        inbox, deadline = self.service.chunks_in, time.monotonic() + timeout
        while (inbox.received < received or len(inbox)) and time.monotonic() < deadline:
            self.step()

    def join(self, groups, names: list[str], timeout: float = 120.0) -> None:
        """Wait for every actor to be up and to have received a broadcast (subscriptions reach the
        router(s) some time after they are declared): untimed broadcasts until each acked one."""
        deadline = time.monotonic() + timeout
        for g in groups:
            while not g.ready.wait(0.2):
                if not g.process.is_alive() or time.monotonic() > deadline:
                    raise RuntimeError(f"actor process {g.process.name} did not start (exit {g.process.exitcode})")
        receipts, first, heard = defaultdict(dict), self.version + 1, set()
        while True:
            self.publish(False)
            t = time.monotonic()
            while time.monotonic() - t < 0.5:
                self.step()
                self.take_acks(lambda name, version, arrived: receipts[version].setdefault(name, arrived))
            heard = {name for v, got in receipts.items() if v >= first for name in got}
            if heard >= set(names):
                return
            if time.monotonic() > deadline:
                raise RuntimeError(f"{len(set(names) - heard)} of {len(names)} actors never received weights")

    def phase(
        self,
        groups,
        names: list[str],
        rate: float,
        log_mu: bool,
        seconds: float,
        warmup: float,
        broadcasts: int | None,
        every: float,
        sample_every: float = 0.0,
    ) -> dict:
        """The actors send, the learner ingests and broadcasts: the figures of the phase.

        `broadcasts` None: every `every` s until `seconds` are up; `sample_every` > 0: router and
        learner RSS every that many s (the memory run).
        """
        before = self.counters()  # the previous phase ended with an empty inbox
        start = time.time() + 0.05
        for g in groups:
            g.send(log_mu, start)
        acks = Acks(names)
        t = time.perf_counter()
        while time.perf_counter() - t < warmup:
            self.step()
            self.take_acks(acks.add)
        at_t0, read0 = self.counters(), self.readings(groups)
        inserted0 = at_t0["inserted"]
        broadcasts_sent = 0
        samples: list[dict] = []
        busy, calls, t0 = 0.0, 0, time.perf_counter()
        next_broadcast, next_sample = t0, t0
        while True:
            now = time.perf_counter()
            if now - t0 >= seconds and (broadcasts is None or broadcasts_sent >= broadcasts):
                break
            if (broadcasts is None or broadcasts_sent < broadcasts) and now >= next_broadcast:
                acks.published(*self.publish(log_mu))
                broadcasts_sent += 1
                next_broadcast += every
            if sample_every and now >= next_sample:
                samples.append({name: rss for name, (_, rss) in self.readings([]).items() if name != "actors"})
                next_sample += sample_every
            spent = self.step()
            busy, calls = busy + spent, calls + (spent > 0)
            self.take_acks(acks.add)
        t1, at_t1 = time.perf_counter(), self.counters()
        inserted = at_t1["inserted"]
        read1 = self.readings(groups)
        stopped = [g.stop() for g in groups]
        sent = sum(s for s, _ in stopped)
        self.settle(before["received"] + sent)
        deadline = time.time() + ACK_WAIT_S
        while time.time() < deadline and acks.waiting:
            self.step()
            self.take_acks(acks.add)
        acks.close()
        after = self.counters()
        d = {k: after[k] - before[k] for k in after}
        window, chunk_len = t1 - t0, self.cfg.actor.chunk_len

        each, to_all = acks.each, acks.to_all  # each broadcast x subscriber; each broadcast to the last of the N
        result = {
            "window_s": round(window, 3),
            "transitions_per_s": (inserted - inserted0) / window,
            "offered_transitions_per_s": len(names) * rate * chunk_len,
            "learner_busy_fraction": busy / window,
            # per second inside ingest(), at this load's batch size (below a saturated learner's)
            "ingest_per_busy_s": (inserted - inserted0) / busy if busy else None,
            "chunks_per_ingest": (at_t1["chunks"] - at_t0["chunks"]) / calls if calls else None,
            "chunks_sent": sent,
            "chunks_received": d["received"],
            "chunks_inserted": d["chunks"],
            "chunks_lost": d["lost"],
            # never reached the learner: losses at the end of a stream, which seq gaps cannot see
            "chunks_missing": sent - d["received"],
            "inbox_dropped": d["dropped"],
            # chunks that found the inbox full and held Zenoh's reader (back-pressure, learner.inbox_wait_s)
            "inbox_waited": d["waited"],
            "rejected": d["rejected"],
            "send_lag_max_ms": max(lag for _, lag in stopped) * 1e3,
            "broadcasts": broadcasts_sent,
            "weights_acks": each.count,
            "weights_missed": acks.missed,
            "weights_latency_p50_ms": each.percentile(50),
            "weights_latency_p99_ms": each.percentile(99),
            "weights_all_p50_ms": to_all.percentile(50),
            "weights_all_p99_ms": to_all.percentile(99),
            "cpu_s": {k: read1[k][0] - read0[k][0] for k in read1},
            "rss_mb": {k: v[1] for k, v in read1.items()},
            "_latencies": each,
        }
        if samples:
            result["rss_samples"] = samples
        return result
