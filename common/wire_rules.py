"""What a well-formed message must also mean before a receiver acts on it. `common.wire` checks
the form (types, shapes, sizes, finite numbers); these rules check the content against the
sender's key, the environment's documented bounds and the receiver's own state. A message that
breaks one raises `WireError` with its own kind, so that `RejectCounter.reject` counts and
drops it like a malformed one: a receiver never crashes on, learns from or is steered by it.

    kind        rule
    identity    a chunk's or summary's `actor` is the last chunk of the key it came on
    range       values within BOUNDS (docs/wire.md): actions and last actions in [-1, 1], speed
                in [0, 1], reward, alpha and beta within the environment's bounds, log_mu in [-50, 50]
    seq         `seq` (SequenceTracker): 0 announces an actor's (re)start; otherwise it must
                move forward, by at most MAX_SEQ_GAP; duplicates and backward steps are dropped
    weights     names, shapes and dtypes equal to the receiver's own policy, every value finite
    track       a track table or summary naming a road the receiver does not know, or too many
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from common.wire import EpisodeSummary, TrackTable, TransitionChunk, Weights, WireError

BOUNDS: dict[str, tuple[float, float]] = {
    "action": (-1.0, 1.0),
    "last_action": (-1.0, 1.0),
    "speed": (0.0, 1.0),
    # r = v / v_max (cos beta - |alpha|): v / v_max <= 1, and |alpha| <= 4 (see alpha)
    "reward": (-5.0, 1.0),
    # an episode ends once |alpha| > 1; its last step can overshoot by one step's lateral move
    "alpha": (-4.0, 4.0),
    "beta": (-math.pi, math.pi),
    # log mu_hat = logit g + log eta: |logit| > 40 is beyond float32's sigmoid, a sender's bug
    "log_mu": (-50.0, 50.0),
}
MAX_SEQ_GAP = 10_000
"""A larger forward jump of one actor's `seq` is refused rather than counted as lost chunks."""


def _in_range(name: str, values) -> None:
    lo, hi = BOUNDS[name]
    values = np.asarray(values)
    if values.size and (values.min() < lo or values.max() > hi):
        raise WireError("range", f"{name} outside [{lo:g}, {hi:g}]: {values.min():g} .. {values.max():g}")


def check_sender(actor: str, key: str) -> None:
    """The payload names the actor whose key it came on."""
    if key and actor != key.rsplit("/", 1)[-1]:
        raise WireError("identity", f"payload names actor {actor!r} but came on {key!r}")


def check_chunk(chunk: TransitionChunk, key: str = "") -> None:
    """A transition chunk's sender and value ranges (see the module docstring)."""
    check_sender(chunk.actor, key)
    for name in BOUNDS:
        if getattr(chunk, name) is not None:  # log_mu is optional
            _in_range(name, getattr(chunk, name))


def check_episode(summary: EpisodeSummary, key: str = "") -> None:
    check_sender(summary.actor, key)
    if summary.steps < 0:
        raise WireError("range", f"episode steps {summary.steps} < 0")


def check_weights(weights: Weights, own: dict) -> None:
    """`weights` fit the receiver's policy state dict `own` exactly and are finite."""
    if set(weights.tensors) != set(own):
        missing, extra = sorted(set(own) - set(weights.tensors)), sorted(set(weights.tensors) - set(own))
        raise WireError("weights", f"tensors missing {missing[:3]}, unknown {extra[:3]}")
    for name, tensor in own.items():
        got = np.asarray(weights.tensors[name])
        if tuple(got.shape) != tuple(tensor.shape):
            raise WireError("weights", f"{name}: shape {tuple(got.shape)}, this policy has {tuple(tensor.shape)}")
        if got.dtype not in (np.float32, np.float16):  # float16: learner.weights_dtype, half the bytes
            raise WireError("weights", f"{name}: dtype {got.dtype}, expected float32 or float16")
        if not np.isfinite(got).all():
            raise WireError("weights", f"{name}: non-finite values")


def check_tracks(table: TrackTable, known: set[str]) -> None:
    """A track table names only roads the receiver knows (so it also holds at most that many)."""
    unknown = [name for name in table.steps if name not in known]
    if unknown:
        raise WireError("track", f"{len(unknown)} unknown roads, e.g. {unknown[0]!r}")
    if any(n < 0 for n in table.steps.values()):
        raise WireError("range", "a track's steps < 0")


@dataclass
class SequenceTracker:
    """Per-actor `seq` accounting: lost chunks from gaps, announced restarts, refused repeats.

    `see` returns the chunks lost just before this one, or raises WireError('seq') for a
    duplicate, a backward step that is not a restart (seq 0), or a jump over MAX_SEQ_GAP.
    """

    expected: dict[str, int] = field(default_factory=dict)
    lost: int = 0
    received: int = 0
    restarts: int = 0

    def see(self, actor: str, seq: int) -> int:
        want = self.expected.get(actor)
        if want is not None and seq != 0 and not want <= seq <= want + MAX_SEQ_GAP:
            raise WireError("seq", f"actor {actor!r}: seq {seq} where {want} was next")
        self.received += 1
        self.expected[actor] = seq + 1
        if want is None:
            return 0
        if seq == 0:  # the actor announced a restart
            self.restarts += 1
            return 0
        self.lost += seq - want
        return seq - want
