"""Wire format: round trips, frames sent once, and every hostile input refused as WireError."""

from __future__ import annotations

import logging
import re
from pathlib import Path

import msgpack
import numpy as np
import pytest

from common import wire
from common.wire import (
    Control,
    Limits,
    RejectCounter,
    TrackTable,
    TransitionChunk,
    Weights,
    WireError,
    decode,
    encode,
)
from tests.wire_helpers import VALID, H, W, as_map, assert_kind, make_chunk, pack

# --- round trips ---------------------------------------------------------------------------


def test_chunk_round_trip_keeps_every_field():
    chunk = make_chunk(steps=5, terminated=np.array([0, 0, 0, 0, 1], bool))
    out = decode(encode(chunk), expect=TransitionChunk)
    for name in ("actor", "env", "episode", "seq", "policy_version", "step0"):
        assert getattr(out, name) == getattr(chunk, name)
    for name in ("frames", "speed", "last_action", "action", "reward", "terminated", "truncated", "alpha", "beta"):
        got, want = getattr(out, name), getattr(chunk, name)
        assert got.dtype == want.dtype and np.array_equal(got, want), name
    assert out.num_steps == 5 and not out.frames.flags.writeable


@pytest.mark.parametrize("msg", VALID[1:], ids=lambda m: type(m).__name__)
def test_other_messages_round_trip(msg):
    out = decode(encode(msg))
    assert type(out) is type(msg)
    if isinstance(msg, Weights):
        assert (out.version, out.epoch) == (msg.version, msg.epoch) and out.tensors.keys() == msg.tensors.keys()
        for name, value in msg.tensors.items():
            assert out.tensors[name].dtype == value.dtype
            assert np.array_equal(out.tensors[name], value)
    else:
        assert out == msg


def test_observations_and_frames_are_inverse():
    chunk = make_chunk(steps=6)
    obs = chunk.observations()
    assert obs.shape == (7, 2, H, W)
    assert np.array_equal(obs[3, 0], chunk.frames[4]) and np.array_equal(obs[3, 1], chunk.frames[3])
    assert np.array_equal(wire.frames_from_images(obs), chunk.frames)
    broken = obs.copy()
    broken[2, 1] ^= 1
    with pytest.raises(ValueError):
        wire.frames_from_images(broken)


def test_each_frame_is_sent_once():
    steps = 32
    size = len(encode(make_chunk(steps=steps)))
    frame = H * W
    # T+1 observations of (current, previous) share T+2 frames; the rest is a few bytes per step
    assert (steps + 2) * frame <= size < (steps + 2) * frame + 64 * steps + 1024
    assert size < 2 * (steps + 1) * frame * 0.55


def test_encode_accepts_numpy_scalars_and_refuses_bad_fields():
    chunk = make_chunk(env=np.int64(3), seq=np.uint32(9))
    assert decode(encode(chunk)).env == 3
    assert decode(encode(TrackTable(np.int64(1), {"oval": np.int32(4)}))).steps == {"oval": 4}
    for bad, kind in [
        (make_chunk(seq=1.0), "schema"),
        (make_chunk(actor="a b"), "value"),
        (make_chunk(reward=np.full(8, np.nan)), "nonfinite"),
        (make_chunk(action=np.zeros((8, 3))), "shape"),
    ]:
        with pytest.raises(WireError) as info:
            encode(bad)
        assert info.value.kind == kind


def test_expect_rejects_other_types():
    assert_kind(encode(Control("stop")), "schema", expect=TransitionChunk)


# --- hostile inputs ------------------------------------------------------------------------


def test_garbage_empty_truncated_and_trailing_bytes():
    assert_kind(b"", "decode")
    assert_kind(b"\xc1", "decode")
    assert_kind(b"\x00" * 5, "decode")
    assert_kind("not bytes", "decode")
    good = encode(VALID[1])
    for cut in range(len(good)):
        assert_kind(good[:cut], "decode")
    assert_kind(good + b"\x00", "decode")


@pytest.mark.parametrize("version", [0, 1, 3, "2", 2.0, True, None])
def test_wrong_or_missing_schema_version(version):
    m = as_map(VALID[4])
    if version is None:
        del m["v"]
    else:
        m["v"] = version
    assert_kind(pack(m), "version")


