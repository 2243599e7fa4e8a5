"""Priority track sampling (the paper's appendix, "TORCS Experiments"): at every reset the next
road i is drawn with probability

    P(i) = exp(-n_i / kappa) / sum_j exp(-n_j / kappa),    kappa = mean_j n_j,

where n_i is the number of steps survived the last time road i was driven. Roads the agent
fails on early come back more often. Initial probabilities are equal (all n_i = 0).

An actor keeps its own counts and replaces them with the learner's global table (published on
`gvf/<run>/tracks`) whenever one arrives.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np


class PriorityTrackSampler:
    """Draws the next road from `names` by the steps survived on each the last time it was driven."""

    def __init__(self, names: Sequence[str], rng: np.random.Generator | None = None) -> None:
        if not names:
            raise ValueError("track sampling needs at least one road name")
        self.names = list(names)
        self.steps = np.zeros(len(self.names))
        self._index = {n: i for i, n in enumerate(self.names)}
        self.rng = rng or np.random.default_rng()

    def probabilities(self) -> np.ndarray:
        kappa = self.steps.mean()
        if kappa <= 0:
            return np.full(len(self.names), 1.0 / len(self.names))
        logits = -self.steps / kappa
        p = np.exp(logits - logits.max())  # shifted for numerical safety; P is unchanged
        return p / p.sum()

    def sample(self) -> str:
        return self.names[int(self.rng.choice(len(self.names), p=self.probabilities()))]

    def record(self, name: str, steps_survived: int) -> None:
        """Remember how long the last drive on `name` lasted (a '-r' suffix counts for its road)."""
        i = self._index.get(name.removesuffix("-r"), self._index.get(name))
        if i is not None:
            self.steps[i] = float(steps_survived)

    def update(self, table: Mapping[str, float]) -> None:
        """Adopt a (global) table of steps survived per road; unknown names are ignored."""
        for name, n in table.items():
            self.record(name, int(n))

    def table(self) -> dict[str, float]:
        return {n: float(s) for n, s in zip(self.names, self.steps)}
