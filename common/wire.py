"""The wire format: every message that crosses Zenoh, encoded as a msgpack map.

Schema (version `SCHEMA_VERSION`) is documented for outside clients in docs/wire.md; the
message classes live in `common.wire_messages` and are re-exported here.
Every payload is one msgpack map `{"v": 2, "type": <str>, ...fields}`; arrays travel as
`{"dtype": "<f4", "shape": [..], "data": <bin>}` (raw little-endian bytes, C order).
Nothing is ever pickled. A TransitionChunk holds T consecutive steps of one episode of one
env and sends each camera frame once: T+1 observations (current, previous) share T+2 frames.

`decode` is strict: a total size limit, msgpack's max_*_len limits, the schema version, the
exact set of fields, their types, array dtypes and shapes, finiteness. Every hostile input
raises `WireError` (a ValueError) whose `kind` says which check failed; `encode` runs the
same checks, so a sender never emits what a receiver would drop.
"""

from __future__ import annotations

import logging
from collections import Counter
from typing import Any

import msgpack
import numpy as np

from common import wire_checks as chk
from common import wire_quant
from common.wire_checks import KINDS, Limits, WireError
from common.wire_messages import (
    AVERAGE,
    BEHAVIOUR,
    Control,
    EpisodeSummary,
    Message,
    TrackTable,
    TransitionChunk,
    Weights,
    frames_from_images,
)

__all__ = [
    "SCHEMA_VERSION",
    "AVERAGE",
    "BEHAVIOUR",
    "KINDS",
    "Limits",
    "WireError",
    "TransitionChunk",
    "EpisodeSummary",
    "Weights",
    "TrackTable",
    "Control",
    "Message",
    "encode",
    "decode",
    "frames_from_images",
    "RejectCounter",
]

log = logging.getLogger(__name__)

SCHEMA_VERSION = 2
DEFAULT_LIMITS = Limits()
CONTROL_COMMANDS = ("stop", "pause", "resume")
U8, F4, B1 = "|u1", "<f4", "|b1"
WEIGHT_DTYPES = ("<f2", "<f4", "<f8")
F4_MAX = float(np.finfo(np.float32).max)

# msgpack raises these (all ValueError subclasses in msgpack 1.x, UnicodeDecodeError for bad str)
_MSGPACK_ERRORS = (
    msgpack.exceptions.ExtraData,
    msgpack.exceptions.FormatError,
    msgpack.exceptions.StackError,
    msgpack.exceptions.UnpackException,
    UnicodeDecodeError,
    ValueError,
    TypeError,
)


# --- to and from the msgpack map -------------------------------------------------------------


def _array_map(value: Any, dtype: str) -> dict:
    arr = np.ascontiguousarray(value, dtype=np.dtype(dtype))
    return {"dtype": dtype, "shape": list(arr.shape), "data": memoryview(arr).cast("B")}


_STEP_FIELDS = {  # name -> (dtype, number of rows relative to T, trailing shape)
    "speed": (F4, 1, (1,)),
    "last_action": (F4, 1, (2,)),
    "action": (F4, 0, (2,)),
    "reward": (F4, 0, ()),
    "terminated": (B1, 0, ()),
    "truncated": (B1, 0, ()),
    "alpha": (F4, 1, ()),
    "beta": (F4, 1, ()),
}
_CHUNK_SCALARS = ("actor", "env", "episode", "seq", "policy_version", "step0")
_FIELDS = {
    "transitions": frozenset(_CHUNK_SCALARS) | {"frames"} | set(_STEP_FIELDS),
    "episode": frozenset({"actor", "env", "episode", "track", "steps", "return", "policy_version"}),
    "weights": frozenset({"version", "epoch", "tensors"}),
    "tracks": frozenset({"version", "steps"}),
    "control": frozenset({"command", "reason"}),
}
_OPTIONAL = {
    "control": frozenset({"expires_s"}),
    "transitions": frozenset({"log_mu", "behaviour_version"}),
    "weights": frozenset({"quant"}),
}


def _int(value: Any) -> Any:
    """numpy integers -> int for msgpack; anything else is left for the checks to refuse."""
    return int(value) if isinstance(value, np.integer) else value


