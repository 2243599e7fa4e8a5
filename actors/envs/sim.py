"""The LaneDrive simulator core: N cars stepped together with numpy.

Each car drives its own road (a :class:`~actors.envs.tracks.Track` and its camera map).
Vehicle: kinematic bicycle at 10 Hz with a steering-rate limit, a first-order lag from target
speed to speed, and a grip limit (path curvature capped at a_lat / v^2, so a car too fast for
a bend runs wide). Ground truth per step: alpha = signed lateral offset / half lane width
(positive left of centre), beta = car heading - road heading (positive pointing left),
reward r = v/v_max * (cos beta - |alpha|), termination when |alpha| > 1.
"""

from __future__ import annotations

import copy
import math
import zlib
from functools import lru_cache

import numpy as np

from actors.envs.camera import HEIGHT, WIDTH, Camera
from actors.envs.road_map import RoadMap, build_road_map
from actors.envs.tracks import Track, get_track, track_names
from common.config.env import DamageConfig, EnvConfig


def target_speed(v_max: float, a_speed):
    """The target speed of a speed action in [-1, 1]: -1..1 maps to 0.5..1.0 v_max (both simulators)."""
    return v_max * (0.75 + 0.25 * a_speed)


LOOKAHEAD_M = 40.0  # horizon of `curvature_ahead`, for speed planning by controllers
_WINDOW = np.arange(-8, 48)  # nearest-sample search, in samples of 0.25 m: -2 m .. +12 m (2 m per step at most)
PATH_LEN = 4000  # positions kept for the top-down view


@lru_cache(maxsize=48)
def road_map(base_name: str, lane_width: float, damage: tuple) -> RoadMap:
    """Camera map of a road (shared by both directions), drawn once per process."""
    return build_road_map(get_track(base_name), lane_width, DamageConfig(*damage), zlib.crc32(base_name.encode()))


@lru_cache(maxsize=256)
def curvature_ahead(name: str) -> np.ndarray:
    return get_track(name).curvature_ahead(LOOKAHEAD_M)


def _brightness_table(rng: np.random.Generator, vary: bool) -> np.ndarray:
    """Per-episode lighting: contrast about mid-grey and a brightness shift, as a lookup table."""
    gain, bias = (rng.uniform(0.7, 1.3), rng.uniform(-25, 25)) if vary else (1.0, 0.0)
    return np.clip(np.arange(256) * gain + (1 - gain) * 110 + bias, 0, 255).astype(np.uint8)


