"""Messages and payload helpers shared by the wire tests."""

from __future__ import annotations

import msgpack
import numpy as np
import pytest

from common.wire import Control, EpisodeSummary, TrackTable, TransitionChunk, Weights, WireError, decode, encode

H, W = 64, 128


def make_chunk(steps: int = 8, seed: int = 0, **overrides) -> TransitionChunk:
    rng = np.random.default_rng(seed)
    fields = dict(
        actor="a0",
        env=2,
        episode=5,
        seq=11,
        policy_version=3,
        step0=40,
        frames=rng.integers(0, 256, (steps + 2, H, W), dtype=np.uint8),
        speed=rng.random((steps + 1, 1), dtype=np.float32),
        last_action=rng.uniform(-1, 1, (steps + 1, 2)).astype(np.float32),
        action=rng.uniform(-1, 1, (steps, 2)).astype(np.float32),
        reward=rng.standard_normal(steps).astype(np.float32),
        terminated=np.zeros(steps, bool),
        truncated=np.zeros(steps, bool),
        alpha=rng.uniform(-1, 1, steps + 1).astype(np.float32),
        beta=rng.uniform(-0.5, 0.5, steps + 1).astype(np.float32),
    )
    fields.update(overrides)
    return TransitionChunk(**fields)


def as_map(msg) -> dict:
    return msgpack.unpackb(encode(msg), raw=False)


def pack(m: dict) -> bytes:
    return msgpack.packb(m, use_bin_type=True)


def assert_kind(payload, kind: str, **kwargs) -> None:
    with pytest.raises(WireError) as info:
        decode(payload, **kwargs)
    assert info.value.kind == kind, str(info.value)


VALID = [
    make_chunk(),
    EpisodeSummary(actor="a1", env=0, episode=9, track="oval-3", steps=1200, episode_return=-2.5, policy_version=7),
    Weights(
        version=4,
        tensors={"actor.0.weight": np.ones((3, 4), np.float32), "critic.bias": np.arange(5, dtype=np.float64)},
        epoch=1_795_000_000_000_000_000,
    ),
    TrackTable(version=2, steps={"oval": 100, "hairpin": 0}),
    Control(command="pause", reason="maintenance"),
]
