"""Race files for TORCS's results-only mode (``torcs-bin -r race.xml``): one practice session, one
car driven by our ``gvfdrive`` robot, on a chosen road, posed where the episode should start.

The layout is TORCS's own race-manager format (``config/raceman/practice.xml`` in the TORCS source):
sections ``Header``, ``Tracks``, ``Races``, the race's own section with its ``Starting Grid``, and
``Drivers``. Three grid attributes are ours, read by deploy/torcs/patches/gvf-start-pose.patch:
``gvf start distance`` (m along the road from the start line), ``gvf start to middle`` (m, + left)
and ``gvf start yaw`` (rad, relative to the road); without the patch TORCS would put the car on the
track's own grid. ``raceengine_xml`` is the per-process ``config/raceengine.xml`` that tells TORCS
which track loader and physics to load.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from xml.sax.saxutils import quoteattr

ROBOT = "gvfdrive"
"""Our robot's module name: lib/torcs/drivers/gvfdrive/gvfdrive.so and its driver description."""

# A lap count no episode reaches: the race must never end by itself (TORCS would exit).
ENDLESS_LAPS = 10_000


@dataclass(frozen=True)
class RaceSpec:
    """Where one TORCS race starts: a road of torcs-data and the car's pose on it."""

    track: str
    """Road name, e.g. ``g-track-1`` (a folder under tracks/<category>/ of the data dir)."""
    category: str
    """``road``, ``oval`` or ``dirt``: the folder the road lives in."""
    start: float = 0.0
    """Distance along the road's middle from the start line, m (wrapped to the road's length)."""
    to_middle: float = 0.0
    """Lateral offset from the road's middle, m, + left."""
    yaw: float = 0.0
    """Heading relative to the road's direction, rad, + left. (No initial speed: TORCS holds every
    car with its brakes on for 1 s before the start, so a race always starts from rest.)"""


def find_category(track: str, data_dir: Path) -> str:
    """The category folder (road, oval, dirt) that holds ``track`` in a TORCS data dir."""
    found = sorted(p.parent.parent.name for p in (data_dir / "tracks").glob(f"*/{track}/{track}.xml"))
    if not found:
        raise ValueError(f"no TORCS road named {track!r} under {data_dir / 'tracks'}")
    return found[0]


def _num(name: str, value: float) -> str:
    return f'      <attnum name="{name}" val="{value:.6f}"/>\n'


def race_xml(spec: RaceSpec, name: str = "gvf-practice") -> str:
    """The race file for ``spec``: an endless practice session of our robot alone on the road."""
    for value in (spec.start, spec.to_middle, spec.yaw):
        if value != value or value in (float("inf"), float("-inf")):
            raise ValueError(f"race pose must be finite, got {spec}")
    if spec.start < 0:
        raise ValueError(f"start distance must be >= 0, got {spec.start}")
    grid = (
        _num("rows", 1)
        + _num("distance to start", 0)
        + _num("initial speed", 0.0)
        + _num("initial height", 0.2)
        + _num("gvf start distance", spec.start)
        + _num("gvf start to middle", spec.to_middle)
        + _num("gvf start yaw", spec.yaw)
    )
    return f"""<?xml version="1.0" encoding="UTF-8"?>
<params name={quoteattr(name)} type="param" mode="mw">
  <section name="Header">
    <attstr name="name" val={quoteattr(name)}/>
    <attstr name="description" val="gvf-drive lockstep episode"/>
    <attnum name="priority" val="100"/>
  </section>
  <section name="Tracks">
    <attnum name="maximum number" val="1"/>
    <section name="1">
      <attstr name="name" val={quoteattr(spec.track)}/>
      <attstr name="category" val={quoteattr(spec.category)}/>
    </section>
  </section>
  <section name="Races">
    <section name="1">
      <attstr name="name" val="Practice"/>
    </section>
  </section>
  <section name="Practice">
    <attnum name="laps" val="{ENDLESS_LAPS}"/>
    <attstr name="type" val="practice"/>
    <attstr name="starting order" val="drivers list"/>
    <attstr name="restart" val="yes"/>
    <attstr name="display mode" val="results only"/>
    <attstr name="display results" val="no"/>
    <attnum name="distance" unit="km" val="0"/>
    <attnum name="fuel consumption factor" val="0.0"/>
    <attnum name="damage factor" val="1.0"/>
    <section name="Starting Grid">
{grid}    </section>
  </section>
  <section name="Drivers">
    <attnum name="maximum number" val="1"/>
    <attstr name="focused module" val="{ROBOT}"/>
    <attnum name="focused idx" val="0"/>
    <section name="1">
      <attnum name="idx" val="0"/>
      <attstr name="module" val="{ROBOT}"/>
    </section>
  </section>
</params>
"""


def raceengine_xml() -> str:
    """TORCS's config/raceengine.xml: the track loader and the physics (no graphics in results-only mode)."""
    return """<?xml version="1.0" encoding="UTF-8"?>
<params name="" type="template" mode="mw">
  <section name="Modules">
    <attstr name="track" val="track"/>
    <attstr name="simu" val="simuv2"/>
    <attstr name="graphic" val="ssggraph"/>
  </section>
</params>
"""
