"""Behaviour estimation (learner/behaviour.py): the density ratio trick recovers a known
behaviour density mu(a|s) (paper eqs. 6-7, Algorithm 1 lines 15-17)."""

import math

import pytest
import torch
from torch import nn

from common.networks import BehaviourNetwork
from learner.behaviour import behaviour_loss, log_eta, log_mu_hat, relabel_half, sample_eta
from learner.gvf import log_tau

MU_WIDTH = 0.3  # behaviour: truncated normal around the last action, per dimension


def sample_mu(last_action: torch.Tensor, g: torch.Generator) -> torch.Tensor:
    """Exact truncated-normal samples on [-1, 1] around the last action (by rejection)."""
    a = last_action + MU_WIDTH * torch.randn(last_action.shape, generator=g)
    bad = (a.abs() > 1).any(-1)
    while bad.any():
        a[bad] = last_action[bad] + MU_WIDTH * torch.randn(last_action[bad].shape, generator=g)
        bad = (a.abs() > 1).any(-1)
    return a


def test_eta_is_uniform_on_the_box_and_its_log_density_is_minus_log_4():
    a = sample_eta(40_000, generator=torch.Generator().manual_seed(0))
    assert a.min() >= -1 and a.max() <= 1
    counts = torch.histc(a[:, 0], bins=10, min=-1, max=1)
    assert (counts / 4000 - 1).abs().max() < 0.1
    assert torch.allclose(log_eta(a[:3]), torch.full((3, 1), -math.log(4.0)))


def test_relabel_half_replaces_exactly_half_with_label_zero():
    action = torch.full((64, 2), 5.0)  # outside the box: tells recorded from eta actions
    mixed, z = relabel_half(action, torch.Generator().manual_seed(1))
    assert int(z.sum()) == 32
    recorded = z.reshape(-1).bool()
    assert torch.all(mixed[recorded] == 5.0)
    assert torch.all(mixed[~recorded].abs() <= 1.0)


def test_behaviour_network_depends_on_the_action_and_the_state():
    torch.manual_seed(0)
    g = BehaviourNetwork([4, 4, 4, 4, 4], [16, 8])
    image = torch.randint(0, 255, (3, 2, 64, 128), dtype=torch.uint8)
    speed, last, action = torch.rand(3, 1), torch.zeros(3, 2), torch.zeros(3, 2)
    base = g(image, speed, last, action)
    assert base.shape == (3, 1)
    assert not torch.allclose(base, g(image, speed, last, action + 0.5))
    assert not torch.allclose(base, g(image, speed, last + 0.5, action))


def test_trained_discriminator_recovers_a_known_behaviour_density():
    """mu(a|s) = truncated N(last_action, 0.3^2) per dimension; s = last action.

    Tolerance: on fresh (s, a ~ mu), the median |log mu_hat - log mu| < 0.15 and the mean of
    mu_hat / mu lies within 15% of 1 (a wrong eta normaliser would be off by log 2 = 0.69).
    """
    torch.manual_seed(0)
    g = torch.Generator().manual_seed(0)
    net = nn.Sequential(nn.Linear(4, 64), nn.ReLU(), nn.Linear(64, 64), nn.ReLU(), nn.Linear(64, 1))

    def discriminator(last_action, action):
        return net(torch.cat([last_action, action], -1))

    optimizer = torch.optim.Adam(net.parameters(), lr=3e-3)
    decay = torch.optim.lr_scheduler.LambdaLR(optimizer, lambda step: 1.0 - 0.9 * step / 1500)
    for step in range(1500):
        last = torch.rand(256, 2, generator=g) * 1.6 - 0.8
        optimizer.zero_grad()
        behaviour_loss(discriminator, (last,), sample_mu(last, g), g).backward()
        optimizer.step()
        decay.step()
    last = torch.rand(4000, 2, generator=g) * 1.6 - 0.8
    action = sample_mu(last, g)
    with torch.no_grad():
        estimate = log_mu_hat(discriminator(last, action), action)
    truth = log_tau(action, last, MU_WIDTH)  # same truncated-normal form as tau
    error = (estimate - truth).abs()
    ratio = (estimate - truth).exp()
    print(f"median |log error| {error.median():.3f}, mean ratio {ratio.mean():.3f}")
    assert error.median() < 0.15
    assert abs(float(ratio.mean()) - 1.0) < 0.15


@pytest.mark.slow
def test_behaviour_network_recovers_a_density_that_depends_on_the_image():
    """The real g(a, s): the behaviour mean is drawn as a bright column in the frames.

    Tolerance: median |log mu_hat - log mu| < 0.3 on fresh samples.
    """
    torch.manual_seed(0)
    g = torch.Generator().manual_seed(0)
    net = BehaviourNetwork([8, 12, 16, 16, 16], [64, 32])
    optimizer = torch.optim.Adam(net.parameters(), lr=1e-3)

    def batch(n):
        mean = torch.rand(n, 2, generator=g) * 1.6 - 0.8
        image = torch.zeros(n, 2, 64, 128, dtype=torch.uint8)
        cols = ((mean[:, 0] + 1) / 2 * 120).long()
        rows = ((mean[:, 1] + 1) / 2 * 56).long()
        for i in range(n):  # a bright square at (speed-mean, steer-mean)
            image[i, :, rows[i] : rows[i] + 8, cols[i] : cols[i] + 8] = 255
        return image, torch.zeros(n, 1), torch.zeros(n, 2), mean

    for step in range(2000):
        image, speed, last, mean = batch(128)
        optimizer.zero_grad()
        behaviour_loss(net, (image, speed, last), sample_mu(mean, g), g).backward()
        optimizer.step()
    image, speed, last, mean = batch(1000)
    action = sample_mu(mean, g)
    with torch.no_grad():
        estimate = log_mu_hat(net(image, speed, last, action), action)
    error = (estimate - log_tau(action, mean, MU_WIDTH)).abs()
    print(f"median |log error| {error.median():.3f}")
    assert error.median() < 0.3
