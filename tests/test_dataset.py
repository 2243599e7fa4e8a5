"""The offline dataset (common.dataset): round trip, append, damaged files refused, nothing lost."""

from __future__ import annotations

import json
import os

import pytest
import torch
from tensordict import TensorDict

from common.dataset import FIELDS, MANIFEST, Dataset, DatasetError, DatasetWriter


def random_transitions(n: int, seed: int = 0, n_tracks: int = 2) -> TensorDict:
    g = torch.Generator().manual_seed(seed)
    cols = {}
    for name, (dtype, shape, _) in FIELDS.items():
        if dtype == torch.uint8:
            cols[name] = torch.randint(0, 256, (n, *shape), generator=g, dtype=torch.uint8)
        elif dtype == torch.bool:
            cols[name] = torch.rand(n, *shape, generator=g) < 0.1
        elif name == "track":
            cols[name] = torch.randint(0, n_tracks, (n, *shape), generator=g).to(dtype)
        elif dtype.is_floating_point:
            cols[name] = torch.randn(n, *shape, generator=g).to(dtype)
        else:
            cols[name] = torch.randint(0, 2**20, (n, *shape), generator=g).to(dtype)
    return TensorDict(cols, batch_size=[n])


def assert_same(a: TensorDict, b: TensorDict) -> None:
    for name in FIELDS:
        assert a[name].dtype == b[name].dtype, name
        assert torch.equal(a[name].nan_to_num(), b[name].nan_to_num()), name


def test_a_dataset_round_trips_and_appends_with_every_field_intact(tmp_path):
    first, second, third = random_transitions(50, 0), random_transitions(30, 1), random_transitions(20, 2, 3)
    writer = DatasetWriter(tmp_path, "a", meta={"controller": "test"})
    writer.append(first, ["elm", "fjord"])
    writer.append(second, ["elm", "fjord"])
    ds = Dataset.open(tmp_path)
    assert len(ds) == 80 and ds.meta == {"controller": "test"}
    DatasetWriter(tmp_path, "b").append(third, ["elm", "fjord", "nettle"])  # reopened by another writer
    ds = Dataset.open(tmp_path)
    assert len(ds) == 100 and ds.tracks() == ["elm", "fjord", "nettle"]
    shards = list(ds)
    for (td, tracks), want in zip(shards, (first, second, third)):
        assert_same(td, want)
    assert shards[2][1] == ["elm", "fjord", "nettle"]


def test_a_truncated_or_corrupt_file_is_refused_by_name_and_the_rest_is_kept(tmp_path):
    writer = DatasetWriter(tmp_path, "a")
    good, bad = random_transitions(40, 0), random_transitions(40, 1)
    writer.append(good, ["elm", "fjord"])
    name = writer.append(bad, ["elm", "fjord"])
    manifest = (tmp_path / MANIFEST).read_bytes()
    victim = tmp_path / name / "image.memmap"
    os.truncate(victim, victim.stat().st_size // 2)
    with pytest.raises(DatasetError, match=rf"{name}/image.memmap: .* bytes.*truncated"):
        Dataset.open(tmp_path)
    kept = Dataset.open(tmp_path, skip_damaged=True)
    assert len(kept) == 40 and "truncated" in kept.damaged[0]
    assert_same(kept.shard(0)[0], good)
    assert (tmp_path / MANIFEST).read_bytes() == manifest  # reading never rewrites

    # same size, one byte changed: only the hash can tell
    victim = tmp_path / kept.shards[0]["name"] / "action.memmap"
    data = bytearray(victim.read_bytes())
    data[3] ^= 0xFF
    victim.write_bytes(bytes(data))
    with pytest.raises(DatasetError, match="action.memmap: its sha256 differs"):
        Dataset.open(tmp_path, skip_damaged=False)


def test_a_half_written_shard_is_invisible_and_a_damaged_manifest_is_refused(tmp_path):
    writer = DatasetWriter(tmp_path, "a")
    writer.append(random_transitions(10), ["elm", "fjord"])
    (tmp_path / ".shard-a-000001.tmp-999").mkdir()  # what a crash mid-write leaves
    (tmp_path / ".shard-a-000001.tmp-999" / "image.memmap").write_bytes(b"x" * 10)
    assert len(Dataset.open(tmp_path)) == 10
    writer.append(random_transitions(5, 1), ["elm", "fjord"])
    assert len(Dataset.open(tmp_path)) == 15
    (tmp_path / MANIFEST).write_text('{"format": "gvf-drive-dataset", "shards": [')
    with pytest.raises(DatasetError, match="not valid JSON"):
        Dataset.open(tmp_path)


def test_a_batch_with_a_wrong_field_is_refused_naming_it(tmp_path):
    writer = DatasetWriter(tmp_path, "a")
    td = random_transitions(4)
    td["speed"] = td["speed"].double()
    with pytest.raises(DatasetError, match="field 'speed'"):
        writer.append(td, ["elm", "fjord"])
    td = random_transitions(4).exclude("log_mu")
    with pytest.raises(DatasetError, match=r"missing \['log_mu'\]"):
        writer.append(td, ["elm", "fjord"])
    with pytest.raises(DatasetError, match="field 'track'"):
        writer.append(random_transitions(4, n_tracks=3), ["elm"])
    assert json.loads((tmp_path / MANIFEST).read_text())["shards"] == []
