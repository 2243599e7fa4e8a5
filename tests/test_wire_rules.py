"""Content rules (common.wire_rules) at the learner's intake: each well-formed but wrong message
is dropped, counted under its own kind, and nothing of it enters the batch for the replay."""

import dataclasses
import re

import numpy as np
import pytest

from common import wire
from common.wire_rules import MAX_SEQ_GAP, SequenceTracker, check_tracks
from learner.ingestor import Ingestor
from tests.test_ingestor import chunk, inbox

KEY = "gvf/r/transitions/a"


def _take(*chunks, intake=None):
    intake = intake or Ingestor(max_chunk_bytes=1 << 24, ingest_batch=64)
    batch = intake.take(inbox(*(wire.encode(c) for c in chunks), key=KEY), inbox(), updates=0)
    return intake, batch


@pytest.mark.parametrize(
    "field, value, kind",
    [
        ("actor", "b", "identity"),  # the payload names another actor than its key
        ("action", np.full((4, 2), 5.0, np.float32), "range"),
        ("reward", np.full(4, 3e38, np.float32), "range"),  # finite, absurd: it made the weights NaN
        ("speed", np.full((5, 1), 2.0, np.float32), "range"),
        ("alpha", np.full(5, -9.0, np.float32), "range"),
        ("beta", np.full(5, 4.0, np.float32), "range"),
    ],
)
def test_a_chunk_breaking_a_rule_is_dropped_and_counted_under_its_kind(field, value, kind):
    bad = dataclasses.replace(chunk(seq=1), **{field: value})
    intake, batch = _take(chunk(seq=0), bad, chunk(seq=2))
    assert intake.rejects.counts == {kind: 1}
    assert batch.shape[0] == 8 and float(batch["action"].abs().max()) <= 1.0  # only the two good ones
    assert intake.seq.lost == 1  # the refused chunk counts as lost: its seq never arrived


def test_duplicate_backward_and_huge_seq_are_refused_and_seq_0_announces_a_restart():
    seqs = [0, 1, 1, 0, 1, 2**63 - 1, 2 + MAX_SEQ_GAP + 1, 3]
    intake, batch = _take(*(chunk(seq=s) for s in seqs))
    # 0, 1 in; 1 again: duplicate; 0: a restart; 1 in; the huge ones refused; 3 in (2 lost)
    assert intake.rejects.counts == {"seq": 3}
    assert (intake.seq.restarts, intake.seq.lost, batch.shape[0]) == (1, 1, 5 * 4)


def test_the_track_table_is_bounded():
    intake = Ingestor(max_chunk_bytes=1 << 24, ingest_batch=64, max_tracks=3)
    summaries = [wire.EpisodeSummary("a", 0, i, f"road{i}", 10, 1.0, 0) for i in range(5)]
    summaries.append(wire.EpisodeSummary("b", 0, 9, "road0", 10, 1.0, 0))  # on actor a's key
    intake.take(inbox(), inbox(*map(wire.encode, summaries), key="gvf/r/episodes/a"), updates=0)
    assert sorted(intake.tracks) == ["road0", "road1", "road2"]
    assert intake.rejects.counts == {"track": 2, "identity": 1}


def test_a_track_table_naming_unknown_roads_is_refused():
    check_tracks(wire.TrackTable(1, {"alder": 5}), {"alder", "brook"})
    with pytest.raises(wire.WireError) as err:
        check_tracks(wire.TrackTable(1, {"alder": 5, "x" * 40: 1}), {"alder"})
    assert err.value.kind == "track"


def test_sequence_tracker_counts_a_gap_up_to_the_bound():
    s = SequenceTracker()
    s.see("a", 0)
    assert s.see("a", 1 + MAX_SEQ_GAP) == MAX_SEQ_GAP
    with pytest.raises(wire.WireError, match="seq"):
        s.see("a", 2 + 2 * MAX_SEQ_GAP + 1)


def test_wire_doc_lists_every_kind_and_the_bounds_of_the_rules():
    from pathlib import Path

    from common.wire import KINDS
    from common.wire_rules import BOUNDS

    text = (Path(__file__).resolve().parents[1] / "docs" / "wire.md").read_text()
    documented = set(
        re.findall(r"^\| `(\w+)` \| ", text.split("## What a receiver refuses")[1].split("## Example")[0], re.M)
    )
    assert documented == set(KINDS)
    for name, (lo, hi) in BOUNDS.items():
        bound = "[-pi, pi]" if name == "beta" else f"[{lo:g}, {hi:g}]"
        assert f"`{name}` in {bound}" in text, name
    assert f"within [next, next + {MAX_SEQ_GAP}]" in text
