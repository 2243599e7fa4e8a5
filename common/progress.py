"""The live progress display of `gvf-train`: what the learner last wrote to progress.json
(env steps/s, updates/s, episodes, return, rho_bar, policy-version lag) and the processes."""

from __future__ import annotations

import json
from pathlib import Path

from rich.console import Console
from rich.live import Live
from rich.table import Table

FIELDS = [
    ("env steps/s", "env_steps_per_s", "{:,.0f}"),
    ("updates/s", "updates_per_s", "{:,.1f}"),
    ("updates", "updates", "{:,}"),
    ("replay", "replay", "{:,}"),
    ("episodes", "episodes", "{:,}"),
    ("return (last 100)", "return_mean", "{:.2f}"),
    ("rho_bar", "rho_bar", "{:.3f}"),
    ("policy lag (updates)", "policy_lag", "{:.1f}"),
    ("actors alive", "actors_alive", "{}"),
    ("lost / rejected chunks", None, None),
]


class Progress:
    """`with Progress(run_dir): ... progress.update(children)` refreshes a table in place."""

    def __init__(self, run_dir: Path, enabled: bool = True) -> None:
        self.path = run_dir / "progress.json"
        self.enabled = enabled
        self.last: dict = {}
        self._live = Live(console=Console(stderr=True), refresh_per_second=2) if enabled else None

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
        t = Table(title=f"gvf-train  {self.path.parent}", show_header=False)
        for label, key, fmt in FIELDS:
            if key is None:
                t.add_row(label, f"{p.get('lost_chunks', 0)} / {p.get('rejected', 0)}")
            else:
                value = p.get(key)
                t.add_row(label, fmt.format(value) if value is not None else "-")
        states = ", ".join(f"{c.name}{'' if c.proc is not None and c.proc.is_alive() else ' (down)'}{f' x{c.restarts}' if c.restarts else ''}" for c in children)
        t.add_row("processes", states)
        return t

    def update(self, children: list) -> None:
        self.read()
        if self._live is not None:
            self._live.update(self.table(children))
