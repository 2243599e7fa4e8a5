"""The paper's data-collection controller (appendix "Data collection", eqs. 9-12, numbered
in order through the paper; eq. 8 is track sampling): pure pursuit toward the road's centre
waypoints shifted by a clipped random walk, at a random-walk target speed, so that an offline
data set covers states off the centreline and many actions while the car stays on the road.

    eq. 9   a_steer = clip(angle(p_t, p*_k(t)) - theta_t, -pi/2, pi/2),   a_speed = clip(v*_k(t), 0.2, 0.5)
    eq. 10  k(1) = 1,   k(t+1) = k(t) + 1 if ||p_t - p*_k(t)|| < r else k(t)          (r = 0.025 m)
    eq. 11  p*_j = p~_(j % N) + eps^p_j,   v*_j = v*_(j-1) + eps^v_j,   v*_1 = 0.35 m/s
    eq. 12  eps^p_j = clip(eps^p_(j-1) + N(0, 0.02 I), -0.3, 0.3),  eps^p_1 = 0,   eps^v_j = N(0, 0.02)

The walks are kept in the robot's units (m, m/s) so the paper's numbers appear unchanged, and
are scaled to LaneDrive (half lane width H = 3 m, speeds 10-20 m/s) as follows:

- eps^p (eqs. 11-12) by `scale` LaneDrive m per robot m. `for_lane_drive` uses
  REACH * H / 0.38, REACH = 0.35: the robot's walk reaches 0.3 / 0.38 = 0.79 of its half
  lane per axis, so diagonally past its lane edge (the paper: "not too far outside the road
  area"); LaneDrive ends the episode at the edge, and its car runs up to 0.7 H wide of the
  centreline in S-bends even without noise (a car at >= 10 m/s cannot turn like a robot on
  the spot), so the walk keeps to <= 0.28 H per axis (0.39 H diagonally).
- eq. 9's clip bands are the action box: steering [-pi/2, pi/2] -> [-1, 1], and target speed
  [0.2, 0.5] m/s -> `speed_actions`; `for_lane_drive` takes [-1, a_grip], a_grip being the
  fastest target speed that holds the tightest library bend (sqrt(a_lat * 18 m) = 12 m/s).
  v* is kept inside [0.2, 0.5] (eq. 9's clip applied to the walk's state): an unbounded walk
  of eq. 11 would sit at one end of the band after a few hundred targets.
- r of eq. 10 is not scaled (2.5 cm is less than one step of the robot; the car moves up to
  2 m per step): r is the pure-pursuit lookahead. eq. 9 steers in proportion to the heading
  error, delta = delta_max * e / (pi/2); a target l ahead on a circle of radius R is seen at
  e = l / 2R, so delta = L / R on every circle when l = pi * L / delta_max (16.3 m by default).
  The waypoints p~ are the centreline every 2 m (>= v_max * dt, so one advance per step keeps
  up) and r is that lookahead less half a spacing.

REACH is the largest multiple of 0.05 with which no car left the lane in 80 full episodes
(1200 steps, random starts) on the 40 library roads and 240 runs of 300 steps on the held-out
ones (0.4: one of each; 0.5: 2 and 4, all in tight S-bends).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from actors.envs.tracks import MIN_RADIUS

ROBOT_HALF_WIDTH = 0.38  # H of the paper's lane, m
STEER_CLIP = math.pi / 2  # eq. 9, rad
SPEED_CLIP = (0.2, 0.5)  # eq. 9, m/s
V_START = 0.35  # eq. 11, m/s
SIGMA_P, EPS_P_CLIP, SIGMA_V = 0.02, 0.3, 0.02  # eq. 12, m, m, m/s
WAYPOINT_SPACING = 2.0  # m of LaneDrive road between waypoints p~
REACH = 0.35  # fraction of the robot's lane-relative walk kept on LaneDrive (see above)


@dataclass
class RandomWalkPursuit:
    """One car's collector: `act(pose)` maps a world pose (x, y, theta) to an action in [-1, 1]^2."""

    p_tilde: np.ndarray
    """(N, 2) centre waypoints of the closed road in driving order, m."""
    rng: np.random.Generator
    scale: float
    """m of the simulator per m of the robot, for eps^p."""
    radius: float
    """Arrival radius r of eq. 10, m of the simulator."""
    speed_actions: tuple[float, float] = (-1.0, 1.0)
    """Target-speed actions that eq. 9's band [0.2, 0.5] m/s maps onto."""
    noise: bool = True
    """False: eps = 0, a plain pure-pursuit lane follower at v*_1."""
    k: int = 0
    """Index j of the current target pose (eq. 10), counted without the wrap j % N."""
    eps_p: np.ndarray = field(default_factory=lambda: np.zeros(2))
    """eps^p_k, robot m (eq. 12)."""
    v_star: float = V_START
    """v*_k, robot m/s (eq. 11)."""

    def target(self) -> np.ndarray:
        """p*_k in simulator metres (eq. 11)."""
        return self.p_tilde[self.k % len(self.p_tilde)] + self.scale * self.eps_p

    def advance(self) -> None:
        """Move to target pose j = k + 1 and draw its noise (eqs. 11-12)."""
        self.k += 1
        if self.noise:
            self.eps_p = np.clip(self.eps_p + self.rng.normal(0.0, SIGMA_P, 2), -EPS_P_CLIP, EPS_P_CLIP)
            self.v_star = float(np.clip(self.v_star + self.rng.normal(0.0, SIGMA_V), *SPEED_CLIP))

    def act(self, pose) -> np.ndarray:
        """Action (2,) for a world pose (x, y, theta): eq. 9 toward p*_k(t), then eq. 10 gives k(t+1)."""
        x, y, theta = (float(v) for v in pose)
        dx, dy = self.target() - (x, y)
        heading_error = (math.atan2(dy, dx) - theta + math.pi) % (2 * math.pi) - math.pi
        steer = np.clip(heading_error, -STEER_CLIP, STEER_CLIP) / STEER_CLIP
        lo, hi = self.speed_actions
        v = np.clip(self.v_star, *SPEED_CLIP)
        speed = lo + (hi - lo) * (v - SPEED_CLIP[0]) / (SPEED_CLIP[1] - SPEED_CLIP[0])
        if math.hypot(dx, dy) < self.radius:
            self.advance()
        return np.array([steer, speed], np.float32)


