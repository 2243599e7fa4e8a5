"""The broadcast precision of the weights (`learner.weights_dtype`): float32, float16, or uint8 by
per-row affine quantization of each weight matrix and kernel, value = code x scale[r] + offset[r]
in row r (docs/wire.md, `weights`); vectors (biases, sign buffers) travel as they are.

Hand-written in numpy: torch's quantized tensors (`torch.quantize_per_channel`) are deprecated in
torch 2.14, and a receiver in any language applies the formula above.
"""

from __future__ import annotations

import numpy as np

WEIGHTS_DTYPES = ("float32", "float16", "uint8")
LEVELS = 255  # uint8 codes 0..255


def quantized(shape: tuple[int, ...]) -> bool:
    """Whether uint8 sends a tensor of `shape` as codes: weight matrices and kernels (2 or more
    dimensions, a row per output unit or channel). Vectors are a few hundred bytes and some must
    stay exact (the mirror actor's +-1 signs)."""
    return len(shape) >= 2


def quantize(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(codes uint8 of x's shape, params float32 (rows, 2) of (scale, offset) per row), rounding
    to the nearest code: |dequantize(...) - x| <= scale / 2. Each row's range holds 0, so a zero
    weight decodes to exactly 0."""
    x = np.asarray(x, np.float32)
    if not quantized(x.shape):
        raise ValueError(f"only tensors of 2 or more dimensions are quantized, got shape {x.shape}")
    flat = x.reshape(x.shape[0], -1)
    lo = np.minimum(flat.min(axis=1, initial=0.0), 0.0)
    hi = np.maximum(flat.max(axis=1, initial=0.0), 0.0)
    scale = (hi - lo) / LEVELS
    scale[scale == 0] = 1.0  # an all-zero row: any positive scale codes it exactly
    zero = np.clip(np.rint(-lo / scale), 0, LEVELS).astype(np.float32)
    codes = np.clip(np.rint(flat / scale[:, None]) + zero[:, None], 0, LEVELS).astype(np.uint8)
    scale = scale.astype(np.float32)
    return codes.reshape(x.shape), np.stack([scale, -(zero * scale)], axis=1)


def dequantize(codes: np.ndarray, params: np.ndarray) -> np.ndarray:
    """float32 values of `codes`: code x scale + offset, (scale, offset) = params[row]."""
    flat = codes.reshape(codes.shape[0], -1).astype(np.float32)
    flat *= params[:, :1]  # in place: a quarter faster on a 128 x 147 layer than a new array each
    flat += params[:, 1:]
    return flat.reshape(codes.shape)


def floats(tensors: dict[str, np.ndarray], quant: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """A `Weights` message's tensors with its uint8 codes as float32 values; the float tensors as
    they are (a receiver widens float16 when it loads them, as it converts the codes here)."""
    return {name: dequantize(t, quant[name]) if name in quant else t for name, t in tensors.items()}


def narrowed(t: np.ndarray, dtype: str) -> np.ndarray:
    """`t` as float16 where `dtype` asks it and it fits; a tensor beyond float16's range stays
    float32 (receivers take either) rather than turning into inf."""
    if dtype == "float16" and np.abs(t).max(initial=0.0) <= np.finfo(np.float16).max:
        return t.astype(np.float16)
    return t


def for_broadcast(tensors: dict[str, np.ndarray], dtype: str) -> tuple[dict[str, np.ndarray], dict]:
    """(tensors, quant) of a `Weights` message in precision `dtype`: with uint8 the matrices and
    kernels as codes with their params in `quant`, the vectors as they are; else float tensors and
    no quant."""
    if dtype not in WEIGHTS_DTYPES:
        raise ValueError(f"weights dtype must be one of {WEIGHTS_DTYPES}, got {dtype!r}")
    out, quant = {}, {}
    for name, t in tensors.items():
        t = np.asarray(t)
        if dtype == "uint8" and quantized(t.shape):
            out[name], quant[name] = quantize(t)
        else:
            out[name] = narrowed(t, dtype)
    return out, quant
