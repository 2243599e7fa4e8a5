"""A grayscale top-down map of one road, stored as tiles, that the camera samples.

Only the tiles along the road are stored (about 2 MB for a 600 m road at 10 cm per cell);
every other tile points at one of a few shared grass tiles, so every library road fits in
memory at once and a reset never waits for a map to be drawn twice.

Pixel values: off-road grass ~45-85, asphalt ~100-115, lane markings ~215. Damaged markings
(random gaps, faded stretches) and distractor marks on the road are drawn here, seeded, for
the paper's damaged-road tests.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from actors.envs.tracks import Track
from common.config.env import DamageConfig

RES = 0.1  # metres per cell
TILE_BITS = 5
TILE = 1 << TILE_BITS  # cells per tile side
MARGIN = 125.0  # metres of grass around the road; more than the camera's range (121 m at 3 m high)
MARKING_WIDTH = 0.2
SHOULDER = 1.0  # asphalt beyond each lane marking
N_GRASS = 16
ASPHALT, MARKING = 106, 215


@dataclass
class RoadMap:
    """Tiles (n, TILE, TILE) uint8, a (rows, cols) table of tile ids, and the map origin."""

    tiles: np.ndarray
    table: np.ndarray
    x0: float
    y0: float

    def lookup(self, gx: np.ndarray, gy: np.ndarray) -> np.ndarray:
        """Cell values at grid coordinates (cells from the origin); clipped at the map edge."""
        ix = gx.astype(np.int32)
        iy = gy.astype(np.int32)
        rows, cols = self.table.shape
        tile = self.table.ravel().take((iy >> TILE_BITS) * cols + (ix >> TILE_BITS), mode="clip")
        flat = (tile << (2 * TILE_BITS)) | ((iy & (TILE - 1)) << TILE_BITS) | (ix & (TILE - 1))
        return self.tiles.ravel().take(flat, mode="clip")

    def to_grid(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return (x - self.x0) / RES, (y - self.y0) / RES


def _grass_tiles(rng: np.random.Generator) -> np.ndarray:
    """A few grass tiles: a per-tile tone, smooth blotches and fine noise."""
    coarse = rng.normal(0.0, 8.0, (N_GRASS, 5, 5))
    up = np.linspace(0, 4, TILE)
    i0 = np.floor(up).astype(int).clip(0, 3)
    f = up - i0
    rows = coarse[:, i0] * (1 - f)[None, :, None] + coarse[:, i0 + 1] * f[None, :, None]
    smooth = rows[:, :, i0] * (1 - f) + rows[:, :, i0 + 1] * f
    tone = rng.uniform(55, 75, (N_GRASS, 1, 1))
    return np.clip(tone + smooth + rng.normal(0, 6.0, smooth.shape), 0, 255).astype(np.uint8)


def _intervals(rng: np.random.Generator, length: float, fraction: float, lo: float, hi: float) -> np.ndarray:
    """Random [start, end) stretches along the lap covering about `fraction` of it."""
    if fraction <= 0:
        return np.zeros((0, 2))
    n = max(1, int(fraction * length / ((lo + hi) / 2)))
    start = rng.uniform(0, length, n)
    return np.stack([start, start + rng.uniform(lo, hi, n)], 1)


def _in_intervals(s: np.ndarray, iv: np.ndarray, length: float) -> np.ndarray:
    hit = np.zeros(s.shape, bool)
    for a, b in iv:
        hit |= ((s - a) % length) < (b - a)
    return hit


def build_road_map(track: Track, lane_width: float, damage: DamageConfig, seed: int) -> RoadMap:
    """Draw `track` with a lane of `lane_width` metres (markings at +-lane_width/2)."""
    rng = np.random.default_rng(seed)
    half = lane_width / 2
    lo, hi = track.xy.min(0) - MARGIN, track.xy.max(0) + MARGIN
    cols = int(math.ceil((hi[0] - lo[0]) / RES / TILE))
    rows = int(math.ceil((hi[1] - lo[1]) / RES / TILE))
    grass = _grass_tiles(rng)
    table = rng.integers(0, N_GRASS, (rows, cols)).astype(np.int32)

    # Centreline at half-cell spacing so that the painted band has no holes.
    step = RES / 2
    s = np.arange(0, track.length, step)
    i = s / track.spacing
    i0 = np.floor(i).astype(int) % len(track.xy)
    i1 = (i0 + 1) % len(track.xy)
    w = (i - np.floor(i))[:, None]
    c = track.xy[i0] * (1 - w) + track.xy[i1] * w
    normal = np.stack([-np.sin(track.heading[i0]), np.cos(track.heading[i0])], 1)  # points left

    def cells(offsets: np.ndarray, mask: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        cc, nn = (c, normal) if mask is None else (c[mask], normal[mask])
        p = cc[:, None, :] + offsets[None, :, None] * nn[:, None, :]
        return ((p[..., 0] - lo[0]) / RES).astype(np.int64).ravel(), ((p[..., 1] - lo[1]) / RES).astype(
            np.int64
        ).ravel()

    road_x, road_y = cells(np.arange(-(half + SHOULDER), half + SHOULDER + 1e-9, step))
    # Give every tile the road touches its own copy of its grass tile, then paint into those copies.
    touched = np.unique((road_y >> TILE_BITS) * cols + (road_x >> TILE_BITS))
    own = np.arange(N_GRASS, N_GRASS + len(touched), dtype=np.int32)
    tiles = np.concatenate([grass, grass[table.ravel()[touched]]])
    table.ravel()[touched] = own
    flat_tiles = tiles.reshape(-1)

    def paint(x: np.ndarray, y: np.ndarray, value: np.ndarray | int) -> None:
        tid = table.ravel()[(y >> TILE_BITS) * cols + (x >> TILE_BITS)]
        flat_tiles[(tid.astype(np.int64) << (2 * TILE_BITS)) | ((y & (TILE - 1)) << TILE_BITS) | (x & (TILE - 1))] = (
            value
        )

    paint(road_x, road_y, (ASPHALT + rng.normal(0, 3.0, road_x.shape)).clip(0, 255).astype(np.uint8))
    band = np.arange(-MARKING_WIDTH / 2, MARKING_WIDTH / 2 + 1e-9, step)
    for side in (-1.0, 1.0):
        gaps = _intervals(rng, track.length, damage.gap_fraction, 1.0, 6.0)
        faded = _intervals(rng, track.length, damage.fade_fraction, 3.0, 15.0)
        keep = ~_in_intervals(s, gaps, track.length)
        level = np.where(_in_intervals(s, faded, track.length), rng.uniform(0.15, 0.5), 1.0)[keep]
        mx, my = cells(side * half + band, keep)
        value = ASPHALT + (MARKING - ASPHALT) * np.repeat(level, len(band))
        paint(mx, my, value.astype(np.uint8))
    n_marks = int(damage.distractors_per_100m * track.length / 100)
    for _ in range(n_marks):
        k = int(rng.integers(len(s)))
        ang = rng.uniform(0, math.pi)
        along = np.arange(-rng.uniform(0.5, 1.5), rng.uniform(0.5, 1.5), step)
        centre = c[k] + rng.uniform(-half * 0.8, half * 0.8) * normal[k]
        d = np.array([math.cos(ang), math.sin(ang)])
        p = centre[None, None, :] + along[:, None, None] * d + band[None, :, None] * np.array([-d[1], d[0]])
        paint(
            ((p[..., 0] - lo[0]) / RES).astype(np.int64).ravel(),
            ((p[..., 1] - lo[1]) / RES).astype(np.int64).ravel(),
            MARKING,
        )
    return RoadMap(tiles, table, float(lo[0]), float(lo[1]))
