"""Wire format under random damage: mutated bytes and mutated structure raise only WireError."""

from __future__ import annotations

import random

import numpy as np

from common.wire import Weights, WireError, decode, encode
from common.wire_quant import for_broadcast
from tests.wire_helpers import VALID, as_map, make_chunk, pack


def _mutations(rng: random.Random, good: bytes) -> bytes:
    data = bytearray(good)
    for _ in range(rng.randint(1, 4)):
        op = rng.randrange(4)
        pos = rng.randrange(len(data)) if data else 0
        if op == 0 and data:
            data[pos] = rng.randrange(256)
        elif op == 1:
            data[pos:pos] = bytes(rng.randrange(256) for _ in range(rng.randint(1, 8)))
        elif op == 2 and data:
            del data[pos : pos + rng.randint(1, 8)]
        else:
            data = data[:pos]
    return bytes(data)


def test_fuzz_only_wire_errors():
    rng = random.Random(1234)
    goods = [encode(msg) for msg in VALID[1:]] + [encode(make_chunk(steps=2))]
    kinds = set()
    for i in range(4000):
        if i % 4 == 0:
            payload = bytes(rng.randrange(256) for _ in range(rng.randint(0, 64)))
        else:
            payload = _mutations(rng, rng.choice(goods))
        try:
            decode(payload)
        except WireError as err:
            kinds.add(err.kind)
    assert {"decode", "schema"} <= kinds


def _random_value(rng: random.Random):
    return rng.choice(
        [
            None,
            True,
            -1,
            0,
            2**64 - 1,
            -(2**63),
            1.5,
            float("nan"),
            float("inf"),
            "",
            "x" * 70,
            "a/b",
            b"",
            b"\x00" * 9,
            [],
            [0, 2**62],
            [2**31, 2**31],
            [-1],
            [1.0],
            {},
            {"dtype": "<f4"},
            {"dtype": "<f4", "shape": [0, 2**40], "data": b""},
            {"dtype": "|u1", "shape": [0, 3], "data": b""},
            {"dtype": "<f4", "shape": [0, 2], "data": b""},
            {"a": {"b": {"c": []}}},
        ]
    )


def _structural_mutation(rng: random.Random, m: dict) -> dict:
    target = m
    nested = [k for k, v in m.items() if isinstance(v, dict)]
    if nested and rng.random() < 0.5:
        target = m[rng.choice(nested)]
        nested_inner = [k for k, v in target.items() if isinstance(v, dict)]
        if nested_inner and rng.random() < 0.5:
            target = target[rng.choice(nested_inner)]
    key = rng.choice(list(target) + ["new"])
    if rng.random() < 0.2:
        target.pop(key, None)
    else:
        target[key] = _random_value(rng)
    return m


def test_fuzz_structure_only_wire_errors():
    rng = random.Random(99)
    rows = np.linspace(-1.0, 1.0, 12, dtype=np.float32).reshape(3, 4)
    tensors, quant = for_broadcast({"fc.weight": rows, "fc.bias": rows[0]}, "uint8")
    quantized = Weights(3, tensors, epoch=1, quant=quant)
    messages = [*VALID, quantized]
    for i in range(3000):
        m = as_map(messages[i % len(messages)] if i % 2 else make_chunk(steps=2))
        for _ in range(rng.randint(1, 3)):
            m = _structural_mutation(rng, m)
        try:
            decode(pack(m))
        except WireError:
            pass