@pytest.mark.parametrize(
    "mutate",
    [
        lambda m: m.update(type="nonsense"),
        lambda m: m.pop("seq"),
        lambda m: m.update(extra=1),
        lambda m: m.update(env="2"),
        lambda m: m.update(env=True),
        lambda m: m.update(seq=1.5),
        lambda m: m.update(actor=b"a0"),
        lambda m: m.update(frames=b"raw"),
        lambda m: m["reward"].pop("shape"),
        lambda m: m["reward"].update(data="text"),
    ],
    ids=[
        "type",
        "missing",
        "unknown",
        "str-int",
        "bool-int",
        "float-int",
        "bytes-str",
        "array-not-map",
        "array-no-shape",
        "array-data-str",
    ],
)
def test_schema_violations(mutate):
    m = as_map(make_chunk())
    mutate(m)
    assert_kind(pack(m), "schema")
    assert_kind(pack([1, 2, 3]), "schema")


@pytest.mark.parametrize(
    "name,shape",
    [
        ("frames", [9, H, W]),
        ("frames", [10, H, 64]),
        ("speed", [9]),
        ("action", [8, 3]),
        ("reward", [8, 1]),
        ("alpha", [8]),
        ("frames", [10, -1, W]),
        ("reward", "8"),
        ("reward", [8.0]),
    ],
)
def test_wrong_shapes(name, shape):
    m = as_map(make_chunk(steps=8))
    m[name]["shape"] = shape
    assert_kind(pack(m), "shape")


def test_data_length_must_match_shape_and_steps_are_bounded():
    m = as_map(make_chunk(steps=8))
    m["reward"]["data"] = m["reward"]["data"][:-4]
    assert_kind(pack(m), "shape")
    m = as_map(make_chunk(steps=8))
    m["frames"]["shape"] = [10, 2**40, 2**40]
    assert_kind(pack(m), "shape", limits=Limits(frame_shape=None))
    m = as_map(VALID[2])
    m["tensors"]["critic.bias"].update(shape=[0, 2**30, 2**30], data=b"")
    assert_kind(pack(m), "shape")
    assert_kind(encode(make_chunk(steps=8)), "shape", limits=Limits(max_steps=4))


@pytest.mark.parametrize(
    "name,dtype",
    [
        ("frames", "<f4"),
        ("speed", "<f8"),
        ("terminated", "|u1"),
        ("action", ">f4"),
        ("reward", 4),
    ],
)
def test_wrong_dtypes(name, dtype):
    m = as_map(make_chunk())
    m[name]["dtype"] = dtype
    assert_kind(pack(m), "dtype")


def test_weights_must_be_float():
    m = as_map(VALID[2])
    m["tensors"]["critic.bias"]["dtype"] = "<i8"
    assert_kind(pack(m), "dtype")
    with pytest.raises(WireError) as info:
        encode(Weights(1, {"count": np.array([1, 2])}))
    assert info.value.kind == "dtype"


@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf])
def test_non_finite_numbers(value):
    for name in ("reward", "speed", "alpha"):
        m = as_map(make_chunk())
        arr = np.frombuffer(m[name]["data"], np.float32).copy()
        arr[0] = value
        m[name]["data"] = arr.tobytes()
        assert_kind(pack(m), "nonfinite")
    m = as_map(VALID[1])
    m["return"] = float(value)
    assert_kind(pack(m), "nonfinite")
    with pytest.raises(WireError) as info:
        encode(Weights(1, {"w": np.array([0.0, value])}))
    assert info.value.kind == "nonfinite"


