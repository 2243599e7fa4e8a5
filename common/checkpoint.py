"""Checkpoint files: their one layout, written atomically and read back by every role that needs
them (the learner's resume, the periodic evaluator's best policy, gvf-eval and the comparison).

    <checkpoint_dir>/ckpt-<updates, 9 digits>.pt     the learner; every learner.checkpoint_every
                                                     updates and at exit; the newest 3 are kept
    <checkpoint_dir>/best-policy.pt                  the periodic evaluator: the policy of the best
                                                     validation so far

Each is one `torch.save`d dict. What any reader may rely on (`policy_entries`):
    policy   state_dict of `common.networks.make_policy(agent, scale)` (the acting network)
    agent    dataclasses.asdict(AgentConfig) that built it
    scale    dataclasses.asdict(ScaleConfig) that built it
    core     {"updates": learner updates when the policy was taken, ...}
The learner's files add, in "core", the networks, optimisers and generator (and "replay" with
learner.checkpoint_replay), plus "tracks" and "counters"; best-policy.pt adds "validation"
and "eval" (the mean metrics that chose it). A write goes to a temporary file in the same
folder, is fsynced, then renamed: a crash mid-write never leaves a torn file.
"""

from __future__ import annotations

import dataclasses
import math
import os
import re
from pathlib import Path
from typing import Any

import torch

PATTERN = re.compile(r"^ckpt-(\d{9})\.pt$")


def policy_entries(policy: dict, agent: Any, scale: Any, updates: int) -> dict[str, Any]:
    """The part of the layout every reader relies on (see the module docstring)."""
    return {
        "policy": {k: v.detach().cpu() for k, v in policy.items()},
        "agent": dataclasses.asdict(agent),
        "scale": dataclasses.asdict(scale),
        "core": {"updates": int(updates)},
    }


def write(path: str | Path, state: dict[str, Any]) -> Path:
    """Save `state` at `path` atomically (temporary file, fsync, rename)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.parent / f".{path.name}.tmp-{os.getpid()}"
    with open(tmp, "wb") as f:
        torch.save(state, f)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)
    return path


def save(directory: str | Path, updates: int, state: dict[str, Any], keep: int = 3) -> Path:
    """Save `state` as ckpt-<updates>.pt atomically and keep only the newest `keep` files."""
    directory = Path(directory)
    final = write(directory / f"ckpt-{updates:09d}.pt", state)
    for old in sorted(p for p in directory.iterdir() if PATTERN.match(p.name))[:-keep]:
        old.unlink()
    return final


def all_finite(state: Any) -> bool:
    """Every tensor and float anywhere in `state` (dicts, lists, tensors) is finite."""
    if isinstance(state, torch.Tensor):
        return not state.is_floating_point() or bool(torch.isfinite(state).all())
    if isinstance(state, float):
        return math.isfinite(state)
    if isinstance(state, dict):
        return all(all_finite(v) for v in state.values())
    if isinstance(state, (list, tuple)):
        return all(all_finite(v) for v in state)
    return True


def newest_good(directory: str | Path, log: Any = None) -> tuple[Path, dict] | None:
    """The newest ckpt-*.pt in `directory` that loads and holds only finite values, with its state;
    each bad one on the way is reported to `log` and skipped (None if there is no good one)."""
    directory = Path(directory)
    if not directory.is_dir():
        return None
    for path in sorted((p for p in directory.iterdir() if PATTERN.match(p.name)), reverse=True):
        try:
            state = load(path)
        except Exception as exc:  # a torn or foreign file: the next older one may be good
            if log is not None:
                log.error("checkpoint %s cannot be read (%s); trying an older one", path, exc)
            continue
        if all_finite(state):
            return path, state
        if log is not None:
            log.error("checkpoint %s holds non-finite values; refused, trying an older one", path)
    return None


def latest(directory: str | Path) -> Path | None:
    """The newest complete ckpt-*.pt in `directory`, or None."""
    directory = Path(directory)
    if not directory.is_dir():
        return None
    found = sorted(p for p in directory.iterdir() if PATTERN.match(p.name))
    return found[-1] if found else None


def find(path: str | Path) -> Path:
    """`path` itself if a file, else the newest ckpt-*.pt in it (or in a run folder's checkpoints/ below it)."""
    path = Path(path)
    if not path.is_dir():
        return path
    found = latest(path) or next(reversed(sorted(path.glob("**/checkpoints/ckpt-*.pt"))), None)
    if found is None:
        raise FileNotFoundError(f"no checkpoint (ckpt-*.pt) under {path}")
    return found


def load(path: str | Path) -> dict[str, Any]:
    # weights_only=False: our own file, holding optimiser states and plain counters
    return torch.load(path, map_location="cpu", weights_only=False)
