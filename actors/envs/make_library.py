"""Regenerate the named track library (``tracks/library.json``): 40 roads, 34 train / 6 test.

The library is committed so track shapes never change under a user's feet; run this only to
build a new library on purpose: ``python -m actors.envs.make_library``.
"""

from __future__ import annotations

import json

import numpy as np

from actors.envs.tracks import LIBRARY_PATH, build_centreline, procedural_segments

NAMES = [
    "alder",
    "birch",
    "cedar",
    "dune",
    "ember",
    "fjord",
    "glen",
    "heath",
    "isle",
    "juniper",
    "karst",
    "larch",
    "marsh",
    "nettle",
    "oak",
    "pine",
    "quarry",
    "ridge",
    "sage",
    "thorn",
    "umber",
    "vale",
    "willow",
    "yarrow",
    "zephyr",
    "aspen",
    "brook",
    "cliff",
    "delta",
    "elm",
    "fern",
    "grove",
    "hollow",
    "iris",
    "jasper",
    "kestrel",
    "lagoon",
    "moor",
    "north",
    "orchard",
]
# Fixed held-out roads (15%, as the paper's 6 of 40), spread over the generation order.
TEST = ["dune", "karst", "sage", "brook", "jasper", "moor"]
SEED = 20240521


def main() -> None:
    rng = np.random.default_rng(SEED)
    tracks = {name: procedural_segments(rng) for name in NAMES}
    lengths = {name: round(build_centreline(name, segs).length, 1) for name, segs in tracks.items()}
    library = {
        "description": "LaneDrive named tracks: closed loops of straight and arc segments (angle > 0 turns left)",
        "train": [n for n in NAMES if n not in TEST],
        "test": TEST,
        "lengths_m": lengths,
        "tracks": tracks,
    }
    LIBRARY_PATH.parent.mkdir(exist_ok=True)
    LIBRARY_PATH.write_text(json.dumps(library, indent=1) + "\n")
    print(f"wrote {len(tracks)} tracks to {LIBRARY_PATH}; lengths {min(lengths.values())}-{max(lengths.values())} m")


if __name__ == "__main__":
    main()