def test_values_out_of_range():
    cases = [
        (make_chunk(), lambda m: m.update(seq=-1)),
        (make_chunk(), lambda m: m.update(actor="a/b")),
        (make_chunk(), lambda m: m.update(actor="x" * 65)),
        (make_chunk(), lambda m: m.update(env=2**31)),
        (make_chunk(), lambda m: m["terminated"].update(data=b"\x02" + b"\x00" * 7)),
        (make_chunk(), lambda m: m["truncated"].update(data=b"\x01" + b"\x00" * 7)),
        (VALID[3], lambda m: m["steps"].update(oval=-5)),
        (VALID[3], lambda m: m["steps"].update({"": 1})),
        (VALID[4], lambda m: m.update(command="reboot")),
        (VALID[1], lambda m: m.update(track="")),
    ]
    for msg, mutate in cases:
        m = as_map(msg)
        mutate(m)
        assert_kind(pack(m), "value")


def test_oversized_payloads_and_containers():
    small = Limits(max_bytes=100_000)
    assert_kind(encode(make_chunk(steps=16)), "size", limits=small)
    assert_kind(b"\x00" * 100_001, "size", limits=small)
    assert_kind(pack({"v": 2, "type": "control", "reason": b"x" * 100_001}), "size", limits=small)
    assert_kind(pack({str(i): i for i in range(70_000)}), "size")
    assert_kind(pack({"v": 2, "shape": list(range(20))}), "size")
    assert_kind(b"\xdd\xff\xff\xff\xff", "size")  # array header claiming 4 G items
    assert_kind(b"\xdf\xff\xff\xff\xff", "size")  # map header claiming 4 G entries
    assert_kind(pack(msgpack.ExtType(3, b"abc")), "size")  # no extension types at all
    tensors = {f"t{i}": np.zeros(1, np.float32) for i in range(20)}
    assert_kind(encode(Weights(1, tensors)), "size", limits=Limits(max_tensors=10))
    with pytest.raises(WireError) as info:
        encode(make_chunk(steps=16), limits=small)
    assert info.value.kind == "size"


def test_deeply_nested_and_odd_keys():
    assert_kind(b"\x91" * 100_000 + b"\xc0", "decode")  # 100k nested arrays: msgpack's stack limit
    assert_kind(b"\x81\xa1a" * 5000 + b"\xc0", "decode")  # 5k nested maps
    nested = {"v": 2, "type": "control", "command": "stop", "reason": [[[["deep"]]]]}
    assert_kind(pack(nested), "schema")
    assert_kind(pack({1: 2}), "decode")
    assert_kind(b"\x81\xa2\xff\xfe\x01", "decode")  # key that is not utf-8


def test_reject_counter_counts_and_logs_once_per_kind(caplog):
    rejects = RejectCounter()
    with caplog.at_level(logging.WARNING, logger="common.wire"):
        for _ in range(3):
            assert rejects.decode(b"\xc1", key="k") is None
        assert rejects.decode(pack({"v": 9}), key="k") is None
        assert isinstance(rejects.decode(encode(VALID[4])), Control)
    assert rejects.counts == {"decode": 3, "version": 1} and rejects.total == 4
    assert len([r for r in caplog.records if "first of kind" in r.getMessage()]) == 2


def test_docs_example_is_a_valid_chunk():
    text = (Path(__file__).resolve().parents[1] / "docs" / "wire.md").read_text()
    example = re.search(r"## Example.*?```python\n(.*?)```", text, re.S).group(1)
    scope: dict = {}
    exec(compile(example, "docs/wire.md", "exec"), scope)
    chunk = decode(scope["payload"], expect=TransitionChunk)
    assert chunk.actor == "ext-1" and chunk.num_steps == 2 and bool(chunk.terminated[-1])


def test_control_pause_carries_its_expiry_and_an_out_of_range_one_is_refused():
    pause = wire.decode(wire.encode(wire.Control("pause", reason="ahead", expires_s=5.0)))
    assert (pause.command, pause.expires_s) == ("pause", 5.0)
    assert wire.decode(wire.encode(wire.Control("stop"))).expires_s == 0.0  # optional: absent means none
    m = {"v": wire.SCHEMA_VERSION, "type": "control", "command": "pause", "reason": "", "expires_s": -1.0}
    with pytest.raises(wire.WireError) as err:
        wire.decode(msgpack.packb(m))
    assert err.value.kind == "value"
    m["expires_s"], m["other"] = 1.0, 2
    with pytest.raises(wire.WireError, match="unknown fields"):
        wire.decode(msgpack.packb(m))
