"""The paper's evaluation metrics of one drive (Jackal appendix, "Test Results"; TORCS section
for jerkiness), from the per-step rewards, ground truth and actions of the drive:

    reward per step      1/N sum r_t                (the paper calls it "per second")
    average speed        1/N sum v_t
    offcenteredness      1/N sum |alpha_t|
    absolute road angle  1/N sum |beta_t|
    near out of lane     1/N sum 1[|alpha_t| > 0.75]
    first-order comfort  -1/(N-1) sum |a_{t+1} - a_t|                     (per action)
    second-order comfort -1/(N-2) sum |(a_{t+2} - a_{t+1}) - (a_{t+1} - a_t)|  (per action)
    jerkiness            std(a_{t+1} - a_t)  (angular: steering, longitudinal: target speed)
"""

from __future__ import annotations

import numpy as np

NEAR_OUT = 0.75
CONTROL_HZ = 10.0  # the paper's control rate (TORCS steps 0.1 s; LaneDrive's env.vehicle.dt may differ)


def drive_metrics(
    reward, speed, alpha, beta, actions, lap_completed: bool, control_hz: float = CONTROL_HZ
) -> dict[str, float]:
    """Metrics of one drive; actions (N, 2) = (steering, target speed); `control_hz` steps per second."""
    reward, speed = np.asarray(reward, float), np.asarray(speed, float)
    alpha, beta = np.asarray(alpha, float), np.asarray(beta, float)
    actions = np.asarray(actions, float).reshape(-1, 2)
    if len(reward) == 0:
        raise ValueError("a drive needs at least one step")
    d1 = np.diff(actions, axis=0)
    d2 = np.diff(actions, n=2, axis=0)
    out = {
        "reward_per_step": float(reward.mean()),
        "reward_per_s": float(reward.mean() * control_hz),
        "average_speed": float(speed.mean()),
        "offcenteredness": float(np.abs(alpha).mean()),
        "abs_road_angle": float(np.abs(beta).mean()),
        "near_out_of_lane": float((np.abs(alpha) > NEAR_OUT).mean()),
        "episode_length": float(len(reward)),
        "lap_completed": float(bool(lap_completed)),
    }
    for k, name in enumerate(("steering", "speed")):
        out[f"comfort1_{name}"] = float(-np.abs(d1[:, k]).mean()) if len(d1) else 0.0
        out[f"comfort2_{name}"] = float(-np.abs(d2[:, k]).mean()) if len(d2) else 0.0
    out["jerkiness_angular"] = float(d1[:, 0].std()) if len(d1) else 0.0
    out["jerkiness_longitudinal"] = float(d1[:, 1].std()) if len(d1) else 0.0
    return out
