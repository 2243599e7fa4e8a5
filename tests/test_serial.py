"""Serial mode: learner and an actor in one process over the in-process transport."""

import threading

from common.launch import run_serial
from tests.helpers import TINY, compose_run


def test_serial_run_trains_and_actor_policy_version_rises(tmp_path):
    cfg = compose_run([*TINY, "serial=true", "actors.count=1", "max_seconds=40", "learner.max_updates=30"])
    result = run_serial(cfg, str(tmp_path), threading.Event())
    assert result["updates"] >= 30
    assert result["inserted"] >= 64 and result["episodes"] > 0
    assert result["rejected"] == 0 and result["lost_chunks"] == 0
    assert result["policy_lag"] is not None
    assert (tmp_path / "checkpoints").is_dir() and any((tmp_path / "tb").iterdir())
