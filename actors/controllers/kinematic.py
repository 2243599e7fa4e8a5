"""The paper's classical baseline: a kinematic controller that steers from lane centeredness
(alpha) and road angle (beta) and sets speed from the road's curvature ahead (Paden et al. 2016,
a Stanley-type law with curvature feed-forward).

    steer  = atan(L * kappa_road) - k_beta * beta - atan(k_e * e / (v + v_soft)),   e = alpha * half width
    speed  = min(v_max, sqrt(a_comfort / max|kappa| over the next 40 m))

It reads only `info` (ground truth from localisation and a map), never the image.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from common.config.env import VehicleConfig


@dataclass
class KinematicController:
    """Maps LaneDrive `info` (one car, or arrays for a batch) to actions in [-1, 1]^2."""

    vehicle: VehicleConfig = None  # type: ignore[assignment]
    k_beta: float = 1.0
    """Gain on road angle."""
    k_e: float = 1.2
    """Cross-track gain of the Stanley term, 1/s."""
    v_soft: float = 2.0
    """Softening speed of the Stanley term, m/s."""
    comfort_accel: float = 4.0
    """Lateral acceleration planned for bends, m/s^2 (half the grip limit)."""

    def __post_init__(self) -> None:
        if self.vehicle is None:
            self.vehicle = VehicleConfig()

    def act(self, info: dict) -> np.ndarray:
        """Action (2,) for one car's info, or (n, 2) for a vector env's info of arrays."""
        vc = self.vehicle
        alpha, beta = np.asarray(info["alpha"], float), np.asarray(info["beta"], float)
        speed, kappa = np.asarray(info["speed"], float), np.asarray(info["curvature"], float)
        e = alpha * np.asarray(info["lane_half_width"], float)
        steer = np.arctan(vc.wheelbase * kappa) - self.k_beta * beta - np.arctan(self.k_e * e / (speed + self.v_soft))
        ahead = np.maximum(np.asarray(info["curvature_ahead"], float), 1e-6)
        v_des = np.minimum(vc.v_max, np.sqrt(self.comfort_accel / ahead))
        action = np.stack([steer / vc.max_steer, (v_des / vc.v_max - 0.75) / 0.25], axis=-1)
        return np.clip(action, -1.0, 1.0).astype(np.float32)


def drive_lap(env, controller: KinematicController, max_steps: int = 5000, **reset_kwargs) -> dict:
    """Drive one car until it completes a lap or the episode ends; returns a summary."""
    _, info = env.reset(**reset_kwargs)
    alphas, steps, done = [abs(info["alpha"])], 0, False
    while not done and steps < max_steps and not info["lap_completed"]:
        _, _, terminated, truncated, info = env.step(controller.act(info))
        alphas.append(abs(info["alpha"]))
        steps += 1
        done = terminated or truncated
    return {
        "track": info["track"],
        "steps": steps,
        "lap_completed": bool(info["lap_completed"]),
        "max_abs_alpha": float(max(alphas)),
        "mean_abs_alpha": float(np.mean(alphas)),
    }