def _to_map(msg: Message) -> dict:
    if isinstance(msg, TransitionChunk):
        m = {name: _int(getattr(msg, name)) for name in _CHUNK_SCALARS}
        m["frames"] = _array_map(msg.frames, U8)
        for name, (dtype, _, _) in _STEP_FIELDS.items():
            m[name] = _array_map(getattr(msg, name), dtype)
        if msg.log_mu is not None:
            m["log_mu"] = _array_map(msg.log_mu, F4)
            m["behaviour_version"] = _int(msg.behaviour_version)
        return {"v": SCHEMA_VERSION, "type": "transitions", **m}
    if isinstance(msg, EpisodeSummary):
        return {
            "v": SCHEMA_VERSION,
            "type": "episode",
            "actor": msg.actor,
            "env": _int(msg.env),
            "episode": _int(msg.episode),
            "track": msg.track,
            "steps": _int(msg.steps),
            "return": float(msg.episode_return),
            "policy_version": _int(msg.policy_version),
        }
    if isinstance(msg, Weights):
        tensors = {}
        for name, value in msg.tensors.items():
            arr = np.asarray(value)
            # keep the float width; any other dtype goes out as-is and is refused as 'dtype'
            tensors[name] = _array_map(arr, arr.dtype.newbyteorder("<").str)
        m = {"v": SCHEMA_VERSION, "type": "weights", "version": _int(msg.version), "epoch": _int(msg.epoch)}
        if msg.quant:
            m["quant"] = {name: _array_map(params, F4) for name, params in msg.quant.items()}
        return {**m, "tensors": tensors}
    if isinstance(msg, TrackTable):
        steps = {track: _int(n) for track, n in msg.steps.items()}
        return {"v": SCHEMA_VERSION, "type": "tracks", "version": _int(msg.version), "steps": steps}
    if isinstance(msg, Control):
        m = {"v": SCHEMA_VERSION, "type": "control", "command": msg.command, "reason": msg.reason}
        if msg.expires_s:
            m["expires_s"] = float(msg.expires_s)
        return m
    raise TypeError(f"not a wire message: {type(msg).__name__}")


def _chunk_from_map(m: dict, limits: Limits) -> TransitionChunk:
    scalars = dict(
        actor=chk.name(m, "actor"),
        env=chk.integer(m, "env", hi=2**31 - 1),
        episode=chk.integer(m, "episode"),
        seq=chk.integer(m, "seq"),
        policy_version=chk.integer(m, "policy_version"),
        step0=chk.integer(m, "step0"),
    )
    action = chk.array(m, "action", F4, (None, 2))
    steps = action.shape[0]
    if not 1 <= steps <= limits.max_steps:
        raise WireError("shape", f"a chunk holds 1..{limits.max_steps} steps, got {steps}")
    frame_shape = limits.frame_shape or (None, None)
    frames = chk.array(m, "frames", U8, (steps + 2, *frame_shape))
    if 0 in frames.shape:
        raise WireError("shape", f"empty frames {frames.shape}")
    arrays = {"action": action}
    for name, (dtype, extra_rows, tail) in _STEP_FIELDS.items():
        if name != "action":
            arrays[name] = chk.array(m, name, dtype, (steps + extra_rows, *tail))
    ends = arrays["terminated"][:-1].any() or arrays["truncated"][:-1].any()
    if ends:
        raise WireError("value", "only the last step of a chunk may be terminated or truncated")
    if ("log_mu" in m) != ("behaviour_version" in m):
        raise WireError("schema", "transitions: log_mu and behaviour_version come together")
    if "log_mu" in m:
        arrays["log_mu"] = chk.array(m, "log_mu", F4, (steps,))
        scalars["behaviour_version"] = chk.integer(m, "behaviour_version")
    return TransitionChunk(frames=frames, **scalars, **arrays)


