"""Does a policy that fails the test roads still drive the roads it was trained on?

Each checkpoint's policy drives one lap of every train road, test road and validation road in
both directions, without exploration. Per set of roads: laps, the step-weighted mean speed and
mean abs(alpha) (is an offset from the centre the test roads' or also the train roads'?), and
the per-step probability of leaving the road p (failed drives / steps driven), the quantity the
objective trades against speed (`actors.evaluation.speed_tradeoff`). If a policy that crept to
a speed where it fails the test roads still laps the train roads with a p near zero, the
objective it optimises (on the train roads) has no reason to slow down: the creep is a gap
between the roads, not only the discount's trade. Resumable: a checkpoint already in the
cache file is not driven again.

    python -m actors.evaluation.road_gap runs/crash-penalty-300 runs/default-repeat --last 3 \\
        --cache docs/results/road-gap.json --out docs/results/road-gap.md
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Callable

from actors.envs.simulators import road_names
from actors.evaluation.evaluate import PolicyFn, evaluate
from actors.evaluation.main import eval_env_kwargs
from actors.evaluation.periodic import validation_roads
from actors.evaluation.policies import checkpoint_policy
from common.config.run import RunConfig

SPLITS = ("train", "test", "validation")


def split_summary(results: list[dict]) -> dict[str, float]:
    """Laps, step-weighted speed and p (failed drives per step driven) of one set of drives."""
    return pool(
        [
            {
                "drives": 1,
                "laps": int(r["metrics"]["lap_completed"] >= 1),
                "steps": float(r["metrics"]["episode_length"]),
                "speed": float(r["metrics"]["average_speed"]),
                "offcentre": float(r["metrics"]["offcenteredness"]),
            }
            for r in results
        ]
    )


def pool(parts: list[dict]) -> dict:
    """Drives, laps and steps summed, speed and mean abs(alpha) weighted by steps (the latter only
    where every part has it: cached entries made before it have not), p = failed drives per step."""
    drives, laps = sum(p["drives"] for p in parts), sum(p["laps"] for p in parts)
    steps = sum(p["steps"] for p in parts)
    out = {"drives": drives, "laps": laps, "steps": steps, "p": (drives - laps) / steps}
    for key in ("speed", "offcentre"):
        if all(key in p for p in parts):
            out[key] = sum(p[key] * p["steps"] for p in parts) / steps
    return out


def roads(cfg: RunConfig) -> dict[str, list[str]]:
    """The train, test and validation roads of a run, as its actors and evaluator name them."""
    return {
        "train": road_names(cfg.env, "train"),
        "test": road_names(cfg.env, "test"),
        "validation": validation_roads(cfg),
    }


def drive_splits(policy: PolicyFn, cfg: RunConfig | None = None, by_split: dict | None = None) -> dict[str, dict]:
    """`split_summary` of `policy` on each set of roads of `by_split` (default: `roads(cfg)`, a
    default run's where `cfg` is None), both directions as the run's evaluator drives them."""
    cfg = cfg or RunConfig()
    env, directions = eval_env_kwargs(cfg), tuple(cfg.eval.directions)
    return {
        split: split_summary(evaluate(policy, directions=directions, tracks=names, **env))
        for split, names in (by_split or roads(cfg)).items()
    }


def measure_checkpoint(path: Path) -> dict:
    policy, meta = checkpoint_policy(path)
    return {"agent": meta["agent"], "updates": meta["updates"], **drive_splits(policy)}


def newest(dirs: list[Path], last: int = 0) -> list[Path]:
    """The checkpoints (checkpoints/ckpt-*.pt) under `dirs`; with `last`, each run's `last` newest."""
    runs: dict[Path, list[Path]] = {}
    for p in sorted({p for d in dirs for p in d.glob("**/checkpoints/ckpt-*.pt")}):
        runs.setdefault(p.parent, []).append(p)  # names hold zero-padded update counts: sorted is oldest first
    return [p for ckpts in runs.values() for p in (ckpts[-last:] if last else ckpts)]


def measure_all(paths: list[Path], cache: Path | None, measure: Callable[[Path], dict] = measure_checkpoint) -> dict:
    """Every checkpoint's `measure`, taken from `cache` where already there; the cache is
    rewritten after each new one (an interrupted pass keeps what it measured)."""
    done = json.loads(cache.read_text()) if cache and cache.exists() else {}
    for path in paths:
        if str(path) in done:
            continue
        done[str(path)] = measure(path)
        if cache:
            cache.write_text(json.dumps(done, indent=1, sort_keys=True) + "\n")
    return {str(p): done[str(p)] for p in paths}


def _offcentre(split: dict) -> str:
    return f"{split['offcentre']:.3f}" if "offcentre" in split else "-"


def report(measured: dict[str, dict], fail_below: int = 11) -> list[str]:
    lines = [
        "| checkpoint | updates | test laps | test speed | test p (x 1e-4) | train laps | train speed "
        "| train p (x 1e-4) | validation laps | validation p (x 1e-4) | test abs(alpha) | train abs(alpha) |",
        "|" + " --- |" * 12,
    ]
    for path, m in measured.items():
        t, tr, v = m["test"], m["train"], m["validation"]
        lines.append(
            f"| {path} | {m['updates']} | {t['laps']}/{t['drives']} | {t['speed']:.1f} | {t['p'] * 1e4:.1f} "
            f"| {tr['laps']}/{tr['drives']} | {tr['speed']:.1f} | {tr['p'] * 1e4:.1f} "
            f"| {v['laps']}/{v['drives']} | {v['p'] * 1e4:.1f} | {_offcentre(t)} | {_offcentre(tr)} |"
        )
    for name, keep in (
        (f"failing the test roads (< {fail_below} laps)", lambda m: m["test"]["laps"] < fail_below),
        (f"holding the test roads (>= {fail_below} laps)", lambda m: m["test"]["laps"] >= fail_below),
    ):
        group = [m for m in measured.values() if keep(m)]
        if not group:
            continue
        pooled = {s: pool([m[s] for m in group]) for s in SPLITS}
        lines += [
            "",
            f"Pooled over the {len(group)} checkpoints {name}: "
            + "; ".join(
                f"{s} {pooled[s]['laps']}/{pooled[s]['drives']} laps, {pooled[s]['speed']:.1f} m/s, "
                f"p {pooled[s]['p'] * 1e4:.1f}e-4"
                for s in SPLITS
            ),
        ]
    return lines


def cell(m: dict, key: str, fmt: str) -> str:
    """A table cell of a cached measurement: "-" where it is missing (cached before a column existed)."""
    return "-" if m.get(key) is None else format(m[key], fmt)


def checkpoint_tool(
    argv: list[str] | None, doc: str, module: str, measure: Callable[[Path], dict], table: Callable, title: str
) -> None:
    """The command line of a per-checkpoint tool: run folders, `--last`, a resumable `--cache`,
    then `title` and `table(measured)` printed and written to `--out`."""
    ap = argparse.ArgumentParser(description=doc.split("\n\n")[0])
    ap.add_argument("dirs", nargs="+", type=Path, help="run folders; their checkpoints/ckpt-*.pt are measured")
    ap.add_argument("--cache", type=Path, help="JSON of the checkpoints measured so far (read and extended)")
    ap.add_argument("--last", type=int, default=0, help="only each run's this many newest checkpoints (0: all)")
    ap.add_argument("--out", type=Path)
    args = ap.parse_args(argv)
    paths = newest(args.dirs, args.last)
    if not paths:
        raise SystemExit(f"no checkpoints (checkpoints/ckpt-*.pt) under {', '.join(map(str, args.dirs))}")
    measured = measure_all(paths, args.cache, measure)
    command = " ".join([f"python -m {module}", *(argv if argv is not None else sys.argv[1:])])
    lines = [f"# {title}", "", f"Built by `{command}`.", "", *table(measured)]
    print("\n".join(lines))
    if args.out:
        args.out.write_text("\n".join(lines) + "\n")


def main(argv: list[str] | None = None) -> None:
    checkpoint_tool(
        argv,
        __doc__,
        "actors.evaluation.road_gap",
        measure_checkpoint,
        report,
        "Train roads against test roads, per checkpoint",
    )


if __name__ == "__main__":
    main()
