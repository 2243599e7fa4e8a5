"""actors.evaluation.offset_probe: a controller without the bend's feed-forward holds its offset on
the outside of the bends; the kinematic controller, with it, does not."""

import numpy as np

from actors.evaluation.offset_probe import offsets
from actors.evaluation.policies import kinematic_policy
from common.config.env import VehicleConfig


def without_feed_forward(policy, vehicle=VehicleConfig()):
    """The kinematic controller less its curvature feed-forward: it steers on alpha and beta alone."""

    def act(obs, info):
        action = policy(obs, info).copy()
        action[:, 0] -= np.arctan(vehicle.wheelbase * np.asarray(info["curvature"])) / vehicle.max_steer
        return np.clip(action, -1.0, 1.0)

    return act


def test_the_offset_without_feed_forward_sits_on_the_outside_of_the_bends():
    roads = {"tracks": ["sage", "moor"]}
    with_ff = offsets(kinematic_policy(), **roads)
    without = offsets(without_feed_forward(kinematic_policy()), **roads)
    assert with_ff["laps"] == 4 and abs(with_ff["bend_outside_alpha"]) < 0.05
    assert without["bend_outside_alpha"] > with_ff["bend_outside_alpha"] + 0.1
    assert without["bend_outside_alpha"] > without["straight_abs_alpha"]  # the bends, not the straights


def keeping_left(policy, offset: float):
    """`policy` told the car is `offset` further right than it is: it centres that, `offset` left."""

    def act(obs, info):
        return policy(obs, {**info, "alpha": np.asarray(info["alpha"]) - offset})

    return act


def test_a_steering_bias_keeps_the_same_side_in_both_directions_and_the_controller_none():
    roads = {"tracks": ["sage"]}
    centred = offsets(kinematic_policy(), **roads)
    biased = offsets(keeping_left(kinematic_policy(), 0.3), **roads)
    assert set(centred["side_alpha"]) == {"ccw", "cw"}
    assert all(abs(v) < 0.05 for v in centred["side_alpha"].values())
    assert all(v > 0.2 for v in biased["side_alpha"].values())  # left whichever way it drives
