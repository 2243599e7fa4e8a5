"""The learner service: the learning core (`learner.core`) wrapped in the plumbing of a run,
each part in its own module:

  control    a `stop` on the control key ends the run (a clean exit: gvf-train ends it all)
  ingest     `learner.ingestor`: decode, check, count; then rho and insert (Algorithm 1, lines 8-10)
  train      as many updates as `learner.rate_limit` owes; weights every `publish_every`
             updates (and the weights query answered); a checkpoint every `checkpoint_every`
  flow       pause the actors while the data is too far ahead of the updates, resume at half
  tracks     the global n_i table of priority track sampling, every `track_table_every_s`
  log        `learner.run_log`: TensorBoard and progress.json, every second
  exit       a last checkpoint (atomic, `common.checkpoint`)
"""

from __future__ import annotations

import logging
import threading
import time
from pathlib import Path

import numpy as np
import torch

from common import checkpoint, wire
from common.config.run import RunConfig
from common.keys import Keys
from common.wire_quant import for_broadcast
from learner.core import LearningCore
from learner.ingestor import Ingestor
from learner.rate_limit import RateLimiter
from learner.run_log import RunLog

log = logging.getLogger(__name__)
ROLE = "learner"
WARM_START_PAUSE_S = 120.0  # longest the warm start may hold the actors; flow() resumes them sooner
PAUSE_REFRESHES = 5  # a flow pause lives this many flow_refresh_s: a few lost repeats don't end it


def resolve_device(name: str) -> str:
    if name == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    return name


