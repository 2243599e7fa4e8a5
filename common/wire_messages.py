"""The messages that cross Zenoh, as Python objects (`common.wire` encodes and checks them).

A TransitionChunk holds T consecutive steps of one episode of one env and sends each camera
frame once: T+1 observations (current, previous) share T+2 frames.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Union

import numpy as np

BEHAVIOUR = "behaviour."  # Weights: prefix of the discriminator's tensors
AVERAGE = "average."  # Weights: prefix of the averaged policy's tensors


@dataclass(frozen=True, eq=False)
class TransitionChunk:
    """T consecutive steps of one episode of one env, each camera frame sent once.

    Observation t (t = 0..T) is image (frames[t+1], frames[t]) = (current, previous), speed[t],
    last_action[t], with the ground truth alpha[t], beta[t] of that observation; step t goes
    from observation t to t+1 with action[t], reward[t], terminated[t], truncated[t]. The GVF
    cumulants of step t are alpha[t+1], beta[t+1]; alpha[t], beta[t] are DDPG-LowDim's inputs.
    Only the last step may be terminated or truncated.
    """

    actor: str
    env: int
    episode: int
    seq: int
    """Per-actor sequence number of this chunk (0, 1, 2, ...): gaps are lost chunks."""
    policy_version: int
    step0: int
    """Episode step index of the chunk's first step."""
    frames: np.ndarray  # (T+2, H, W) uint8
    speed: np.ndarray  # (T+1, 1) float32
    last_action: np.ndarray  # (T+1, 2) float32
    action: np.ndarray  # (T, 2) float32
    reward: np.ndarray  # (T,) float32
    terminated: np.ndarray  # (T,) bool
    truncated: np.ndarray  # (T,) bool
    alpha: np.ndarray  # (T+1,) float32, observation-aligned
    beta: np.ndarray  # (T+1,) float32, observation-aligned
    log_mu: np.ndarray | None = None
    """(T,) float32, optional (`learner.rho_at=actor`): log mu_hat(action[t] | observation t) under
    the broadcast discriminator of version `behaviour_version`; absent: the learner computes it."""
    behaviour_version: int = -1

    @property
    def num_steps(self) -> int:
        return int(np.shape(self.action)[0])

    def observations(self) -> np.ndarray:
        """The T+1 stacked images (T+1, 2, H, W): [t, 0] current frame, [t, 1] previous frame."""
        frames = np.asarray(self.frames)
        return np.stack([frames[1:], frames[:-1]], axis=1)


@dataclass(frozen=True)
class EpisodeSummary:
    """One finished episode, for priority track sampling and progress display."""

    actor: str
    env: int
    episode: int
    track: str
    steps: int
    """Steps survived (n_i of this track in priority track sampling)."""
    episode_return: float
    policy_version: int


@dataclass(frozen=True, eq=False)
class Weights:
    """A version of the acting networks' parameters: name -> float array. Names under
    `BEHAVIOUR` are the discriminator's (`learner.rho_at=actor`), under `AVERAGE` the averaged
    policy's (`scale.policy_average`), the rest the online policy's."""

    version: int
    tensors: dict[str, np.ndarray] = field(default_factory=dict)
    epoch: int = 0
    """The publishing learner's incarnation: a resumed learner counts versions from its
    checkpoint again, so a new epoch tells receivers to accept a lower version."""
    quant: dict[str, np.ndarray] = field(default_factory=dict)
    """Tensors sent as uint8 codes (`learner.weights_dtype=uint8`): name -> (scale, offset) per row.
    `decode` validates them; `common.wire_quant.floats` gives the values, where a receiver loads them."""


@dataclass(frozen=True)
class TrackTable:
    """The learner's global table of n_i (steps survived last time) per track."""

    version: int
    steps: dict[str, int] = field(default_factory=dict)


@dataclass(frozen=True)
class Control:
    """A launcher command to every process of the run."""

    command: str
    """One of CONTROL_COMMANDS: 'stop', 'pause', 'resume'."""
    reason: str = ""
    expires_s: float = 0.0
    """A 'pause' ends by itself this many seconds after it arrives unless repeated (0: only a
    'resume' ends it); the learner's rate limit sets it, so that a silent learner stops nobody."""


Message = Union[TransitionChunk, EpisodeSummary, Weights, TrackTable, Control]


def frames_from_images(images: np.ndarray) -> np.ndarray:
    """(T+1, 2, H, W) stacked observations -> the (T+2, H, W) distinct frames they share.

    Raises ValueError if the observations are not consecutive (image[t+1][1] != image[t][0]).
    """
    images = np.asarray(images)
    if images.ndim != 4 or images.shape[1] != 2:
        raise ValueError(f"images must be (T+1, 2, H, W), got {images.shape}")
    if not np.array_equal(images[1:, 1], images[:-1, 0]):
        raise ValueError("observations are not consecutive: image[t+1][1] != image[t][0]")
    return np.concatenate([images[:1, 1], images[:, 0]], axis=0)
