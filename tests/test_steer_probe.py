"""The steering probe (actors/evaluation/steer_probe.py): branches of the simulator drive on
independently, and the true slope of a controller that holds an offset points to the centre."""

import dataclasses

import numpy as np
import pytest

from actors.controllers.kinematic import KinematicController
from actors.envs.sim import LaneDriveSim
from actors.evaluation.steer_probe import ddpg_reward, probe_drives, summarise
from common.config.env import EnvConfig
from tests.core_fixtures import TINY


def sim_on(track: str, directions=("ccw", "cw")) -> LaneDriveSim:
    sim = LaneDriveSim(EnvConfig.from_kwargs(lighting=False), len(directions))
    rng = np.random.default_rng(0)
    for i, d in enumerate(directions):
        sim.reset(i, rng, {"track": track, "direction": d, "random_start": False})
    return sim


def test_a_branch_drives_on_without_touching_the_sim_and_matches_it_on_the_same_actions():
    sim = sim_on("dune")
    for _ in range(5):
        sim.step(np.array([[0.2, 0.5], [-0.1, 0.0]]))
    before = {k: v.copy() for k, v in vars(sim).items() if isinstance(v, np.ndarray)}
    b = sim.branch()
    swerve = np.array([[1.0, 1.0], [-1.0, 1.0]])
    for _ in range(10):
        b.step(swerve)
    assert all(np.array_equal(before[k], getattr(sim, k)) for k in before)  # the original untouched
    assert not np.allclose(b.x, sim.x)
    again = sim.branch()
    for _ in range(10):
        sim.step(swerve)
        again.step(swerve)
    for k in ("x", "y", "theta", "v", "alpha", "frames", "travelled"):
        assert np.array_equal(getattr(sim, k), getattr(again, k)), k


def biased_controller(bias: float):
    """The kinematic controller with its steering pushed to one side: it holds an offset there."""
    controller = KinematicController()

    def act(sim: LaneDriveSim):
        info = {k: np.array([sim.info(i)[k] for i in range(sim.n)]) for k in sim.info(0)}
        actions = controller.act(info)
        actions[:, 0] = np.clip(actions[:, 0] + bias, -1.0, 1.0)
        return None, actions

    return act


def test_steering_to_the_centre_pays_for_a_controller_that_holds_an_offset_and_the_critic_is_read_as_given():
    reward = lambda sim, terminated: sim.reward - 10.0 * terminated  # noqa: E731
    left = lambda features, actions: np.ones(len(actions))  # a critic that always wants more left steering  # noqa: E731
    rows = probe_drives(
        sim_on("dune"), biased_controller(0.08), left, reward, 0.99, every=60, horizon=150, min_offset=0.1
    )
    m = summarise(rows)
    assert m["states"] >= 10 and m["mean_abs_alpha"] >= 0.1
    assert (rows[:, 0] > 0).all()  # pushed left, the car holds its offset left of the centre
    assert m["true_to_centre"] >= 0.9  # a nudge to the centre pays while the controller drifts back
    assert m["critic_to_centre"] == 0.0 and m["agree"] == pytest.approx(1.0 - m["true_to_centre"])
    assert m["true_slope_median"] > 0 and m["critic_slope_median"] == -1.0  # more left is away


def test_no_off_centre_state_no_rows():
    reward = lambda sim, terminated: sim.reward  # noqa: E731
    rows = probe_drives(sim_on("dune", ("ccw",)), biased_controller(0.0), None, reward, 0.99, every=60, min_offset=0.9)
    assert rows.shape == (0, 3) and summarise(rows) == {"states": 0}


def test_the_probes_reward_is_the_envs_with_the_offset_weighted_and_the_crash_charged():
    sim = sim_on("dune")
    for _ in range(20):
        terminated, _ = sim.step(np.array([[0.4, 1.0], [0.0, 1.0]]))
    assert abs(sim.alpha[0]) > 0.05  # off the centre: the offset term matters
    paper = ddpg_reward(TINY, sim.cfg.vehicle.v_max)
    assert np.allclose(paper(sim, terminated), sim.reward)
    weighted = ddpg_reward(dataclasses.replace(TINY, offset_weight=3.0, crash_penalty=5.0), sim.cfg.vehicle.v_max)
    # LaneDrive's reward with the offset term weighted: v/v_max (cos beta - 3 |alpha|), less 5 on a lane exit
    expected = sim.v / sim.cfg.vehicle.v_max * (np.cos(sim.beta) - 3 * np.abs(sim.alpha))
    assert np.allclose(weighted(sim, np.array([False, True])), expected - [0.0, 5.0])


def test_a_branch_shares_only_what_never_changes():
    sim = sim_on("dune")
    b = sim.branch()
    shared = {name for name, value in vars(sim).items() if getattr(b, name) is value}
    assert shared <= {"cfg", "n", "camera", "half"}  # every mutable piece of state is the branch's own


def test_twin_slopes_are_read_each_and_their_mean_where_they_disagree():
    # twin 1 wants more left steering, twin 2 twice as much right: the car pushed left of the centre
    twins = lambda features, actions: np.tile([1.0, -2.0], (len(actions), 1))  # noqa: E731
    reward = lambda sim, terminated: sim.reward - 10.0 * terminated  # noqa: E731
    rows = probe_drives(
        sim_on("dune"), biased_controller(0.08), twins, reward, 0.99, every=60, horizon=150, min_offset=0.1
    )
    m = summarise(rows)
    assert rows.shape[1] == 4 and m["states"] >= 10
    assert m["critic_to_centre"] == 0.0 and m["twin2_to_centre"] == 1.0 and m["twins_agree"] == 0.0
    assert m["mean_to_centre"] == 1.0 and m["mean_where_it_pays"] == 1.0  # the mean (+0.5 to the centre) follows twin 2
