"""BCQ's networks (Fujimoto, Meger and Precup 2019) with the paper's sizes (appendix "GVF-BCQ
Training", "End-to-end BCQ Baseline Training"), shared by the offline learner (`learner.bcq`,
the losses) and the evaluator (which drives `BCQPolicy` from a gvf-offline checkpoint).

- `VAE` G_omega(a|s): (s, a) -> 256 -> mean, log std of z (d_z = 4); (s, z) -> 256 -> a.
  Sampling draws z ~ N(0, 1) clipped to [-0.5, 0.5] (BCQ), the action clipped to the box.
- `Perturbation` xi_phi(s, a, Phi): (s, a) -> 256 -> Phi * tanh(.), Phi = 0.05; a + xi clipped
  to [-1, 1]^2.
- `TwinQ` Q1, Q2: (s, a) -> 256 -> 1 each.
- `BCQPolicy`: n = 10 actions a~ ~ G(s) perturbed by xi, the argmax of Q1.

Each network reads its state through a `state` module: the identity on GVF-BCQ's flat phi(s),
or for E2E-BCQ an `ImageState`, the GVF network's PilotNet trunk with speed and last action
joined after it ("the encoding branch of the VAE, the actor and critic networks use the same
architecture as the prediction model"; the VAE's decoder reads the VAE's trunk). Each network
encodes a state once and repeats the features for its n sampled actions (`n`), which keeps
E2E-BCQ's n = 10 samples from costing 10 trunk passes.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor, nn

from common.layers import ACTION_DIM, IMAGE_SHAPE, LOW_DIM, PilotNetTrunk, mlp

HIDDEN = (256,)
IMAGE_SIZE = IMAGE_SHAPE[0] * IMAGE_SHAPE[1] * IMAGE_SHAPE[2]
E2E_STATE_DIM = IMAGE_SIZE + LOW_DIM  # E2E-BCQ's flat observation: pixels (0-255), speed, last action


class ImageState(nn.Module):
    """E2E-BCQ's state module: a flat observation [pixels of the 2 frames, speed, last action] ->
    [PilotNet features, speed, last action]."""

    def __init__(self, channels: Sequence[int]):
        super().__init__()
        self.trunk = PilotNetTrunk(channels)
        self.out_dim = self.trunk.out_dim + LOW_DIM

    def forward(self, s: Tensor) -> Tensor:
        image = s[..., :IMAGE_SIZE].reshape(-1, *IMAGE_SHAPE)
        return torch.cat([self.trunk(image), s[..., IMAGE_SIZE:].reshape(-1, LOW_DIM)], -1)


def flat_observation(image: Tensor, speed: Tensor, last_action: Tensor) -> Tensor:
    """E2E-BCQ's flat observation (B, E2E_STATE_DIM) from uint8 frames, speed and last action."""
    return torch.cat([image.reshape(image.shape[0], -1).float(), speed, last_action], -1)


def _features(state: nn.Module, s: Tensor, n: int) -> Tensor:
    f = state(s)
    return f.repeat_interleave(n, 0) if n > 1 else f


