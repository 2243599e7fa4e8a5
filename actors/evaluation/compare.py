"""The paper's comparison, built from the run summaries of `actors.evaluation.study` alone (no
checkpoints): tables of the final policies (the last checkpoint and the validation-selected one,
test roads clean and with damaged markings; mean ± std over seeds), the staying-good record of
each run, and figures as in the paper: one per metric against training updates with every variant
overlaid (mean ± std over seeds), and lane centeredness along each test road for the last policies.

    python -m actors.evaluation.compare docs/results/runs [--out docs/results]
"""

from __future__ import annotations

import argparse
import json
from collections import defaultdict
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only; no display on servers
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from actors.evaluation.report import COLUMNS, std_band  # noqa: E402

CURVES = [
    ("reward_per_s", "test reward /s"),
    ("jerkiness_angular", "angular jerkiness"),
    ("jerkiness_longitudinal", "longitudinal jerkiness"),
    ("episode_length", "episode length (steps)"),
    ("offcenteredness", "lane centeredness |alpha|"),
    ("lap_completed", "test laps completed (fraction)"),
]
FINALS = [
    ("last", "clean", "last checkpoint, test roads"),
    ("last", "damaged", "last checkpoint, test roads, damaged lane markings"),
    ("selected", "clean", "validation-selected policy, test roads"),
    ("selected", "damaged", "validation-selected policy, test roads, damaged lane markings"),
]


def load(runs: Path) -> dict[str, list[dict]]:
    """Run summaries per variant, in seed order."""
    per: dict[str, list[dict]] = defaultdict(list)
    for path in sorted(runs.glob("*/seed*.json")):
        record = json.loads(path.read_text())
        per[record["variant"]].append(record)
    return {v: sorted(rs, key=lambda r: r["seed"]) for v, rs in sorted(per.items())}


def final_table(per: dict[str, list[dict]], which: str, condition: str, reference: dict | None) -> list[str]:
    head = "| method | runs | " + " | ".join(f"{h} {a}" for _, h, a in COLUMNS) + " |"
    lines = [head, "|" + " --- |" * (len(COLUMNS) + 2)]
    for variant, records in per.items():
        means = [r[which][condition]["mean"] for r in records if r.get(which)]
        if not means:
            continue
        cells = [f"{np.mean([m[k] for m in means]):.3f} ± {np.std([m[k] for m in means]):.3f}" for k, _, _ in COLUMNS]
        lines.append(f"| {variant} | {len(means)} | " + " | ".join(cells) + " |")
    if reference is not None:
        lines.append(
            "| kinematic controller | - | " + " | ".join(f"{reference[condition][k]:.3f}" for k, _, _ in COLUMNS) + " |"
        )
    return lines


def staying_good(record: dict) -> dict:
    """First all-lap minute, laps of the last checkpoint, and how often later evaluations held >= 11 of 12."""
    evals = record["evaluations"]
    n = len(evals[0]["drives"]) if evals else 12
    laps = [round(e["mean"]["lap_completed"] * len(e["drives"])) for e in evals]
    first = next((i for i, x in enumerate(laps) if x == n), None)
    after = laps[first + 1 :] if first is not None else []
    last = record.get("last") or {}
    clean = last.get("clean", {})
    mean = clean.get("mean", {})
    return {
        "seed": record["seed"],
        # a wall-clock budget buys each variant a different number of updates
        "updates": (record.get("progress") or {}).get("updates"),
        "minutes_to_all_laps": evals[first]["minute"] if first is not None else None,
        "updates_to_all_laps": evals[first]["updates"] if first is not None else None,
        "last_laps": round(clean["mean"]["lap_completed"] * len(clean["drives"])) if clean else None,
        "last_near_out_of_lane": mean.get("near_out_of_lane"),
        "last_offcenteredness": mean.get("offcenteredness"),
        "last_jerkiness_angular": mean.get("jerkiness_angular"),
        "evaluations_after": len(after),
        "after_with_11": sum(x >= n - 1 for x in after),
        "fraction_after_with_11": (sum(x >= n - 1 for x in after) / len(after)) if after else None,
        "selected_laps": (
            round(record["selected"]["clean"]["mean"]["lap_completed"] * n) if record.get("selected") else None
        ),
        "laps_per_evaluation": laps,
    }


def staying_good_table(per: dict[str, list[dict]]) -> list[str]:
    lines = [
        # updates to the first all-12 evaluation as well as minutes: runs made on machines of other speeds compare by updates
        "| method | seed | updates | min to all 12 laps | updates to all 12 laps | last checkpoint laps | its near-out-of-lane | its mean abs(alpha) | its angular jerkiness | evals after | share >= 11 | validation-selected laps |",
        "|" + " --- |" * 12,
    ]
    fmt = lambda x, f="{:.2f}": "-" if x is None else f.format(x)  # noqa: E731
    for variant, records in per.items():
        for r in records:
            s = staying_good(r)
            lines.append(
                f"| {variant} | {s['seed']} | {fmt(s['updates'], '{}')} | {fmt(s['minutes_to_all_laps'], '{:.1f}')} | "
                f"{fmt(s['updates_to_all_laps'], '{}')} | {fmt(s['last_laps'], '{}')} | {fmt(s['last_near_out_of_lane'], '{:.3f}')} | "
                f"{fmt(s['last_offcenteredness'], '{:.3f}')} | {fmt(s['last_jerkiness_angular'], '{:.3f}')} | {s['evaluations_after']} | "
                f"{fmt(s['fraction_after_with_11'])} | {fmt(s['selected_laps'], '{}')} |"
            )
    return lines