def _weights_from_map(m: dict, limits: Limits) -> Weights:
    tensors_map = chk.field(m, "tensors", dict)
    if len(tensors_map) > limits.max_tensors:
        raise WireError("size", f"{len(tensors_map)} tensors > {limits.max_tensors}")
    quant_map = chk.field(m, "quant", dict) if "quant" in m else {}
    if unknown := set(quant_map) - set(tensors_map):
        raise WireError("schema", f"weights: quant for tensors not sent, e.g. {sorted(unknown)[:3]}")
    tensors, quant = {}, {}
    for name, spec in tensors_map.items():
        chk.text(name, "tensor name", 256, allow_empty=False)
        if name not in quant_map:
            tensors[name] = chk.array({name: spec}, name, WEIGHT_DTYPES, None, finite=False)
            continue
        codes = chk.array({name: spec}, name, U8, None)
        if not wire_quant.quantized(codes.shape) or codes.size == 0:  # an empty one: no row to scale
            raise WireError(
                "shape", f"quantized tensor {name!r} has shape {codes.shape}: codes need 2 or more dims, none 0"
            )
        tensors[name], quant[name] = codes, chk.array(quant_map, name, F4, (codes.shape[0], 2), finite=False)
    _check_weight_values(tensors, quant)  # validated here; the receiver converts what it loads
    return Weights(version=chk.integer(m, "version"), tensors=tensors, epoch=chk.integer(m, "epoch"), quant=quant)


def _check_weight_values(tensors: dict[str, np.ndarray], quant: dict[str, np.ndarray]) -> None:
    """Every float tensor finite, every quant scale > 0 and |code x scale + offset| <= 256
    max(|scale|, |offset|) within float32, checked over all tensors at once: every actor decodes
    every broadcast, and per-tensor numpy calls cost it more than the bytes (bench/scale.py).
    Only a refused message pays for finding which tensor failed."""
    floats = [t.ravel() for name, t in tensors.items() if name not in quant]
    if (not floats or np.isfinite(np.concatenate(floats)).all()) and (
        not quant or _quant_params_ok(np.concatenate(list(quant.values())))
    ):
        return
    for name, t in tensors.items():
        for what, values in ((name, t), (f"quant {name}", quant.get(name))):
            if values is not None and values.dtype.kind == "f" and not np.isfinite(values).all():
                raise WireError("nonfinite", f"array {what!r} has NaN or inf")
        if name in quant and not _quant_params_ok(quant[name]):
            raise WireError("value", f"quant {name!r}: a scale <= 0, or values beyond float32")


def _quant_params_ok(params: np.ndarray) -> bool:
    """Scales > 0 and |code x scale + offset| <= 256 max(|scale|, |offset|) within float32; a NaN
    fails both comparisons. `params` has rows: empty codes are refused before."""
    return bool(params[:, 0].min() > 0 and float(np.abs(params).max()) * 256 <= F4_MAX)


def _tracks_from_map(m: dict, limits: Limits) -> TrackTable:
    steps_map = chk.field(m, "steps", dict)
    if len(steps_map) > limits.max_tracks:
        raise WireError("size", f"{len(steps_map)} tracks > {limits.max_tracks}")
    steps = {}
    for track in steps_map:
        chk.text(track, "track name", 256, allow_empty=False)
        steps[track] = chk.integer(steps_map, track)
    return TrackTable(version=chk.integer(m, "version"), steps=steps)


def _from_map(m: Any, limits: Limits, expect: type | None) -> Message:
    if not isinstance(m, dict):
        raise WireError("schema", f"a message is a map, got {type(m).__name__}")
    version = m.get("v")
    if type(version) is not int or version != SCHEMA_VERSION:
        raise WireError("version", f"schema version {version!r}, this side speaks {SCHEMA_VERSION}")
    kind = m.get("type")
    if not isinstance(kind, str) or kind not in _FIELDS:
        raise WireError("schema", f"unknown message type {kind!r}")
    keys = set(m) - {"v", "type"}
    optional = _OPTIONAL.get(kind, frozenset())
    if not _FIELDS[kind] <= keys <= _FIELDS[kind] | optional:
        missing, extra = sorted(_FIELDS[kind] - keys), sorted(keys - _FIELDS[kind] - optional)
        raise WireError("schema", f"{kind}: missing fields {missing}, unknown fields {extra}")
    if kind == "transitions":
        msg: Message = _chunk_from_map(m, limits)
    elif kind == "episode":
        msg = EpisodeSummary(
            actor=chk.name(m, "actor"),
            env=chk.integer(m, "env", hi=2**31 - 1),
            episode=chk.integer(m, "episode"),
            track=chk.text(chk.field(m, "track", str), "track", 256, allow_empty=False),
            steps=chk.integer(m, "steps"),
            episode_return=chk.real(m, "return"),
            policy_version=chk.integer(m, "policy_version"),
        )
    elif kind == "weights":
        msg = _weights_from_map(m, limits)
    elif kind == "tracks":
        msg = _tracks_from_map(m, limits)
    else:
        command = chk.field(m, "command", str)
        if command not in CONTROL_COMMANDS:
            raise WireError("value", f"control command {command!r} not in {CONTROL_COMMANDS}")
        expires = chk.real(m, "expires_s") if "expires_s" in m else 0.0
        if not 0.0 <= expires <= 86400.0:
            raise WireError("value", f"control expires_s {expires} not in [0, 86400]")
        msg = Control(command=command, reason=chk.text(chk.field(m, "reason", str), "reason", 1024), expires_s=expires)
    if expect is not None and not isinstance(msg, expect):
        raise WireError("schema", f"expected {expect.__name__}, got {type(msg).__name__}")
    return msg


