"""The camera map of a TORCS road: LaneDrive's tiled grayscale ground map (actors/envs/road_map.py)
drawn from the road's XML geometry, so LaneDrive's camera renders TORCS roads unchanged.

What is drawn, across the road from its middle line: the road surface over the road's width
(asphalt ~100, dirt and sand roads lighter ~140), white edge lines 0.3 m inside both edges on paved
roads (TORCS's asphalt textures carry them; dirt roads have none), the default side strips of the
XML (sand/gravel/dirt lighter, asphalt/concrete mid-grey, grass left as grass, capped at 6 m), and
LaneDrive's grass everywhere else. Damage (gaps, faded stretches, distractor strokes) works as on
LaneDrive, on the edge lines. Elevation is ignored: the camera sees the road as if it were flat.

TORCS roads are long (up to 22 km), so a map is painted in chunks (bounded memory) and kept on disk
under ``map_cache_dir()``: each road is drawn once per machine (seconds) and loaded in milliseconds.
"""

from __future__ import annotations

import hashlib
import math
import os
import tempfile
from pathlib import Path

import numpy as np

from actors.envs.road_map import (
    MARGIN,
    MARKING,
    MARKING_WIDTH,
    N_GRASS,
    RES,
    TILE,
    TILE_BITS,
    RoadMap,
    _grass_tiles,
    _in_intervals,
    _intervals,
)
from actors.envs.torcs.geometry import TorcsRoad
from actors.envs.tracks import Track
from common.config.env import DamageConfig

MAP_VERSION = 1  # bump when the drawing changes: cached maps of another version are redrawn
EDGE_INSET = 0.3  # edge line centre, m inside the road edge
MAX_SIDE = 6.0  # side strips drawn at most this wide (pit lanes are 15 m; the camera needs the edge)
CHUNK_M = 100.0  # metres of road painted at once (memory stays at a few tens of MB)
STEP = RES / 2  # sampling of the painted band, along and across: no holes between cells
DIRT_WORDS = ("dirt", "sand", "gravel", "mud", "snow")


def _surface_tone(material: str) -> float | None:
    """Mean grey of a TORCS surface material; None for grass (left as LaneDrive's grass tiles)."""
    m = material.lower()
    if "grass" in m:
        return None
    if any(w in m for w in DIRT_WORDS):
        return 140.0
    return 120.0  # asphalt, concrete, pits, curbs: paved, a little lighter than the road


def is_paved(road: TorcsRoad) -> bool:
    """Paved roads get edge lines; dirt and sand roads do not."""
    return not any(w in road.surface.lower() for w in DIRT_WORDS)


def map_cache_dir() -> Path:
    """$GVF_TORCS_MAP_CACHE, else ~/.cache/gvf-drive/torcs-maps."""
    env = os.environ.get("GVF_TORCS_MAP_CACHE")
    return Path(env) if env else Path.home() / ".cache" / "gvf-drive" / "torcs-maps"


def _key(road: TorcsRoad, damage: DamageConfig, seed: int) -> str:
    text = repr((MAP_VERSION, road.name, road.width, road.length, road.surface, road.side_width, road.side_surface))
    text += repr((damage.gap_fraction, damage.fade_fraction, damage.distractors_per_100m, seed))
    return f"{road.name}-{hashlib.sha256(text.encode()).hexdigest()[:16]}.npz"


def load_or_build(road: TorcsRoad, track: Track, damage: DamageConfig, seed: int, cache: bool = True) -> RoadMap:
    """The road's map from the disk cache, or drawn now (and stored atomically for the next process)."""
    path = map_cache_dir() / _key(road, damage, seed)
    if cache and path.exists():
        with np.load(path) as z:
            return RoadMap(z["tiles"], z["table"], float(z["x0"]), float(z["y0"]))
    m = build_torcs_road_map(road, track, damage, seed)
    if cache:
        path.parent.mkdir(parents=True, exist_ok=True)
        # Several actor processes may draw the same road at once: each writes its own file, the last rename wins.
        fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp.npz")
        with os.fdopen(fd, "wb") as f:
            np.savez(f, tiles=m.tiles, table=m.table, x0=m.x0, y0=m.y0)
        os.replace(tmp, path)
    return m


