"""The live view of gvf-train (common.progress) on hand-made progress.json and eval.jsonl."""

import json

from rich.console import Console

from common.progress import Progress, env_rate


def _record(updates, laps, reward):
    return {"updates": updates, "mean": {"lap_completed": laps / 12, "reward_per_s": reward}, "drives": [{}] * 12}


def _render(table) -> str:
    console = Console(width=200, record=True)
    console.print(table)
    return console.export_text()


def test_zero_env_steps_under_the_rate_limit_read_as_paused_not_dead():
    assert env_rate({"env_steps_per_s": 0.0, "flow_paused": True}) == "paused (rate limit)"
    assert env_rate({"env_steps_per_s": 0.0, "flow_paused": False}) == "0"
    assert env_rate({"env_steps_per_s": 1234.4, "flow_paused": True}) == "1,234"
    assert env_rate({}) == "-"


def test_view_shows_the_last_and_best_evaluation_and_the_end_summary_names_the_eval_command(tmp_path):
    (tmp_path / "progress.json").write_text(
        json.dumps({"updates": 3000, "env_steps_per_s": 0, "flow_paused": True, "episodes": 9})
    )
    lines = [_record(1000, 3, 2.5), _record(2000, 12, 4.75), _record(3000, 8, 4.9)]
    (tmp_path / "eval.jsonl").write_text("".join(json.dumps(x) + "\n" for x in lines) + '{"half-writ')
    progress = Progress(tmp_path, enabled=False)
    progress.read()
    text = _render(progress.table([]))
    assert "paused (rate limit)" in text
    assert "8/12 laps, 4.90 reward/s at 3,000 updates" in text  # the last
    assert "12/12 laps, 4.75 reward/s at 2,000 updates" in text  # the best
    summary = progress.final({"updates": 3000, "inserted": 40000, "episodes": 9}, tmp_path / "checkpoints")
    assert "3,000 updates" in summary and f"gvf-eval checkpoint={tmp_path / 'checkpoints'}" in summary
