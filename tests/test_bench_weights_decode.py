"""Smoke test of bench/weights_decode.py: a short run whose last line is the JSON result with every
precision, without and with the discriminator. No timing assertions."""

import math

from tests.helpers import run_bench


def test_bench_weights_decode_times_every_precision_against_msgpack_alone():
    result = run_bench("weights_decode", ["--seconds", "0.02"], timeout=180)
    cases = result["cases"]
    assert set(cases) == {f"{d}{b}" for d in ("float32", "float16", "uint8") for b in ("", "+behaviour")}
    for name, case in cases.items():
        for key in ("decode_us", "unpack_us", "decode_over_unpack"):
            assert isinstance(case[key], float) and math.isfinite(case[key]) and case[key] > 0, (name, key)
    for suffix in ("", "+behaviour"):
        sizes = [cases[f"{d}{suffix}"]["bytes"] for d in ("uint8", "float16", "float32")]
        assert sizes == sorted(sizes) and sizes[0] < 0.3 * sizes[2]
    assert cases["uint8+behaviour"]["tensors"] > cases["uint8"]["tensors"]