def build_torcs_road_map(road: TorcsRoad, track: Track, damage: DamageConfig, seed: int) -> RoadMap:
    """Draw ``road`` (whose middle line is ``track``) into a LaneDrive ``RoadMap``."""
    rng = np.random.default_rng(seed)
    half = road.width / 2
    sides = [
        min(MAX_SIDE, w) if _surface_tone(m) is not None else 0.0 for w, m in zip(road.side_width, road.side_surface)
    ]
    left_reach, right_reach = half + max(sides[0], 1.0), half + max(sides[1], 1.0)
    lo, hi = track.xy.min(0) - MARGIN, track.xy.max(0) + MARGIN
    cols = int(math.ceil((hi[0] - lo[0]) / RES / TILE))
    rows = int(math.ceil((hi[1] - lo[1]) / RES / TILE))
    grass = _grass_tiles(rng)
    table = rng.integers(0, N_GRASS, (rows, cols)).astype(np.int32)
    road_tone = 140.0 if not is_paved(road) else 103.0
    side_tone = [_surface_tone(m) for m in road.side_surface]
    offsets = np.arange(-right_reach, left_reach + 1e-9, STEP)  # + left, as TORCS's toMiddle
    tone = np.full(offsets.shape, np.nan)
    tone[np.abs(offsets) <= half] = road_tone
    for side, sign in ((0, 1.0), (1, -1.0)):
        band = (sign * offsets > half) & (sign * offsets <= half + sides[side])
        if side_tone[side] is not None:
            tone[band] = side_tone[side]
    painted = ~np.isnan(tone)
    offsets, tone = offsets[painted], tone[painted]
    line_band = np.arange(-MARKING_WIDTH / 2, MARKING_WIDTH / 2 + 1e-9, STEP)
    lines = []
    if is_paved(road):
        for sign in (1.0, -1.0):
            gaps = _intervals(rng, track.length, damage.gap_fraction, 1.0, 6.0)
            faded = _intervals(rng, track.length, damage.fade_fraction, 3.0, 15.0)
            lines.append((sign * (half - EDGE_INSET) + line_band, gaps, faded, rng.uniform(0.15, 0.5)))

    tiles = np.concatenate([grass, np.empty((1024, TILE, TILE), np.uint8)])
    n_tiles = N_GRASS
    flat_table = table.ravel()
    fresh = np.zeros(flat_table.shape, bool)  # scratch: tiles first touched by the current chunk
    per_chunk = int(CHUNK_M / STEP)
    noise = rng.normal(0, 3.0, (per_chunk, len(offsets))).astype(np.float32)  # reused: a 100 m repeat is invisible
    base = np.broadcast_to(tone.astype(np.float32), noise.shape) + noise
    s_all = np.arange(0, track.length, STEP)
    for start in range(0, len(s_all), per_chunk):
        s = s_all[start : start + per_chunk]
        c, normal = _frame(track, s)
        x, y = _cells(c, normal, offsets, lo)
        # Every tile this chunk touches gets its own copy of its grass tile (once), then is painted.
        tid = (y >> TILE_BITS) * cols + (x >> TILE_BITS)
        fresh[tid[flat_table[tid] < N_GRASS]] = True
        new = np.flatnonzero(fresh)
        fresh[new] = False
        if n_tiles + len(new) > len(tiles):  # grow by doubling: appending chunk by chunk stays linear
            tiles = np.concatenate([tiles, np.empty((max(len(tiles), len(new)), TILE, TILE), np.uint8)])
        tiles[n_tiles : n_tiles + len(new)] = grass[flat_table[new]]
        flat_table[new] = np.arange(n_tiles, n_tiles + len(new), dtype=np.int32)
        n_tiles += len(new)
        flat_tiles = tiles.reshape(-1)
        _paint(flat_tiles, flat_table, cols, x, y, base[: len(s)].ravel().clip(0, 255).astype(np.uint8))
        for offs, gaps, faded, fade_level in lines:
            keep = ~_in_intervals(s, gaps, track.length)
            level = np.where(_in_intervals(s, faded, track.length), fade_level, 1.0)[keep]
            mx, my = _cells(c[keep], normal[keep], offs, lo)
            v = road_tone + (MARKING - road_tone) * np.repeat(level, len(offs))
            _paint(flat_tiles, flat_table, cols, mx, my, v.astype(np.uint8))
    tiles = tiles[:n_tiles]
    n_marks = int(damage.distractors_per_100m * track.length / 100)
    flat_tiles = tiles.reshape(-1)
    for _ in range(n_marks):  # distractor strokes on the road, as LaneDrive's
        s0 = rng.uniform(0, track.length)
        c, normal = _frame(track, np.array([s0]))
        ang = rng.uniform(0, math.pi)
        along = np.arange(-rng.uniform(0.5, 1.5), rng.uniform(0.5, 1.5), STEP)
        centre = c[0] + rng.uniform(-half * 0.8, half * 0.8) * normal[0]
        d = np.array([math.cos(ang), math.sin(ang)])
        p = centre[None, None, :] + along[:, None, None] * d + line_band[None, :, None] * np.array([-d[1], d[0]])
        px, py = (
            ((p[..., 0] - lo[0]) / RES).astype(np.int64).ravel(),
            ((p[..., 1] - lo[1]) / RES).astype(np.int64).ravel(),
        )
        ok = flat_table[(py >> TILE_BITS) * cols + (px >> TILE_BITS)] >= N_GRASS  # only onto painted tiles
        _paint(flat_tiles, flat_table, cols, px[ok], py[ok], MARKING)
    return RoadMap(tiles, table, float(lo[0]), float(lo[1]))


