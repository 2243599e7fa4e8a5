"""The TORCS counterpart of LaneDriveSim: N cars, each in its own TORCS process (protocol.py),
stepped together (every process is sent its action before any is read, so they simulate at once),
with LaneDrive's camera rendering each car's view of its road drawn from the track XML.

Ground truth from TORCS, in LaneDrive's terms. The lane is the whole road: alpha = toMiddle / (road
width / 2), +1 on the left edge (the car's centre on the edge line's outside), as gym_torcs's
trackPos; beta = -angle (car heading minus road heading, + pointing left). Reward
r = v/v_max (cos beta - |alpha|), termination when |alpha| > 1, truncation at max_steps, or when
TORCS had to be relaunched mid-episode (the episode cannot go on from the same state).

The camera pose is TORCS's track-relative pose (distFromStartLine, toMiddle, angle) placed on our
centreline of the same road (geometry.py), so the image agrees with alpha and beta by construction;
tests check that centreline against TORCS's own x, y at hand-placed poses.
"""

from __future__ import annotations

import math
from functools import lru_cache
from pathlib import Path

import numpy as np

from actors.envs.camera import HEIGHT, WIDTH, Camera
from actors.envs.road_map import RoadMap
from actors.envs.sim import LOOKAHEAD_M, _brightness_table, target_speed
from actors.envs.torcs.geometry import TorcsRoad, centreline, read_road
from actors.envs.torcs.protocol import CarState, TorcsInstall, TorcsProcess
from actors.envs.torcs.race import RaceSpec
from actors.envs.torcs.road_map import load_or_build
from actors.envs.torcs.roads import training_roads
from actors.envs.tracks import Track
from common.config.env import DamageConfig, EnvConfig, VehicleConfig

STEER_LOCK = math.radians(21.0)  # car1-trb1's steer lock: TORCS turns the wheels this far at steer = 1
WHEELBASE = 2.64  # car1-trb1: front axle 1.22 m, rear axle -1.42 m from the centre of gravity


def torcs_vehicle(v_max: float) -> VehicleConfig:
    """The TORCS car in the terms the kinematic controller and the MPC read (action +1 = STEER_LOCK)."""
    return VehicleConfig(wheelbase=WHEELBASE, max_steer=STEER_LOCK, v_max=v_max)


@lru_cache(maxsize=64)
def road_geometry(name: str, data_dir: str) -> tuple[TorcsRoad, Track, np.ndarray]:
    """A road's XML geometry, its centreline and its curvature ahead, read once per process."""
    road = read_road(name, Path(data_dir))
    track = centreline(road)
    return road, track, track.curvature_ahead(LOOKAHEAD_M)


@lru_cache(maxsize=12)  # ~10 MB a road (spring: 60 MB); actors sample from ~26 roads, the disk cache holds all
def road_map(name: str, data_dir: str, damage: tuple) -> RoadMap:
    road, track, _ = road_geometry(name, data_dir)
    return load_or_build(road, track, DamageConfig(*damage), seed=0)


