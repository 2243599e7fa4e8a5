"""The track library and procedural roads: split, closure, curvature limits, determinism."""

import math

import numpy as np
import pytest

from actors.envs.tracks import MIN_RADIUS, build_centreline, get_track, has_clearance, load_library, track_names


def test_library_has_40_tracks_split_34_6_and_disjoint():
    train, test = track_names("train"), track_names("test")
    assert len(train) == 34 and len(test) == 6
    assert not set(train) & set(test)
    assert set(train) | set(test) == set(load_library()["tracks"])


@pytest.mark.parametrize("name", track_names("all"))
def test_library_track_is_a_closed_loop_of_straights_and_arcs(name):
    segments = load_library()["tracks"][name]
    assert {s["type"] for s in segments} <= {"straight", "arc"}
    assert all(s["radius"] >= MIN_RADIUS for s in segments if s["type"] == "arc")
    assert sum(s["angle"] for s in segments if s["type"] == "arc") == pytest.approx(2 * math.pi, abs=1e-4)
    track = get_track(name)
    steps = np.linalg.norm(np.diff(np.vstack([track.xy, track.xy[:1]]), axis=0), axis=1)
    assert steps.max() < 1.5 * track.spacing  # closed: the last sample is next to the first
    assert np.abs(track.curvature).max() <= 1 / MIN_RADIUS + 1e-9
    assert has_clearance(track)


def test_reversed_track_runs_the_other_way():
    t, r = get_track("alder"), get_track("alder-r")
    assert r.length == pytest.approx(t.length)
    np.testing.assert_allclose(r.xy[::-1], t.xy)
    assert np.mean(t.curvature) > 0 > np.mean(r.curvature)  # ccw turns left overall, cw right


def test_procedural_tracks_are_seeded_and_valid():
    a, b, c = get_track("procedural:7"), get_track("procedural:7"), get_track("procedural:8")
    np.testing.assert_array_equal(a.xy, b.xy)
    assert a.length != pytest.approx(c.length)
    assert has_clearance(c) and 450 <= c.length <= 1150


def test_segments_that_do_not_close_are_refused():
    with pytest.raises(ValueError, match="do not close"):
        build_centreline("open", [{"type": "straight", "length": 100.0}])