class LearnerService:
    """One learner of one run; `run(stop)` until stopped or `learner.max_updates`."""

    def __init__(self, cfg: RunConfig, transport, run_dir: str | Path) -> None:
        self.cfg, self.lc, self.t = cfg, cfg.learner, transport
        self.keys = Keys(cfg.run)
        self.epoch = time.time_ns()  # this incarnation; weights versions restart on resume
        self.run_dir = Path(run_dir)
        torch.set_num_threads(self.lc.torch_threads)
        self.core = LearningCore(cfg.agent, cfg.scale, device=resolve_device(self.lc.device), seed=cfg.seed)
        ckpt = Path(self.lc.checkpoint_dir)
        self.ckpt_dir = ckpt if ckpt.is_absolute() else self.run_dir / ckpt
        crash_steps = cfg.scale.crash_steps if cfg.scale.crash_memory else 0
        self.intake = Ingestor(
            self.lc.max_chunk_bytes,
            self.lc.ingest_batch,
            self.lc.max_tracks,
            crash_steps,
            accept_log_mu=self.lc.rho_at == "actor",
        )
        self.limiter = RateLimiter(self.core.batch_size, self.lc.samples_per_insert, self.lc.max_owed_updates)
        self.flow_pauses = 0
        if cfg.resume:
            self.restore()
        self.run_log = RunLog(self.run_dir)

    # -- state ----------------------------------------------------------------------------
    def restore(self) -> bool:
        """Resume from the newest good checkpoint: one with a non-finite value or that cannot be read
        is refused (logged) and the next older one tried."""
        found = checkpoint.newest_good(self.ckpt_dir, log)
        if found is None:
            log.warning("resume: no good checkpoint in %s, starting fresh", self.ckpt_dir)
            return False
        path, state = found
        self.core.load_state_dict(state["core"])
        self.intake.tracks = dict(state.get("tracks", {}))
        counters = dict(state.get("counters", {}))
        self.flow_pauses = counters.pop("flow_pauses", 0)
        self.intake.counters.update(counters)
        log.info("resumed from %s at update %d", path, self.core.updates)
        return True

    def save(self) -> Path | None:
        """A checkpoint of everything (common.checkpoint's layout), never of non-finite weights."""
        # the layout of common.checkpoint: what an evaluator reads without the learner, then ours
        state = checkpoint.policy_entries(
            self.core.deployed_state_dict(), self.cfg.agent, self.cfg.scale, self.core.updates
        )
        counters = {**self.intake.counters, "flow_pauses": self.flow_pauses}
        state.update(
            core=self.core.state_dict(with_replay=self.lc.checkpoint_replay),
            tracks=self.intake.tracks,
            counters=counters,
        )
        if not checkpoint.all_finite(state["core"]):
            log.error("non-finite weights at update %d: no checkpoint written", self.core.updates)
            return None
        return checkpoint.save(self.ckpt_dir, self.core.updates, state)

    # -- wire -----------------------------------------------------------------------------
    def open(self) -> None:
        """Declare every key of the learner's row in the wiring table (common.keys)."""
        k, t = self.keys, self.t
        self.chunks_in = t.subscribe(
            k.subscribe("transitions", ROLE), capacity=self.lc.inbox_chunks, wait_s=self.lc.inbox_wait_s
        )
        self.episodes_in = t.subscribe(k.subscribe("episodes", ROLE), capacity=4096)
        self.control_in = t.subscribe(k.subscribe("control", ROLE), capacity=16)
        weights = k.publish("weights", ROLE)
        self.weights_out, self.weights_srv = t.publisher(weights), t.serve_latest(weights)
        self.tracks_out = t.publisher(k.publish("tracks", ROLE))
        self.flow_out = t.publisher(k.publish("flow", ROLE))
        self._flow_sent = 0.0
        self.alive = t.watch_alive(k.all_alive("actor"))
        t.declare_alive(k.publish("alive", ROLE, role=ROLE, name=ROLE))
        self.publish_weights()

    def publish_weights(self) -> None:
        """Broadcast (and serve) the acting weights; non-finite ones are never sent: the learner
        stops with an error instead, and a supervisor resumes it from its last good checkpoint."""
        state = self.core.broadcast_state_dict(with_behaviour=self.lc.rho_at == "actor")
        tensors = {name: v.detach().cpu().numpy() for name, v in state.items()}
        if not all(np.isfinite(t).all() for t in tensors.values()):
            raise FloatingPointError(f"non-finite acting weights at update {self.core.updates}: not published")
        tensors, quant = for_broadcast(tensors, self.lc.weights_dtype)
        payload = wire.encode(wire.Weights(self.core.updates, tensors, epoch=self.epoch, quant=quant))
        self.weights_srv.update(payload)
        self.weights_out.put(payload)

    def stop_requested(self) -> bool:
        """A `stop` on the control key (from gvfctl); pause and resume are for actors."""
        stop = False
        for r in self.control_in.drain(16):
            msg = self.intake.rejects.decode(r.payload, expect=wire.Control, key=r.key)
            stop = stop or (msg is not None and msg.command == "stop")
        return stop

    def ingest(self) -> int:
        """Decode, check and insert what has arrived (Algorithm 1, lines 8-10); returns transitions inserted."""
        batch = self.intake.take(self.chunks_in, self.episodes_in, self.core.updates)
        if self.intake.held_out is not None and self.core.held_out is None:
            self.core.set_held_out(self.intake.held_out)
        if batch is None:
            return 0
        self.core.add(batch)
        crashes = self.intake.take_crashes()
        if crashes is not None:
            self.core.add_crashes(crashes)
        return batch.shape[0]

    # -- training -------------------------------------------------------------------------
    def train(self, max_updates: int, stop: threading.Event | None = None) -> dict:
        """As many updates as the rate limit owes (at most `max_updates`, fewer once `stop` is
        set), publishing and checkpointing on their schedules; returns the last metrics."""
        metrics: dict = {}
        owed = self.limiter.owed(self.intake.counters["inserted"], self.core.ready)
        if owed and self.core.needs_warm_start:
            self.warm_start()
        for _ in range(min(owed, max_updates)):
            if stop is not None and stop.is_set():
                break  # 32 updates take 10 s on a slow machine: past the launcher's grace, the last checkpoint was lost
            metrics = self.core.update() or metrics
            self.limiter.done += 1
            self.flow(time.monotonic())  # a long run of updates must keep the pause fresh
            u = self.core.updates
            if u % self.lc.publish_every == 0:
                self.publish_weights()
            if u % self.lc.checkpoint_every == 0:
                self.save()
        return metrics

    def warm_start(self) -> None:
        """g's warm start and the first rho refresh hold this loop for seconds: the actors are
        paused meanwhile, or the inbox overflows (1,909 chunks dropped at the start of a
        15-minute run, measured), then resumed by `flow` once the data is not ahead."""
        if self.lc.max_owed_updates:
            pause = wire.Control("pause", reason="warm start", expires_s=WARM_START_PAUSE_S)
            self.flow_out.put(wire.encode(pause))
            self.limiter.paused = True
            self.flow_pauses += 1
        self.core.warm_start()
        self.intake.min_behaviour_version = self.core.updates + 1  # the actors' g is the untrained one until then
        self.flow(time.monotonic())

    def flow(self, now: float) -> None:
        """Rate limit on the actors' side (`learner.rate_limit`): pause them while the learner is
        far behind the data (which would otherwise pile up, be dropped at the inbox and take CPU
        from the updates); repeated every `flow_refresh_s` so that late actors learn it."""
        if not self.lc.max_owed_updates:
            return
        was = self.limiter.paused
        waiting = round(len(self.chunks_in) * self.intake.mean_chunk_steps())  # not decoded yet
        ahead = self.limiter.ahead(self.intake.counters["inserted"], waiting, len(self.core.replay), self.core.warmup)
        paused = self.limiter.should_pause(ahead)
        if paused != was or now - self._flow_sent >= self.lc.flow_refresh_s:
            command = "pause" if paused else "resume"
            expires = PAUSE_REFRESHES * self.lc.flow_refresh_s
            self.flow_out.put(
                wire.encode(wire.Control(command, reason=f"{ahead:.0f} transitions ahead", expires_s=expires))
            )
            self.flow_pauses += int(paused and not was)
            self._flow_sent = now

    def publish_tracks(self) -> None:
        if self.intake.tracks:
            self.tracks_out.put(wire.encode(wire.TrackTable(self.core.updates, dict(self.intake.tracks))))

    # -- the loop -------------------------------------------------------------------------
    def run(self, stop: threading.Event) -> dict:
        """control -> ingest -> train -> flow -> track table -> log, until stopped or max_updates."""
        self.open()
        clock = _Clock(self.core.updates, self.intake.counters["inserted"])
        last_tracks = time.monotonic()
        metrics: dict = {}
        try:
            while not stop.is_set() and not self.stop_requested():
                t0 = time.perf_counter()
                n = self.ingest()
                t1 = time.perf_counter()
                metrics = self.train(max_updates=32, stop=stop) or metrics
                t2 = time.perf_counter()
                clock.spent(t1 - t0, t2 - t1)
                if n == 0 and t2 - t1 < 1e-3:
                    time.sleep(0.005)  # nothing arrived and nothing owed
                now = time.monotonic()
                self.flow(now)
                if now - last_tracks >= self.lc.track_table_every_s:
                    self.publish_tracks()
                    last_tracks = now
                if clock.due(now):
                    self.run_log.write(
                        self.progress(), metrics, clock.rates(now, self.core.updates, self.intake.counters["inserted"])
                    )
                if self.lc.max_updates and self.core.updates >= self.lc.max_updates:
                    break
        finally:
            self.save()
            self.run_log.close()
        return self.progress()

    def progress(self) -> dict:
        return {
            "updates": self.core.updates,
            "replay": len(self.core.replay),
            "crash_memory": len(self.core.crashes) if self.core.crashes is not None else 0,
            **self.intake.progress(),
            "rho_bar": self.core.replay.rho_bar if len(self.core.replay) else None,
            "inbox_dropped": self.chunks_in.dropped,
            "inbox_waited": self.chunks_in.waited,
            "actors_alive": len(self.alive.alive()),
            "policy_version": self.core.updates,
            "flow_paused": self.limiter.paused,
            "flow_pauses": self.flow_pauses,
            "skipped_updates": self.core.skipped_nonfinite,
        }


