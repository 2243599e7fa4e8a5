"""The offline comparison in the paper's Jackal layout (appendix "Test Results"): GVF-BCQ, E2E-BCQ,
the MPC baseline and the kinematic controller, each on every held-out road, in both directions,
at two target speeds, with clean and damaged markings.

    python -m actors.evaluation.offline_eval --policy GVF-BCQ=CKPT --policy E2E-BCQ=CKPT --out DIR

The two target speeds are the Jackal's 0.25 and 0.4 m/s carried through the collector's speed
scaling (`actors.controllers.random_walk`: its band [0.2, 0.5] m/s is LaneDrive's [v_max / 2,
v_grip]), 10.3 and 11.3 m/s. A target speed caps a learned policy's target-speed action (the
Jackal's maximum-speed setting), and is the MPC's set speed.

Writes offline_eval.json (every drive's metrics), offline_eval.md (per road, a table of method x
direction x speed x markings with the paper's metrics) and distributions.png (alpha, beta,
speed and both actions per method at the fast speed, clean markings; the paper's figure).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from actors.controllers.mpc import MPCController, speed_action  # noqa: E402
from actors.controllers.random_walk import SPEED_CLIP  # noqa: E402
from actors.envs.tracks import MIN_RADIUS  # noqa: E402
from actors.evaluation.evaluate import evaluate  # noqa: E402
from actors.evaluation.main import DEFAULT_DAMAGE  # noqa: E402
from actors.evaluation.policies import checkpoint_policy, kinematic_policy  # noqa: E402
from common.config.env import VehicleConfig  # noqa: E402

ROBOT_SPEEDS = (0.25, 0.4)  # m/s, the Jackal's target speeds
COLUMNS = [  # the paper's metrics, and the lap
    ("reward/s", "reward_per_s", "{:.2f}"),
    ("speed (m/s)", "average_speed", "{:.2f}"),
    ("offcenteredness", "offcenteredness", "{:.3f}"),
    ("abs road angle", "abs_road_angle", "{:.3f}"),
    ("near out of lane", "near_out_of_lane", "{:.3f}"),
    ("speed comfort", "comfort1_speed", "{:.4f}"),
    ("steering comfort", "comfort1_steering", "{:.4f}"),
    ("lap", "lap_completed", "{:.0f}"),
]


def target_speeds(vehicle: VehicleConfig | None = None) -> dict[str, float]:
    """{"0.25 m/s": m/s on LaneDrive, "0.4 m/s": ...} through the collector's speed band."""
    vc = vehicle or VehicleConfig()
    slow, grip = vc.v_max / 2, min(vc.v_max, (vc.max_lateral_accel * MIN_RADIUS) ** 0.5)
    lo, hi = SPEED_CLIP
    return {f"{r} m/s": slow + (grip - slow) * (r - lo) / (hi - lo) for r in ROBOT_SPEEDS}


def capped(policy, v: float, vehicle: VehicleConfig | None = None):
    """`policy` with its target-speed action capped at the action that asks for v m/s."""
    cap = speed_action(v, vehicle or VehicleConfig())

    def act(obs, info):
        a = np.array(policy(obs, info), np.float32).reshape(-1, 2)
        a[:, 1] = np.minimum(a[:, 1], cap)
        return a

    return act


def drive_all(policies: dict[str, object], split: str = "test", tracks: list[str] | None = None) -> list[dict]:
    """Every (method, target speed, markings) over the roads in both directions; one row per drive."""
    rows = []
    for label, v in target_speeds().items():
        for damaged in (False, True):
            kwargs = {"damage": dict(vars(DEFAULT_DAMAGE))} if damaged else {}
            for method, policy in policies.items():
                if policy == "mpc":
                    mpc = MPCController(target_speed=v)
                    act = lambda obs, info, mpc=mpc: mpc.act(info)  # noqa: E731
                else:
                    act = capped(policy, v)
                for r in evaluate(act, split, ("ccw", "cw"), tracks=tracks, **kwargs):
                    rows.append(
                        {
                            "method": method,
                            "road": r["track"].removesuffix("-r"),
                            "direction": r["direction"],
                            "speed": label,
                            "markings": "damaged" if damaged else "clean",
                            "metrics": r["metrics"],
                            "trace": r["trace"],
                        }
                    )
    return rows


