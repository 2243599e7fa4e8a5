"""Turns the steps of N simulators into wire chunks of consecutive steps of one episode each.

Each chunk starts from an observation (two frames) and adds one new frame per step, so every
camera frame crosses the wire once per chunk (see `common.wire.TransitionChunk`). A chunk is
sent when it holds `chunk_len` steps or its episode ends; the next chunk of the same episode
starts from the last observation of the previous one.
"""

from __future__ import annotations

import numpy as np

from common.wire import TransitionChunk


class _Open:
    """The steps gathered so far for one env."""

    def __init__(self, obs: dict, alpha: float, beta: float, episode: int, step0: int, version: int) -> None:
        self.frames = [obs["image"][1], obs["image"][0]]
        self.speed, self.last_action = [obs["speed"]], [obs["last_action"]]
        self.alpha, self.beta = [alpha], [beta]
        self.action, self.reward, self.terminated, self.truncated = [], [], [], []
        self.episode, self.step0, self.version = episode, step0, version


class ChunkBuilder:
    """Per-env chunk assembly for one actor; `seq` numbers every chunk the actor emits."""

    def __init__(self, actor: str, n_envs: int, chunk_len: int) -> None:
        if chunk_len < 1:
            raise ValueError(f"actor.chunk_len must be >= 1, got {chunk_len}")
        self.actor, self.chunk_len = actor, chunk_len
        self.seq = 0
        self.episodes = np.zeros(n_envs, np.int64)
        self.steps = np.zeros(n_envs, np.int64)
        self._open: list[_Open | None] = [None] * n_envs

    def start(self, i: int, obs: dict, alpha: float, beta: float, version: int) -> None:
        """Begin a new episode of env `i` at observation `obs` (one env's arrays) and its ground truth."""
        self.steps[i] = 0
        self._open[i] = _Open(obs, alpha, beta, int(self.episodes[i]), 0, version)

    def add(
        self,
        i: int,
        action,
        reward: float,
        terminated: bool,
        truncated: bool,
        alpha: float,
        beta: float,
        next_obs: dict,
        version: int,
    ) -> TransitionChunk | None:
        """Record one step of env `i` (alpha, beta of `next_obs`); returns a finished chunk or None."""
        o = self._open[i]
        o.frames.append(next_obs["image"][0])
        o.speed.append(next_obs["speed"])
        o.last_action.append(next_obs["last_action"])
        o.action.append(action)
        o.reward.append(reward)
        o.terminated.append(terminated)
        o.truncated.append(truncated)
        o.alpha.append(alpha)
        o.beta.append(beta)
        self.steps[i] += 1
        done = terminated or truncated
        if not done and len(o.action) < self.chunk_len:
            return None
        chunk = TransitionChunk(
            actor=self.actor,
            env=i,
            episode=o.episode,
            seq=self.seq,
            policy_version=o.version,
            step0=o.step0,
            frames=np.stack(o.frames),
            speed=np.asarray(o.speed, np.float32).reshape(-1, 1),
            last_action=np.asarray(o.last_action, np.float32),
            action=np.asarray(o.action, np.float32),
            reward=np.asarray(o.reward, np.float32),
            terminated=np.asarray(o.terminated, bool),
            truncated=np.asarray(o.truncated, bool),
            alpha=np.asarray(o.alpha, np.float32),
            beta=np.asarray(o.beta, np.float32),
        )
        self.seq += 1
        if done:
            self.episodes[i] += 1
            self._open[i] = None
        else:  # the next chunk of this episode starts where this one ended
            self._open[i] = _Open(next_obs, alpha, beta, o.episode, int(self.steps[i]), version)
        return chunk
