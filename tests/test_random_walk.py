"""The random-walk pure-pursuit collector (actors/controllers/random_walk.py): paper eqs. 9-12
on hand-made poses, and it keeps a car on the held-out LaneDrive roads with its noise on."""

import math

import numpy as np
import pytest

from actors.controllers.random_walk import RandomWalkPursuit, for_lane_drive, lane_drive_pose
from actors.envs.lane_drive import LaneDriveEnv, LaneDriveVectorEnv
from actors.envs.tracks import track_names

LINE = np.stack([np.arange(0.0, 100.0, 2.0), np.zeros(50)], 1)  # waypoints along +x every 2 m


def controller(k: int = 5, noise: bool = False, seed: int = 0, **kwargs) -> RandomWalkPursuit:
    kwargs = {"scale": 4.0, "radius": 5.0, **kwargs}
    return RandomWalkPursuit(LINE, np.random.default_rng(seed), k=k, noise=noise, **kwargs)


@pytest.mark.parametrize(
    "pose, steer",
    [
        ((0.0, 0.0, 0.0), 0.0),  # target (10, 0) dead ahead
        ((0.0, 10.0, 0.0), -0.5),  # 45 deg to the right: -pi/4 / (pi/2)
        ((10.0, -10.0, 0.0), 1.0),  # 90 deg to the left: the edge of the band
        ((0.0, 0.0, -0.3), 0.3 / (math.pi / 2)),  # heading 0.3 rad right of the target
        ((20.0, 0.5, 0.0), -1.0),  # behind, a little to the right: clipped to -pi/2
        ((20.0, -0.5, 0.0), 1.0),  # behind, a little to the left: clipped to +pi/2
        ((0.0, 0.0, 2 * math.pi - 0.3), 0.3 / (math.pi / 2)),  # yaw wraps
    ],
)
def test_steering_is_the_clipped_angle_to_the_target(pose, steer):
    """Eq. 9: a_steer = clip(angle(p, p*) - theta, -pi/2, pi/2), on the action scale [-1, 1]."""
    assert controller(k=5, radius=0.1).act(pose)[0] == pytest.approx(steer, abs=1e-6)


def test_target_index_advances_once_inside_the_radius_and_after_acting():
    """Eq. 10: k(t+1) = k(t) + 1 when ||p_t - p*_k(t)|| < r; the action at t still aims at p*_k(t)."""
    c = controller(k=5, radius=5.0)  # p*_5 = (10, 0)
    c.act((4.0, 0.0, 0.0))  # 6 m away
    assert c.k == 5
    steer = c.act((10.0, -3.0, 0.0))[0]  # 3 m away: aims at (10, 0), then moves on
    assert steer == pytest.approx(1.0) and c.k == 6
    steer = c.act((10.0, -3.0, 0.0))[0]  # now at p*_6 = (12, 0)
    assert steer == pytest.approx(math.atan2(3.0, 2.0) / (math.pi / 2)) and c.k == 7
    c.act((14.0, 0.0, 0.0))  # inside the radius of several waypoints: still one per step
    assert c.k == 8


def test_waypoints_wrap_around_the_closed_road():
    """Eq. 11: p*_j = p~_(j % N) + eps^p_j."""
    c = controller(k=len(LINE) + 2)
    c.eps_p = np.array([0.1, -0.2])
    np.testing.assert_allclose(c.target(), LINE[2] + 4.0 * np.array([0.1, -0.2]))


def test_random_walks_step_by_the_papers_noise_and_are_clipped():
    """Eqs. 11-12: eps^p += N(0, 0.02) clipped to +-0.3 m, from 0; v* += N(0, 0.02) kept in [0.2, 0.5], from 0.35."""
    c = controller(k=0, noise=True, seed=3)
    assert np.all(c.eps_p == 0.0) and c.v_star == 0.35
    eps, v = [], []
    for _ in range(20000):
        c.advance()
        eps.append(c.eps_p.copy())
        v.append(c.v_star)
    eps, v = np.array(eps), np.array(v)
    assert c.k == 20000
    assert np.abs(eps).max() <= 0.3 and np.abs(eps).max() > 0.29  # reaches the clip, never passes it
    assert v.min() >= 0.2 and v.max() <= 0.5 and v.min() < 0.21 and v.max() > 0.49
    far = np.all(np.abs(eps[:-1]) < 0.24, axis=1)  # 3 sigma inside the clip: steps there are unclipped
    assert np.std(np.diff(eps, axis=0)[far]) == pytest.approx(0.02, rel=0.05)
    v_far = (v[:-1] > 0.26) & (v[:-1] < 0.44)
    assert np.std(np.diff(v)[v_far]) == pytest.approx(0.02, rel=0.05)


@pytest.mark.parametrize(
    "v_star, band, speed",
    [(0.35, (-1.0, 1.0), 0.0), (0.2, (-1.0, 1.0), -1.0), (0.5, (-1.0, 1.0), 1.0), (0.9, (-1.0, 1.0), 1.0)]
    + [(-1.0, (-1.0, 1.0), -1.0), (0.35, (-1.0, -0.6), -0.8), (0.9, (-1.0, -0.6), -0.6)],
)
def test_speed_is_the_clipped_random_walk_on_the_action_band(v_star, band, speed):
    """Eq. 9: a_speed = clip(v*, 0.2, 0.5), mapped onto the target-speed action band."""
    c = controller(speed_actions=band)
    c.v_star = v_star
    assert c.act((0.0, 0.0, 0.0))[1] == pytest.approx(speed)


def _drive(env, noise: bool, steps: int) -> tuple[list, list]:
    c = for_lane_drive(env, np.random.default_rng(1), noise=noise)
    alphas, actions = [], []
    for _ in range(steps):
        action = c.act(lane_drive_pose(env))
        _, _, terminated, truncated, info = env.step(action)
        assert not terminated and not truncated, (info["track"], info["steps"], info["alpha"])
        alphas.append(abs(info["alpha"]))
        actions.append(action)
    assert info["progress"] > 0.35  # it drives along the road, not in circles
    return alphas, actions


def test_the_collector_stays_on_every_held_out_road_and_explores():
    noisy, quiet, actions, noisy_speeds = [], [], [], []
    for track in track_names("test"):
        for direction in ("ccw", "cw"):
            env = LaneDriveEnv(track=track, direction=direction, lighting=False)
            for noise in (True, False):
                env.reset(seed=0)  # a random start, the same for both
                alphas, acts = _drive(env, noise, 300)
                (noisy if noise else quiet).extend(alphas)
                actions += acts
                noisy_speeds += [a[1] for a in acts] if noise else []
    actions = np.array(actions)
    assert np.all(np.abs(actions) <= 1.0)
    assert np.mean(noisy) > 1.1 * np.mean(quiet)  # the random walk takes it off the centreline
    assert np.std(noisy_speeds) > 0.05  # so does its target speed


def test_one_collector_per_car_of_a_vector_env():
    envs = LaneDriveVectorEnv(2, track="test", lighting=False)
    envs.reset(seed=5)
    cs = [for_lane_drive(envs, np.random.default_rng(i), i=i) for i in range(2)]
    for i, c in enumerate(cs):  # the first target: the first waypoint of car i's road a lookahead ahead
        assert c.radius <= np.linalg.norm(c.target() - lane_drive_pose(envs, i)[:2]) < c.radius + 2.5
    for _ in range(100):
        actions = np.stack([c.act(lane_drive_pose(envs, i)) for i, c in enumerate(cs)])
        _, _, terminated, truncated, _ = envs.step(actions)
        assert not (terminated | truncated).any()