class TorcsSim:
    """State of `n` cars in `n` TORCS processes; the gymnasium envs are thin views of this."""

    def __init__(self, cfg: EnvConfig, n: int, install: TorcsInstall) -> None:
        cfg.validate()
        if cfg.track == "procedural":
            raise ValueError("TorcsDrive drives torcs-data roads: track must be 'train', 'test', 'all' or a road name")
        self.cfg, self.n, self.install = cfg, n, install
        self.v_max = cfg.vehicle.v_max
        self.data_dir = str(install.data_dir)
        self.damage = (cfg.damage.gap_fraction, cfg.damage.fade_fraction, cfg.damage.distractors_per_100m)
        self.camera = Camera(cfg.camera_height)
        self.procs = [TorcsProcess(install) for _ in range(n)]
        z = lambda: np.zeros(n)  # noqa: E731
        self.alpha, self.beta, self.speed, self.reward, self.travelled = z(), z(), z(), z(), z()
        self.x, self.y, self.theta = z(), z(), z()
        self.idx = np.zeros(n, np.int64)
        self.steps = np.zeros(n, np.int64)
        self.relaunched = np.zeros(n, bool)
        self.last_action = np.zeros((n, 2), np.float32)
        self.frames = np.zeros((n, 2, HEIGHT, WIDTH), np.uint8)  # [current, previous]
        self.luts = np.tile(np.arange(256, dtype=np.uint8), (n, 1))
        self.states: list[CarState] = [None] * n  # type: ignore[list-item]
        self.roads: list[TorcsRoad] = [None] * n  # type: ignore[list-item]
        self.tracks: list[Track] = [None] * n  # type: ignore[list-item]
        self.maps: list[RoadMap] = [None] * n  # type: ignore[list-item]
        self.ahead: list[np.ndarray] = [None] * n  # type: ignore[list-item]

    # -- episodes -----------------------------------------------------------------------
    def reset(self, i: int, rng: np.random.Generator, options: dict | None = None) -> None:
        """Start car `i` on a road chosen by `options['track']` or the configured road set.

        ``options`` may pose the car: ``start`` (m from the start line), ``to_middle`` (m, + left),
        ``yaw`` (rad from the road's direction); otherwise ``random_start`` draws them as LaneDrive.
        """
        options = options or {}
        name = options.get("track") or self.cfg.track
        if name in ("train", "test", "all"):  # the validation roads are never drawn
            name = str(rng.choice(training_roads(name)))
        road, track, ahead = road_geometry(name, self.data_dir)
        self.roads[i], self.tracks[i], self.ahead[i] = road, track, ahead
        self.maps[i] = road_map(name, self.data_dir, self.damage)
        half = road.width / 2
        random_start = options.get("random_start", self.cfg.random_start)
        start = rng.uniform(0, road.length) if random_start else 0.0
        to_middle = rng.uniform(-0.25, 0.25) * half if random_start else 0.0
        yaw = rng.uniform(-0.1, 0.1) if random_start else 0.0
        spec = RaceSpec(
            name,
            road.category,
            start=float(options.get("start", start)),
            to_middle=float(options.get("to_middle", to_middle)),
            yaw=float(options.get("yaw", yaw)),
        )
        self.states[i] = self.procs[i].reset(spec)
        self.steps[i] = 0
        self.travelled[i] = 0.0
        self.reward[i] = 0.0
        self.relaunched[i] = False
        self.last_action[i] = (0.0, -1.0)
        self.luts[i] = _brightness_table(rng, self.cfg.lighting)
        self._locate(i)
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
    def step(self, actions: np.ndarray, active: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Advance every car (or the `active` ones; the others stand still, their TORCS idle) by 0.1 s of
        TORCS time; returns (terminated, truncated)."""
        actions = np.asarray(actions, np.float64).reshape(self.n, 2)
        if not np.isfinite(actions).all():
            raise ValueError(f"TorcsDrive actions must be finite, got {actions.tolist()}")
        live = np.ones(self.n, bool) if active is None else np.asarray(active, bool).reshape(self.n)
        a = np.where(live[:, None], np.clip(actions, -1.0, 1.0), self.last_action)
        target = target_speed(self.v_max, a[:, 1])
        cars = np.flatnonzero(live)
        for i in cars:
            self.procs[i].send(float(a[i, 0]), float(target[i]))
        for i in cars:
            p = self.procs[i]
            before = self.states[i].dist_from_start
            self.states[i] = p.receive()
            self.relaunched[i] = self.states[i].step == 0  # a relaunch started the race afresh
            moved = self.states[i].dist_from_start - before
            length = self.states[i].track_length
            self.travelled[i] += (moved + length / 2) % length - length / 2 if not self.relaunched[i] else 0.0
            self._locate(i)
        self.last_action[:] = a
        self.steps[live] += 1
        self.reward = self.speed * (np.cos(self.beta) - np.abs(self.alpha)) / self.v_max
        self.frames[live, 1] = self.frames[live, 0]  # a car that stood still keeps its pair (its view is unchanged)
        self.camera.render(self.maps, self.x, self.y, self.theta, self.luts, self.frames[:, 0])
        terminated = (np.abs(self.alpha) > 1.0) & ~self.relaunched
        truncated = ((self.steps >= self.cfg.max_steps) | self.relaunched) & ~terminated
        return terminated, truncated

    def _locate(self, i: int) -> None:
        """alpha and beta from TORCS, and the camera's pose: TORCS's road-relative pose on our centreline."""
        st, tr, road = self.states[i], self.tracks[i], self.roads[i]
        self.alpha[i] = st.to_middle / (road.width / 2)
        self.beta[i] = -st.angle
        self.speed[i] = st.speed
        m = len(tr.xy)
        f = (st.dist_from_start / st.track_length) % 1.0 * m
        k0 = int(f) % m
        w = f - int(f)
        k1 = (k0 + 1) % m
        h = tr.heading[k0] + tr.curvature[k0] * w * tr.spacing
        px = tr.xy[k0, 0] * (1 - w) + tr.xy[k1, 0] * w
        py = tr.xy[k0, 1] * (1 - w) + tr.xy[k1, 1] * w
        self.x[i] = px - math.sin(h) * st.to_middle
        self.y[i] = py + math.cos(h) * st.to_middle
        self.theta[i] = h - st.angle
        self.idx[i] = k0

    # -- views --------------------------------------------------------------------------
    def observation(self) -> dict[str, np.ndarray]:
        return {
            "image": self.frames.copy(),
            "speed": np.clip(self.speed / self.v_max, 0.0, 1.0).astype(np.float32)[:, None],
            "last_action": self.last_action.copy(),
        }

    def info(self, i: int) -> dict:
        st, tr = self.states[i], self.tracks[i]
        return {
            "alpha": float(self.alpha[i]),
            "beta": float(self.beta[i]),
            "speed": float(self.speed[i]),
            "track": self.roads[i].name,
            "progress": float(self.travelled[i] / st.track_length),
            "lap_completed": bool(self.travelled[i] >= st.track_length),
            "curvature": float(tr.curvature[self.idx[i]]),
            "curvature_ahead": float(self.ahead[i][self.idx[i]]),
            "lane_half_width": self.roads[i].width / 2,
            "station": float(st.dist_from_start % st.track_length),  # TORCS reports the start line as L, not 0
            "steer": float(st.steer * STEER_LOCK),
            "steps": int(self.steps[i]),
            "relaunched": bool(self.relaunched[i]),
            "damage": int(st.damage),
        }

    def close(self) -> None:
        for p in self.procs:
            p.close()