def curve_figures(per: dict[str, list[dict]], out: Path) -> list[Path]:
    paths = []
    for key, label in CURVES:
        fig, ax = plt.subplots(figsize=(6, 3.4))
        for variant, records in per.items():
            series = [r["evaluations"] for r in records if r["evaluations"]]
            if not series:
                continue
            steps = np.array(sorted({e["updates"] for s in series for e in s}))
            steps = steps[steps <= min(s[-1]["updates"] for s in series)]  # where every seed has data
            metric = (
                (lambda e: float(np.mean([d[key] for d in e["drives"]])))
                if key == "episode_length"
                else (lambda e: e["mean"][key])
            )
            grid = np.array([np.interp(steps, [e["updates"] for e in s], [metric(e) for e in s]) for s in series])
            ax.plot(steps, grid.mean(0), label=f"{variant} ({len(series)})")
            std_band(ax, steps, grid, alpha=0.2)
        ax.set_xlabel("learner updates")
        ax.set_title(f"{label}, mean ± std over seeds (within their range)", fontsize=9)
        ax.legend(fontsize=7)
        fig.tight_layout()
        path = out / f"curve_{key}.png"
        fig.savefig(path, dpi=80)
        plt.close(fig)
        paths.append(path)
    return paths


def lane_figure(per: dict[str, list[dict]], out: Path) -> Path | None:
    drives = sorted({t for rs in per.values() for r in rs if r.get("last") for t in r["last"]["clean"]["traces"]})
    if not drives:
        return None
    cols = 4
    rows = (len(drives) + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(4 * cols, 2.4 * rows), squeeze=False)
    colours = {v: f"C{i}" for i, v in enumerate(per)}
    for ax, track in zip(axes.flat, drives):
        for variant, records in per.items():
            for j, r in enumerate(records):
                trace = (r.get("last") or {}).get("clean", {}).get("traces", {}).get(track)
                if trace:
                    ax.plot(
                        trace["progress"],
                        trace["alpha"],
                        color=colours[variant],
                        lw=0.7,
                        alpha=0.7,
                        label=variant if j == 0 else None,
                    )
        ax.axhline(0.75, color="r", ls=":", lw=0.8)
        ax.axhline(-0.75, color="r", ls=":", lw=0.8)
        ax.set_ylim(-1.1, 1.1)
        ax.set_xlim(0.0, 1.0)  # the whole lap, so where a drive ended shows
        ax.set_title(track, fontsize=9)
        ax.set_xlabel("lap progress", fontsize=8)
    for ax in list(axes.flat)[len(drives) :]:
        ax.axis("off")
    axes.flat[0].legend(fontsize=6)
    fig.suptitle("lane centeredness alpha along each test road, last checkpoints (one line per seed)", fontsize=10)
    fig.tight_layout()
    path = out / "lane_centeredness_final.png"
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path


def reference(runs: Path) -> dict:
    """The kinematic controller on the same roads (deterministic), cached beside the summaries."""
    path = runs / "kinematic.json"
    if path.exists():
        return json.loads(path.read_text())
    import dataclasses

    from actors.evaluation.evaluate import evaluate, summary
    from actors.evaluation.main import DEFAULT_DAMAGE
    from actors.evaluation.policies import kinematic_policy

    ref = {
        "clean": summary(evaluate(kinematic_policy())),
        "damaged": summary(evaluate(kinematic_policy(), damage=dataclasses.asdict(DEFAULT_DAMAGE))),
    }
    path.write_text(json.dumps(ref))
    return ref


def compare(runs: Path, out: Path, with_reference: bool = True) -> Path:
    out.mkdir(parents=True, exist_ok=True)
    per = load(runs)
    ref = reference(runs) if with_reference else None
    lines = [
        f"Built by `python -m actors.evaluation.compare {runs}` from {sum(map(len, per.values()))} run summaries.",
        "",
    ]
    for which, condition, title in FINALS:
        lines += [f"### {title}", "", *final_table(per, which, condition, ref), ""]
    lines += ["### staying good (every run)", "", *staying_good_table(per), ""]
    curve_figures(per, out)
    lane_figure(per, out)
    path = out / "comparison.md"
    path.write_text("\n".join(lines))
    return path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("runs", type=Path, help="the study's summaries (docs/results/runs)")
    parser.add_argument("--out", type=Path, default=Path("docs/results"))
    args = parser.parse_args()
    print(compare(args.runs, args.out).read_text())


if __name__ == "__main__":
    main()
