"""Networks of GVF-DDPG and its baselines (paper, appendix "GVF-DDPG Training" and
"Baseline DDPG Training"), shared by the learner and the actors.

- `PilotNetTrunk` (common/layers.py): Bojarski et al. 2016 conv layers on the two frames.
- `GVFNetwork` v^tau(s): trunk, then [features, speed, last action] -> FC 512, 384 -> one
  linear output per (cumulant, gamma), cumulant-major (all gammas of alpha, then of beta).
- `BehaviourNetwork` g(a, s): same trunk, [features, speed, last action, action] -> FC 512,
  256 -> 1 logit; g = sigmoid(logit), so g / (1 - g) = exp(logit) (paper eq. 6).
- `BranchedActor`: one branch per action (steering, target speed), FC 256, 128, 1 each; the
  last layer of each branch U(-1e-3, 1e-3), bias 0; linear output clipped to [-1, 1].
- `BranchedCritic`, `AdvantageCritic` (common/critics.py): Q from [x, a], branch outputs summed.
- DDPG-Image / DDPG-LowDim: `ImageEncoder` (trunk + speed + last action, and for LowDim
  alpha, beta through a 12-unit ReLU branch) under a `BranchedActor` (512, 256 branches)
  or a one-branch `BranchedCritic` (512, 256, 1), as the appendix describes.

`make_networks` builds what the learner trains; `make_policy` builds only the acting
network, whose `state_dict` is what the learner broadcasts to the actors.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import torch
from torch import Tensor, nn

from common.config.agent import REPRESENTATIONS, SQUASHES, AgentConfig, ScaleConfig, actor_squash
from common.critics import AdvantageCritic, BranchedCritic
from common.layers import ACTION_DIM, LOW_DIM, PilotNetTrunk, mlp


class GVFNetwork(nn.Module):
    """v^tau(s; theta): one prediction per (cumulant, gamma) from frames, speed, last action.

    `odd` makes every prediction odd under the left-right mirror by construction, v(s) = (f(s) -
    f(Ms)) / 2 with Ms the frames flipped and the last steering negated: alpha and beta negate under
    the mirror and tau mirrors with the last action, so the true values are odd; learned without it
    they are odd only as far as the mirrored minibatches taught them. A buffer, so that a checkpoint
    made without it is refused."""

    def __init__(self, channels: Sequence[int], hidden: Sequence[int], n_predictions: int, odd: bool = False):
        super().__init__()
        self.trunk = PilotNetTrunk(channels)
        self.head = mlp(self.trunk.out_dim + LOW_DIM, hidden, n_predictions)
        self.n_predictions = n_predictions
        self.register_buffer("mirror_last", torch.tensor([-1.0, 1.0]) if odd else None)

    @staticmethod
    def head_input(features: Tensor, speed: Tensor, last_action: Tensor) -> Tensor:
        return torch.cat([features, speed, last_action], -1)

    def features_and_values(self, image: Tensor, speed: Tensor, last_action: Tensor) -> tuple[Tensor, Tensor]:
        """The trunk's features and the predictions of one pass without the mirror (learner.offset_steer)."""
        features = self.trunk(image)
        return features, self.head(self.head_input(features, speed, last_action))

    def _raw(self, image: Tensor, speed: Tensor, last_action: Tensor) -> Tensor:
        return self.features_and_values(image, speed, last_action)[1]

    def forward(self, image: Tensor, speed: Tensor, last_action: Tensor) -> Tensor:
        if self.mirror_last is None:
            return self._raw(image, speed, last_action)
        both = self._raw(  # one pass over the batch and its mirror image
            torch.cat([image, image.flip(-1)]),
            torch.cat([speed, speed]),
            torch.cat([last_action, last_action * self.mirror_last]),
        )
        direct, mirrored = both.chunk(2)
        return (direct - mirrored) * 0.5


class BehaviourNetwork(nn.Module):
    """Discriminator g(a, s) as a logit: sigmoid(logit) = P(a came from mu, not eta)."""

    def __init__(self, channels: Sequence[int], hidden: Sequence[int]):
        super().__init__()
        self.trunk = PilotNetTrunk(channels)
        self.head = mlp(self.trunk.out_dim + LOW_DIM + ACTION_DIM, hidden, 1)

    def forward(self, image: Tensor, speed: Tensor, last_action: Tensor, action: Tensor) -> Tensor:
        return self.head(torch.cat([self.trunk(image), speed, last_action, action], -1))


