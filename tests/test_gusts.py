"""`env.gust_rate`: heading kicks during training drives (recoveries stay in the replay); no
evaluation drive gusts, and a bad setting is refused naming the field."""

import numpy as np
import pytest

from actors.envs.sim import LaneDriveSim
from actors.evaluation.evaluate import evaluate
from actors.evaluation.policies import kinematic_policy
from common.config.env import EnvConfig


def headings(gust_rate: float, seed: int = 0, steps: int = 30) -> np.ndarray:
    """Heading changes of a car on dune with its wheels straight, at the slowest speed: only gusts turn it."""
    sim = LaneDriveSim(EnvConfig.from_kwargs(lighting=False, gust_rate=gust_rate, gust_yaw=0.1), 1)
    sim.reset(0, np.random.default_rng(seed), {"track": "dune", "direction": "ccw", "random_start": False})
    out = []
    for _ in range(steps):
        before = sim.theta.copy()
        sim.step(np.array([[0.0, -1.0]]))
        out.append(float(sim.theta[0] - before[0]))
    return np.array(out)


def test_gusts_kick_the_heading_within_their_size_and_follow_the_seed():
    calm, gusty = headings(0.0), headings(1.0)
    assert np.allclose(calm, 0.0, atol=1e-9)  # straight road, straight wheels: no turn without gusts
    assert np.all(np.abs(gusty) <= 0.1 + 1e-9) and np.abs(gusty).mean() > 0.02
    assert np.array_equal(gusty, headings(1.0)) and not np.array_equal(gusty, headings(1.0, seed=1))
    rare = headings(0.1, steps=200)
    assert 5 <= np.count_nonzero(rare) <= 40  # about one step in ten


def test_evaluation_drives_never_gust():
    roads = {"tracks": ["sage"], "directions": ("ccw",)}
    calm = evaluate(kinematic_policy(), **roads)
    gusty = evaluate(kinematic_policy(), **roads, gust_rate=1.0, gust_yaw=0.5)
    assert np.array_equal(calm[0]["trace"]["alpha"], gusty[0]["trace"]["alpha"])


@pytest.mark.parametrize(
    "kwargs, field",
    [
        ({"gust_rate": 1.5}, "env.gust_rate"),
        ({"gust_yaw": 0.8}, "env.gust_yaw"),
        ({"gust_rate": -0.1}, "env.gust_rate"),
    ],
)
def test_a_bad_gust_is_refused_naming_the_field(kwargs, field):
    with pytest.raises(ValueError, match=field):
        EnvConfig.from_kwargs(**kwargs)


def test_torcs_refuses_gusts():
    with pytest.raises(ValueError, match="env.gust_rate"):
        EnvConfig.from_kwargs(id="TorcsDrive-v0", track="test", gust_rate=0.1)
