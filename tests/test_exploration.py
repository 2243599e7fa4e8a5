"""OU exploration noise (actors/exploration.py): the paper's parameters give the known
stationary spread and autocorrelation, and resets are per environment."""

import numpy as np

from actors.acting import ou_parameters
from actors.exploration import OrnsteinUhlenbeck
from common.config.run import ActorConfig


def test_stationary_std_and_autocorrelation_match_theory():
    # theta=1, sigma=0.1, dt=0.01: std sigma/sqrt(2 theta) = 0.0707, lag-k corr (1-theta dt)^k
    ou = OrnsteinUhlenbeck(2000, 2, theta=1.0, sigma=0.1, dt=0.01, seed=0)
    for _ in range(1000):  # 10 relaxation times: stationary
        ou.sample()
    x0 = ou.sample()
    for _ in range(49):
        ou.sample()
    x50 = ou.sample()
    std = x0.std()
    corr = float(np.corrcoef(x0.ravel(), x50.ravel())[0, 1])
    # 4000 samples: std of the std estimate ~1.1%, of the correlation ~0.01
    assert abs(std - 0.1 / np.sqrt(2.0)) < 0.004, std
    assert abs(corr - 0.99**50) < 0.04, corr
    assert abs(x0.mean()) < 0.005


def test_theta_dt_of_one_makes_the_noise_white_with_std_sigma_sqrt_dt():
    ou = OrnsteinUhlenbeck(2000, 2, theta=100.0, sigma=0.75, dt=0.01, seed=0)
    x0, x1 = ou.sample(), ou.sample()
    assert abs(x0.std() - 0.075) < 0.004, x0.std()
    assert abs(float(np.corrcoef(x0.ravel(), x1.ravel())[0, 1])) < 0.05  # the next step forgets this one


def test_per_action_parameters_make_the_steering_white_and_leave_the_speed_slow():
    theta, sigma = ou_parameters(ActorConfig(ou_steer_theta=100.0, ou_steer_sigma=0.75))
    ou = OrnsteinUhlenbeck(2000, 2, theta=theta, sigma=sigma, dt=0.01, seed=0)
    for _ in range(1000):
        ou.sample()
    x0, x1 = ou.sample(), ou.sample()
    steer, speed = (float(np.corrcoef(x0[:, k], x1[:, k])[0, 1]) for k in (0, 1))
    assert abs(steer) < 0.07 and speed > 0.97  # white steering; the paper's OU on the target speed
    assert abs(x0[:, 0].std() - 0.075) < 0.006 and abs(x0[:, 1].std() - 0.1 / np.sqrt(2.0)) < 0.006
    assert np.array_equal(ou_parameters(ActorConfig())[0], [1.0, 1.0])  # unset: the shared values


def test_the_target_speed_can_wander_wider_than_the_steering():
    theta, sigma = ou_parameters(ActorConfig(ou_speed_sigma=0.4))
    assert np.array_equal(theta, [1.0, 1.0])
    ou = OrnsteinUhlenbeck(2000, 2, theta=theta, sigma=sigma, dt=0.01, seed=0)
    for _ in range(1000):
        ou.sample()
    x0, x1 = ou.sample(), ou.sample()
    assert abs(x0[:, 0].std() - 0.1 / np.sqrt(2.0)) < 0.006  # the paper's steering noise kept
    assert abs(x0[:, 1].std() - 0.4 / np.sqrt(2.0)) < 0.02  # 1.4 m/s of target speed, the same 10-s wander
    assert float(np.corrcoef(x0[:, 1], x1[:, 1])[0, 1]) > 0.97


def test_reset_restarts_only_the_masked_envs():
    ou = OrnsteinUhlenbeck(4, 2, seed=1)
    for _ in range(100):
        ou.sample()
    before = ou.state.copy()
    mask = np.array([True, False, True, False])
    ou.reset(mask)
    assert np.all(ou.state[mask] == 0.0)
    assert np.array_equal(ou.state[~mask], before[~mask])
    assert np.all(before[mask] != 0.0)
    ou.reset()
    assert np.all(ou.state == 0.0)


def test_sample_returns_a_copy_of_float32_state():
    ou = OrnsteinUhlenbeck(3, 2, seed=2)
    x = ou.sample()
    assert x.dtype == np.float32 and x.shape == (3, 2)
    x[:] = 5.0
    assert not np.any(ou.state == 5.0)
