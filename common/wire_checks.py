"""Strict checks for decoded wire maps: the one exception type, the limits, field validators.

Used by `common.wire` on both sides (decode, and encode before sending). Each validator
takes the decoded msgpack map and a field name and returns a clean Python/numpy value or
raises `WireError` with the kind of the failure.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any

import numpy as np

KINDS = (
    "decode",
    "size",
    "version",
    "schema",
    "shape",
    "dtype",
    "nonfinite",
    "value",
    "identity",
    "range",
    "seq",
    "weights",
    "track",
)
"""decode: not msgpack (garbage, truncated, trailing bytes); size: over a limit; version: wrong
schema version; schema: not a map, unknown type, missing/unknown field or wrong field type;
shape/dtype: an array's; nonfinite: NaN or inf; value: a well-typed value out of range. The
rest are the content rules of `common.wire_rules`: identity (payload vs key), range (the
environment's bounds), seq, weights (vs the receiver's policy), track (table bounds)."""

NAME_RE = re.compile(r"^[A-Za-z0-9_.\-]{1,64}$")
INT_MAX = 2**63 - 1
MAX_NDIM = 8
MAX_DIM = 2**31 - 1
MAX_VIRTUAL_BYTES = 2**40
_ARRAY_KEYS = frozenset({"dtype", "shape", "data"})
_NP_DTYPES: dict[str, np.dtype] = {}


class WireError(ValueError):
    """A payload that is not a valid message; `kind` is one of KINDS."""

    def __init__(self, kind: str, message: str) -> None:
        if kind not in KINDS:
            raise ValueError(f"unknown WireError kind {kind!r}")
        super().__init__(f"[{kind}] {message}")
        self.kind = kind


@dataclass(frozen=True)
class Limits:
    """What a receiver accepts; anything beyond is refused before or while decoding."""

    max_bytes: int = 64 * 1024 * 1024
    """Largest payload (and largest single array) in bytes."""
    max_steps: int = 4096
    """Most steps in one TransitionChunk."""
    max_tensors: int = 4096
    """Most named tensors in one Weights message."""
    max_tracks: int = 65536
    """Most tracks in one TrackTable."""
    frame_shape: tuple[int, int] | None = (64, 128)
    """(H, W) of every camera frame, or None to accept any."""


def unpack_options(limits: Limits) -> dict[str, Any]:
    """Keyword arguments of msgpack.unpackb that bound every container by `limits`."""
    return dict(
        raw=False,
        strict_map_key=True,
        use_list=True,
        max_bin_len=limits.max_bytes,
        max_str_len=4096,
        # the only msgpack arrays in the schema are shapes
        max_array_len=MAX_NDIM,
        max_map_len=max(limits.max_tensors, limits.max_tracks, 64),
        max_ext_len=0,
    )


def field(m: dict, name: str, typ: type | tuple[type, ...]) -> Any:
    """m[name], which must exist and be of type `typ` (bool is not an int here)."""
    if name not in m:
        raise WireError("schema", f"missing field {name!r}")
    value = m[name]
    if isinstance(value, bool) and bool not in (typ if isinstance(typ, tuple) else (typ,)):
        raise WireError("schema", f"field {name!r} must be {typ}, got bool")
    if not isinstance(value, typ):
        raise WireError("schema", f"field {name!r} must be {typ}, got {type(value).__name__}")
    return value


def integer(m: dict, name: str, lo: int = 0, hi: int = INT_MAX) -> int:
    value = field(m, name, int)
    if not lo <= value <= hi:
        raise WireError("value", f"field {name!r} = {value} outside [{lo}, {hi}]")
    return int(value)


def real(m: dict, name: str) -> float:
    value = float(field(m, name, (int, float)))
    if not np.isfinite(value):
        raise WireError("nonfinite", f"field {name!r} = {value}")
    return value


def text(value: str, what: str, max_len: int, allow_empty: bool = True) -> str:
    if not isinstance(value, str):
        raise WireError("schema", f"{what} must be a str, got {type(value).__name__}")
    if len(value) > max_len or (not allow_empty and not value):
        raise WireError("value", f"{what} must be {0 if allow_empty else 1}..{max_len} characters")
    if not value.isprintable():
        raise WireError("value", f"{what} has non-printable characters")
    return value


def name(m: dict, key: str) -> str:
    value = field(m, key, str)
    if not NAME_RE.match(value):
        raise WireError("value", f"field {key!r} = {value[:80]!r} must match {NAME_RE.pattern}")
    return value


def array(m: dict, key: str, dtype: str | tuple[str, ...], shape: tuple | None, finite: bool = True) -> np.ndarray:
    """A {"dtype", "shape", "data"} map -> read-only ndarray of that dtype and shape.

    `shape` entries of None accept any length; shape None accepts any shape. `finite=False`
    leaves the NaN/inf check of a float array to the caller (who checks many at once).
    """
    spec = field(m, key, dict)
    if spec.keys() != _ARRAY_KEYS:
        raise WireError("schema", f"array {key!r} needs exactly dtype, shape, data; got {sorted(spec)}")
    dt = spec["dtype"]
    allowed = (dtype,) if isinstance(dtype, str) else dtype
    if not isinstance(dt, str) or dt not in allowed:
        raise WireError("dtype", f"array {key!r} dtype {dt!r}, expected one of {allowed}")
    dims = spec["shape"]
    # one loop checks the dims and multiplies them (Python ints: a hostile shape cannot overflow);
    # every actor decodes each broadcast's tens of arrays, so this function's overhead counts
    count, nonzero = 1, 1
    if not isinstance(dims, list):
        raise WireError("shape", f"array {key!r} shape must be a list of ints in [0, {MAX_DIM}], got {dims!r}")
    for d in dims:
        if type(d) is not int or not 0 <= d <= MAX_DIM:
            raise WireError("shape", f"array {key!r} shape must be a list of ints in [0, {MAX_DIM}], got {dims!r}")
        count *= d
        nonzero *= d or 1
    data = spec["data"]
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise WireError("schema", f"array {key!r} data must be bin, got {type(data).__name__}")
    if shape is not None and (
        len(dims) != len(shape) or any(want is not None and got != want for got, want in zip(dims, shape))
    ):
        raise WireError("shape", f"array {key!r} shape {dims}, expected {shape}")
    np_dtype = _NP_DTYPES.get(dt)  # dt is one of `allowed`: the cache stays small
    if np_dtype is None:
        np_dtype = _NP_DTYPES[dt] = np.dtype(dt)
    itemsize = np_dtype.itemsize
    if nonzero * itemsize > MAX_VIRTUAL_BYTES:
        # numpy refuses even an empty array whose other dimensions multiply past its limits
        raise WireError("shape", f"array {key!r} shape {dims} is absurd")
    nbytes = len(data) if isinstance(data, bytes) else memoryview(data).nbytes
    if count * itemsize != nbytes:
        raise WireError("shape", f"array {key!r} shape {dims} x {itemsize} B != {nbytes} data bytes")
    arr = np.frombuffer(data, dtype=np_dtype, count=count).reshape(dims)
    kind = np_dtype.kind
    if finite and kind == "f" and not np.isfinite(arr).all():
        raise WireError("nonfinite", f"array {key!r} has NaN or inf")
    if kind == "b" and arr.size and arr.view(np.uint8).max() > 1:
        raise WireError("value", f"bool array {key!r} has bytes other than 0 and 1")
    return arr
