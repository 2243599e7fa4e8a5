"""The learner's intake, free of training: decode and check what arrived, count what was lost
or refused, and turn the good chunks into one batch of replay transitions.

Per `take`: at most `ingest_batch` transition chunks and 1024 episode summaries are drained;
a payload that fails the wire checks or the rules of `common.wire_rules` (sender, value ranges,
`seq`) is counted by kind and dropped: it never reaches the replay. Per-actor sequence numbers
count lost chunks and announced restarts (`SequenceTracker`); at most `max_tracks` roads enter
the track table (more are refused as kind 'track'); the
policy lag of each chunk (updates now minus the version that acted) is kept for the progress
view; episode summaries feed the global track table (n_i per road) and the mean return; the
first whole episode of one env is kept as the held-out trajectory of the prediction metric.

With `crash_steps` > 0 the intake also keeps the last `crash_steps` transitions before every
termination (across the chunk boundary: the env's previous chunk of the same episode is kept
until its next one arrives) for the learner's crash memory (`learner.replay.CrashMemory`);
`take_crashes` hands them over.
"""

from __future__ import annotations

import dataclasses
import logging
from collections import deque

import numpy as np
import torch
from tensordict import TensorDict

from common import wire
from common.wire_rules import SequenceTracker, check_chunk, check_episode
from learner.ingest import chunks_to_transitions

log = logging.getLogger(__name__)
MAX_STREAMS = 4096  # envs whose last chunk is kept for the crash memory