def markdown(rows: list[dict]) -> str:
    lines = []
    for road in sorted({r["road"] for r in rows}):
        lines += [f"### {road}", ""]
        head = ["method", "direction", "target speed", "markings", *(c[0] for c in COLUMNS)]
        lines += ["| " + " | ".join(head) + " |", "|" + " --- |" * len(head)]
        for r in (r for r in rows if r["road"] == road):
            cells = [r["method"], r["direction"].upper(), r["speed"], r["markings"]]
            cells += [fmt.format(r["metrics"][key]) for _, key, fmt in COLUMNS]
            lines.append("| " + " | ".join(cells) + " |")
        lines.append("")
    return "\n".join(lines)


def summary_table(rows: list[dict]) -> str:
    """Means over roads and directions per method, speed and markings (laps as a count)."""
    keys = sorted({(r["method"], r["speed"], r["markings"]) for r in rows}, key=lambda k: (k[1], k[2], k[0]))
    head = ["method", "target speed", "markings", "laps", *(c[0] for c in COLUMNS[:-1])]
    lines = ["| " + " | ".join(head) + " |", "|" + " --- |" * len(head)]
    for method, speed, markings in keys:
        sel = [r["metrics"] for r in rows if (r["method"], r["speed"], r["markings"]) == (method, speed, markings)]
        laps = f"{sum(int(m['lap_completed']) for m in sel)} of {len(sel)}"
        cells = [method, speed, markings, laps]
        cells += [fmt.format(np.mean([m[key] for m in sel])) for _, key, fmt in COLUMNS[:-1]]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def distributions(rows: list[dict], path: Path) -> Path:
    """Histograms of alpha, beta, speed and both actions per method (fast speed, clean markings)."""
    fast = list(target_speeds())[-1]
    panels = ["alpha", "beta", "speed", "steering action", "target speed action"]
    fig, axes = plt.subplots(1, len(panels), figsize=(3.2 * len(panels), 2.8))
    for method in dict.fromkeys(r["method"] for r in rows):
        sel = [r["trace"] for r in rows if r["method"] == method and r["speed"] == fast and r["markings"] == "clean"]
        action = np.concatenate([t["action"] for t in sel])
        values = [np.concatenate([t[k] for t in sel]) for k in ("alpha", "beta", "speed")]
        for ax, data in zip(axes, [*values, action[:, 0], action[:, 1]]):
            ax.hist(data, bins=40, density=True, histtype="step", label=method)
    for ax, label in zip(axes, panels):
        ax.set_xlabel(label, fontsize=8)
    axes[0].legend(fontsize=7)
    fig.suptitle(f"test roads, both directions, target speed {fast} (Jackal units), clean markings", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path


def write(rows: list[dict], out: str | Path) -> list[Path]:
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    speeds = ", ".join(f"{k} = {v:.1f} m/s" for k, v in target_speeds().items())
    record = [{k: v for k, v in r.items() if k != "trace"} for r in rows]
    (out / "offline_eval.json").write_text(json.dumps({"target_speeds": target_speeds(), "drives": record}, indent=1))
    text = f"# Offline comparison (Jackal layout)\n\nTarget speeds: {speeds}.\n\n## Means over the roads\n\n"
    text += summary_table(rows) + "\n\n## Per road\n\n" + markdown(rows)
    (out / "offline_eval.md").write_text(text)
    return [out / "offline_eval.json", out / "offline_eval.md", distributions(rows, out / "distributions.png")]


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--policy", action="append", default=[], help="NAME=CHECKPOINT (a gvf-offline checkpoint)")
    parser.add_argument("--out", default="offline_eval")
    parser.add_argument("--tracks", nargs="*", default=None, help="roads (default: every test road)")
    parser.add_argument("--no-baselines", action="store_true", help="leave out MPC and the kinematic controller")
    args = parser.parse_args(argv)
    policies: dict[str, object] = {}
    for item in args.policy:
        name, _, path = item.partition("=")
        policies[name] = checkpoint_policy(path)[0]
    if not args.no_baselines:
        policies.update({"MPC": "mpc", "kinematic": kinematic_policy()})
    for path in write(drive_all(policies, tracks=args.tracks), args.out):
        print(path)


if __name__ == "__main__":
    main()
