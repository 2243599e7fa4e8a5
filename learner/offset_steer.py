"""The actor's steering pulled by the predictions' own model of it (`scale.actor_offset_weight`, an
option, 0 by default: not the paper's algorithm).

The GVFs predict alpha under tau, "repeat the last action" (paper section 3), so v_alpha of a state
with its last steering replaced by the actor's is the discounted future offset were the car to
hold the actor's steering from now on. The term w * mean_gamma v_alpha(image, speed, [pi_steer,
last speed])^2 added to the actor's loss moves the steering where the predictions say the offset
goes to 0. Measured (docs/results.md, the steering probe): late in a run the critic's slope along
the steering points to the centre at chance; the predictions' slope is learned from every
transition (`actors.evaluation.prediction_probe` checks its sign against the simulator's).
The GVFs' parameters are detached (only the actor moves) and their trunk features are the ones
phi was computed from (`learner.ddpg_batch`). Written here: no library has it.
"""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from torch import Tensor, nn
from torch.func import functional_call

from common.networks import prediction_columns

FEATURES = "gvf_features"  # the GVF trunk's features of s, kept by phi_batch for this term


class OffsetSteer:
    """w * mean over the chosen gammas of v_alpha(s, last steering := pi's)^2, differentiable in the actor."""

    def __init__(self, gvf: nn.Module, actor: nn.Module, columns: list[int], weight: float, after: int = 0):
        if getattr(gvf, "mirror_last", None) is not None:
            raise ValueError("scale.actor_offset_weight needs scale.mirror_gvf=false (it reads the head of one pass)")
        self.gvf, self.actor, self.weight, self.after = gvf, actor, weight, after
        self.columns = torch.as_tensor(columns)

    @classmethod
    def build(cls, nets, agent, scale) -> OffsetSteer | None:
        """None where the weight is 0 or the variant has no predictions; refuses gammas the GVFs do
        not predict, or no alpha cumulant."""
        if not scale.actor_offset_weight or nets.representation != "predictive":
            return None
        cumulants, gammas = list(agent.cumulants), list(agent.gammas)
        if "alpha" not in cumulants:
            raise ValueError(f"scale.actor_offset_weight needs the alpha cumulant, got agent.cumulants={cumulants}")
        missing = [g for g in scale.actor_offset_gammas if g not in gammas]
        if missing:
            raise ValueError(f"scale.actor_offset_gammas {missing} are not in agent.gammas {gammas}")
        alpha = prediction_columns(agent, "alpha")
        columns = [alpha.start + gammas.index(g) for g in scale.actor_offset_gammas]
        return cls(nets.gvf, nets.actor, columns, scale.actor_offset_weight, scale.actor_offset_after)

    def on(self, updates: int) -> bool:
        """Whether the term applies at this update count (`scale.actor_offset_after`)."""
        return updates >= self.after

    def __call__(self, batch: TensorDictBase, speed: Tensor, last_action: Tensor) -> Tensor:
        steer = self.actor(batch["phi"])[..., :1]
        last = torch.cat([steer, last_action[..., 1:]], -1)  # the speed action stays as it was
        params = {k: v.detach() for k, v in self.gvf.head.named_parameters()}
        x = self.gvf.head_input(batch[FEATURES], speed, last)
        predicted = functional_call(self.gvf.head, params, (x,))[..., self.columns.to(x.device)]
        return self.weight * predicted.pow(2).mean()
