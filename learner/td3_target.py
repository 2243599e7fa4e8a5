"""TD3's target with the twin critics blended instead of their minimum (an option, `scale.td3_target_min_weight`).

TD3 bootstraps from min(Q1', Q2'), whose downward bias compounds over 1 / (1 - gamma) backups; with
the crash penalty the twins disagree most where a crash is near, and the final checkpoints' critics
sat 100-195 below their own policy's return at every test-lap state (docs/results/value-probe.md).
A weight w < 1 bootstraps from w min + (1 - w) max (Weighted Double Q, Zhang et al. 2017; w 0.5: the
twins' mean). Written here because torchrl's `TD3Loss.value_loss` takes the minimum inline: the
blend is put into both rows of the target critics' output, so that minimum is the blend.
"""

from __future__ import annotations

from tensordict import TensorDictBase
from torchrl.objectives import TD3Loss


class BlendedTD3Loss(TD3Loss):
    """torchrl's TD3Loss whose target is `min_weight` min + (1 - `min_weight`) max of the twin target critics."""

    min_weight: float = 1.0

    def _make_vmap(self) -> None:
        super()._make_vmap()
        plain = self._vmap_qvalue_network00

        def q_values(td: TensorDictBase, params) -> TensorDictBase:
            out = plain(td, params)
            if self.min_weight == 1.0 or params is not self.target_qvalue_network_params:
                return out  # the current critics' values, and TD3's own target, untouched
            q = out.get(self.tensor_keys.state_action_value)
            blend = self.min_weight * q.min(0)[0] + (1.0 - self.min_weight) * q.max(0)[0]
            out.set(self.tensor_keys.state_action_value, blend.expand_as(q).clone())
            return out

        self._vmap_qvalue_network00 = q_values
