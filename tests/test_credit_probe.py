"""The credit probe (actors/evaluation/credit_probe.py) reads the critic's slope along the action
and along phi's last steering at the off-centre states, signed towards the centre."""

import numpy as np
import torch

from actors.controllers.kinematic import KinematicController
from actors.envs.sim import LaneDriveSim
from actors.evaluation.credit_probe import credit_rows, summarise
from common.config.env import EnvConfig


def pushed_left(sim: LaneDriveSim, bias: float = 0.08):
    """The kinematic controller steering `bias` to the left, with a phi-shaped feature row per car:
    [alpha, speed, last steering, last target speed]."""
    controller = KinematicController()
    last = np.zeros((sim.n, 2))

    def act(s: LaneDriveSim):
        info = {k: np.array([s.info(i)[k] for i in range(s.n)]) for k in s.info(0)}
        actions = controller.act(info)
        actions[:, 0] = np.clip(actions[:, 0] + bias, -1.0, 1.0)
        x = torch.tensor(np.column_stack([s.alpha, s.v, last]), dtype=torch.float32)
        last[:] = actions
        return x, actions

    return act


class Linear(torch.nn.Module):
    """Q = w_a * steering + w_last * last steering: slopes known everywhere."""

    def __init__(self, w_action: float, w_last: float):
        super().__init__()
        self.w_action, self.w_last = w_action, w_last

    def forward(self, x, a):
        return (self.w_action * a[:, :1] + self.w_last * x[:, -2:-1]).float()


def test_the_probe_reads_each_slope_where_the_critic_puts_it():
    sim = LaneDriveSim(EnvConfig.from_kwargs(lighting=False), 2)
    rng = np.random.default_rng(0)
    for i, d in enumerate(("ccw", "cw")):
        sim.reset(i, rng, {"track": "dune", "direction": d, "random_start": False})
    rows, changes = credit_rows(sim, pushed_left(sim), Linear(0.5, 3.0), every=20, min_offset=0.1)
    m = summarise(rows, changes)
    assert m["states"] >= 10 and (rows[:, 0] > 0).all()  # pushed left, the car sits left of the centre
    # towards the centre is right (-), so more left steering (+) reads as away, on each input at its size
    assert np.allclose(rows[:, 1], -0.5) and np.allclose(rows[:, 2], -3.0)
    assert m["action_to_centre"] == 0.0 and m["last_to_centre"] == 0.0
    assert m["last_slope_abs_median"] == 3.0 and m["action_slope_abs_median"] == 0.5
    assert len(changes) > 100 and 0.0 <= m["steering_change_median"] < 0.1  # a smooth controller
