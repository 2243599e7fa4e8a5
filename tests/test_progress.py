"""The live view of gvf-train (common.progress) on hand-made progress.json and eval.jsonl."""

import json

from rich.console import Console

from common.progress import Progress, env_rate


def _record(updates, laps, reward, validation_laps=None, validation_near_out=0.0):
    record = {"updates": updates, "mean": {"lap_completed": laps / 12, "reward_per_s": reward}, "drives": [{}] * 12}
    if validation_laps is not None:
        record["validation"] = {
            "lap_completed": validation_laps / 12,
            "near_out_of_lane": validation_near_out,
            "reward_per_s": 4.0,
        }
    return record


def _render(table) -> str:
    console = Console(width=200, record=True)
    console.print(table)
    return console.export_text()


def test_zero_env_steps_under_the_rate_limit_read_as_paused_not_dead():
    assert env_rate({"env_steps_per_s": 0.0, "flow_paused": True}) == "paused (rate limit)"
    assert env_rate({"env_steps_per_s": 0.0, "flow_paused": False}) == "0"
    assert env_rate({"env_steps_per_s": 1234.4, "flow_paused": True}) == "1,234"
    assert env_rate({}) == "-"


def test_view_shows_the_last_and_the_validation_selected_evaluation_never_the_test_best(tmp_path):
    (tmp_path / "progress.json").write_text(
        json.dumps({"updates": 3000, "env_steps_per_s": 0, "flow_paused": True, "episodes": 9})
    )
    lines = [
        _record(1000, 3, 2.5, validation_laps=12, validation_near_out=0.2),
        _record(2000, 12, 4.75, validation_laps=11),  # the most test laps, not the best validation
        _record(3000, 8, 4.9, validation_laps=12, validation_near_out=0.0),  # validation-selected
        _record(3500, 9, 5.0, validation_laps=12, validation_near_out=0.0),  # equal: the first is kept
        _record(4000, 7, 4.0),  # no validation (an older run): passed over
    ]
    (tmp_path / "eval.jsonl").write_text("".join(json.dumps(x) + "\n" for x in lines) + '{"half-writ')
    progress = Progress(tmp_path, enabled=False)
    progress.read()
    text = _render(progress.table([]))
    assert "paused (rate limit)" in text
    assert "7/12 laps, 4.00 reward/s at 4,000 updates" in text  # the last
    assert "8/12 laps, 4.90 reward/s at 3,000 updates" in text  # validation-selected
    assert "12/12 laps" not in text  # the test roads' best is never shown as a choice
    ckpt = tmp_path / "checkpoints"
    summary = progress.final({"updates": 3000, "inserted": 40000, "episodes": 9}, ckpt)
    assert "3,000 updates" in summary and f"gvf-eval checkpoint={ckpt}" in summary
    assert "best-policy.pt" not in summary  # none was kept yet
    ckpt.mkdir()
    (ckpt / "best-policy.pt").write_bytes(b"")
    summary = progress.final({"updates": 3000}, ckpt)
    assert "validation-selected policy: 8/12 laps, 4.90 reward/s at 3,000 updates" in summary
    assert f"gvf-eval checkpoint={ckpt / 'best-policy.pt'}" in summary