class Ingestor:
    """Decode, check and account; see the module docstring."""

    def __init__(
        self,
        max_chunk_bytes: int,
        ingest_batch: int,
        max_tracks: int = 1024,
        crash_steps: int = 0,
        accept_log_mu: bool = True,
    ) -> None:
        self.ingest_batch, self.max_tracks, self.crash_steps = ingest_batch, max_tracks, crash_steps
        self.accept_log_mu = accept_log_mu
        """False (`learner.rho_at=learner`): a chunk's log_mu is ignored, the learner's g decides rho."""
        self.min_behaviour_version = 0
        """A log_mu computed with an older discriminator is ignored (the learner's g decides): set
        past the warm start, whose trained g the actors only get with the next broadcast."""
        self.rejects = wire.RejectCounter(wire.Limits(max_bytes=max_chunk_bytes), logger=log)
        self.seq = SequenceTracker()
        self.tracks: dict[str, int] = {}
        self.returns: deque = deque(maxlen=100)
        self.lags: deque = deque(maxlen=200)
        self.rho_lags: deque = deque(maxlen=200)  # updates since the discriminator that gave a chunk's log_mu
        self.counters = {"inserted": 0, "episodes": 0, "chunks": 0}
        self.held_out: TensorDict | None = None
        """The first whole episode of one env (time-ordered transitions), once complete."""
        self._held: dict | None = None
        self._previous: dict[tuple[str, int], wire.TransitionChunk] = {}  # last chunk of each env
        self._crashes: list[list[wire.TransitionChunk]] = []  # chunks ending in a termination, with their previous

    def take(self, chunks_in, episodes_in, updates: int) -> TensorDict | None:
        """The transitions of the good chunks waiting in `chunks_in` (next state: its new frame
        only, as the replay stores it), or None; episode summaries are applied on the way."""
        good = []
        for r in chunks_in.drain(self.ingest_batch):
            chunk = self.rejects.decode(r.payload, expect=wire.TransitionChunk, key=r.key)
            if chunk is None or not self.rejects.obeys(
                lambda: (check_chunk(chunk, r.key), self.seq.see(chunk.actor, chunk.seq)), r.key
            ):
                continue  # counted by kind and dropped
            self.lags.append(max(0, updates - chunk.policy_version))  # chunks of a previous epoch can be ahead
            if chunk.log_mu is not None and chunk.behaviour_version < self.min_behaviour_version:
                chunk = dataclasses.replace(chunk, log_mu=None)  # from the untrained g: measured rho_bar 26 after it
            if chunk.log_mu is not None and self.accept_log_mu:
                self.rho_lags.append(max(0, updates - chunk.behaviour_version))
            self._hold_out(chunk)
            if self.crash_steps:
                self._see_for_crashes(chunk)
            good.append(chunk)
        for r in episodes_in.drain(1024):
            ep = self.rejects.decode(r.payload, expect=wire.EpisodeSummary, key=r.key)
            if ep is not None and self.rejects.obeys(
                lambda: (check_episode(ep, r.key), self._check_room(ep.track)), r.key
            ):
                self.tracks[ep.track.removesuffix("-r")] = ep.steps
                self.returns.append(ep.episode_return)
                self.counters["episodes"] += 1
        if not good:
            return None
        batch = chunks_to_transitions(good, next_image=False)
        if not self.accept_log_mu and "log_mu" in batch.keys():
            del batch["log_mu"]  # not asked for: an actor must not set its own sampling weight
        self.counters["inserted"] += batch.shape[0]
        self.counters["chunks"] += len(good)
        return batch

    def _see_for_crashes(self, chunk: wire.TransitionChunk) -> None:
        stream = (chunk.actor, chunk.env)
        before = self._previous.pop(stream, None)
        if chunk.terminated[-1]:
            same_episode = before is not None and before.episode == chunk.episode
            if same_episode and before.step0 + before.num_steps == chunk.step0:
                self._crashes.append([before, chunk])
            else:
                self._crashes.append([chunk])
        elif not chunk.truncated[-1]:
            if len(self._previous) >= MAX_STREAMS:  # bounded whatever the senders claim: forget the oldest
                self._previous.pop(next(iter(self._previous)))
            self._previous[stream] = chunk

    def take_crashes(self) -> TensorDict | None:
        """The last `crash_steps` transitions before each termination seen since the last call
        (time-ordered per crash, next state as in `take`), or None."""
        if not self._crashes:
            return None
        parts = [chunks_to_transitions(c, next_image=False)[-self.crash_steps :] for c in self._crashes]
        self._crashes = []
        return torch.cat(parts, 0) if len(parts) > 1 else parts[0]

    def _check_room(self, track: str) -> None:
        if track.removesuffix("-r") not in self.tracks and len(self.tracks) >= self.max_tracks:
            raise wire.WireError("track", f"track table full ({self.max_tracks} roads): {track[:64]!r} refused")

    def mean_chunk_steps(self) -> float:
        """Steps per chunk so far (1 before any): what an undecoded chunk in the inbox is worth."""
        return self.counters["inserted"] / self.counters["chunks"] if self.counters["chunks"] else 1.0

    def _hold_out(self, chunk: wire.TransitionChunk) -> None:
        if self._held is None:
            self._held = {"key": (chunk.actor, chunk.env, chunk.episode), "chunks": []}
        if self._held.get("done") or (chunk.actor, chunk.env, chunk.episode) != self._held["key"]:
            return
        self._held["chunks"].append(chunk)
        if chunk.terminated[-1] or chunk.truncated[-1]:
            self._held["done"] = True
            self.held_out = chunks_to_transitions(self._held["chunks"])

    def progress(self) -> dict:
        """The intake's part of progress.json."""
        return {
            "inserted": self.counters["inserted"],
            "chunks": self.counters["chunks"],
            "episodes": self.counters["episodes"],
            "return_mean": float(np.mean(self.returns)) if self.returns else None,
            "policy_lag": float(np.mean(self.lags)) if self.lags else None,
            "rho_lag": float(np.mean(self.rho_lags)) if self.rho_lags else None,
            "lost_chunks": self.seq.lost,
            "actor_restarts": self.seq.restarts,
            "rejected": self.rejects.total,
            "rejected_by_kind": dict(self.rejects.counts),
            "actors_seen": sorted(self.seq.expected),
        }
