"""The learner service: the learning core (`learner.core`) wrapped in the plumbing of a run.

    loop:
      ingest   decode <= ingest_batch chunks, drop+count bad ones, count lost chunks by sequence
               gaps, compute rho in one batch and insert (Algorithm 1, lines 8-10)
      train    as many updates as the samples-per-insert ratio allows (rate limit)
      publish  weights every `publish_every` updates (and answer the weights query)
      flow     pause the actors while the data (ingested or in the inbox) is more than
               `max_owed_updates` updates ahead of the ratio (or of the warm-up); resume at half
      tracks   aggregate episode summaries into the global n_i table, publish it
      log      TensorBoard (train/, losses/, actors/, time/) and progress.json for the launcher
      checkpoint every `checkpoint_every` updates and at shutdown (atomic)
"""

from __future__ import annotations

import json
import logging
import os
import threading
import time
from collections import deque
from pathlib import Path

import numpy as np
import torch
from torch.utils.tensorboard import SummaryWriter

from common import checkpoint, wire
from common.config.run import RunConfig
from common.keys import Keys
from learner.core import LearningCore
from learner.ingest import SequenceTracker, chunks_to_transitions
from learner.rate_limit import RateLimiter

log = logging.getLogger(__name__)
ROLE = "learner"


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
        self.seq = SequenceTracker()
        self.rejects = wire.RejectCounter(wire.Limits(max_bytes=self.lc.max_chunk_bytes), logger=log)
        self.tracks: dict[str, int] = {}
        self.returns: deque = deque(maxlen=100)
        self.lags: deque = deque(maxlen=200)
        self.counters = {"inserted": 0, "episodes": 0, "chunks": 0, "flow_pauses": 0}
        self.limiter = RateLimiter(self.core.batch_size, self.lc.samples_per_insert, self.lc.max_owed_updates)
        self._held: dict | None = None
        if cfg.resume:
            self.restore()
        self.writer = SummaryWriter(str(self.run_dir / "tb"))

    # -- state ----------------------------------------------------------------------------
    def restore(self) -> bool:
        path = checkpoint.latest(self.ckpt_dir)
        if path is None:
            log.warning("resume: no checkpoint in %s, starting fresh", self.ckpt_dir)
            return False
        state = checkpoint.load(path)
        self.core.load_state_dict(state["core"])
        self.tracks = dict(state.get("tracks", {}))
        self.counters.update(state.get("counters", {}))
        log.info("resumed from %s at update %d", path, self.core.updates)
        return True

    def save(self) -> Path:
        # the layout of common.checkpoint: what an evaluator reads without the learner, then ours
        state = checkpoint.policy_entries(self.core.policy_state_dict(), self.cfg.agent, self.cfg.scale, self.core.updates)
        state.update(core=self.core.state_dict(with_replay=self.lc.checkpoint_replay), tracks=self.tracks,
                     counters=dict(self.counters))
        return checkpoint.save(self.ckpt_dir, self.core.updates, state)

    # -- wire -----------------------------------------------------------------------------
    def open(self) -> None:
        k, t = self.keys, self.t
        self.chunks_in = t.subscribe(k.subscribe("transitions", ROLE), capacity=self.lc.inbox_chunks)
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
        tensors = {name: v.detach().cpu().numpy() for name, v in self.core.policy_state_dict().items()}
        payload = wire.encode(wire.Weights(self.core.updates, tensors, epoch=self.epoch))
        self.weights_srv.update(payload)
        self.weights_out.put(payload)

    def ingest(self) -> int:
        """Decode, check and insert what has arrived; returns transitions inserted."""
        good = []
        for r in self.chunks_in.drain(self.lc.ingest_batch):
            chunk = self.rejects.decode(r.payload, expect=wire.TransitionChunk, key=r.key)
            if chunk is None:  # counted by kind and dropped; it never reaches the replay
                continue
            self.seq.see(chunk.actor, chunk.seq)
            self.lags.append(max(0, self.core.updates - chunk.policy_version))  # chunks of a previous epoch can be ahead
            self._hold_out(chunk)
            good.append(chunk)
        for r in self.episodes_in.drain(1024):
            ep = self.rejects.decode(r.payload, expect=wire.EpisodeSummary, key=r.key)
            if ep is not None:
                self.tracks[ep.track.removesuffix("-r")] = ep.steps
                self.returns.append(ep.episode_return)
                self.counters["episodes"] += 1
        if not good:
            return 0
        batch = chunks_to_transitions(good, next_image=False)  # the replay keeps only the new frame
        self.core.add(batch)
        self.counters["inserted"] += batch.shape[0]
        self.counters["chunks"] += len(good)
        return batch.shape[0]

    def _hold_out(self, chunk: wire.TransitionChunk) -> None:
        """Keep the first whole episode of one env as the held batch of the prediction metric."""
        if self._held is None:
            self._held = {"key": (chunk.actor, chunk.env, chunk.episode), "chunks": []}
        if self._held.get("done") or (chunk.actor, chunk.env, chunk.episode) != self._held["key"]:
            return
        self._held["chunks"].append(chunk)
        if chunk.terminated[-1] or chunk.truncated[-1]:
            self._held["done"] = True
            self.core.set_held_out(chunks_to_transitions(self._held["chunks"]))

    # -- training -------------------------------------------------------------------------
    def train(self, max_updates: int) -> dict:
        metrics: dict = {}
        for _ in range(min(self.limiter.owed(self.counters["inserted"], self.core.ready), max_updates)):
            metrics = self.core.update() or metrics
            self.limiter.done += 1
            self.flow(time.monotonic())  # a long run of updates must keep the pause fresh
            u = self.core.updates
            if u % self.lc.publish_every == 0:
                self.publish_weights()
            if u % self.lc.checkpoint_every == 0:
                self.save()
        return metrics

    def flow(self, now: float) -> None:
        """Rate limit on the actors' side (`learner.rate_limit`): pause them while the learner is
        far behind the data (which would otherwise pile up, be dropped at the inbox and take CPU
        from the updates); repeated every `flow_refresh_s` so that late actors learn it."""
        if not self.lc.max_owed_updates:
            return
        was = self.limiter.paused
        # the inbox's chunks are not decoded yet: count them at the mean length of those seen
        steps = self.counters["inserted"] / self.counters["chunks"] if self.counters["chunks"] else 1.0
        ahead = self.limiter.ahead(self.counters["inserted"], round(len(self.chunks_in) * steps),
                                   len(self.core.replay), self.core.warmup)
        paused = self.limiter.should_pause(ahead)
        if paused != was or now - self._flow_sent >= self.lc.flow_refresh_s:
            command = "pause" if paused else "resume"
            self.flow_out.put(wire.encode(wire.Control(command, reason=f"{ahead:.0f} transitions ahead",
                                                       expires_s=5 * self.lc.flow_refresh_s)))
            self.counters["flow_pauses"] += int(paused and not was)
            self._flow_sent = now

    # -- the loop -------------------------------------------------------------------------
    def run(self, stop: threading.Event) -> dict:
        self.open()
        last_log = last_tracks = time.monotonic()
        t_ingest = t_train = 0.0
        updates0, inserted0 = self.core.updates, self.counters["inserted"]
        metrics: dict = {}
        try:
            while not stop.is_set():
                for r in self.control_in.drain(16):
                    msg = self.rejects.decode(r.payload, expect=wire.Control, key=r.key)
                    if msg is not None and msg.command == "stop":
                        stop.set()
                t0 = time.perf_counter()
                n = self.ingest()
                t1 = time.perf_counter()
                metrics = self.train(max_updates=32) or metrics
                t2 = time.perf_counter()
                t_ingest, t_train = t_ingest + t1 - t0, t_train + t2 - t1
                if n == 0 and t2 - t1 < 1e-3:
                    time.sleep(0.005)  # nothing arrived and nothing owed
                now = time.monotonic()
                self.flow(now)
                if now - last_tracks >= self.lc.track_table_every_s and self.tracks:
                    self.tracks_out.put(wire.encode(wire.TrackTable(self.core.updates, dict(self.tracks))))
                    last_tracks = now
                if now - last_log >= 1.0:
                    dt = now - last_log
                    self.log(metrics, dt, (self.core.updates - updates0) / dt, (self.counters["inserted"] - inserted0) / dt, t_ingest / dt, t_train / dt)
                    updates0, inserted0, t_ingest, t_train, last_log = self.core.updates, self.counters["inserted"], 0.0, 0.0, now
                if self.lc.max_updates and self.core.updates >= self.lc.max_updates:
                    break
        finally:
            self.save()
            self.writer.close()
        return self.progress()

    def progress(self) -> dict:
        return {
            "updates": self.core.updates,
            "replay": len(self.core.replay),
            "inserted": self.counters["inserted"],
            "chunks": self.counters["chunks"],
            "episodes": self.counters["episodes"],
            "return_mean": float(np.mean(self.returns)) if self.returns else None,
            "rho_bar": self.core.replay.rho_bar if len(self.core.replay) else None,
            "policy_lag": float(np.mean(self.lags)) if self.lags else None,
            "lost_chunks": self.seq.lost,
            "actor_restarts": self.seq.restarts,
            "rejected": self.rejects.total,
            "rejected_by_kind": dict(self.rejects.counts),
            "inbox_dropped": self.chunks_in.dropped,
            "actors_alive": len(self.alive.alive()),
            "actors_seen": sorted(self.seq.expected),
            "policy_version": self.core.updates,
            "flow_paused": self.limiter.paused,
            "flow_pauses": self.counters["flow_pauses"],
        }

    def log(self, metrics: dict, dt: float, updates_per_s: float, inserts_per_s: float, ingest_frac: float, train_frac: float) -> None:
        p = self.progress()
        p.update(updates_per_s=updates_per_s, env_steps_per_s=inserts_per_s, time=time.time())
        step = self.core.updates
        w = self.writer
        for key, value in metrics.items():
            w.add_scalar(key, value, step)
        w.add_scalar("train/updates_per_s", updates_per_s, step)
        w.add_scalar("train/inserts_per_s", inserts_per_s, step)
        w.add_scalar("train/replay_size", p["replay"], step)
        w.add_scalar("actors/alive", p["actors_alive"], step)
        w.add_scalar("actors/episodes", p["episodes"], step)
        w.add_scalar("actors/lost_chunks", p["lost_chunks"], step)
        w.add_scalar("actors/rejected", p["rejected"], step)
        w.add_scalar("actors/inbox_dropped", p["inbox_dropped"], step)
        w.add_scalar("actors/flow_paused", float(p["flow_paused"]), step)
        for key in ("return_mean", "policy_lag"):
            if p[key] is not None:
                w.add_scalar(f"actors/{key}", p[key], step)
        w.add_scalar("time/ingest_fraction", ingest_frac, step)
        w.add_scalar("time/train_fraction", train_frac, step)
        tmp = self.run_dir / ".progress.json.tmp"
        tmp.write_text(json.dumps(p))
        os.replace(tmp, self.run_dir / "progress.json")  # the launcher reads it; never half-written


def learner_role(ctx) -> dict:
    """The learner role (`common.roles`): serve until ctx.stop or `learner.max_updates`; returns
    the final progress counters."""
    result = LearnerService(ctx.cfg, ctx.transport, ctx.run_dir).run(ctx.stop)
    log.info("learner stopped: %s", result)
    return result


def main() -> None:
    from common.cli import role_main

    role_main("learner")