class VAE(nn.Module):
    """State-conditioned generative model of the data's actions, G_omega(a|s)."""

    def __init__(self, state_dim: int, action_dim: int = ACTION_DIM, latent_dim: int = 4, hidden=HIDDEN, state=None):
        super().__init__()
        self.latent_dim = latent_dim
        self.state = state if state is not None else nn.Identity()
        self.encoder = mlp(state_dim + action_dim, hidden, 2 * latent_dim)  # mean, log std
        self.decoder = mlp(state_dim + latent_dim, hidden, action_dim)

    def forward(self, s: Tensor, a: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """Reconstruction (unclipped, so the loss keeps its gradient at the box edge), mean, std."""
        f = self.state(s)
        mean, log_std = self.encoder(torch.cat([f, a], -1)).chunk(2, -1)
        std = log_std.clamp(-4.0, 15.0).exp()  # BCQ's clamp, for numerical stability
        z = mean + std * torch.randn_like(std)
        return self.decoder(torch.cat([f, z], -1)), mean, std

    def decode(self, s: Tensor, n: int = 1) -> Tensor:
        """n samples a ~ G(s) per state, (B * n, d_a): z ~ N(0, 1) clipped to [-0.5, 0.5] keeps them near the data."""
        f = _features(self.state, s, n)
        z = torch.randn(f.shape[0], self.latent_dim, device=f.device, dtype=f.dtype).clamp(-0.5, 0.5)
        return self.decoder(torch.cat([f, z], -1)).clamp(-1.0, 1.0)


class Perturbation(nn.Module):
    """xi_phi(s, a, Phi): moves a generated action by at most Phi (BCQ's Phi, not the representation phi)."""

    def __init__(self, state_dim: int, action_dim: int = ACTION_DIM, Phi: float = 0.05, hidden=HIDDEN, state=None):
        super().__init__()
        self.Phi = Phi
        self.state = state if state is not None else nn.Identity()
        self.net = mlp(state_dim + action_dim, hidden, action_dim)

    def forward(self, s: Tensor, a: Tensor, n: int = 1) -> Tensor:
        """a (B * n, d_a) for states s (B, ...)."""
        xi = self.Phi * torch.tanh(self.net(torch.cat([_features(self.state, s, n), a], -1)))
        return (a + xi).clamp(-1.0, 1.0)


class TwinQ(nn.Module):
    """Two critic heads on one state module; forward gives (B * n, 2) = [Q1, Q2]."""

    def __init__(self, state_dim: int, action_dim: int = ACTION_DIM, hidden=HIDDEN, state=None):
        super().__init__()
        self.state = state if state is not None else nn.Identity()
        self.q1_net = mlp(state_dim + action_dim, hidden, 1)
        self.q2_net = mlp(state_dim + action_dim, hidden, 1)

    def forward(self, s: Tensor, a: Tensor, n: int = 1) -> Tensor:
        x = torch.cat([_features(self.state, s, n), a], -1)
        return torch.cat([self.q1_net(x), self.q2_net(x)], -1)

    def q1(self, s: Tensor, a: Tensor, n: int = 1) -> Tensor:
        return self.q1_net(torch.cat([_features(self.state, s, n), a], -1)).squeeze(-1)


def select_action(vae: VAE, actor: Perturbation, critic: TwinQ, s: Tensor, n: int) -> Tensor:
    """BCQ's action for states (B, d): n perturbed samples of G each, the argmax of Q1."""
    a = actor(s, vae.decode(s, n), n)
    best = critic.q1(s, a, n).view(-1, n).argmax(-1)
    return a.view(s.shape[0], n, -1)[torch.arange(s.shape[0]), best]


class BCQPolicy(nn.Module):
    """The acting network of a BCQ learner: `forward(s)` for one state (d,) or a batch (B, d)."""

    def __init__(self, vae: VAE, actor: Perturbation, critic: TwinQ, n_samples: int = 10):
        super().__init__()
        self.vae, self.actor, self.critic, self.n_samples = vae, actor, critic, n_samples

    @torch.no_grad()
    def forward(self, state: Tensor) -> Tensor:
        s = state.reshape(-1, state.shape[-1])
        a = select_action(self.vae, self.actor, self.critic, s, self.n_samples)
        return a.reshape(*state.shape[:-1], a.shape[-1])


def make_bcq_networks(
    state_dim: int,
    *,
    image_channels: Sequence[int] | None = None,
    action_dim: int = ACTION_DIM,
    hidden=HIDDEN,
    latent_dim: int = 4,
    Phi: float = 0.05,
) -> tuple[VAE, Perturbation, TwinQ]:
    """G, xi and the twin Q on a flat state of `state_dim` (GVF-BCQ), or with `image_channels` on
    E2E-BCQ's flat observation, each with its own PilotNet trunk (`state_dim` is then ignored)."""
    if image_channels is None:
        return (
            VAE(state_dim, action_dim, latent_dim, hidden),
            Perturbation(state_dim, action_dim, Phi, hidden),
            TwinQ(state_dim, action_dim, hidden),
        )
    states = [ImageState(image_channels) for _ in range(3)]
    dim = states[0].out_dim
    return (
        VAE(dim, action_dim, latent_dim, hidden, state=states[0]),
        Perturbation(dim, action_dim, Phi, hidden, state=states[1]),
        TwinQ(dim, action_dim, hidden, state=states[2]),
    )
