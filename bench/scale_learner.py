"""The learner side of bench/scale.py: a real `LearnerService` ingesting (no training) in this
process, publishing the Weights of each phase, collecting the emulated actors' acks, and reading
the figures of a phase (ingest, losses, weight latency, CPU and memory of every process)."""

from __future__ import annotations

import multiprocessing as mp
import os
import queue
import time
from collections import defaultdict

import numpy as np

from bench.scale_procs import percentile, usage
from common import wire

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
        # the Weights of each phase: the acting policy, and the discriminator where actors need it
        core = self.service.core
        dtype = np.dtype(cfg.learner.weights_dtype)  # learner.weights_dtype=float16: half the bytes
        self.tensors = {
            log_mu: {
                k: v.detach().cpu().numpy().astype(dtype)
                for k, v in core.broadcast_state_dict(with_behaviour=log_mu).items()
            }
            for log_mu in (False, True)
        }

    def close(self) -> None:
        self.service.run_log.close()
        self.transport.close()

    def publish(self, log_mu: bool) -> tuple[int, float]:
        """Encode and put the next Weights version; its version and time.time() just before the put."""
        self.version += 1
        payload = wire.encode(wire.Weights(self.version, self.tensors[log_mu], epoch=self.service.epoch))
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

    def take_acks(self, receipts: dict) -> None:
        while True:
            try:
                batch = self.acks.get_nowait()
            except queue.Empty:
                return
            for name, version, arrived in batch:
                receipts[version].setdefault(name, arrived)

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
                self.take_acks(receipts)
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
        receipts: dict = defaultdict(dict)
        t = time.perf_counter()
        while time.perf_counter() - t < warmup:
            self.step()
            self.take_acks(receipts)
        at_t0, read0 = self.counters(), self.readings(groups)
        inserted0 = at_t0["inserted"]
        published: dict[int, float] = {}
        samples: list[dict] = []
        busy, calls, t0 = 0.0, 0, time.perf_counter()
        next_broadcast, next_sample = t0, t0
        while True:
            now = time.perf_counter()
            if now - t0 >= seconds and (broadcasts is None or len(published) >= broadcasts):
                break
            if (broadcasts is None or len(published) < broadcasts) and now >= next_broadcast:
                version, at = self.publish(log_mu)
                published[version] = at
                next_broadcast += every
            if sample_every and now >= next_sample:
                samples.append({name: rss for name, (_, rss) in self.readings([]).items() if name != "actors"})
                next_sample += sample_every
            spent = self.step()
            busy, calls = busy + spent, calls + (spent > 0)
            self.take_acks(receipts)
        t1, at_t1 = time.perf_counter(), self.counters()
        inserted = at_t1["inserted"]
        read1 = self.readings(groups)
        stopped = [g.stop() for g in groups]
        sent = sum(s for s, _ in stopped)
        self.settle(before["received"] + sent)
        last = max(published.values(), default=time.time())
        while time.time() < last + ACK_WAIT_S and any(len(receipts[v]) < len(names) for v in published):
            self.step()
            self.take_acks(receipts)
        after = self.counters()
        d = {k: after[k] - before[k] for k in after}
        window, chunk_len = t1 - t0, self.cfg.actor.chunk_len

        # each broadcast x subscriber, and each broadcast to the last of the N
        each, to_all, missed = [], [], 0
        for version, at in published.items():
            got = [receipts[version][n] for n in names if n in receipts[version]]
            each += [(r - at) * 1e3 for r in got]
            missed += len(names) - len(got)
            if len(got) == len(names):
                to_all.append((max(got) - at) * 1e3)
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
            "broadcasts": len(published),
            "weights_acks": len(each),
            "weights_missed": missed,
            "weights_latency_p50_ms": percentile(each, 50),
            "weights_latency_p99_ms": percentile(each, 99),
            "weights_all_p50_ms": percentile(to_all, 50),
            "weights_all_p99_ms": percentile(to_all, 99),
            "cpu_s": {k: read1[k][0] - read0[k][0] for k in read1},
            "rss_mb": {k: v[1] for k, v in read1.items()},
            "_latencies": each,
        }
        if samples:
            result["rss_samples"] = samples
        return result
