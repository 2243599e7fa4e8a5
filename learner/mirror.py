"""Left-right mirroring of sampled transitions (the paper's appendix, Jackal data: "augmented data
was created with horizontally flipped images along with the corresponding signs of the lane
centeredness, road angle, and steering action flipped").

LaneDrive is mirror-symmetric: the camera's principal point is the image centre, so the frame of
a car at (lateral d, yaw b) flipped left-right is the frame at (-d, -b) up to the grass texture;
the reward and termination depend on |alpha| and cos(beta); speed does not change. A mirrored
transition is therefore one the simulator could have produced, on the road's mirror image.
"""

from __future__ import annotations

import torch
from tensordict import TensorDict, TensorDictBase
from torch import Tensor

from common.networks import steer_negated


def mirror(td: TensorDictBase, mask: Tensor) -> TensorDict:
    """A copy of an expanded batch (learner.replay.expand) with the items where `mask` (B,) is
    True mirrored: both frames flipped left-right, steering (in action and last action), alpha
    and beta negated, in the state and the next state; everything else is shared, not copied."""
    mask = mask.reshape(-1).to(torch.bool)
    sign = 1.0 - 2.0 * mask.to(td["alpha"].dtype).reshape(-1, 1)
    out = td.clone(recurse=False)
    out["next"] = td["next"].clone(recurse=False)
    flip = mask.reshape(-1, 1, 1, 1)
    for part in (out, out["next"]):
        part["image"] = torch.where(flip, part["image"].flip(-1), part["image"])
        part["last_action"] = steer_negated(part["last_action"], sign)
        part["alpha"] = part["alpha"] * sign
        part["beta"] = part["beta"] * sign
    out["action"] = steer_negated(td["action"], sign)
    return out
