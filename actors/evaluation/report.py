"""Evaluation reports: eval.json, eval.md (a table in the paper's layout) and PNG figures:
lane centeredness along the lap per road, histograms of alpha, beta, speed and both actions
(as the paper's Jackal figures), and learning curves of test score and jerkiness over runs."""

from __future__ import annotations

import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only; no display on servers
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

COLUMNS = [  # (metric, header, arrow) as in the paper's tables
    ("reward_per_s", "Reward /s", "↑"),
    ("average_speed", "Average speed (m/s)", "↑"),
    ("offcenteredness", "Offcenteredness", "↓"),
    ("abs_road_angle", "Absolute road angle", "↓"),
    ("near_out_of_lane", "Near out of lane", "↓"),
    ("comfort1_speed", "Speed comfort (1st)", "↑"),
    ("comfort2_speed", "Speed comfort (2nd)", "↑"),
    ("comfort1_steering", "Steering comfort (1st)", "↑"),
    ("comfort2_steering", "Steering comfort (2nd)", "↑"),
    ("jerkiness_angular", "Angular jerkiness", "↓"),
    ("jerkiness_longitudinal", "Longitudinal jerkiness", "↓"),
    ("lap_completed", "Lap", "↑"),
]


def markdown_table(rows: list[tuple[str, dict]]) -> str:
    """`rows` = [(label, metrics)] -> a markdown table with the paper's columns."""
    head = "| | " + " | ".join(f"{h} {a}" for _, h, a in COLUMNS) + " |"
    lines = [head, "|" + " --- |" * (len(COLUMNS) + 1)]
    for label, m in rows:
        lines.append(
            f"| {label} | "
            + " | ".join(
                f"{m[k]:.4f}" if k != "lap_completed" else ("yes" if m[k] >= 1 else f"{m[k]:.0%}")
                for k, _, _ in COLUMNS
            )
            + " |"
        )
    return "\n".join(lines)


def write_report(results: list[dict], out_dir: str | Path, title: str) -> list[Path]:
    """Write eval.json, eval.md and the figures for one policy; returns the files written."""
    from actors.evaluation.evaluate import summary

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    mean = summary(results)
    (out / "eval.json").write_text(
        json.dumps(
            {
                "title": title,
                "mean": mean,
                "drives": [
                    {"track": r["track"], "direction": r["direction"], "metrics": r["metrics"]} for r in results
                ],
            },
            indent=1,
        )
    )
    rows = [(f"{r['track']}", r["metrics"]) for r in results] + [("**mean**", mean)]
    (out / "eval.md").write_text(f"# {title}\n\n{markdown_table(rows)}\n")
    return [
        out / "eval.json",
        out / "eval.md",
        lane_figure(results, out / "lane_centeredness.png"),
        histogram_figure(results, out / "distributions.png", title),
    ]


def lane_figure(results: list[dict], path: Path) -> Path:
    n = len(results)
    cols = min(4, n)
    rows = (n + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(4 * cols, 2.6 * rows), squeeze=False)
    for ax, r in zip(axes.flat, results):
        ax.plot(r["trace"]["progress"], r["trace"]["alpha"], lw=1)
        ax.axhline(0.75, color="r", ls=":", lw=0.8)
        ax.axhline(-0.75, color="r", ls=":", lw=0.8)
        ax.set_ylim(-1.1, 1.1)
        ax.set_title(f"{r['track']} ({'lap' if r['metrics']['lap_completed'] else 'off road'})", fontsize=9)
        ax.set_xlabel("lap progress")
        ax.set_ylabel("alpha")
    for ax in list(axes.flat)[n:]:
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path


def histogram_figure(results: list[dict], path: Path, title: str) -> Path:
    cat = {k: np.concatenate([r["trace"][k] for r in results]) for k in ("alpha", "beta", "speed", "action")}
    panels = [
        ("lane centeredness alpha", cat["alpha"]),
        ("road angle beta (rad)", cat["beta"]),
        ("speed (m/s)", cat["speed"]),
        ("steering action", cat["action"][:, 0]),
        ("target speed action", cat["action"][:, 1]),
    ]
    fig, axes = plt.subplots(1, len(panels), figsize=(3.2 * len(panels), 2.6))
    for ax, (label, values) in zip(axes, panels):
        ax.hist(values, bins=40, density=True)
        ax.set_xlabel(label, fontsize=8)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path


def std_band(ax, steps, grid: np.ndarray, alpha: float) -> None:
    """mean +- std over the rows of `grid`, kept within the rows' own range: a lap fraction never
    shows below 0 or above 1."""
    mean, std = grid.mean(0), grid.std(0)
    ax.fill_between(steps, np.maximum(mean - std, grid.min(0)), np.minimum(mean + std, grid.max(0)), alpha=alpha)


def learning_curves(run_dirs: list[Path], path: Path) -> Path | None:
    """Test score and jerkiness against training updates, mean and std over runs (eval.jsonl of each run)."""
    series = []
    for d in run_dirs:
        f = Path(d) / "eval.jsonl"
        if f.exists():
            series.append([json.loads(line) for line in f.read_text().splitlines() if line.strip()])
    if not series:
        return None
    steps = sorted({e["updates"] for s in series for e in s})
    fig, axes = plt.subplots(1, 3, figsize=(12, 3))
    for ax, key, label in zip(
        axes,
        ("reward_per_s", "jerkiness_angular", "jerkiness_longitudinal"),
        ("test reward /s", "angular jerkiness", "longitudinal jerkiness"),
    ):
        grid = np.array(
            [[np.interp(x, [e["updates"] for e in s], [e["mean"][key] for e in s]) for x in steps] for s in series]
        )
        ax.plot(steps, grid.mean(0))
        std_band(ax, steps, grid, alpha=0.3)
        ax.set_xlabel("learner updates")
        ax.set_title(f"{label} ({len(series)} runs)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path
