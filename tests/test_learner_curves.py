"""actors.evaluation.learner_curves: TensorBoard scalars binned by updates for a study summary."""

import pytest
from torch.utils.tensorboard import SummaryWriter

from actors.evaluation.learner_curves import learner_curves


def test_scalars_are_averaged_per_bin_of_updates_and_other_tags_left_out(tmp_path):
    writer = SummaryWriter(str(tmp_path))
    for step, value in [(100, 1.0), (480, 3.0), (500, 5.0), (620, 7.0), (1400, 9.0)]:
        writer.add_scalar("diag/steer_to_centre", value, step)
    writer.add_scalar("train/q_mean", -2.0, 1300)
    writer.add_scalar("train/q_max", 4.0, 1300)  # the Q range is kept beside the mean
    writer.add_scalar("train/updates_per_s", 6.0, 1300)  # not the critic's
    writer.add_scalar("actors/alive", 2.0, 100)  # not a learner diagnostic
    writer.close()
    curves = learner_curves(tmp_path, every=500)
    assert curves["updates"] == [500, 1000, 1500]
    assert curves["diag/steer_to_centre"] == pytest.approx([3.0, 7.0, 9.0])  # (1 + 3 + 5) / 3 up to 500
    assert curves["train/q_mean"] == [None, None, -2.0]
    assert curves["train/q_max"] == [None, None, 4.0]
    assert "actors/alive" not in curves and "train/updates_per_s" not in curves


def test_a_run_without_events_has_no_curves(tmp_path):
    assert learner_curves(tmp_path / "missing") == {}
