"""Atomic checkpoints: write to a temporary file in the same folder, fsync, then rename, so a
crash mid-write never leaves a torn checkpoint; `latest` finds the newest complete one."""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Any

import torch

PATTERN = re.compile(r"^ckpt-(\d{9})\.pt$")


def save(directory: str | Path, updates: int, state: dict[str, Any], keep: int = 3) -> Path:
    """Save `state` as ckpt-<updates>.pt atomically and keep only the newest `keep` files."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    final = directory / f"ckpt-{updates:09d}.pt"
    tmp = directory / f".{final.name}.tmp-{os.getpid()}"
    with open(tmp, "wb") as f:
        torch.save(state, f)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, final)
    for old in sorted(p for p in directory.iterdir() if PATTERN.match(p.name))[:-keep]:
        old.unlink()
    return final


def latest(directory: str | Path) -> Path | None:
    directory = Path(directory)
    if not directory.is_dir():
        return None
    found = sorted(p for p in directory.iterdir() if PATTERN.match(p.name))
    return found[-1] if found else None


def load(path: str | Path) -> dict[str, Any]:
    # weights_only=False: our own file, holding optimiser states and plain counters
    return torch.load(path, map_location="cpu", weights_only=False)
