"""Logged driving data for the offline half of the paper (Algorithm 2, GVF-BCQ, E2E-BCQ): an
appendable folder of shards in tensordict's memory-mapped layout (one raw `.memmap` file per
field and a `meta.json`, `TensorDict.memmap` / `TensorDict.load_memmap`; never pickle).

    <root>/manifest.json        what exists: format, version, the field table, and per shard
                                its name, transitions, roads, and every file's bytes and sha256
    <root>/shard-<writer>-<n>/  one shard: a TensorDict of batch (n,) written by `TensorDict.memmap`

A shard exists once the manifest names it. A write goes to a hidden temporary folder, is
fsynced and renamed, and only then is it added to the manifest (rewritten atomically under an
advisory lock, so several collector processes append to one dataset). A crash mid-write leaves
a temporary folder that no reader sees. tensordict reads a truncated file as zeros without a
word, hence the sizes and hashes: `Dataset.open` refuses a shard whose files differ from the
manifest, naming the file, and touches nothing.

Fields per transition (state s_t, action a_t, next state s_{t+1}), the learner's compact replay
layout (`learner.replay.compact`) with frames as uint8 plus where the data came from:
"""

from __future__ import annotations

import fcntl
import hashlib
import json
import os
import shutil
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import torch
from tensordict import TensorDict, TensorDictBase

FORMAT, VERSION = "gvf-drive-dataset", 1
MANIFEST = "manifest.json"
FIELDS: dict[str, tuple[torch.dtype, tuple[int, ...], str]] = {
    "image": (torch.uint8, (2, 64, 128), "camera frames t and t-1 of s_t"),
    "speed": (torch.float32, (1,), "speed / v_max at s_t"),
    "last_action": (torch.float32, (2,), "a_{t-1}"),
    "alpha": (torch.float32, (1,), "lane centeredness at s_t (1.0 at the lane edge)"),
    "beta": (torch.float32, (1,), "road angle at s_t, rad"),
    "action": (torch.float32, (2,), "a_t in [-1, 1]^2 (steering, target speed)"),
    "next_frame": (torch.uint8, (1, 64, 128), "camera frame t+1 (s_{t+1}'s image is [it, frame t])"),
    "next_speed": (torch.float32, (1,), "speed / v_max at s_{t+1}"),
    "next_alpha": (torch.float32, (1,), "alpha at s_{t+1}"),
    "next_beta": (torch.float32, (1,), "beta at s_{t+1}"),
    "reward": (torch.float32, (1,), "r_{t+1} (unscaled)"),
    "terminated": (torch.bool, (1,), "s_{t+1} left the lane"),
    "truncated": (torch.bool, (1,), "the episode hit its step limit at s_{t+1}"),
    "track": (torch.int16, (1,), "index of the road in the shard's `tracks` list"),
    "episode": (torch.int64, (1,), "episode id, unique in the dataset"),
    "step": (torch.int32, (1,), "step t within the episode"),
    "log_mu": (torch.float32, (1,), "log mu(a_t|s_t) of the collector if known, else NaN"),
}
__doc__ += "\n".join(f"    {k:12s} {str(d).removeprefix('torch.'):8s} {s}  {w}" for k, (d, s, w) in FIELDS.items())


class DatasetError(ValueError):
    """A dataset that cannot be read or written as asked (the message names the file and field)."""


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while block := f.read(1 << 22):
            h.update(block)
    return h.hexdigest()


def _files(shard: Path) -> dict[str, dict[str, Any]]:
    return {
        str(p.relative_to(shard)): {"bytes": p.stat().st_size, "sha256": _sha256(p)}
        for p in sorted(shard.rglob("*"))
        if p.is_file()
    }


def check_fields(td: TensorDictBase) -> None:
    """Refuse a batch whose fields differ from `FIELDS` (missing, extra, dtype or shape), naming the field."""
    names = set(td.keys())
    if names != set(FIELDS):
        missing, extra = sorted(set(FIELDS) - names), sorted(names - set(FIELDS))
        raise DatasetError(f"dataset fields differ: missing {missing}, unexpected {extra}")
    for name, (dtype, shape, _) in FIELDS.items():
        value = td.get(name)
        if value.dtype != dtype or tuple(value.shape[1:]) != shape:
            raise DatasetError(
                f"field {name!r}: expected {dtype} {shape} per transition, got {value.dtype} {tuple(value.shape[1:])}"
            )


def _fsync_tree(folder: Path) -> None:
    for p in folder.rglob("*"):
        if p.is_file():
            with open(p, "rb") as f:
                os.fsync(f.fileno())