def _init_last_layer(branch: nn.Sequential) -> None:
    # paper: "in order to not bias the replay buffer", near-zero initial actions
    nn.init.uniform_(branch[-1].weight, -1e-3, 1e-3)
    nn.init.zeros_(branch[-1].bias)


class BranchedActor(nn.Module):
    """pi(x): one MLP branch per action dimension, linear output squashed to [-1, 1].

    `mirror_sign` (in_dim,), if given, makes pi mirror-equivariant by construction: with M = diag
    (mirror_sign), the steering output is (f(x) - f(Mx)) / 2 and the target speed (g(x) + g(Mx)) / 2,
    so pi(Mx) is pi(x) with the steering negated and x = Mx (a centred car on a straight road) steers
    exactly 0. It is a buffer, so an actor built without it refuses these weights.

    `speed_init` in (-1, 1) is the speed branch's initial output (its last bias, through the squash):
    0, the paper's near-zero initial actions; below 0 the first drives are slower (`scale.actor_speed_init`).

    `steer_increment` > 0 makes the steering integrate: x's last two entries are the last action
    (phi's layout), and the steering is clip(last steering + steer_increment * out, -1, 1), so a
    weak feedback gain still removes a bend's steady-state offset (docs/results.md "Lever IS").
    Also a buffer; odd under the mirror as both terms are.
    """

    def __init__(
        self,
        in_dim: int,
        hidden: Sequence[int],
        n_actions: int = ACTION_DIM,
        squash: str = "clip",
        mirror_sign: Tensor | None = None,
        steer_increment: float = 0.0,
        speed_init: float = 0.0,
    ):
        super().__init__()
        if squash not in SQUASHES:
            raise ValueError(f"squash must be one of {SQUASHES}, got {squash!r}")
        if not -1.0 < speed_init < 1.0:
            raise ValueError(
                f"speed_init must be in (-1, 1) (the clip passes no gradient at its ends), got {speed_init}"
            )
        self.branches = nn.ModuleList(mlp(in_dim, hidden, 1) for _ in range(n_actions))
        for branch in self.branches:
            _init_last_layer(branch)
        if n_actions > 1:  # the bias that squashes to speed_init
            bias = speed_init if squash == "clip" else math.atanh(speed_init)
            nn.init.constant_(self.branches[1][-1].bias, bias)
        self.squash = squash
        if mirror_sign is not None and mirror_sign.shape != (in_dim,):
            raise ValueError(f"mirror_sign must have shape ({in_dim},), got {tuple(mirror_sign.shape)}")
        self.register_buffer("mirror_sign", None if mirror_sign is None else mirror_sign.float().clone())
        if steer_increment < 0:
            raise ValueError(f"steer_increment must be >= 0, got {steer_increment}")
        increment = (
            torch.tensor([float(steer_increment)]) if steer_increment > 0 else None
        )  # (1,): the wire keeps no 0-d arrays
        self.register_buffer("steer_increment", increment)

    def _raw(self, x: Tensor) -> Tensor:
        return torch.cat([branch(x) for branch in self.branches], -1)

    def forward(self, x: Tensor) -> Tensor:
        out = self._raw(x)
        if self.mirror_sign is not None:
            mirrored = self._raw(x * self.mirror_sign)
            out = torch.cat([out[..., :1] - mirrored[..., :1], out[..., 1:] + mirrored[..., 1:]], -1) * 0.5
        out = out.clamp(-1.0, 1.0) if self.squash == "clip" else torch.tanh(out)
        if self.steer_increment is not None:
            steer = (x[..., -2:-1] + self.steer_increment * out[..., :1]).clamp(-1.0, 1.0)
            out = torch.cat([steer, out[..., 1:]], -1)
        return out