def _frame(track: Track, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Middle-line points and left normals at arclengths ``s`` (linear between the 0.25 m samples)."""
    i = s / track.spacing
    i0 = np.floor(i).astype(int) % len(track.xy)
    i1 = (i0 + 1) % len(track.xy)
    w = (i - np.floor(i))[:, None]
    c = track.xy[i0] * (1 - w) + track.xy[i1] * w
    h = track.heading[i0] + track.curvature[i0] * w[:, 0] * track.spacing
    return c, np.stack([-np.sin(h), np.cos(h)], 1)


def _cells(c: np.ndarray, normal: np.ndarray, offsets: np.ndarray, lo: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Grid cells (x, y) of the points at lateral ``offsets`` from middle-line points ``c`` (float32: cells
    stay exact to a hundredth over any torcs-data road)."""
    cx = ((c[:, 0] - lo[0]) / RES).astype(np.float32)[:, None]
    cy = ((c[:, 1] - lo[1]) / RES).astype(np.float32)[:, None]
    o = (offsets / RES).astype(np.float32)[None, :]
    x = (cx + o * normal[:, 0].astype(np.float32)[:, None]).astype(np.int64).ravel()
    y = (cy + o * normal[:, 1].astype(np.float32)[:, None]).astype(np.int64).ravel()
    return x, y


def _paint(flat_tiles: np.ndarray, flat_table: np.ndarray, cols: int, x: np.ndarray, y: np.ndarray, value) -> None:
    tid = flat_table[(y >> TILE_BITS) * cols + (x >> TILE_BITS)].astype(np.int64)
    flat_tiles[(tid << (2 * TILE_BITS)) | ((y & (TILE - 1)) << TILE_BITS) | (x & (TILE - 1))] = value
