"""Closed-loop roads made of straight and arc segments, and the named track library.

A track is described the way TORCS track files describe roads: a list of segments, each
``{"type": "straight", "length": L}`` or ``{"type": "arc", "radius": R, "angle": phi}``
(phi signed, positive turns left). :func:`build_centreline` integrates them into a densely
sampled centreline (points, heading, curvature, arclength) that the simulator uses for
ground truth (alpha, beta, progress) and the camera map.

Procedural tracks are rounded star-shaped polygons: every corner is filleted with an arc,
so a track is a loop of straights and arcs by construction and always closes.
The library (40 named tracks, fixed 34/6 train/test split) lives in ``tracks/library.json``
and is regenerated only by ``python -m actors.envs.make_library``.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

LIBRARY_PATH = Path(__file__).with_name("tracks") / "library.json"
SAMPLE_SPACING = 0.25  # metres between centreline samples used for ground truth
MIN_RADIUS = 18.0  # tightest arc; drivable at the minimum target speed without understeer
CLEARANCE = 24.0  # minimum distance between non-adjacent parts of a road (no overlaps in view)


@dataclass(frozen=True)
class Track:
    """A sampled closed centreline; arrays are indexed by sample i at arclength s[i]."""

    name: str
    segments: tuple
    xy: np.ndarray  # (M, 2) centreline points, metres
    heading: np.ndarray  # (M,) road direction, rad
    curvature: np.ndarray  # (M,) signed curvature, 1/m (positive = left turn)
    length: float  # lap length, metres

    @property
    def spacing(self) -> float:
        return self.length / len(self.xy)

    def reversed(self) -> "Track":
        """The same road driven the other way (clockwise <-> counter-clockwise)."""
        xy = self.xy[::-1].copy()
        heading = (self.heading[::-1] + math.pi + math.pi) % (2 * math.pi) - math.pi
        return Track(self.name + "-r", self.segments, xy, heading, -self.curvature[::-1].copy(), self.length)

    def curvature_ahead(self, horizon_m: float) -> np.ndarray:
        """Max |curvature| over the next `horizon_m` metres from every sample (for speed planning)."""
        n = max(1, int(round(horizon_m / self.spacing)))
        k = np.abs(self.curvature)
        padded = np.concatenate([k, k[:n]])
        # Sliding max by doubling windows: O(M log n), done once per track.
        out = padded.copy()
        width = 1
        while width < n:
            step = min(width, n - width)
            out[: len(padded) - step] = np.maximum(out[: len(padded) - step], out[step:])
            width += step
        return out[: len(k)]


def build_centreline(name: str, segments: list[dict], spacing: float = SAMPLE_SPACING) -> Track:
    """Integrate segments from the origin (heading 0) into a closed, evenly sampled centreline."""
    pts, heads, curvs = [], [], []
    x, y, th = 0.0, 0.0, 0.0
    for seg in segments:
        if seg["type"] == "straight":
            length, k = float(seg["length"]), 0.0
        elif seg["type"] == "arc":
            length, k = (
                float(seg["radius"]) * abs(float(seg["angle"])),
                math.copysign(1.0 / float(seg["radius"]), seg["angle"]),
            )
        else:
            raise ValueError(f"track {name}: unknown segment type {seg['type']!r}")
        ds = np.arange(0.0, length, spacing / 4)  # fine sub-samples, resampled evenly below
        if k == 0.0:
            px, py, ph = x + ds * math.cos(th), y + ds * math.sin(th), np.full_like(ds, th)
        else:
            ph = th + k * ds
            px, py = x + (np.sin(ph) - math.sin(th)) / k, y - (np.cos(ph) - math.cos(th)) / k
        pts.append(np.stack([px, py], 1))
        heads.append(ph)
        curvs.append(np.full_like(ds, k))
        if k == 0.0:
            x, y = x + length * math.cos(th), y + length * math.sin(th)
        else:
            th_end = th + k * length
            x, y = x + (math.sin(th_end) - math.sin(th)) / k, y - (math.cos(th_end) - math.cos(th)) / k
            th = th_end
    xy, heading, curvature = np.concatenate(pts), np.concatenate(heads), np.concatenate(curvs)
    # Rounded segment values leave a millimetre-scale gap; spread it linearly along the lap.
    gap = np.array([x, y]) - xy[0]
    if np.linalg.norm(gap) > 1.0:
        raise ValueError(f"track {name}: segments do not close (gap {np.linalg.norm(gap):.2f} m)")
    xy = xy - np.linspace(0, 1, len(xy), endpoint=False)[:, None] * gap
    seglen = np.linalg.norm(np.diff(np.vstack([xy, xy[:1]]), axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seglen)])
    length = float(s[-1])
    m = int(round(length / spacing))
    s_even = np.linspace(0.0, length, m, endpoint=False)
    closed = np.vstack([xy, xy[:1]])
    xy_e = np.stack([np.interp(s_even, s, closed[:, 0]), np.interp(s_even, s, closed[:, 1])], 1)
    uh = np.concatenate([heading, [heading[0] + th]])  # heading is accumulated, so th is the total turn
    head_e = (np.interp(s_even, s, uh) + math.pi) % (2 * math.pi) - math.pi
    curv_e = curvature[np.minimum(np.searchsorted(s, s_even, side="right") - 1, len(curvature) - 1)]
    return Track(name, tuple(dict(seg) for seg in segments), xy_e, head_e, curv_e, length)


def fillet_polygon(vertices: np.ndarray, radii: np.ndarray, min_straight: float = 5.0) -> list[dict] | None:
    """Segments of a polygon whose corners are rounded by arcs; None if the arcs do not fit."""
    n = len(vertices)
    edges = np.roll(vertices, -1, axis=0) - vertices  # edge i goes from vertex i to i+1
    lengths = np.linalg.norm(edges, axis=1)
    dirs = np.arctan2(edges[:, 1], edges[:, 0])
    turn = (dirs - np.roll(dirs, 1) + math.pi) % (2 * math.pi) - math.pi  # turn at vertex i
    tangent = radii * np.tan(np.abs(turn) / 2)
    straight = lengths - tangent - np.roll(tangent, -1)
    if np.any(straight < min_straight) or np.any(radii < MIN_RADIUS - 1e-9):
        return None
    segments = []
    for i in range(n):
        segments.append({"type": "straight", "length": round(float(straight[i]), 3)})
        j = (i + 1) % n
        if abs(turn[j]) > 1e-6:
            segments.append({"type": "arc", "radius": round(float(radii[j]), 3), "angle": round(float(turn[j]), 6)})
    return segments


def has_clearance(track: Track, clearance: float = CLEARANCE) -> bool:
    """True when no two parts of the road that are far apart along it come close in the plane."""
    step = max(1, int(2.0 / track.spacing))
    p, s = track.xy[::step], np.arange(0, len(track.xy), step) * track.spacing
    d = np.linalg.norm(p[:, None] - p[None], axis=2)
    ds = np.abs(s[:, None] - s[None])
    ds = np.minimum(ds, track.length - ds)
    return bool(np.all(d[ds > math.pi * clearance] >= clearance))


def procedural_segments(rng: np.random.Generator, max_tries: int = 200) -> list[dict]:
    """A random closed road: a rounded star-shaped polygon with curvature and clearance limits."""
    for _ in range(max_tries):
        n = int(rng.integers(5, 12))
        angles = np.sort(rng.uniform(0, 2 * math.pi, n))
        if np.min(np.diff(np.concatenate([angles, angles[:1] + 2 * math.pi]))) < 0.25:
            continue
        scale = rng.uniform(80.0, 170.0)
        r = scale * rng.uniform(0.45, 1.0, n)
        verts = np.stack([r * np.cos(angles), r * np.sin(angles)], 1)
        radii = rng.uniform(MIN_RADIUS, 90.0, n)
        segments = None
        for _shrink in range(8):
            segments = fillet_polygon(verts, radii)
            if segments is not None:
                break
            radii = np.maximum(radii * 0.75, MIN_RADIUS)
        if segments is None:
            continue
        track = build_centreline("procedural", segments, spacing=1.0)
        if 450.0 <= track.length <= 1150.0 and has_clearance(track):
            return segments
    raise RuntimeError("could not generate a procedural track; loosen the limits")


@lru_cache(maxsize=1)
def load_library() -> dict:
    """The named library: {"tracks": {name: segments}, "train": [...], "test": [...]}."""
    with open(LIBRARY_PATH) as f:
        return json.load(f)


def track_names(split: str) -> list[str]:
    """Names of the library tracks in `split` ('train', 'test' or 'all')."""
    lib = load_library()
    if split == "all":
        return lib["train"] + lib["test"]
    if split not in ("train", "test"):
        raise ValueError(f"track split must be 'train', 'test' or 'all', got {split!r}")
    return list(lib[split])


@lru_cache(maxsize=256)  # both directions of every library road, plus procedural ones
def get_track(name: str) -> Track:
    """A library track by name, or 'procedural:SEED'; a trailing '-r' drives it clockwise."""
    if name.endswith("-r"):
        return get_track(name[:-2]).reversed()
    if name.startswith("procedural:"):
        seed = int(name.split(":", 1)[1])
        return build_centreline(name, procedural_segments(np.random.default_rng(seed)))
    lib = load_library()
    if name not in lib["tracks"]:
        raise KeyError(f"unknown track {name!r}; known: {', '.join(sorted(lib['tracks']))} or procedural:SEED")
    return build_centreline(name, lib["tracks"][name])
