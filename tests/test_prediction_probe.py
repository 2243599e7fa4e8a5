"""The predictions' steering probe (actors/evaluation/prediction_probe.py): the held-steering
returns are the simulator's, holding more left steering raises the offset, and a GVF's slope is
read with its sign."""

import numpy as np
import torch
from torch import nn

from actors.evaluation.prediction_probe import held_returns, probe_drives, summarise
from tests.test_steer_probe import biased_controller, sim_on

GAMMAS = np.array([0.0, 0.5, 0.9, 0.95, 0.97])


def test_held_returns_leave_the_sim_alone_and_gamma_zero_is_the_next_offset():
    sim, act = sim_on("dune"), biased_controller(0.0)
    for _ in range(20):
        sim.step(act(sim)[1])
    before = sim.alpha.copy()
    held = act(sim)[1]
    returns = held_returns(sim, held, GAMMAS, horizon=300)
    assert np.array_equal(sim.alpha, before)
    b = sim.branch()
    terminated, _ = b.step(held)
    assert not terminated.any() and np.allclose(returns[:, 0], b.alpha)
    assert np.all(returns[:, 1] != returns[:, 0])  # longer horizons read later steps


class SlopedGVF(nn.Module):
    """Every alpha prediction is `slope` x the last steering; beta's are 0."""

    def __init__(self, slope: float):
        super().__init__()
        self.slope = slope

    def forward(self, image, speed, last_action):
        alpha = self.slope * last_action[:, :1].expand(-1, len(GAMMAS))
        return torch.cat([alpha, torch.zeros_like(alpha)], -1)


def test_holding_more_left_steering_raises_the_offset_and_the_gvf_slope_is_read_with_its_sign():
    rows = {}
    for slope in (1.0, -1.0):
        sim = sim_on("dune")
        rows[slope] = probe_drives(
            sim, biased_controller(0.08), SlopedGVF(slope), GAMMAS, slice(0, 5), every=60, min_offset=0.1
        )
    assert len(rows[1.0]) >= 5
    right, wrong = summarise(rows[1.0], GAMMAS), summarise(rows[-1.0], GAMMAS)
    for gamma in ("0.5", "0.9", "0.97"):  # steering left (+) moves alpha up, over any short horizon
        assert right[gamma]["true_positive"] > 0.9, right[gamma]
        assert right[gamma]["sign_agrees"] > 0.9 and wrong[gamma]["sign_agrees"] < 0.1
        assert right[gamma]["gvf_median"] == 1.0
