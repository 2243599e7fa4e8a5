"""The geometry of a torcs-data road, read from its track XML file (issue 15, stages 4-5).

TORCS describes a road as a list of segments (``str`` with a length ``lg``; ``lft``/``rgt`` with a
``radius``, an optional ``end radius`` and an ``arc``), a constant road ``width`` and per-segment
elevations. :func:`read_road` reads them the way TORCS's track loader does
(src/modules/track/track4.cpp and track3.cpp, ``CreateSegRing``): units converted as
``GfParmUnit2SI``, a changing radius (a spiral) cut into ``profil steps`` arcs with TORCS's own
arithmetic, elevation carried from segment to segment. :func:`centreline` integrates the segments
into the same :class:`~actors.envs.tracks.Track` LaneDrive uses (points every 0.25 m, heading,
signed curvature), starting at the start line: TORCS's ``distFromStartLine`` is arclength on it.
"""

from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from actors.envs.tracks import Track, build_centreline

# GfParmUnit2SI's factors for the units torcs-data uses (params.cpp, evalUnit).
_UNITS = {"m": 1.0, "rad": 1.0, "deg": math.pi / 180, "ft": 0.304801, "feet": 0.304801, "km": 1000.0}
_UNITS |= {"cm": 0.01, "mm": 0.001, "%": 0.01, "percent": 0.01, "in": 0.0254, "inch": 0.0254}
_DOCTYPE = re.compile(r"<!DOCTYPE.*?\]>", re.S)
_ENTITY = re.compile(r"&[A-Za-z][\w.-]*;")


def _section(node: ET.Element, name: str) -> ET.Element | None:
    return next((s for s in node.findall("section") if s.get("name") == name), None)


def _num(node: ET.Element | None, name: str, default: float | None = None) -> float | None:
    """An ``attnum`` in SI units, or ``default`` when the section does not set it."""
    if node is None:
        return default
    for a in node.findall("attnum"):
        if a.get("name") == name:
            return float(a.get("val")) * _UNITS.get(a.get("unit", "m"), 1.0)
    return default


def _str(node: ET.Element | None, name: str, default: str | None = None) -> str | None:
    if node is None:
        return default
    for a in node.findall("attstr"):
        if a.get("name") == name:
            return a.get("val")
    return default


def _parse(path: Path) -> ET.Element:
    # Track files pull shared surfaces in through external entities; the geometry never needs them.
    text = path.read_text(encoding="latin-1")
    return ET.fromstring(_ENTITY.sub("", _DOCTYPE.sub("", text)).encode("latin-1"))


@dataclass(frozen=True)
class TorcsRoad:
    """One torcs-data road: its TORCS segments cut as TORCS cuts them, elevation and surfaces."""

    name: str
    category: str
    width: float
    """Road width, m (constant along a TORCS road's main track)."""
    segments: tuple
    """Constant-curvature pieces in LaneDrive's format: {"type": "straight", "length"} or
    {"type": "arc", "radius", "angle" (signed, + left)}, as many as TORCS's own segments."""
    length: float
    """Sum of the pieces' lengths, m: TORCS's track length."""
    z: np.ndarray
    """(n, 2) elevation of the middle line at the start and the end of every XML segment, m."""
    banking: np.ndarray
    """(n, 2) cross slope at the start and the end of every XML segment, rad (+: left edge higher)."""
    seg_lengths: np.ndarray
    """(n,) length of every XML segment, m (for grades)."""
    surface: str
    """The main track's surface material at the start line (e.g. asphalt-lines, dirt)."""
    side_width: tuple[float, float]
    """Default (left, right) side widths beside the road, m."""
    side_surface: tuple[str, str]
    """Default (left, right) side materials (grass, sand, concrete, ...)."""

    @property
    def elevation_range(self) -> float:
        """Highest minus lowest middle-line elevation over the lap, m."""
        return float(self.z.max() - self.z.min())

    @property
    def max_banking(self) -> float:
        """Steepest cross slope anywhere on the lap, rad."""
        return float(np.max(np.abs(self.banking)))

    @property
    def max_grade(self) -> float:
        """Largest |rise / run| of one XML segment (0.05 = 5%)."""
        return float(np.max(np.abs(self.z[:, 1] - self.z[:, 0]) / np.maximum(self.seg_lengths, 1e-6)))


def road_file(name: str, data_dir: Path) -> Path:
    found = sorted((data_dir / "tracks").glob(f"*/{name}/{name}.xml"))
    if not found:
        raise ValueError(f"no TORCS road named {name!r} under {data_dir / 'tracks'}")
    return found[0]


