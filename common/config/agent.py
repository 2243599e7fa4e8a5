"""Config schemas of the `agent` and `scale` groups (Hydra structured configs).

`AgentConfig` holds what the paper fixes per algorithm variant (appendix, "GVF-DDPG
Training" and "Baseline DDPG Training"); `ScaleConfig` holds network widths, replay sizes
and step sizes, `paper` being the appendix's values and `small` a CPU-sized version of the
same shapes with larger steps (the paper's actor rate of 1e-6 assumes millions of updates;
a 2-core machine does a few thousand in 30 minutes). A value set on the agent
(`agent.lr_actor=...`) overrides the scale's; `step_sizes` resolves them. The YAML files in `conf/agent/` and `conf/scale/` fill these in; `register()` puts
the schemas in Hydra's ConfigStore under `agent/agent_schema` and `scale/scale_schema`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

from omegaconf import MISSING

PAPER_GAMMAS = [0.0, 0.5, 0.9, 0.95, 0.97]
REPRESENTATIONS = ("predictive", "image", "lowdim")


@dataclass
class AgentConfig:
    name: str = MISSING
    """Variant name: gvf_ddpg, gvf_ddpg_g0, gvf_ddpg_g095, ddpg_image or ddpg_lowdim."""
    representation: str = "predictive"
    """What DDPG sees: predictive (phi from the GVFs), image, or lowdim (image plus alpha and beta)."""
    cumulants: list[str] = field(default_factory=lambda: ["alpha", "beta"])
    """Cumulants predicted by the GVFs, read from the next state (lane centeredness, road angle)."""
    gammas: list[float] = field(default_factory=lambda: list(PAPER_GAMMAS))
    """GVF discounts; one prediction per (cumulant, gamma), cumulant-major order."""
    tau_width: float = 0.1
    """Std (action units, box [-1, 1]) of the truncated normal target policy tau around the last action."""
    rho_max: float = 100.0
    """Importance ratios rho are clipped to this maximum before entering the replay."""
    refresh_rho: bool = False
    """Recompute rho of each GVF minibatch with the current discriminator (the paper computes it once, at insert)."""
    behaviour_warmup_updates: int = 200
    """Discriminator-only steps on the warm-up data before the first update, then every rho is recomputed
    (the warm-up's rho came from an untrained g, ~55 where a fitted g gives ~1)."""
    rho_refresh_every: int = 1000
    """Recompute the rho of every item in the replay with the current g every this many updates (0: never)."""
    gvf_terminal: str = "zero"
    """GVF target at a termination: zero (continuation 0, an ordinary TD target) or absorbing (the last cumulant
    continues, target c_T); zero drove better (docs/results.md, learner.gvf)."""
    gvf_bootstrap_bound: bool = True
    """Clamp the GVFs' bootstrapped v(s') to +-max |c| seen per cumulant (learner.gvf.ReturnBound),
    where every true value lies; false: the paper's unclamped TD target."""
    discount: Optional[float] = None
    """DDPG discount of the reward (not stated in the paper); None: the scale's."""
    target_update: Optional[float] = None
    """Soft target-network update rate of DDPG's actor and critic; None: the scale's (paper: 0.001)."""
    lr_actor: Optional[float] = None
    """Actor (policy) learning rate; None: the scale's (paper: 1e-6)."""
    lr_critic: Optional[float] = None
    """Critic (action-value) learning rate; None: the scale's (paper: 1e-4)."""
    lr_gvf: Optional[float] = None
    """GVF predictor learning rate; None: the scale's (paper: 1e-4)."""
    lr_behaviour: Optional[float] = None
    """Behaviour discriminator learning rate; None: the scale's (paper: 1e-4)."""
    actor_squash: Optional[str] = None
    """Actor output squashing, clip or tanh; None: the scale's."""
    metrics_every: int = 100
    """Updates between two metric reports."""


@dataclass
class ScaleConfig:
    name: str = MISSING
    """Scale name: small (CPU) or paper (the appendix's sizes)."""
    conv_channels: list[int] = field(default_factory=lambda: [24, 36, 48, 64, 64])
    """Output channels of the five PilotNet conv layers (5x5 stride 2 three times, then 3x3 twice)."""
    gvf_hidden: list[int] = field(default_factory=lambda: [512, 384])
    """Fully connected widths of the GVF network before its prediction outputs."""
    behaviour_hidden: list[int] = field(default_factory=lambda: [512, 256])
    """Fully connected widths of the behaviour discriminator g(a, s) before its single output."""
    policy_hidden: list[int] = field(default_factory=lambda: [256, 128])
    """Widths of each branch of GVF-DDPG's actor and critic on phi."""
    image_policy_hidden: list[int] = field(default_factory=lambda: [512, 256])
    """Widths of the image baselines' actor branches and critic head."""
    lowdim_width: int = 12
    """Width of DDPG-LowDim's separate branch for (alpha, beta)."""
    batch_size: int = 128
    """Minibatch size of every update (GVF, discriminator, DDPG)."""
    buffer_size: int = 100_000
    """Replay capacity in transitions (paper: 100,000)."""
    warmup: int = 10_000
    """Transitions in the replay before the first update (paper: 10,000)."""
    discount: float = 0.99
    """DDPG discount of the reward (not stated in the paper)."""
    target_update: float = 0.001
    """Soft target-network update rate of DDPG's actor and critic (paper: 0.001)."""
    lr_actor: float = 1e-6
    """Actor (policy) learning rate (paper: 1e-6)."""
    lr_critic: float = 1e-4
    """Critic (action-value) learning rate (paper: 1e-4)."""
    lr_gvf: float = 1e-4
    """GVF predictor learning rate (paper: 1e-4)."""
    lr_behaviour: float = 1e-4
    """Behaviour discriminator learning rate (paper: 1e-4)."""
    actor_squash: str = "clip"
    """Actor output squashing: clip (paper: linear then clip to [-1, 1]; an output past a bound
    gets no gradient, so it can stay there) or tanh (bounded, its gradient never exactly 0)."""
    mirror: float = 0.0
    """Fraction of every sampled minibatch mirrored left-right (frames flipped; steering, alpha and
    beta negated; learner.mirror), as the paper augmented its Jackal data; 0 in its TORCS setup."""
    mirror_actor: bool = False
    """GVF-DDPG's actor mirror-equivariant by construction (common.networks.BranchedActor's
    mirror_sign): steering odd, target speed even under negating every prediction and the last
    steering; the image baselines are unaffected (their input would need flipped frames)."""
    mirror_gvf: bool = False
    """The GVFs' predictions odd under the left-right mirror by construction (common.networks.
    GVFNetwork's `odd`: (f(s) - f(Ms)) / 2, two trunk passes): the representation the mirror actor
    reads holds no side either. False: odd only as far as the mirrored minibatches taught them."""
    steer_increment: float = 0.0
    """GVF-DDPG's actor outputs a change of the steering: steering = clip(last steering +
    steer_increment * output, -1, 1) (common.networks.BranchedActor), an integrating controller;
    0: the paper's absolute steering. The image baselines are unaffected."""
    critic_norm: bool = False
    """A LayerNorm before each hidden ReLU of DDPG's critic (Ball et al. 2023; common.critics.
    BranchedCritic): Q bounded wherever the actor moves the action; False: the paper's plain MLP."""
    critic_last_action: bool = True
    """False: GVF-DDPG's critic reads phi without its last action (the predictions and the speed):
    with the paper's slow OU noise the action differs from the last action by ~0.01 per step, so
    the critic can credit the steering to either input and the actor's dQ/da is left the residual;
    the actor keeps it. The image baselines are unaffected."""
    critic_advantage: bool = False
    """True: GVF-DDPG's critic is V(phi) + A(phi, a) - A(phi, pi(phi)) (common.critics.AdvantageCritic),
    so the action's small part of Q has its own head; False: the paper's Q(phi, a). The image
    baselines are unaffected."""
    reward_scale: float = 1.0
    """DDPG's reward is multiplied by this (the paper scaled its reward so that action values lie in [-1, 1])."""
    crash_penalty: float = 0.0
    """Subtracted from DDPG's reward (before reward_scale) on a transition that leaves the lane
    (terminated): the cost of a crash in one backup instead of the lost future reward alone; 0: the paper."""
    offset_weight: float = 1.0
    """Weight of the lane offset in DDPG's reward: r = v/v_max (cos beta - offset_weight |alpha|)
    (the env's reward less (offset_weight - 1) v/v_max |alpha| of the reached state, v/v_max the
    observed speed, which TORCS clips to [0, 1]); online only (gvf-offline refuses it); 1: the paper's."""
    n_step: int = 1
    """Steps of reward in DDPG's target before it bootstraps from Q' (learner.nstep; at most to
    the end of the actor's chunk); 1: the paper's one-step target. The GVFs stay one-step."""
    act_with_target: bool = False
    """Broadcast (act and evaluate with) DDPG's Polyak-averaged target actor instead of the online one."""
    policy_average: float = 0.0
    """Rate of an exponential moving average of the acting network, stepped every update
    (learner.policy_average): the evaluator drives it and checkpoints keep it, the actors still
    explore with the online policy; 0: none (the paper deploys the online policy)."""
    crash_memory: int = 0
    """Capacity (transitions) of a second replay that keeps the last `crash_steps` steps before each
    termination after the main ring evicted them; DDPG and g sample both together (learner.replay); 0: none, the paper."""
    crash_steps: int = 30
    """Steps before a termination kept in the crash memory (at most the actor's chunk_len + 1)."""
    crash_memory_actor: bool = True
    """false: the actor's loss leaves out the crash memory's items; the critic still learns from them (learner.ddpg)."""
    lr_actor_decay_updates: int = 0
    """Updates over which the actor's step size falls linearly from lr_actor to lr_actor *
    lr_actor_final, then stays there; 0: constant, as the paper."""
    lr_actor_final: float = 0.1
    """lr_actor_decay_updates: the final step size as a fraction of lr_actor."""
    lr_actor_decay_after: int = 0
    """lr_actor_decay_updates: the step size holds at lr_actor for this many updates before it falls."""
    td3: bool = False
    """TD3-style critic (twin critics, target-policy smoothing, delayed actor steps) instead of the paper's DDPG (learner.ddpg)."""
    td3_policy_noise: float = 0.2
    """td3: std of the Gaussian noise on the target action (action units)."""
    td3_noise_clip: float = 0.5
    """td3: the target action's noise is clipped to +-this."""
    td3_actor_delay: int = 2
    """td3: the actor is stepped once every this many updates."""
    td3_target_min_weight: float = 1.0
    """td3: the target bootstraps from w min + (1 - w) max of the twin target critics (learner.td3_target); 1: TD3's minimum."""
    actor_min_q: bool = False
    """td3: the actor maximises min(Q1, Q2) (as SAC) instead of TD3's Q1 (learner.ddpg)."""
    critic_steer_penalty: float = 0.0
    """lambda of lambda E[(dQ/d steering)^2] at the minibatch's actions, added to each critic's loss (learner.ddpg); 0: none, the paper."""
    critic_steer_penalty_after: int = 0
    """critic_steer_penalty applies from this many DDPG updates on (0: from the first)."""
    actor_offset_weight: float = 0.0
    """w of w * mean v_alpha(s, last steering := the actor's)^2 added to GVF-DDPG's actor loss: the steering the predictions say centres the car (learner.offset_steer); 0: none, the paper."""
    actor_offset_gammas: Optional[list[float]] = None
    """actor_offset_weight: the alpha predictions (by their agent.gammas) the term reads, each one the GVFs must predict; None: those the GVFs predict at gamma <= 0.5, the short ones that slope the true way along the steering (actors.evaluation.prediction_probe), none for GVF-0.95 (the term is then off)."""
    actor_offset_after: int = 0
    """actor_offset_weight applies from this many updates on (0: from the first), so the first laps come as without it."""
    actor_speed_init: float = 0.0
    """The actor's initial speed action, in (-1, 1) (its target speed v_max (0.75 + 0.25 a)): 0 as the paper (near-zero initial actions, 0.75 v_max); below 0 the first drives are slower."""
    actor_speed_hold: int = 0
    """The actor's speed branch is not stepped for this many updates (0: stepped from the first), so its target speed stays at actor_speed_init while the steering learns."""
    actor_offset_guard: bool = False
    """actor_offset_weight applies only where the prediction's slope along the steering is positive (the simulator's sign), so a turned slope switches it off."""


SQUASHES = ("clip", "tanh")
STEP_SIZES = ("discount", "target_update", "lr_actor", "lr_critic", "lr_gvf", "lr_behaviour")


def step_sizes(agent: AgentConfig, scale: ScaleConfig) -> dict[str, float]:
    """Learning rates, soft-update rate and discount in force: the agent's where set, else the scale's."""
    return {name: getattr(scale, name) if getattr(agent, name) is None else getattr(agent, name) for name in STEP_SIZES}


def actor_squash(agent: AgentConfig, scale: ScaleConfig) -> str:
    """The actor's output squashing in force: the agent's where set, else the scale's."""
    name, value = ("agent", agent.actor_squash) if agent.actor_squash is not None else ("scale", scale.actor_squash)
    if value not in SQUASHES:
        raise ValueError(f"{name}.actor_squash must be one of {SQUASHES}, got {value!r}")
    return value


def shaped_reward(reward, terminated, offset, scale: ScaleConfig, penalty_weight=1.0):
    """DDPG's reward from the env's: less (`scale.offset_weight` - 1) times `offset` (v/v_max |alpha|
    of the reached state), less `scale.crash_penalty` (times `penalty_weight`) where `terminated`,
    times `scale.reward_scale`; numpy arrays or tensors alike, so the learner and the evaluation
    tools (which may not import the learner) form it once."""
    extra = (scale.offset_weight - 1.0) * offset
    return (reward - extra - scale.crash_penalty * penalty_weight * terminated) * scale.reward_scale


TERMINALS = ("absorbing", "zero")  # learner.gvf.td_target


def check_scale(scale: ScaleConfig) -> None:
    """Refuses a scale whose values cannot work, naming the field."""
    if not 0.0 <= scale.mirror <= 1.0:
        raise ValueError(f"scale.mirror must be in [0, 1], got {scale.mirror}")
    if not scale.reward_scale > 0.0:
        raise ValueError(f"scale.reward_scale must be > 0, got {scale.reward_scale}")
    if not scale.crash_penalty >= 0.0:
        raise ValueError(f"scale.crash_penalty must be >= 0, got {scale.crash_penalty}")
    if scale.n_step < 1:
        raise ValueError(f"scale.n_step must be >= 1, got {scale.n_step}")
    if not scale.offset_weight >= 1.0:
        raise ValueError(f"scale.offset_weight must be >= 1, got {scale.offset_weight}")
    if scale.n_step > 1 and scale.offset_weight != 1.0:
        raise ValueError("scale.n_step > 1 needs scale.offset_weight=1 (the n-step reward is the env's sum)")
    if scale.n_step > 1 and scale.crash_memory:
        raise ValueError("scale.n_step > 1 needs scale.crash_memory=0 (the crash memory keeps no bootstrap states)")
    if not 0.0 <= scale.policy_average < 1.0:
        raise ValueError(f"scale.policy_average must be in [0, 1), got {scale.policy_average}")
    if scale.crash_memory < 0:
        raise ValueError(f"scale.crash_memory must be >= 0, got {scale.crash_memory}")
    if not scale.crash_memory_actor and not scale.crash_memory:
        raise ValueError(
            "scale.crash_memory_actor=false needs scale.crash_memory > 0 (there are no crash items to leave out)"
        )
    if scale.crash_steps < 1:
        raise ValueError(f"scale.crash_steps must be >= 1, got {scale.crash_steps}")
    if scale.lr_actor_decay_updates < 0:
        raise ValueError(f"scale.lr_actor_decay_updates must be >= 0, got {scale.lr_actor_decay_updates}")
    if scale.lr_actor_decay_after < 0 or (scale.lr_actor_decay_after and not scale.lr_actor_decay_updates):
        raise ValueError(
            f"scale.lr_actor_decay_after must be >= 0 and needs scale.lr_actor_decay_updates > 0, "
            f"got {scale.lr_actor_decay_after}"
        )
    if not 0.0 < scale.lr_actor_final <= 1.0:
        raise ValueError(f"scale.lr_actor_final must be in (0, 1], got {scale.lr_actor_final}")
    if scale.actor_min_q and not scale.td3:
        raise ValueError("scale.actor_min_q needs scale.td3=true (it takes the smaller of the twin critics)")
    if not 0.0 <= scale.steer_increment <= 2.0:
        raise ValueError(f"scale.steer_increment must be in [0, 2], got {scale.steer_increment}")
    if not 0.0 <= scale.td3_target_min_weight <= 1.0:
        raise ValueError(f"scale.td3_target_min_weight must be in [0, 1], got {scale.td3_target_min_weight}")
    if scale.td3_target_min_weight != 1.0 and not scale.td3:
        raise ValueError("scale.td3_target_min_weight needs scale.td3=true (it blends the twin critics)")
    if not scale.critic_steer_penalty >= 0.0:
        raise ValueError(f"scale.critic_steer_penalty must be >= 0, got {scale.critic_steer_penalty}")
    if scale.critic_steer_penalty_after < 0:
        raise ValueError(f"scale.critic_steer_penalty_after must be >= 0, got {scale.critic_steer_penalty_after}")
    if not scale.actor_offset_weight >= 0.0:
        raise ValueError(f"scale.actor_offset_weight must be >= 0, got {scale.actor_offset_weight}")
    if scale.actor_offset_after < 0:
        raise ValueError(f"scale.actor_offset_after must be >= 0, got {scale.actor_offset_after}")
    if scale.actor_offset_weight and scale.actor_offset_gammas is not None and not scale.actor_offset_gammas:
        raise ValueError("scale.actor_offset_gammas must name at least one of agent.gammas")
    if not -1.0 < scale.actor_speed_init < 1.0:
        raise ValueError(f"scale.actor_speed_init must be in (-1, 1), got {scale.actor_speed_init}")
    if scale.actor_speed_hold < 0:
        raise ValueError(f"scale.actor_speed_hold must be >= 0, got {scale.actor_speed_hold}")
    if scale.actor_offset_guard and not scale.actor_offset_weight:
        raise ValueError("scale.actor_offset_guard needs scale.actor_offset_weight > 0 (it guards that term)")
    if scale.td3_actor_delay < 1:
        raise ValueError(f"scale.td3_actor_delay must be >= 1, got {scale.td3_actor_delay}")


def check_agent(agent: AgentConfig) -> None:
    """Refuses an agent whose values cannot work, naming the field."""
    if agent.gvf_terminal not in TERMINALS:
        raise ValueError(f"agent.gvf_terminal must be one of {TERMINALS}, got {agent.gvf_terminal!r}")
    for name in ("behaviour_warmup_updates", "rho_refresh_every"):
        if getattr(agent, name) < 0:
            raise ValueError(f"agent.{name} must be >= 0, got {getattr(agent, name)}")


def register() -> None:
    """Store the schemas in Hydra's ConfigStore (YAML files list them in their defaults)."""
    from hydra.core.config_store import ConfigStore

    store = ConfigStore.instance()
    store.store(group="agent", name="agent_schema", node=AgentConfig)
    store.store(group="scale", name="scale_schema", node=ScaleConfig)