class LaneDriveSim:
    """State and dynamics of `n` cars; the gymnasium envs are thin views of this."""

    def __init__(self, cfg: EnvConfig, n: int) -> None:
        cfg.validate()
        self.cfg, self.n = cfg, n
        self.camera = Camera(cfg.camera_height)
        self.half = cfg.lane_width / 2
        z = lambda: np.zeros(n)  # noqa: E731
        self.x, self.y, self.theta, self.v, self.delta = z(), z(), z(), z(), z()
        self.alpha, self.beta, self.travelled, self.reward = z(), z(), z(), z()
        self.idx = np.zeros(n, np.int64)
        self.steps = np.zeros(n, np.int64)
        self.last_action = np.zeros((n, 2), np.float32)
        self.frames = np.zeros((n, 2, HEIGHT, WIDTH), np.uint8)  # [current, previous]
        self.luts = np.tile(np.arange(256, dtype=np.uint8), (n, 1))
        self.tracks: list[Track] = [None] * n  # type: ignore[list-item]
        self.maps: list[RoadMap] = [None] * n  # type: ignore[list-item]
        self.gust_rng: np.random.Generator | None = None  # the last reset's, so gusts follow the env's seed
        self.ahead: list[np.ndarray] = [None] * n  # type: ignore[list-item]
        self.path: list[list[tuple[float, float]]] = [[] for _ in range(n)]

    def branch(self) -> "LaneDriveSim":
        """A copy whose cars go on independently of this one's (the roads, maps and camera shared,
        read-only): what-if drives from the same states (actors.evaluation.steer_probe)."""
        other = copy.copy(self)
        for name, value in vars(self).items():
            if isinstance(value, np.ndarray):
                setattr(other, name, value.copy())
        other.tracks, other.maps, other.ahead = list(self.tracks), list(self.maps), list(self.ahead)
        other.path = [list(p) for p in self.path]
        other.gust_rng = copy.deepcopy(self.gust_rng)  # the branch's gusts draw on without moving this one's
        return other

    # -- episodes -----------------------------------------------------------------------
    def _choose_track(self, rng: np.random.Generator, options: dict) -> str:
        name = options.get("track") or self.cfg.track
        if name in ("train", "test", "all"):
            name = str(rng.choice(track_names(name)))
        direction = options.get("direction") or self.cfg.direction
        if direction == "random":
            direction = "cw" if rng.random() < 0.5 else "ccw"
        if name == "procedural":
            name = f"procedural:{int(options.get('track_seed', rng.integers(2**31)))}"
        return name + ("-r" if direction == "cw" and not name.endswith("-r") else "")

    def reset(self, i: int, rng: np.random.Generator, options: dict | None = None) -> None:
        """Start car `i` on a road chosen by `options['track']` or the configured track set."""
        options = options or {}
        damage = (self.cfg.damage.gap_fraction, self.cfg.damage.fade_fraction, self.cfg.damage.distractors_per_100m)
        if isinstance(options.get("track"), Track):  # a hand-made road, drawn just for this episode
            track = options["track"]
            self.maps[i] = build_road_map(track, self.cfg.lane_width, DamageConfig(*damage), 0)
            self.ahead[i] = track.curvature_ahead(LOOKAHEAD_M)
        else:
            name = self._choose_track(rng, options)
            track = get_track(name)
            self.maps[i] = road_map(name.removesuffix("-r"), self.cfg.lane_width, damage)
            self.ahead[i] = curvature_ahead(name)
        self.tracks[i] = track
        random_start = options.get("random_start", self.cfg.random_start)
        s0 = rng.uniform(0, track.length) if random_start else 0.0
        offset = rng.uniform(-0.25, 0.25) * self.half if random_start else 0.0
        yaw = rng.uniform(-0.1, 0.1) if random_start else 0.0
        self.v[i] = 0.5 * self.cfg.vehicle.v_max  # the slowest target speed
        self.delta[i] = 0.0
        self.steps[i] = 0
        self.reward[i] = 0.0
        self.last_action[i] = (0.0, -1.0)
        self.luts[i] = _brightness_table(rng, self.cfg.lighting)
        self.gust_rng = rng
        self.place(i, s0, offset, yaw)

    def place(self, i: int, s: float, lateral: float, yaw: float) -> None:
        """Put car `i` at arclength `s` (m), `lateral` m left of the centre, heading `yaw` rad
        left of the road; restarts its lap count, path and both camera frames there."""
        track = self.tracks[i]
        k = int(round(s / track.spacing)) % len(track.xy)
        h = track.heading[k]
        self.set_pose(i, track.xy[k, 0] - math.sin(h) * lateral, track.xy[k, 1] + math.cos(h) * lateral, h + yaw)

    def set_pose(self, i: int, x: float, y: float, theta: float) -> None:
        """Put car `i` at a world pose (m, m, rad); restarts its lap count, path and camera frames."""
        self.x[i], self.y[i] = x, y
        self.theta[i] = (theta + math.pi) % (2 * math.pi) - math.pi
        d = self.tracks[i].xy - (x, y)
        self.idx[i] = int(np.argmin(np.einsum("ij,ij->i", d, d)))
        self._locate(i)
        self.travelled[i] = 0.0
        self.path[i] = [(self.x[i], self.y[i])]
        self.camera.render(
            [self.maps[i]],
            self.x[i : i + 1],
            self.y[i : i + 1],
            self.theta[i : i + 1],
            self.luts[i : i + 1],
            self.frames[i : i + 1, 0],
        )
        self.frames[i, 1] = self.frames[i, 0]

    # -- dynamics -----------------------------------------------------------------------
    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Advance every car by one control period; returns (terminated, truncated)."""
        actions = np.asarray(actions, np.float64).reshape(self.n, 2)
        if not np.isfinite(actions).all():
            raise ValueError(f"LaneDrive actions must be finite, got {actions.tolist()}")
        a = np.minimum(np.maximum(actions, -1.0), 1.0)
        vc = self.cfg.vehicle
        dt, rate = vc.dt, vc.steer_rate * vc.dt
        self.delta += np.minimum(np.maximum(a[:, 0] * vc.max_steer - self.delta, -rate), rate)
        self.v += (target_speed(vc.v_max, a[:, 1]) - self.v) * (1.0 - math.exp(-dt / vc.speed_lag))
        k_grip = vc.max_lateral_accel / (self.v * self.v)  # speed never falls below v_max / 2
        kappa = np.minimum(np.maximum(np.tan(self.delta) / vc.wheelbase, -k_grip), k_grip)
        dtheta = self.v * kappa * dt
        mid = self.theta + 0.5 * dtheta
        step = self.v * dt
        self.x += step * np.cos(mid)
        self.y += step * np.sin(mid)
        self.theta = (self.theta + dtheta + self._gusts() + math.pi) % (2 * math.pi) - math.pi
        self.last_action[:] = a
        self.steps += 1
        for i in range(self.n):
            self._locate(i)
            if len(self.path[i]) < PATH_LEN:
                self.path[i].append((self.x[i], self.y[i]))
        self.reward = self.v * (np.cos(self.beta) - np.abs(self.alpha)) / vc.v_max
        self.frames[:, 1] = self.frames[:, 0]
        self.camera.render(self.maps, self.x, self.y, self.theta, self.luts, self.frames[:, 0])
        terminated = np.abs(self.alpha) > 1.0
        truncated = (self.steps >= self.cfg.max_steps) & ~terminated
        return terminated, truncated

    def _gusts(self) -> np.ndarray | float:
        """Heading kicks of `env.gust_rate` (training only), uniform in +-`env.gust_yaw` rad."""
        if not self.cfg.gust_rate or self.gust_rng is None:
            return 0.0
        hit = self.gust_rng.random(self.n) < self.cfg.gust_rate
        return np.where(hit, self.gust_rng.uniform(-self.cfg.gust_yaw, self.cfg.gust_yaw, self.n), 0.0)

    def _locate(self, i: int) -> None:
        """Nearest centreline sample near the last one; sets alpha, beta and lap distance."""
        tr = self.tracks[i]
        m = len(tr.xy)
        x, y = float(self.x[i]), float(self.y[i])
        cand = (int(self.idx[i]) + _WINDOW) % m
        d = tr.xy[cand]
        dx, dy = d[:, 0] - x, d[:, 1] - y
        k = int(cand[np.argmin(dx * dx + dy * dy)])
        h = tr.heading[k]
        px, py = x - tr.xy[k, 0], y - tr.xy[k, 1]
        lateral = math.cos(h) * py - math.sin(h) * px
        along = math.cos(h) * px + math.sin(h) * py
        moved = ((k - self.idx[i]) % m) * tr.spacing
        if moved > tr.length / 2:
            moved -= tr.length
        self.travelled[i] += moved
        self.idx[i] = k
        self.alpha[i] = lateral / self.half
        self.beta[i] = (self.theta[i] - h - tr.curvature[k] * along + math.pi) % (2 * math.pi) - math.pi

    # -- views --------------------------------------------------------------------------
    def observation(self) -> dict[str, np.ndarray]:
        return {
            "image": self.frames.copy(),
            "speed": (self.v / self.cfg.vehicle.v_max).astype(np.float32)[:, None],
            "last_action": self.last_action.copy(),
        }

    def info(self, i: int) -> dict:
        tr = self.tracks[i]
        return {
            "alpha": float(self.alpha[i]),
            "beta": float(self.beta[i]),
            "speed": float(self.v[i]),
            "track": tr.name,
            "progress": float(self.travelled[i] / tr.length),
            "lap_completed": bool(self.travelled[i] >= tr.length),
            "curvature": float(tr.curvature[self.idx[i]]),
            "curvature_ahead": float(self.ahead[i][self.idx[i]]),
            "lane_half_width": self.half,
            "station": float(self.idx[i] * tr.spacing),
            "steer": float(self.delta[i]),
            "steps": int(self.steps[i]),
        }
