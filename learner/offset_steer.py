"""The actor's steering pulled by the predictions' own model of it (`scale.actor_offset_weight`, an
option, 0 by default: not the paper's algorithm).

The GVFs predict alpha under tau, "repeat the last action" (paper section 3), so v_alpha of a state
with its last steering replaced by the actor's is the discounted future offset were the car to
hold the actor's steering from now on. The term w * mean_gamma v_alpha(image, speed, [pi_steer,
last speed])^2 added to the actor's loss moves the steering where the predictions say the offset
goes to 0. Measured (docs/results.md, the steering probe): late in a run the critic's slope along
the steering points to the centre at chance; the predictions' slope is learned from every
transition (`actors.evaluation.prediction_probe` checks its sign against the simulator's).
That slope can turn late in a run (measured: seed 0 lost its laps as it did), and the term then
pulls away from the centre; `scale.actor_offset_guard` applies it only at the (state, gamma) pairs
where the prediction's slope along the steering has the simulator's sign (positive).
The GVFs' parameters are detached (only the actor moves) and their trunk features are the ones
phi was computed from (`learner.ddpg_batch`). Written here: no library has it.
"""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from torch import Tensor, nn
from torch.func import functional_call, jvp

from common.networks import prediction_columns

FEATURES = "gvf_features"  # the GVF trunk's features of s, kept by phi_batch for this term
SHORT = 0.5  # scale.actor_offset_gammas=None reads the predictions up to this gamma: their slope is the simulator's


class OffsetSteer:
    """w * mean over the chosen gammas of v_alpha(s, last steering := pi's)^2, differentiable in the actor."""

    def __init__(
        self, gvf: nn.Module, actor: nn.Module, columns: list[int], weight: float, after: int = 0, guard: bool = False
    ):
        if getattr(gvf, "mirror_last", None) is not None:
            raise ValueError("scale.actor_offset_weight needs scale.mirror_gvf=false (it reads the head of one pass)")
        self.gvf, self.actor, self.weight, self.after, self.guard = gvf, actor, weight, after, guard
        self.columns = torch.as_tensor(columns)

    @classmethod
    def build(cls, nets, agent, scale) -> OffsetSteer | None:
        """None where the weight is 0, the variant has no predictions, or (gammas None) none at gamma <=
        SHORT; refuses named gammas the GVFs do not predict, or no alpha cumulant."""
        if not scale.actor_offset_weight or nets.representation != "predictive":
            return None
        cumulants, gammas = list(agent.cumulants), list(agent.gammas)
        if "alpha" not in cumulants:
            raise ValueError(f"scale.actor_offset_weight needs the alpha cumulant, got agent.cumulants={cumulants}")
        chosen = scale.actor_offset_gammas
        if chosen is None:
            chosen = [g for g in gammas if g <= SHORT]
            if not chosen:  # GVF-0.95: no short prediction to read
                return None
        missing = [g for g in chosen if g not in gammas]
        if missing:
            raise ValueError(f"scale.actor_offset_gammas {missing} are not in agent.gammas {gammas}")
        alpha = prediction_columns(agent, "alpha")
        columns = [alpha.start + gammas.index(g) for g in chosen]
        weight, after, guard = scale.actor_offset_weight, scale.actor_offset_after, scale.actor_offset_guard
        return cls(nets.gvf, nets.actor, columns, weight, after, guard)

    def on(self, updates: int) -> bool:
        """Whether the term applies at this update count (`scale.actor_offset_after`)."""
        return updates >= self.after

    def __call__(self, batch: TensorDictBase, speed: Tensor, last_action: Tensor) -> dict[str, Tensor]:
        """{"actor_offset": the term}, and with the guard the share of (state, gamma) pairs it applied at."""
        features = batch[FEATURES].detach()
        steer = self.actor(batch["phi"])[..., :1]
        predicted = self._predict(features, speed, last_action, steer)
        if not self.guard:
            return {"actor_offset": self.weight * predicted.pow(2).mean()}
        # each item's predictions depend on its own steering only: one forward-mode pass gives every slope
        along = torch.ones_like(steer)
        _, slope = jvp(lambda s: self._predict(features, speed, last_action, s), (steer.detach(),), (along,))
        applies = (slope > 0).to(predicted.dtype)
        return {
            "actor_offset": self.weight * (applies * predicted.pow(2)).mean(),
            "diag/actor_offset_applies": applies.mean(),
        }

    def _predict(self, features: Tensor, speed: Tensor, last_action: Tensor, steer: Tensor) -> Tensor:
        """The chosen alpha predictions with the last steering replaced by `steer` (the speed action stays)."""
        last = torch.cat([steer, last_action[..., 1:]], -1)
        params = {k: v.detach() for k, v in self.gvf.head.named_parameters()}
        x = self.gvf.head_input(features, speed, last)
        return functional_call(self.gvf.head, params, (x,))[..., self.columns.to(x.device)]