# --- public entry points --------------------------------------------------------------------


def encode(msg: Message, limits: Limits = DEFAULT_LIMITS) -> bytes:
    """Message -> msgpack bytes; raises WireError if a receiver with `limits` would reject it."""
    wire_map = _to_map(msg)
    _from_map(wire_map, limits, None)
    payload = msgpack.packb(wire_map, use_bin_type=True)
    if len(payload) > limits.max_bytes:
        raise WireError("size", f"{len(payload)} bytes > limit {limits.max_bytes}")
    return payload


def decode(
    payload: bytes | bytearray | memoryview, limits: Limits = DEFAULT_LIMITS, expect: type | None = None
) -> Message:
    """msgpack bytes -> Message, or WireError for anything that is not a valid message.

    Arrays of the result are read-only views of `payload`'s decoded buffers (copy to keep
    a writable array). `expect` (a message class) rejects other message types as 'schema'.
    """
    if not isinstance(payload, (bytes, bytearray, memoryview)):
        raise WireError("decode", f"payload must be bytes, got {type(payload).__name__}")
    if len(payload) > limits.max_bytes:
        raise WireError("size", f"{len(payload)} bytes > limit {limits.max_bytes}")
    try:
        wire_map = msgpack.unpackb(payload, **chk.unpack_options(limits))
    except _MSGPACK_ERRORS as exc:
        # msgpack reports its max_*_len limits as ValueError("... exceeds max_..._len(...)")
        kind = "size" if "exceeds max_" in str(exc) else "decode"
        raise WireError(kind, f"msgpack: {type(exc).__name__}: {exc}") from None
    return _from_map(wire_map, limits, expect)


class RejectCounter:
    """Counts payloads refused by `decode`, per WireError kind, and logs the first of each kind.

    A receiver's loop: `msg = rejects.decode(r.payload, expect=TransitionChunk, key=r.key)`;
    None means counted and dropped. `counts` feeds the receiver's metrics.
    """

    def __init__(self, limits: Limits = DEFAULT_LIMITS, logger: logging.Logger | None = None) -> None:
        self.limits = limits
        self.counts: Counter[str] = Counter()
        self._log = logger or log

    @property
    def total(self) -> int:
        return sum(self.counts.values())

    def reject(self, err: WireError, key: str = "") -> None:
        self.counts[err.kind] += 1
        if self.counts[err.kind] == 1:
            # once per kind: a hostile or broken sender must not flood the log
            self._log.warning("dropped a bad message on %r (first of kind %r): %s", key, err.kind, err)

    def obeys(self, rule, key: str = "") -> bool:
        """Run `rule()` (e.g. a content rule of `common.wire_rules`); a WireError it raises is
        counted like a refused payload and False returned (the message is then dropped)."""
        try:
            rule()
        except WireError as err:
            self.reject(err, key)
            return False
        return True

    def decode(self, payload: bytes, expect: type | None = None, key: str = "") -> Message | None:
        """`decode(payload)`, or None after counting and (once per kind) logging the refusal."""
        try:
            return decode(payload, self.limits, expect)
        except WireError as err:
            self.reject(err, key)
            return None
