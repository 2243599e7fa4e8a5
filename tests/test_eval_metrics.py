"""Each evaluation metric on hand-made sequences with known answers."""

import numpy as np
import pytest

from actors.evaluation.metrics import drive_metrics


def test_metrics_on_a_hand_made_drive():
    reward = [1.0, 0.5, 0.0, -0.5]
    speed = [10.0, 12.0, 14.0, 16.0]
    alpha = [0.0, 0.5, -0.8, 0.9]
    beta = [0.1, -0.1, 0.2, -0.2]
    actions = [[0.0, 1.0], [0.2, 1.0], [0.6, 0.5], [0.6, 0.5]]
    m = drive_metrics(reward, speed, alpha, beta, actions, lap_completed=True)
    assert m["reward_per_step"] == pytest.approx(0.25)
    assert m["reward_per_s"] == pytest.approx(2.5)
    assert m["average_speed"] == pytest.approx(13.0)
    assert m["offcenteredness"] == pytest.approx(0.55)
    assert m["abs_road_angle"] == pytest.approx(0.15)
    assert m["near_out_of_lane"] == pytest.approx(0.5)
    # steering changes 0.2, 0.4, 0.0; second differences 0.2, -0.4
    assert m["comfort1_steering"] == pytest.approx(-0.2)
    assert m["comfort2_steering"] == pytest.approx(-0.3)
    assert m["jerkiness_angular"] == pytest.approx(np.std([0.2, 0.4, 0.0]))
    # speed action changes 0, -0.5, 0; second differences -0.5, 0.5
    assert m["comfort1_speed"] == pytest.approx(-0.5 / 3)
    assert m["comfort2_speed"] == pytest.approx(-0.5)
    assert m["jerkiness_longitudinal"] == pytest.approx(np.std([0.0, -0.5, 0.0]))
    assert (m["episode_length"], m["lap_completed"]) == (4, 1.0)


def test_constant_actions_are_perfectly_comfortable():
    m = drive_metrics([1.0] * 5, [10.0] * 5, [0.0] * 5, [0.0] * 5, [[0.3, -0.2]] * 5, lap_completed=False)
    assert m["comfort1_steering"] == m["comfort2_speed"] == m["jerkiness_angular"] == 0.0
    assert m["lap_completed"] == 0.0


def test_empty_drive_is_refused():
    with pytest.raises(ValueError, match="at least one step"):
        drive_metrics([], [], [], [], np.zeros((0, 2)), False)


def test_reward_per_second_follows_the_control_rate():
    drive = ([1.0, 0.5], [10.0] * 2, [0.0] * 2, [0.0] * 2, [[0.0, 0.0]] * 2, True)
    assert drive_metrics(*drive)["reward_per_s"] == pytest.approx(7.5)  # 10 Hz, the paper's
    assert drive_metrics(*drive, control_hz=5.0)["reward_per_s"] == pytest.approx(3.75)  # env.vehicle.dt=0.2
