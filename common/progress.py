"""The live view of `gvf-train`: what the learner last wrote to progress.json (env steps/s or
"paused (rate limit)", updates/s, episodes, return, rho_bar, policy-version lag), the periodic
evaluator's last evaluation and its validation-selected one from eval.jsonl (laps of the
held-out roads), the roles, and at the end a short summary with the commands that evaluate the
run's newest checkpoint and its validation-selected policy (checkpoints/best-policy.pt)."""

from __future__ import annotations

import json
from pathlib import Path

from rich.console import Console
from rich.live import Live
from rich.table import Table

from common.selection import BEST, selected

FIELDS = [
    ("updates/s", "updates_per_s", "{:,.1f}"),
    ("updates", "updates", "{:,}"),
    ("replay", "replay", "{:,}"),
    ("episodes", "episodes", "{:,}"),
    ("return (last 100)", "return_mean", "{:.2f}"),
    ("rho_bar", "rho_bar", "{:.3f}"),
    ("policy lag (updates)", "policy_lag", "{:.1f}"),
    ("actors alive", "actors_alive", "{}"),
]


def env_rate(p: dict) -> str:
    """Env steps per second, or why there are none: the learner's rate limit holds the actors."""
    rate = p.get("env_steps_per_s")
    if rate is None:
        return "-"
    if rate < 0.5 and p.get("flow_paused"):
        return "paused (rate limit)"
    return f"{rate:,.0f}"


def read_evaluations(path: Path) -> list[dict]:
    """The records of eval.jsonl (a half-written last line is skipped)."""
    records = []
    try:
        lines = path.read_text().splitlines()
    except FileNotFoundError:
        return records
    for line in lines:
        try:
            records.append(json.loads(line))
        except json.JSONDecodeError:
            continue
    return records


def describe(record: dict | None) -> str:
    """'12/12 laps, 4.75 reward/s at 3,000 updates' for one evaluation record."""
    if record is None:
        return "-"
    mean, n = record["mean"], len(record.get("drives", [])) or 1
    laps = round(mean["lap_completed"] * n)
    return f"{laps}/{n} laps, {mean['reward_per_s']:.2f} reward/s at {record['updates']:,} updates"


class Progress:
    """`with Progress(run_dir): ... progress.update(children)` refreshes a table in place."""

    def __init__(self, run_dir: Path, enabled: bool = True) -> None:
        self.run_dir = run_dir
        self.path = run_dir / "progress.json"
        self.enabled = enabled
        self.last: dict = {}
        self.console = Console(stderr=True)
        self._live = Live(console=self.console, refresh_per_second=2) if enabled else None

    def __enter__(self) -> "Progress":
        if self._live is not None:
            self._live.__enter__()
        return self

    def __exit__(self, *exc) -> None:
        if self._live is not None:
            self._live.__exit__(*exc)

    def read(self) -> dict:
        try:
            self.last = json.loads(self.path.read_text())
        except (FileNotFoundError, json.JSONDecodeError):
            pass
        return self.last

    def table(self, children: list) -> Table:
        p = self.last
        t = Table(title=f"gvf-train  {self.run_dir}", show_header=False)
        t.add_row("env steps/s", env_rate(p))
        for label, key, fmt in FIELDS:
            value = p.get(key)
            t.add_row(label, fmt.format(value) if value is not None else "-")
        t.add_row("lost / rejected chunks", f"{p.get('lost_chunks', 0)} / {p.get('rejected', 0)}")
        records = read_evaluations(self.run_dir / "eval.jsonl")
        t.add_row("last evaluation", describe(records[-1] if records else None))
        t.add_row("validation-selected", describe(selected(records)))
        t.add_row("roles", ", ".join(state(c) for c in children))
        return t

    def update(self, children: list) -> None:
        self.read()
        if self._live is not None:
            self._live.update(self.table(children))

    def final(self, result: dict | None, checkpoint_dir: Path) -> str:
        """The end-of-run summary (printed when the view is on) and returned."""
        result = result or self.last
        records = read_evaluations(self.run_dir / "eval.jsonl")
        lines = [
            f"run finished in {self.run_dir}: {result.get('updates', 0):,} updates, "
            f"{result.get('inserted', 0):,} transitions, {result.get('episodes', 0):,} episodes"
        ]
        if records:
            lines.append(f"  last evaluation: {describe(records[-1])}")
        lines.append(f"  evaluate the newest checkpoint:  gvf-eval checkpoint={checkpoint_dir}")
        if (checkpoint_dir / BEST).exists():
            # the policy to ship: 9 of 10 lapped all and centred where 6 of 10 newest did (docs/results.md)
            lines.append(f"  validation-selected policy: {describe(selected(records))}")
            lines.append(f"  evaluate it:  gvf-eval checkpoint={checkpoint_dir / BEST}")
        text = "\n".join(lines)
        if self.enabled:
            self.console.print(text)
        return text


def state(child) -> str:
    """'actor-0', 'actor-0 (down) x2' or 'learner (done)' for one supervised role."""
    if child.done:
        return f"{child.name} (done)"
    down = "" if child.alive else " (down)"
    return f"{child.name}{down}{f' x{child.restarts}' if child.restarts else ''}"