def lane_drive_pose(env, i: int = 0) -> np.ndarray:
    """Car i's world pose (x, y, theta) in a LaneDrive env: the simulator's localisation."""
    sim = env.unwrapped.sim
    return np.array([sim.x[i], sim.y[i], sim.theta[i]])


def for_lane_drive(env, rng: np.random.Generator, i: int = 0, **overrides) -> RandomWalkPursuit:
    """A collector for car i's current road (build a new one after every reset), scaled as the
    module docstring says. Its first target p*_1 is the first waypoint a lookahead r ahead of
    the car: a target beside a car that starts in a bend would yank it off the road."""
    sim = env.unwrapped.sim
    vc, track = sim.cfg.vehicle, sim.tracks[i]
    stride = max(1, int(round(WAYPOINT_SPACING / track.spacing)))
    p_tilde = track.xy[::stride]
    radius = overrides.get("radius", math.pi * vc.wheelbase / vc.max_steer - stride * track.spacing / 2)
    dist = np.linalg.norm(p_tilde - lane_drive_pose(env, i)[:2], axis=1)
    order = (int(np.argmin(dist)) + np.arange(len(p_tilde))) % len(p_tilde)  # ahead of the car, in order
    v_grip = math.sqrt(vc.max_lateral_accel * MIN_RADIUS) / vc.v_max  # fraction of v_max
    kwargs = {
        "scale": REACH * sim.half / ROBOT_HALF_WIDTH,
        "radius": radius,
        "speed_actions": (-1.0, float(np.clip((v_grip - 0.75) / 0.25, -1.0, 1.0))),
        "k": int(order[np.argmax(dist[order] >= radius)]),
    }
    return RandomWalkPursuit(p_tilde, rng, **{**kwargs, **overrides})
