"""uint8 weights on the wire (`learner.weights_dtype=uint8`): matrices and kernels as codes with a
scale and offset per row whose float32 values are within half a step of the sender's, vectors as
they are; a malformed quant is refused when decoded."""

from __future__ import annotations

import numpy as np
import pytest

from common.wire import Weights, WireError, decode, encode
from common.wire_quant import dequantize, floats, for_broadcast, quantize, quantized
from tests.wire_helpers import as_map, assert_kind, pack

FC = "fc.weight"  # 3 rows


def tensors(seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    conv = rng.normal(0.0, 0.1, (8, 2, 5, 5)).astype(np.float32)
    conv[3] = 0.0  # a dead channel
    conv[5] *= 40.0  # and one far wider than the others: its own scale keeps the rest fine
    fc = rng.normal(0.0, 1.0, (3, 512)).astype(np.float32)
    fc[1] = np.abs(fc[1])  # all positive: 0 still in its range
    return {
        "conv.weight": conv,
        "conv.bias": rng.uniform(0.2, 0.9, 8).astype(np.float32),
        FC: fc,
        "sign": np.array([1.0, -1.0, 1.0], np.float32),  # a vector that must stay exact
    }


def test_each_row_is_within_half_a_step_and_zeros_stay_exact():
    for name, x in tensors().items():
        if not quantized(x.shape):
            with pytest.raises(ValueError, match="2 or more dimensions"):
                quantize(x)
            continue
        q, params = quantize(x)
        assert q.dtype == np.uint8 and q.shape == x.shape
        assert params.dtype == np.float32 and params.shape == (x.shape[0], 2)
        back = dequantize(q, params)
        assert back.dtype == np.float32
        err = np.abs(back - x).reshape(x.shape[0], -1)
        assert (err <= params[:, :1] / 2 * (1 + 1e-5)).all(), name
        assert (back[x == 0] == 0).all()
    _, params = quantize(tensors()["conv.weight"])
    assert params[5, 0] > 20 * np.median(params[:, 0])  # the wide channel did not coarsen the others


def test_uint8_weights_round_trip_at_under_a_third_of_the_bytes_and_vectors_exact():
    float32 = tensors()
    codes, quant = for_broadcast(float32, "uint8")
    assert set(quant) == {"conv.weight", FC}
    small = encode(Weights(7, codes, epoch=3, quant=quant))
    full = encode(Weights(7, float32, epoch=3))
    assert len(small) < 0.35 * len(full)  # 1 byte a value, plus names, the vectors and the params
    got = decode(small, expect=Weights)
    assert (got.version, got.epoch, set(got.quant)) == (7, 3, set(quant))
    values = floats(got.tensors, got.quant)
    for name, x in float32.items():
        assert values[name].dtype == np.float32
        if name in quant:
            assert np.array_equal(got.tensors[name], codes[name]) and np.array_equal(got.quant[name], quant[name])
            assert np.allclose(values[name], x, atol=float(quant[name][:, 0].max()) / 2 * 1.0001)
        else:
            assert np.array_equal(values[name], x)


def test_the_float_precisions_send_no_quant_and_an_unknown_one_is_refused():
    for dtype in ("float32", "float16"):
        out, quant = for_broadcast(tensors(), dtype)
        assert quant == {} and all(t.dtype == np.dtype(dtype) for t in out.values())
    with pytest.raises(ValueError, match="weights dtype"):
        for_broadcast(tensors(), "int4")


def quantized_map() -> dict:
    codes, quant = for_broadcast(tensors(), "uint8")
    return as_map(Weights(1, codes, epoch=1, quant=quant))


def mutate_params(m: dict, name: str, rows) -> dict:
    spec = m["quant"][name]
    spec["data"] = np.asarray(rows, np.float32).tobytes()
    spec["shape"] = list(np.shape(rows))
    return m


@pytest.mark.parametrize(
    "mutate, kind",
    [
        (lambda m: m["quant"].update({"ghost": m["quant"][FC]}), "schema"),  # quant of no tensor
        (lambda m: m["quant"].pop(FC), "dtype"),  # uint8 codes without params are not floats
        (lambda m: m["quant"].update({"conv.bias": m["quant"][FC]}), "dtype"),  # params for a float vector
        (lambda m: mutate_params(m, FC, [[0.1, 0.0]] * 2), "shape"),  # a row each: 3 rows
        (lambda m: mutate_params(m, FC, [0.1, 0.0, 0.1]), "shape"),
        (lambda m: mutate_params(m, FC, [[0.1, 0.0], [0.0, 0.0], [0.1, 0.0]]), "value"),
        (lambda m: mutate_params(m, FC, [[0.1, 0.0], [-0.1, 0.0], [0.1, 0.0]]), "value"),
        (lambda m: mutate_params(m, FC, [[0.1, 0.0], [3e38, 0.0], [0.1, 0.0]]), "value"),  # x 255: past float32
        (lambda m: mutate_params(m, FC, [[0.1, 0.0], [0.1, np.nan], [0.1, 0.0]]), "nonfinite"),
        (lambda m: m.update({"quant": [1, 2]}), "schema"),
    ],
)
def test_a_malformed_quant_is_refused(mutate, kind):
    m = quantized_map()
    mutate(m)
    assert_kind(pack(m), kind)


def test_codes_need_a_matrix_and_a_float_tensor_with_params_is_refused():
    m = quantized_map()
    m["tensors"][FC]["dtype"] = "<f4"  # the quant says codes
    m["tensors"][FC]["data"] = np.zeros((3, 512), np.float32).tobytes()
    assert_kind(pack(m), "dtype")
    m = quantized_map()
    m["tensors"]["sign"] = {"dtype": "|u1", "shape": [3], "data": bytes(3)}
    m["quant"]["sign"] = {"dtype": "<f4", "shape": [3, 2], "data": np.ones((3, 2), np.float32).tobytes()}
    assert_kind(pack(m), "shape")
    for rows, cols in ((0, 512), (3, 0)):  # empty codes: once a ValueError no receiver caught
        m = quantized_map()
        m["tensors"][FC] = {"dtype": "|u1", "shape": [rows, cols], "data": b""}
        m["quant"][FC] = {"dtype": "<f4", "shape": [rows, 2], "data": np.ones((rows, 2), np.float32).tobytes()}
        assert_kind(pack(m), "shape")


@pytest.mark.parametrize("dtype", ["float32", "float16", "uint8"])
@pytest.mark.parametrize("value", [np.nan, np.inf])
def test_one_non_finite_value_among_all_the_tensors_is_refused_and_named(dtype, value):
    """decode checks the float tensors' finiteness all at once; the refusal still names the tensor."""
    sent, quant = for_broadcast(tensors(), dtype)
    for name in [n for n in sent if n not in quant]:
        m = as_map(Weights(1, sent, epoch=1, quant=quant))
        spec = m["tensors"][name]
        bad = np.frombuffer(spec["data"], spec["dtype"]).copy()
        bad[-1] = value
        spec["data"] = bad.tobytes()
        with pytest.raises(WireError, match=name) as info:
            decode(pack(m), expect=Weights)
        assert info.value.kind == "nonfinite"