def read_road(name: str, data_dir: Path) -> TorcsRoad:
    """Read a road's segments, elevation and surfaces from ``tracks/<category>/<name>/<name>.xml``."""
    path = road_file(name, data_dir)
    root = _parse(path)
    main = _section(root, "Main Track")
    if main is None:
        raise ValueError(f"{path}: no 'Main Track' section")
    version = int(_num(_section(root, "Header"), "version", 0) or 0)
    segs_node = _section(main, "Track Segments" if version >= 4 else "segments")
    if segs_node is None:
        raise ValueError(f"{path}: no segment list")
    width = float(_num(main, "width", 15.0))
    global_step = float(_num(main, "profil steps length", 0.0) or 0.0)
    pieces: list[dict] = []
    z, lengths, banking = [], [], []
    # TORCS's running values: elevation of both edges, grade, radius (carried between segments).
    zel = zer = 0.0
    grade = None
    radius = 0.0
    for seg in segs_node.findall("section"):
        kind = _str(seg, "type")
        if kind is None:
            continue
        if kind == "str":
            length = float(_num(seg, "lg", 0.0))
            radius = radius_end = arc = 0.0
        elif kind in ("lft", "rgt"):
            radius = float(_num(seg, "radius", 0.0))
            radius_end = float(_num(seg, "end radius", radius))
            arc = float(_num(seg, "arc", 0.0))
            length = (radius + radius_end) / 2.0 * arc
        else:
            raise ValueError(f"{path}: unknown segment type {kind!r}")
        # Elevation, as CreateSegRing: each edge starts where the last ended unless set; the middle
        # starts at "z start" or the edges' mean and ends at "z end", else by the (carried) grade,
        # else at the edges' mean; then banking moves the end edges about the middle.
        zsl, zsr = _num(seg, "z start left", zel), _num(seg, "z start right", zer)
        zel, zer = _num(seg, "z end left", zel), _num(seg, "z end right", zer)
        zs, ze = _num(seg, "z start"), _num(seg, "z end")
        grade = _num(seg, "grade", grade)
        zs = (zsl + zsr) / 2.0 if zs is None else zs
        if ze is None:
            ze = zs + length * grade if grade is not None else (zel + zer) / 2.0
        else:
            zel = zer = ze
        bank_start = _num(seg, "banking start", math.atan2(zsl - zsr, width))
        bank = _num(seg, "banking end", math.atan2(zel - zer, width))
        zel, zer = ze + math.tan(bank) * width / 2.0, ze - math.tan(bank) * width / 2.0
        banking.append((bank_start, bank))
        z.append((zs, ze))
        lengths.append(length)
        # Sub-steps: only a spiral's shape depends on them (a constant arc cut in pieces is the same arc).
        steps = 1
        if _str(seg, "profil", "spline") == "spline":
            steps = int(_num(seg, "profil steps", 1.0))
            if steps == 1:
                step_len = float(_num(seg, "profil steps length", global_step) or 0.0)
                steps = int(length / step_len) + 1 if step_len else 1
        if kind == "str":
            pieces.append({"type": "straight", "length": length})
            continue
        cur_length, cur_arc = length / steps, arc / steps
        d_radius = (radius_end - radius) / steps
        if radius_end != radius and steps != 1:
            d_radius = (radius_end - radius) / (steps - 1)
            angle, r = 0.0, radius
            for _ in range(steps):
                angle += cur_length / r
                r += d_radius
            cur_length *= arc / angle
        sign = 1.0 if kind == "lft" else -1.0
        r = radius
        for _ in range(steps):
            if d_radius != 0:
                cur_arc = cur_length / r
            pieces.append({"type": "arc", "radius": r, "angle": sign * cur_arc})
            r += d_radius
    sides = [_section(main, "Left Side"), _section(main, "Right Side")]
    side_width = tuple(
        float(_num(s, "width", _num(s, "start width", 0.0)) if s is not None else _num(main, f"{k}side width", 0.0))
        for s, k in zip(sides, "lr")
    )
    side_surface = tuple(
        (_str(s, "surface", "grass") if s is not None else _str(main, f"{k}side surface", "grass")) or "grass"
        for s, k in zip(sides, "lr")
    )
    first = segs_node.find("section")
    surface = _str(first, "surface", _str(main, "surface", "asphalt")) or "asphalt"
    total = sum(p["length"] if p["type"] == "straight" else p["radius"] * abs(p["angle"]) for p in pieces)
    return TorcsRoad(
        name=name,
        category=path.parent.parent.name,
        width=width,
        segments=tuple(pieces),
        length=float(total),
        z=np.asarray(z, float),
        banking=np.asarray(banking, float),
        seg_lengths=np.asarray(lengths, float),
        surface=surface,
        side_width=side_width,  # type: ignore[arg-type]
        side_surface=side_surface,  # type: ignore[arg-type]
    )


def centreline(road: TorcsRoad) -> Track:
    """The road's middle line as a LaneDrive ``Track``: sample 0 on the start line, heading 0 there
    (TORCS's own frame is the same up to a shift: its first segment also starts at heading 0)."""
    return build_centreline(road.name, list(road.segments))


def closure_gap(road: TorcsRoad) -> float:
    """How far the end of the last segment lands from the start line, m (TORCS roads close to mm)."""
    x = y = th = 0.0
    for p in road.segments:
        if p["type"] == "straight":
            x, y = x + p["length"] * math.cos(th), y + p["length"] * math.sin(th)
        else:
            k = math.copysign(1.0 / p["radius"], p["angle"])
            th_end = th + p["angle"]
            x, y = x + (math.sin(th_end) - math.sin(th)) / k, y - (math.cos(th_end) - math.cos(th)) / k
            th = th_end
    return math.hypot(x, y)
