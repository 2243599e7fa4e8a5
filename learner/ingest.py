"""From wire chunks to replay transitions, and the bookkeeping of what arrived.

A chunk of T steps becomes T transitions in torchrl's layout (see `learner.replay`):
observation t is (frames[t+1], frames[t]); alpha and beta are observation-aligned (T+1), so
step t's cumulants are alpha[t+1], beta[t+1] (the next state's, Algorithm 1 line 6). Chunks
that carry the actor's log mu_hat (`learner.rho_at=actor`) give a "log_mu" column (NaN for
those that do not). "steps_left" counts each chunk's steps down to 1: the windows of n-step
returns end there (learner.nstep).
"""

from __future__ import annotations

import numpy as np
import torch
from tensordict import TensorDict

from common.wire import TransitionChunk
from learner.nstep import steps_left


def chunks_to_transitions(chunks: list[TransitionChunk], next_image: bool = True) -> TensorDict:
    """Concatenate the transitions of several chunks into one batch.

    With `next_image=False` the next state carries only its new frame, ("next", "frame")
    (B, 1, H, W), which is all the replay stores of it: one frame copy per step less.
    """
    steps = [c.num_steps for c in chunks]
    total = sum(steps)
    # the images straight from each chunk's frames into the batch: no per-chunk stacks and no
    # concatenated copies of them (copying these bytes is most of what this function costs)
    image = np.empty((total, 2, *np.shape(chunks[0].frames)[1:]), np.uint8)
    following = np.empty((total, 2 if next_image else 1, *image.shape[2:]), np.uint8)
    start = 0
    for c, n in zip(chunks, steps):
        frames, end = c.frames, start + n
        image[start:end, 0], image[start:end, 1] = frames[1 : n + 1], frames[:n]
        following[start:end, 0] = frames[2 : n + 2]
        if next_image:
            following[start:end, 1] = frames[1 : n + 1]
        start = end

    def cat(get) -> torch.Tensor:
        return torch.from_numpy(np.concatenate([get(c) for c in chunks]))

    col = lambda x: x.reshape(-1, 1)  # noqa: E731
    batch = TensorDict(
        {
            "image": torch.from_numpy(image),
            "speed": cat(lambda c: c.speed[:-1]),
            "last_action": cat(lambda c: c.last_action[:-1]),
            "alpha": cat(lambda c: col(c.alpha[:-1])),
            "beta": cat(lambda c: col(c.beta[:-1])),
            "action": cat(lambda c: c.action),
            "next": {
                ("image" if next_image else "frame"): torch.from_numpy(following),
                "speed": cat(lambda c: c.speed[1:]),
                "last_action": cat(lambda c: c.action),
                "alpha": cat(lambda c: col(c.alpha[1:])),
                "beta": cat(lambda c: col(c.beta[1:])),
                "reward": cat(lambda c: col(c.reward)),
                "terminated": cat(lambda c: col(c.terminated)),
                "truncated": cat(lambda c: col(c.truncated)),
            },
            "steps_left": steps_left(steps),
        },
        batch_size=[total],
    )
    if any(c.log_mu is not None for c in chunks):  # NaN where a chunk came without it
        nan = np.full(1, np.nan, np.float32)
        batch["log_mu"] = cat(lambda c: col(c.log_mu if c.log_mu is not None else np.repeat(nan, c.num_steps)))
    return batch
