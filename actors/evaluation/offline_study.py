"""The paper's offline comparison as resumable jobs: one dataset (`gvf-collect`), one `gvf-offline`
run per (method, seed), each leaving a small JSON summary (its drives in the Jackal layout,
`actors.evaluation.offline_eval`, and histograms of alpha, beta, speed and both actions), plus the
MPC and kinematic baselines once; `--build` makes every table and the distributions figure from
the committed summaries alone.

    python -m actors.evaluation.offline_study --data datasets/lanedrive-100k --collect 100000 \
        --methods gvf_bcq e2e_bcq --seeds 0 1 2 -- [overrides ...]
    python -m actors.evaluation.offline_study --build

A job whose summary exists is skipped; checkpoints and the dataset stay in the scratch folders.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from actors.evaluation.offline_eval import COLUMNS, drive_all, target_speeds  # noqa: E402
from actors.evaluation.policies import checkpoint_policy, kinematic_policy  # noqa: E402
from common import checkpoint  # noqa: E402
from common.dataset import Dataset  # noqa: E402

NAMES = {"gvf_bcq": "GVF-BCQ", "e2e_bcq": "E2E-BCQ"}
BINS = {  # fixed histogram bins, so that summaries combine
    "alpha": np.linspace(-1.0, 1.0, 41),
    "beta": np.linspace(-0.5, 0.5, 41),
    "speed": np.linspace(9.0, 20.0, 45),
    "steering": np.linspace(-1.0, 1.0, 41),
    "target speed": np.linspace(-1.0, 1.0, 41),
}
OUT = Path("docs/results/offline")


def histograms(rows: list[dict]) -> dict[str, list[int]]:
    """Counts per BINS of the fast-speed, clean-marking drives."""
    fast = list(target_speeds())[-1]
    sel = [r["trace"] for r in rows if r["speed"] == fast and r["markings"] == "clean"]
    action = np.concatenate([t["action"] for t in sel])
    values = {k: np.concatenate([t[k] for t in sel]) for k in ("alpha", "beta", "speed")}
    values.update({"steering": action[:, 0], "target speed": action[:, 1]})
    return {k: np.histogram(np.clip(v, BINS[k][0], BINS[k][-1]), BINS[k])[0].tolist() for k, v in values.items()}


def summarize(rows: list[dict], **extra) -> dict:
    return {**extra, "drives": [{k: v for k, v in r.items() if k != "trace"} for r in rows], "hist": histograms(rows)}


def ensure_dataset(data: Path, transitions: int, seed: int = 0) -> None:
    if (data / "manifest.json").exists():
        return
    subprocess.run(
        [sys.executable, "-m", "actors.collect", f"collect.out={data}", f"collect.transitions={transitions}"]
        + ["progress=false", f"seed={seed}", f"hydra.run.dir={data.parent / (data.name + '-collect')}"],
        check=True,
    )


def run_job(
    method: str, seed: int, data: Path, out: Path, work: Path, overrides: list[str], tracks: list[str] | None = None
) -> Path:
    path = out / method / f"seed{seed}.json"
    if path.exists():
        print(f"skip {method} seed {seed}: {path} exists", flush=True)
        return path
    run_dir = work / f"{method}-seed{seed}"
    cmd = [sys.executable, "-m", "learner.offline_main", f"offline.dataset={data}", f"offline.method={method}"]
    cmd += [f"seed={seed}", "progress=false", f"hydra.run.dir={run_dir}", *overrides]
    print(f"run {method} seed {seed} in {run_dir}", flush=True)
    work.mkdir(parents=True, exist_ok=True)
    with open(work / f"{method}-seed{seed}.out", "wb") as log:
        subprocess.run(
            cmd, stdout=log, stderr=subprocess.STDOUT, check=True, env={**os.environ, "OMP_NUM_THREADS": "1"}
        )
    ckpt = checkpoint.find(run_dir / "checkpoints" / "offline")
    policy, meta = checkpoint_policy(ckpt)
    state = checkpoint.load(ckpt)
    rows = drive_all({NAMES[method]: policy}, tracks=tracks)
    curves = [json.loads(line) for line in (run_dir / "offline_metrics.jsonl").read_text().splitlines()]
    summary = summarize(
        rows,
        curves=curves,
        method=method,
        seed=seed,
        overrides=overrides,
        updates=meta["updates"],
        offline_seconds=state.get("offline_seconds"),
        dataset=str(data),
        transitions=len(Dataset.open(data, verify=False)),
    )
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(summary))
    return path


def baselines(out: Path, tracks: list[str] | None = None) -> Path:
    path = out / "baselines.json"
    if not path.exists():
        rows = drive_all({"MPC": "mpc", "kinematic": kinematic_policy()}, tracks=tracks)
        by = {m: summarize([r for r in rows if r["method"] == m], method=m) for m in ("MPC", "kinematic")}
        path.write_text(json.dumps(by))
    return path


def load(out: Path) -> list[dict]:
    """Every summary: one per (method, seed) run, and one per baseline."""
    runs = [json.loads(p.read_text()) for p in sorted(out.glob("*/seed*.json"))]
    base = json.loads((out / "baselines.json").read_text()) if (out / "baselines.json").exists() else {}
    return runs + list(base.values())


def table(summaries: list[dict]) -> str:
    """Mean +- std over seeds of the per-run means, per method, target speed and markings; laps summed."""
    head = ["method", "runs", "target speed", "markings", "laps", *(c[0] for c in COLUMNS[:-1])]
    lines = ["| " + " | ".join(head) + " |", "|" + " --- |" * len(head)]
    methods = list(dict.fromkeys(NAMES.get(s["method"], s["method"]) for s in summaries))
    for speed in target_speeds():
        for markings in ("clean", "damaged"):
            for method in methods:
                runs = [s for s in summaries if NAMES.get(s["method"], s["method"]) == method]
                per_run = [[d for d in s["drives"] if d["speed"] == speed and d["markings"] == markings] for s in runs]
                laps = sum(int(d["metrics"]["lap_completed"]) for drives in per_run for d in drives)
                total = sum(len(d) for d in per_run)
                cells = [method, str(len(runs)), speed, markings, f"{laps} of {total}"]
                for _, key, fmt in COLUMNS[:-1]:
                    means = [np.mean([d["metrics"][key] for d in drives]) for drives in per_run]
                    spread = f" ± {fmt.format(np.std(means))}" if len(means) > 1 else ""
                    cells.append(fmt.format(np.mean(means)) + spread)
                lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def per_road(summaries: list[dict], speed: str) -> str:
    """Laps per road and direction (summed over seeds) at one target speed, clean and damaged."""
    roads = sorted({d["road"] for s in summaries for d in s["drives"]})
    head = ["method", "markings", *(f"{r} {d}" for r in roads for d in ("CCW", "CW"))]
    lines = ["| " + " | ".join(head) + " |", "|" + " --- |" * len(head)]
    for method in dict.fromkeys(NAMES.get(s["method"], s["method"]) for s in summaries):
        runs = [s for s in summaries if NAMES.get(s["method"], s["method"]) == method]
        for markings in ("clean", "damaged"):
            cells = [method, markings]
            for road in roads:
                for direction in ("ccw", "cw"):
                    sel = [
                        d
                        for s in runs
                        for d in s["drives"]
                        if (d["road"], d["direction"], d["speed"], d["markings"]) == (road, direction, speed, markings)
                    ]
                    cells.append(f"{sum(int(d['metrics']['lap_completed']) for d in sel)}/{len(sel)}")
            lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def figure(summaries: list[dict], path: Path) -> Path:
    fig, axes = plt.subplots(1, len(BINS), figsize=(3.2 * len(BINS), 2.8))
    for method in dict.fromkeys(NAMES.get(s["method"], s["method"]) for s in summaries):
        runs = [s for s in summaries if NAMES.get(s["method"], s["method"]) == method]
        for ax, (key, edges) in zip(axes, BINS.items()):
            counts = np.sum([s["hist"][key] for s in runs], axis=0).astype(float)
            density = counts / max(counts.sum(), 1.0) / np.diff(edges)
            ax.stairs(density, edges, label=method)
            ax.set_xlabel(key, fontsize=8)
    axes[0].legend(fontsize=7)
    fast = list(target_speeds())[-1]
    fig.suptitle(f"test roads, both directions, target speed {fast} (Jackal units), clean markings", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path


def training_curves(summaries: list[dict], path: Path) -> Path | None:
    """Algorithm 2's TD loss, behaviour loss and rho_bar against updates per GVF-BCQ run (the
    paper's figure), a dashed line where the replay became full."""
    runs = [s for s in summaries if s.get("method") == "gvf_bcq" and s.get("curves")]
    if not runs:
        return None
    panels = [("losses/td", "TD loss"), ("losses/behaviour", "behaviour loss"), ("train/rho_bar", "mean rho in D")]
    fig, axes = plt.subplots(1, 3, figsize=(11, 2.8))
    for s in runs:
        gvf = [r for r in s["curves"] if r["phase"] == "gvf"]
        x = [r["update"] for r in gvf]
        for ax, (key, label) in zip(axes, panels):
            ax.plot(x, [r[key] for r in gvf], label=f"seed {s['seed']}")
            ax.set_title(label, fontsize=9)
        full = next((r["update"] for r in gvf if r.get("train/loaded", 0) >= s.get("transitions", 1)), None)
        for ax in axes if full else ():
            ax.axvline(full, ls="--", lw=0.8, color="grey")
    axes[0].set_yscale("log")
    axes[0].legend(fontsize=7)
    for ax in axes:
        ax.set_xlabel("Algorithm 2 updates", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path


def build(out: Path) -> list[Path]:
    summaries = load(out)
    if not summaries:
        raise SystemExit(f"no summaries under {out}")
    speeds = ", ".join(f"{k} = {v:.1f} m/s" for k, v in target_speeds().items())
    text = f"Built by `python -m actors.evaluation.offline_study --build` from {len(summaries)} summaries.\n\n"
    text += f"Target speeds (the Jackal's, through the collector's speed scaling): {speeds}.\n\n"
    text += "### Means over the test roads and both directions\n\n" + table(summaries) + "\n\n"
    for speed in target_speeds():
        text += f"### Laps per road, target speed {speed}\n\n" + per_road(summaries, speed) + "\n\n"
    (out / "comparison.md").write_text(text)
    curves = training_curves(summaries, out / "algorithm2_curves.png")
    return [out / "comparison.md", figure(summaries, out / "distributions.png")] + ([curves] if curves else [])


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", type=Path, default=Path("datasets/lanedrive-100k"))
    parser.add_argument("--collect", type=int, default=100_000, help="transitions to collect if --data is missing")
    parser.add_argument("--methods", nargs="+", default=list(NAMES), choices=list(NAMES))
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--out", type=Path, default=OUT, help="where summaries go (commit these)")
    parser.add_argument("--work", type=Path, default=Path("runs/offline-study"), help="scratch: runs, checkpoints")
    parser.add_argument("--tracks", nargs="*", default=None, help="roads driven (default: every test road)")
    parser.add_argument("--build", action="store_true", help="only build the tables and figure from the summaries")
    parser.add_argument("overrides", nargs="*", help="extra Hydra overrides for every gvf-offline run")
    args = parser.parse_args(argv)
    if not args.build:
        ensure_dataset(args.data, args.collect)
        args.out.mkdir(parents=True, exist_ok=True)
        print(baselines(args.out, args.tracks), flush=True)
        for seed in args.seeds:
            for method in args.methods:
                path = run_job(method, seed, args.data, args.out, args.work, args.overrides, args.tracks)
                print(path, flush=True)
    for path in build(args.out):
        print(path)


if __name__ == "__main__":
    main()