class _Clock:
    """Rates over each 1-second log interval, and where the loop's time went."""

    def __init__(self, updates: int, inserted: int) -> None:
        self.last, self.updates, self.inserted = time.monotonic(), updates, inserted
        self.ingest = self.train = 0.0

    def spent(self, ingest: float, train: float) -> None:
        self.ingest += ingest
        self.train += train

    def due(self, now: float) -> bool:
        return now - self.last >= 1.0

    def rates(self, now: float, updates: int, inserted: int) -> dict:
        dt = now - self.last
        rates = {
            "updates_per_s": (updates - self.updates) / dt,
            "env_steps_per_s": (inserted - self.inserted) / dt,
            "ingest_fraction": self.ingest / dt,
            "train_fraction": self.train / dt,
        }
        self.last, self.updates, self.inserted, self.ingest, self.train = now, updates, inserted, 0.0, 0.0
        return rates


def learner_role(ctx) -> dict:
    """The learner role (`common.roles`): serve until ctx.stop or `learner.max_updates`; returns
    the final progress counters."""
    result = LearnerService(ctx.cfg, ctx.transport, ctx.run_dir).run(ctx.stop)
    log.info("learner stopped: %s", result)
    return result


def main() -> None:
    from common.cli import role_main

    role_main("learner")
