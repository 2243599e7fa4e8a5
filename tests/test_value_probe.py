"""The value probe (actors/evaluation/value_probe.py) sets the critic's Q at the policy's action
against the policy's discounted return on a branch of the simulator."""

import numpy as np
import pytest
import torch

from actors.envs.sim import LaneDriveSim
from actors.evaluation.value_probe import summarise, value_rows
from common.config.env import EnvConfig
from tests.test_credit_probe import pushed_left


class Constant(torch.nn.Module):
    def __init__(self, value: float):
        super().__init__()
        self.value = value

    def forward(self, x, a):
        return torch.full((len(x), 1), self.value)


def two_cars() -> LaneDriveSim:
    sim = LaneDriveSim(EnvConfig.from_kwargs(lighting=False), 2)
    rng = np.random.default_rng(0)
    for i, d in enumerate(("ccw", "cw")):
        sim.reset(i, rng, {"track": "dune", "direction": d, "random_start": False})
    return sim


def test_a_car_that_stays_on_the_road_returns_the_geometric_sum_and_the_bias_is_the_critics_excess():
    sim, discount, horizon = two_cars(), 0.9, 20
    rows = value_rows(sim, pushed_left(sim, bias=0.0), Constant(5.0), lambda s, t: np.ones(s.n), discount, 200, horizon)
    full = (1 - discount**horizon) / (1 - discount)
    assert len(rows) >= 4 and np.allclose(rows[:, 3], full)
    m = summarise(rows)
    assert m["bias_median"] == pytest.approx(5.0 - full) and m["below_share"] == 1.0 and m["corr"] is None


def test_a_crash_inside_the_horizon_cuts_the_return_and_charges_the_penalty():
    sim, discount = two_cars(), 0.99
    reward = lambda s, terminated: 1.0 - 100.0 * terminated  # noqa: E731
    rows = value_rows(sim, pushed_left(sim, bias=2.0), Constant(0.0), reward, discount, every=1000, horizon=300)
    assert len(rows) == 2  # the first step of each car: full lock leaves the lane well inside 300 steps
    assert (rows[:, 3] < 0).all()  # the penalty, discounted by under 300 steps, outweighs the steps before it