class ImageEncoder(nn.Module):
    """DDPG-Image input [trunk(frames), speed, last action]; LowDim adds a 12-unit (alpha, beta) branch."""

    def __init__(self, channels: Sequence[int], lowdim_width: int = 0):
        super().__init__()
        self.trunk = PilotNetTrunk(channels)
        self.lowdim = nn.Sequential(nn.Linear(2, lowdim_width), nn.ReLU()) if lowdim_width else None
        self.out_dim = self.trunk.out_dim + LOW_DIM + lowdim_width

    def forward(self, image: Tensor, speed: Tensor, last_action: Tensor, lowdim: Tensor | None = None) -> Tensor:
        parts = [self.trunk(image), speed, last_action]
        if self.lowdim is not None:
            parts.append(self.lowdim(lowdim))
        return torch.cat(parts, -1)


class ImageActor(nn.Module):
    """DDPG-Image / LowDim actor: encoder, then one 512-256-1 branch per action."""

    def __init__(self, encoder: ImageEncoder, hidden: Sequence[int], squash: str = "clip", speed_init: float = 0.0):
        super().__init__()
        self.encoder = encoder
        self.head = BranchedActor(encoder.out_dim, hidden, squash=squash, speed_init=speed_init)

    def forward(self, image: Tensor, speed: Tensor, last_action: Tensor, lowdim: Tensor | None = None) -> Tensor:
        return self.head(self.encoder(image, speed, last_action, lowdim))


class ImageCritic(nn.Module):
    """DDPG-Image / LowDim critic: the behaviour network's shape, encoder then 512-256-1."""

    def __init__(self, encoder: ImageEncoder, hidden: Sequence[int], norm: bool = False):
        super().__init__()
        self.encoder = encoder
        self.head = BranchedCritic(encoder.out_dim, hidden, n_branches=1, norm=norm)

    def forward(
        self, image: Tensor, speed: Tensor, last_action: Tensor, action: Tensor, lowdim: Tensor | None = None
    ) -> Tensor:
        return self.head(self.encoder(image, speed, last_action, lowdim), action)


def phi(predictions: Tensor, speed: Tensor, last_action: Tensor) -> Tensor:
    """Predictive representation phi(s) = [GVF predictions, speed, last action] (paper section 3)."""
    return torch.cat([predictions, speed, last_action], -1)


ODD_CUMULANTS = {"alpha", "beta"}  # lane centeredness and road angle negate under the left-right mirror


def phi_mirror_sign(n_predictions: int) -> Tensor:
    """Sign of each entry of phi under a left-right mirror: every prediction is of alpha or beta
    (both negate), speed stays, of the last action the steering negates and the target speed stays."""
    return torch.tensor([-1.0] * n_predictions + [1.0, -1.0, 1.0])


def steer_negated(action: Tensor, sign: Tensor | float = -1.0) -> Tensor:
    """An action (or last action) with its steering, the first entry, times `sign` (-1: its mirror
    image left-right; a (B, 1) sign mirrors some items of a batch); the target speed stays."""
    return torch.cat([action[..., :1] * sign, action[..., 1:]], -1)


class Policy(nn.Module):
    """The acting network: obs mapping (image, speed, last_action[, alpha, beta]) -> action.

    Predictive: actor(phi(gvf(obs))). Image / LowDim: the image actor. Accepts one
    observation (image of shape (2, 64, 128)) or a batch.
    """

    def __init__(self, representation: str, actor: nn.Module, gvf: GVFNetwork | None = None):
        super().__init__()
        self.representation = representation
        self.gvf = gvf
        self.actor = actor

    def forward(self, obs: Mapping[str, Tensor]) -> Tensor:
        image, speed, last_action = obs["image"], obs["speed"], obs["last_action"]
        single = image.dim() == 3
        if single:
            image, speed, last_action = image[None], speed[None], last_action[None]
        if self.representation == "predictive":
            action = self.actor(phi(self.gvf(image, speed, last_action), speed, last_action))
        elif self.representation == "lowdim":
            lowdim = torch.cat([obs["alpha"], obs["beta"]], -1)
            action = self.actor(image, speed, last_action, lowdim[None] if single else lowdim)
        else:
            action = self.actor(image, speed, last_action)
        return action[0] if single else action


@dataclass
class Networks:
    """What the learner trains; `policy` shares its modules with `gvf` and `actor`."""

    representation: str
    actor: nn.Module
    critic: nn.Module
    policy: Policy
    gvf: GVFNetwork | None = None
    behaviour: BehaviourNetwork | None = None

    def modules(self) -> dict[str, nn.Module]:
        named = {"gvf": self.gvf, "behaviour": self.behaviour, "actor": self.actor, "critic": self.critic}
        return {name: module for name, module in named.items() if module is not None}


