"""The paper's TORCS road set (issue 15, stage 5): every non-sloped road of torcs-data, split 85/15
with the paper's test roads in the test split. The list lives in ``roads.json`` beside this file;
``python -m actors.envs.torcs.roads`` regenerates it from the torcs-data that ``make torcs`` links.

"Sloped", read from the track XML: a road is sloped when its cross slope (banking: the XML's
``banking start``/``banking end``, or the edge elevations ``z start left/right``) exceeds 12 degrees
anywhere on the lap. The paper removed sloped roads yet kept alpine-2 as a test road, and alpine-2
has the steepest grades of torcs-data (20% over 50 m), so "sloped" cannot mean uphill or downhill;
banking is the slope left to read. The rule removes the six 15-16 degree speedways (b- to g-speedway)
and ole-road-1. The paper's test roads in torcs-data 1.3.7 are dirt-4, spring, alpine-2, wheel-2 and
a-speedway (evo-2-r is not in it); with 31 roads, 15% is those 5.

Validation roads (``validation``: dirt-3, g-track-1, michigan; a dirt road, a road course and an oval,
short so each evaluation stays cheap, all lapped by the kinematic controller) are train roads held out of
priority track sampling (`training_roads`): the periodic evaluator picks its best policy on them, not on test roads.
"""

from __future__ import annotations

import argparse
import json
import math
from functools import lru_cache
from pathlib import Path

ROADS_PATH = Path(__file__).with_name("roads.json")
PAPER_TEST_ROADS = ("dirt-4", "evo-2-r", "spring", "alpine-2", "wheel-2", "a-speedway")
MAX_BANKING_DEG = 12.0
TEST_FRACTION = 0.15
VALIDATION_ROADS = ("dirt-3", "g-track-1", "michigan")


def make_road_set(data_dir: Path) -> dict:
    """Read every road of ``data_dir/tracks``, drop the sloped ones, split train/test."""
    from actors.envs.torcs.geometry import closure_gap, read_road  # numpy only: no TORCS binary needed

    roads, excluded = {}, {}
    for xml in sorted((data_dir / "tracks").glob("*/*/*.xml")):
        if xml.stem != xml.parent.name:
            continue
        road = read_road(xml.stem, data_dir)
        summary = {
            "category": road.category,
            "length": round(road.length, 1),
            "width": road.width,
            "max_banking_deg": round(math.degrees(road.max_banking), 1),
            "elevation_range": round(road.elevation_range, 1),
            "closure_gap": round(closure_gap(road), 3),
        }
        if summary["max_banking_deg"] > MAX_BANKING_DEG:
            excluded[road.name] = {**summary, "why": f"sloped: banked {summary['max_banking_deg']} deg"}
        else:
            roads[road.name] = summary
    test = [n for n in PAPER_TEST_ROADS if n in roads]
    n_test = round(TEST_FRACTION * len(roads))
    # Roads beyond the paper's (if torcs-data held fewer of them) are drawn in name order by a fixed stride.
    extra = [n for n in sorted(roads) if n not in test][:: max(1, len(roads) // max(1, n_test))]
    test += extra[: max(0, n_test - len(test))]
    return {
        "rule": f"roads of torcs-data with no cross slope over {MAX_BANKING_DEG} deg; test = the paper's where present",
        "paper_test_missing": [n for n in PAPER_TEST_ROADS if n not in roads and n not in excluded],
        "train": sorted(n for n in roads if n not in test),
        "test": test,
        "validation": [n for n in VALIDATION_ROADS if n in roads and n not in test],
        "roads": roads,
        "excluded": excluded,
    }


@lru_cache(maxsize=1)
def load_road_set() -> dict:
    with open(ROADS_PATH) as f:
        return json.load(f)


def road_names(split: str) -> list[str]:
    """TORCS roads in ``split`` ('train', 'test', 'all', or 'validation': a few of 'train')."""
    roads = load_road_set()
    if split == "all":
        return roads["train"] + roads["test"]
    if split not in ("train", "test", "validation"):
        raise ValueError(f"TORCS road split must be 'train', 'test', 'all' or 'validation', got {split!r}")
    return list(roads[split])


def training_roads(split: str) -> list[str]:
    """The roads a reset draws from for ``split``: its roads less the validation roads."""
    held_out = set(road_names("validation"))
    return [n for n in road_names(split) if n not in held_out]


def main() -> None:
    from actors.envs.torcs.protocol import default_prefix, find_install

    parser = argparse.ArgumentParser(description="Write actors/envs/torcs/roads.json from torcs-data.")
    parser.add_argument("--data-dir", type=Path, help="TORCS data dir (default: the `make torcs` install's)")
    args = parser.parse_args()
    data_dir = args.data_dir
    if data_dir is None:
        install = find_install()
        if install is None:
            raise SystemExit(f"no TORCS under {default_prefix()}: run `make torcs` or pass --data-dir")
        data_dir = install.data_dir
    road_set = make_road_set(data_dir)
    ROADS_PATH.write_text(json.dumps(road_set, indent=1) + "\n")
    print(
        f"{len(road_set['train'])} train, {len(road_set['test'])} test, {len(road_set['excluded'])} sloped -> {ROADS_PATH}"
    )


if __name__ == "__main__":
    main()
