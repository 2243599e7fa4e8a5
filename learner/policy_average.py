"""The deployed policy of `scale.policy_average`: an exponential moving average of the whole
acting network (GVFs and actor), stepped after every update. The evaluator drives it and the
checkpoints keep it as their policy, while the actors explore with the online one. Averaging the
weights damps an off-policy actor's swings between a good and a bad policy (Nikishin et al.
2018, "Improving Stability in Deep Reinforcement Learning with Weight Averaging"); torch's
AveragedModel keeps the average (no hand-written EMA)."""

from __future__ import annotations

from typing import Any

from torch import Tensor, nn
from torch.optim.swa_utils import AveragedModel, get_ema_multi_avg_fn


class PolicyAverage:
    """avg <- (1 - rate) avg + rate online, per update; the first update copies the online policy."""

    def __init__(self, policy: nn.Module, rate: float) -> None:
        if not 0.0 < rate < 1.0:
            raise ValueError(f"scale.policy_average must be in (0, 1) to average, got {rate}")
        self.model = AveragedModel(policy, multi_avg_fn=get_ema_multi_avg_fn(1.0 - rate), use_buffers=True)

    def update(self, policy: nn.Module) -> None:
        self.model.update_parameters(policy)

    def policy_state_dict(self) -> dict[str, Tensor]:
        """The averaged weights under the acting network's own names (`make_policy`)."""
        return {k: v.detach().clone() for k, v in self.model.module.state_dict().items()}

    def state_dict(self) -> dict[str, Any]:
        return self.model.state_dict()

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.model.load_state_dict(state)