def n_predictions(agent: AgentConfig) -> int:
    return len(agent.cumulants) * len(agent.gammas)


def prediction_columns(agent: AgentConfig, cumulant: str) -> slice:
    """The columns of `cumulant`'s predictions, one per gamma, in the GVFs' cumulant-major output."""
    start = list(agent.cumulants).index(cumulant) * len(agent.gammas)
    return slice(start, start + len(agent.gammas))


def _check(agent: AgentConfig) -> None:
    if agent.representation not in REPRESENTATIONS:
        raise ValueError(f"representation must be one of {REPRESENTATIONS}, got {agent.representation!r}")


def make_gvf(agent: AgentConfig, scale: ScaleConfig) -> GVFNetwork:
    """The GVFs as the scale builds them: odd under the mirror with `scale.mirror_gvf`."""
    if scale.mirror_gvf and not set(agent.cumulants) <= ODD_CUMULANTS:
        raise ValueError(f"scale.mirror_gvf needs cumulants that negate under the mirror {sorted(ODD_CUMULANTS)}")
    return GVFNetwork(scale.conv_channels, scale.gvf_hidden, n_predictions(agent), odd=scale.mirror_gvf)


def make_policy(agent: AgentConfig, scale: ScaleConfig) -> Policy:
    """The acting network alone, as actors build it to load the broadcast weights."""
    _check(agent)
    if agent.representation == "predictive":
        gvf = make_gvf(agent, scale)
        sign = phi_mirror_sign(gvf.n_predictions) if scale.mirror_actor else None
        actor = BranchedActor(
            gvf.n_predictions + LOW_DIM,
            scale.policy_hidden,
            squash=actor_squash(agent, scale),
            mirror_sign=sign,
            steer_increment=scale.steer_increment,
            speed_init=scale.actor_speed_init,
        )
        return Policy("predictive", actor, gvf)
    lowdim = scale.lowdim_width if agent.representation == "lowdim" else 0
    encoder = ImageEncoder(scale.conv_channels, lowdim)
    squash = actor_squash(agent, scale)
    actor = ImageActor(encoder, scale.image_policy_hidden, squash=squash, speed_init=scale.actor_speed_init)
    return Policy(agent.representation, actor)


def make_networks(agent: AgentConfig, scale: ScaleConfig) -> Networks:
    """Every network of the variant: acting policy, critic, and for GVF-DDPG the GVFs and g."""
    policy = make_policy(agent, scale)
    if agent.representation == "predictive":
        n_phi = policy.gvf.n_predictions + LOW_DIM
        reads = n_phi if scale.critic_last_action else n_phi - ACTION_DIM  # phi ends with the last action
        if scale.critic_advantage:
            critic = AdvantageCritic(n_phi, scale.policy_hidden, norm=scale.critic_norm, reads=reads)
            critic.centre_on(policy.actor)
        else:
            critic = BranchedCritic(n_phi, scale.policy_hidden, norm=scale.critic_norm, reads=reads)
        behaviour = BehaviourNetwork(scale.conv_channels, scale.behaviour_hidden)
        return Networks("predictive", policy.actor, critic, policy, policy.gvf, behaviour)
    lowdim = scale.lowdim_width if agent.representation == "lowdim" else 0
    critic = ImageCritic(ImageEncoder(scale.conv_channels, lowdim), scale.image_policy_hidden, scale.critic_norm)
    return Networks(agent.representation, policy.actor, critic, policy)


def main(argv: list[str] | None = None) -> None:
    """Print the tensors of a weights message for a composed config: `python -m common.networks
    agent=gvf_ddpg scale=small` (name, shape, dtype per line), what an outside actor must build."""
    import sys

    from common.cli import compose_run

    cfg = compose_run(sys.argv[1:] if argv is None else argv)
    for name, tensor in make_policy(cfg.agent, cfg.scale).state_dict().items():
        print(f"{name}\t{tuple(tensor.shape)}\t<f4")


if __name__ == "__main__":
    main()
