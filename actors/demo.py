"""Watch the kinematic controller drive the held-out roads, with a live view of the front
camera (as text) and live figures. `make train` runs this until the learner lands.

    python -m actors.demo [--speedup 10] [--split test]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from rich.console import Group
from rich.live import Live
from rich.panel import Panel
from rich.table import Table

from actors.controllers.kinematic import KinematicController
from actors.envs.lane_drive import LaneDriveEnv
from actors.envs.tracks import track_names

SHADES = " .:-=+*#%@"


def camera_text(image: np.ndarray, rows: int = 16, cols: int = 64) -> str:
    """The grayscale frame as characters, darkest to brightest."""
    h, w = image.shape
    small = image[:: h // rows, :: w // cols][:rows, :cols].astype(int)
    return "\n".join("".join(SHADES[v * len(SHADES) // 256] for v in row) for row in small)


def figures(info: dict, steps_per_s: float, done: list[dict]) -> Table:
    t = Table(show_header=False, box=None)
    t.add_row("track", info["track"], "lap", f"{min(info['progress'], 1.0):6.1%}")
    t.add_row("speed", f"{info['speed'] * 3.6:5.1f} km/h", "steps/s", f"{steps_per_s:,.0f}")
    t.add_row("alpha", f"{info['alpha']:+.3f}", "beta", f"{info['beta']:+.3f} rad")
    t.add_row(
        "laps done",
        f"{sum(d['lap'] for d in done)}/{len(done)}",
        "worst |alpha|",
        f"{max([d['max_alpha'] for d in done], default=0):.3f}",
    )
    return t


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument(
        "--speedup", type=float, default=10.0, help="times faster than real time (0: as fast as possible)"
    )
    parser.add_argument("--split", default="test", choices=["train", "test", "all"], help="which roads to drive")
    args = parser.parse_args()
    controller = KinematicController()
    done: list[dict] = []
    with Live(refresh_per_second=10) as live:
        for name in track_names(args.split):
            for direction in ("ccw", "cw"):
                env = LaneDriveEnv(track=name, direction=direction, random_start=False)
                obs, info = env.reset(seed=0)
                worst, steps, start, ended = 0.0, 0, time.perf_counter(), False
                while not info["lap_completed"] and not ended:
                    obs, _, term, trunc, info = env.step(controller.act(info))
                    ended = term or trunc
                    worst, steps = max(worst, abs(info["alpha"])), steps + 1
                    elapsed = time.perf_counter() - start
                    if args.speedup > 0:
                        time.sleep(max(0.0, steps * 0.1 / args.speedup - elapsed))
                    if steps % 5 == 0:
                        panel = Panel(camera_text(obs["image"][0]), title="front camera", expand=False)
                        live.update(Group(panel, figures(info, steps / max(elapsed, 1e-9), done)))
                done.append(
                    {"track": info["track"], "lap": bool(info["lap_completed"]), "max_alpha": worst, "steps": steps}
                )
    summary = Table("track", "lap completed", "steps", "max |alpha|", title="kinematic controller")
    for d in done:
        summary.add_row(d["track"], "yes" if d["lap"] else "NO", str(d["steps"]), f"{d['max_alpha']:.3f}")
    live.console.print(summary)


if __name__ == "__main__":
    main()