class DatasetWriter:
    """Appends shards to a dataset folder (created if missing); one per writing process, named `writer`."""

    def __init__(self, root: str | Path, writer: str = "w0", meta: dict[str, Any] | None = None):
        self.root, self.writer = Path(root), writer
        self.root.mkdir(parents=True, exist_ok=True)
        with self._locked() as manifest:
            if not manifest:
                manifest.update(format=FORMAT, version=VERSION, fields=_field_table(), meta=meta or {}, shards=[])
        self.written = 0

    @contextmanager
    def _locked(self) -> Iterator[dict[str, Any]]:
        """The manifest, read and rewritten (atomically) under an exclusive lock on `.lock`."""
        with open(self.root / ".lock", "a+") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            path = self.root / MANIFEST
            manifest = _read_manifest(self.root) if path.exists() else {}
            before = json.dumps(manifest, sort_keys=True)
            yield manifest
            if json.dumps(manifest, sort_keys=True) != before:
                tmp = self.root / f".{MANIFEST}.tmp-{os.getpid()}"
                tmp.write_text(json.dumps(manifest, indent=1))
                with open(tmp, "rb") as f:
                    os.fsync(f.fileno())
                os.replace(tmp, path)

    def append(self, td: TensorDictBase, tracks: list[str]) -> str:
        """Write one shard of transitions (fields as `FIELDS`, `track` indexing `tracks`); returns its name."""
        check_fields(td)
        if len(td) == 0:
            raise DatasetError("an empty shard")
        if int(td["track"].min()) < 0 or int(td["track"].max()) >= len(tracks):
            raise DatasetError(f"field 'track': indices must lie in [0, {len(tracks)}) of the shard's roads")
        name = f"shard-{self.writer}-{self.written:06d}"
        while (self.root / name).exists():  # a second writer of the same name appends after it
            self.written += 1
            name = f"shard-{self.writer}-{self.written:06d}"
        tmp = self.root / f".{name}.tmp-{os.getpid()}"
        shutil.rmtree(tmp, ignore_errors=True)
        td.select(*FIELDS).contiguous().memmap(prefix=tmp)
        _fsync_tree(tmp)
        entry = {"name": name, "transitions": len(td), "tracks": list(tracks), "files": _files(tmp)}
        os.replace(tmp, self.root / name)
        with self._locked() as manifest:
            manifest["shards"].append(entry)
        self.written += 1
        return name


def _field_table() -> dict[str, dict[str, Any]]:
    return {k: {"dtype": str(d).removeprefix("torch."), "shape": list(s)} for k, (d, s, _) in FIELDS.items()}


def _read_manifest(root: Path) -> dict[str, Any]:
    path = root / MANIFEST
    try:
        manifest = json.loads(path.read_text())
    except FileNotFoundError:
        raise DatasetError(f"{root} is not a dataset: no {MANIFEST}") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise DatasetError(f"{path} is not valid JSON ({e}): the dataset's index is damaged") from None
    if not isinstance(manifest, dict) or manifest.get("format") != FORMAT:
        raise DatasetError(f"{path}: not a {FORMAT} manifest")
    if manifest.get("version") != VERSION:
        raise DatasetError(f"{path}: format version {manifest.get('version')}, this code reads {VERSION}")
    if manifest.get("fields") != _field_table():
        raise DatasetError(f"{path}: its field table differs from this code's (common.dataset.FIELDS)")
    return manifest


def _check_shard(folder: Path, shard: dict[str, Any], verify: bool) -> str | None:
    """What is wrong with a shard's files, or None."""
    for rel, want in shard["files"].items():
        path = folder / rel
        if not path.is_file():
            return f"{path}: missing (shard {shard['name']})"
        size = path.stat().st_size
        if size != want["bytes"]:
            return f"{path}: {size} bytes, the manifest says {want['bytes']} (truncated?)"
        if verify and _sha256(path) != want["sha256"]:
            return f"{path}: its sha256 differs from the manifest (corrupt)"
    return None


class Dataset:
    """A dataset folder opened for reading; every shard checked against the manifest first."""

    def __init__(self, root: Path, manifest: dict[str, Any]):
        self.root, self.manifest = root, manifest
        self.shards: list[dict[str, Any]] = manifest["shards"]
        self.damaged: list[str] = []

    @classmethod
    def open(cls, root: str | Path, verify: bool = True, skip_damaged: bool = False) -> Dataset:
        """Open `root`, checking every file's size (and with `verify` its sha256) against the manifest.
        A damaged shard raises a DatasetError naming the file; with `skip_damaged` it is left out
        (and listed in `damaged`), so the rest stays usable. Nothing on disk is changed either way."""
        root = Path(root)
        manifest = _read_manifest(root)
        good, damaged = [], []
        for shard in manifest["shards"]:
            problem = _check_shard(root / shard["name"], shard, verify)
            if problem and not skip_damaged:
                raise DatasetError(problem)
            (damaged if problem else good).append(problem or shard)
        dataset = cls(root, {**manifest, "shards": good})
        dataset.damaged = damaged
        return dataset

    def __len__(self) -> int:
        return sum(s["transitions"] for s in self.shards)

    @property
    def meta(self) -> dict[str, Any]:
        return self.manifest.get("meta", {})

    def shard(self, i: int) -> tuple[TensorDictBase, list[str]]:
        """Shard i as a memory-mapped TensorDict (nothing read until used) and its road names."""
        entry = self.shards[i]
        td = TensorDict.load_memmap(self.root / entry["name"])
        return td, entry["tracks"]

    def __iter__(self) -> Iterator[tuple[TensorDictBase, list[str]]]:
        """Shards in the order they were written (the collector's recorded order within each writer)."""
        for i in range(len(self.shards)):
            yield self.shard(i)

    def tracks(self) -> list[str]:
        """Every road in the dataset, sorted."""
        return sorted({t for s in self.shards for t in s["tracks"]})
