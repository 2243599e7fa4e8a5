"""The paper's MPC baseline (appendix "MPC Baseline"): a model-predictive controller that follows
the road's centre from localisation and a map, with an optimisation window of 5 steps, at a
fixed target speed. The Jackal's MPC was a ROS package; this one is written here because none of
the project's packages has one, and LaneDrive's model is a few lines.

Model: LaneDrive's own vehicle (kinematic bicycle, steering-rate limit, speed lag, grip limit) in
road coordinates (Frenet frame) along the map's centreline curvature kappa_r(s):

    s' = v cos(psi) / (1 - kappa_r e),   e' = v sin(psi),   psi' = v kappa - kappa_r(s) s'

with e the lateral offset (alpha * half width), psi the heading to the road (beta), kappa the
car's path curvature. Decision: 5 steering actions, each held for `hold` control periods (the
paper spaced its waypoints out for the same reason: a longer look-ahead with 5 steps).
Cost: sum over the horizon of (e / H)^2 + w_psi psi^2, plus w_du per squared change of the
steering action. Solver: the cross-entropy method over the 5 actions, all cars at once.

It reads `info` only (alpha, beta, speed, steer, station, track: localisation and the map),
never the image, like the kinematic controller.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from actors.envs.tracks import get_track
from common.config.env import VehicleConfig

HORIZON = 5  # the paper's optimisation window


@lru_cache(maxsize=64)
def _road(name: str) -> tuple[np.ndarray, float]:
    """Curvature per centreline sample and the sample spacing of a road (the map)."""
    track = get_track(name)
    return track.curvature.astype(np.float64), track.spacing


def speed_action(v: float, vehicle: VehicleConfig) -> float:
    """The target-speed action that asks LaneDrive for v m/s."""
    return float(np.clip((v / vehicle.v_max - 0.75) / 0.25, -1.0, 1.0))


@dataclass
class MPCController:
    """`act(info)` maps LaneDrive info of n cars (arrays) to actions (n, 2)."""

    target_speed: float = 11.0
    """m/s; LaneDrive's slowest is v_max / 2 = 10."""
    vehicle: VehicleConfig = field(default_factory=VehicleConfig)
    hold: int = 3
    """Control periods each of the 5 decisions lasts (5 x 3 x 0.1 s = 1.5 s of look-ahead)."""
    w_psi: float = 1.0
    w_du: float = 0.05
    samples: int = 96
    iterations: int = 4
    elites: int = 12
    seed: int = 0

    def __post_init__(self) -> None:
        self.rng = np.random.default_rng(self.seed)
        self.mean: np.ndarray | None = None  # warm start: last plan shifted by one decision

    def rollout_cost(self, u: np.ndarray, state: dict[str, np.ndarray]) -> np.ndarray:
        """Cost (n, K) of K steering plans u (n, K, 5) from each car's state."""
        vc = self.vehicle
        n, k = u.shape[:2]
        e = np.repeat(state["e"][:, None], k, 1)
        psi = np.repeat(state["psi"][:, None], k, 1)
        v = np.repeat(state["v"][:, None], k, 1)
        delta = np.repeat(state["delta"][:, None], k, 1)
        s = np.repeat(state["s"][:, None], k, 1)
        dt, rate, half = vc.dt, vc.steer_rate * vc.dt, state["half"][:, None]
        v_goal, lag = self.target_speed, 1.0 - math.exp(-vc.dt / vc.speed_lag)
        first = np.broadcast_to(state["u0"][:, None, None], (n, k, 1))
        cost = self.w_du * np.square(np.diff(u, axis=-1, prepend=first)).sum(-1)
        for j in range(HORIZON):
            for _ in range(self.hold):
                delta = delta + np.clip(u[..., j] * vc.max_steer - delta, -rate, rate)
                v = v + (v_goal - v) * lag
                k_grip = vc.max_lateral_accel / (v * v)
                kappa = np.clip(np.tan(delta) / vc.wheelbase, -k_grip, k_grip)
                kappa_r = np.stack([c[(s_i / sp).astype(int) % len(c)] for s_i, (c, sp) in zip(s, state["roads"])])
                s_dot = v * np.cos(psi) / np.maximum(1.0 - kappa_r * e, 0.1)
                dpsi = (v * kappa - kappa_r * s_dot) * dt
                e = e + v * np.sin(psi + 0.5 * dpsi) * dt  # midpoint heading, as LaneDrive integrates
                psi = psi + dpsi
                s = s + s_dot * dt
                cost = cost + np.square(e / half) + self.w_psi * np.square(psi)
        return cost

    def act(self, info: dict) -> np.ndarray:
        names = np.atleast_1d(info["track"])
        n = len(names)
        state = {
            "e": np.atleast_1d(np.asarray(info["alpha"], float)) * np.atleast_1d(info["lane_half_width"]),
            "psi": np.atleast_1d(np.asarray(info["beta"], float)),
            "v": np.atleast_1d(np.asarray(info["speed"], float)),
            "delta": np.atleast_1d(np.asarray(info["steer"], float)),
            "s": np.atleast_1d(np.asarray(info["station"], float)),
            "half": np.atleast_1d(np.asarray(info["lane_half_width"], float)),
            "roads": [_road(str(name)) for name in names],
        }
        state["u0"] = state["delta"] / self.vehicle.max_steer
        mean = np.zeros((n, HORIZON)) if self.mean is None or len(self.mean) != n else self.mean
        std = np.full((n, HORIZON), 0.5)
        for _ in range(self.iterations):
            u = np.clip(mean[:, None] + std[:, None] * self.rng.standard_normal((n, self.samples, HORIZON)), -1, 1)
            u[:, 0] = mean  # the incumbent stays a candidate
            cost = self.rollout_cost(u, state)
            elite = u[np.arange(n)[:, None], np.argsort(cost, axis=1)[:, : self.elites]]
            mean, std = elite.mean(1), elite.std(1) + 0.02
        self.mean = np.concatenate([mean[:, 1:], mean[:, -1:]], 1)
        speed = np.full(n, speed_action(self.target_speed, self.vehicle))
        return np.stack([mean[:, 0], speed], -1).astype(np.float32)
