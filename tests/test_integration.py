"""Real processes over a real Zenoh router on 127.0.0.1: gvf-router, gvf-learner, gvf-actor."""

import json
import time

import pytest

from tests.helpers import TINY, free_port, script, stop


@pytest.fixture
def endpoint():
    return f"tcp/127.0.0.1:{free_port()}"


def wait_for(path, predicate, timeout):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            value = json.loads(path.read_text())
            if predicate(value):
                return value
        except (FileNotFoundError, json.JSONDecodeError):
            pass
        time.sleep(0.5)
    raise AssertionError(f"timed out waiting on {path}")


def last_json_line(path):
    return json.loads(path.read_text().strip().splitlines()[-1])


def test_learner_and_actor_processes_train_over_zenoh(tmp_path, endpoint):
    common = [*TINY, f"transport.connect=[{endpoint}]", "run=it"]
    procs = []
    try:
        procs.append(
            script(
                "gvf-router",
                [f"transport.router_listen=[{endpoint}]", f"hydra.run.dir={tmp_path}/router"],
                tmp_path / "router.log",
            )
        )
        time.sleep(1.0)
        procs.append(script("gvf-learner", [*common, f"hydra.run.dir={tmp_path}/learner"], tmp_path / "learner.log"))
        actor = script(
            "gvf-actor",
            [*common, "actor.max_env_steps=2500", f"hydra.run.dir={tmp_path}/actor"],
            tmp_path / "actor.log",
        )
        procs.append(actor)
        actor.wait(240)
        assert actor.returncode == 0, (tmp_path / "actor.log").read_text()[-3000:]
        stats = last_json_line(tmp_path / "actor.log")
        assert stats["env_steps"] >= 2500 and stats["chunks"] > 0 and stats["dropped"] == 0
        assert stats["weights_loaded"] >= 2 and stats["policy_version"] > 0  # weights came back, newer than v0
        progress = wait_for(tmp_path / "learner" / "progress.json", lambda p: p["updates"] > 0, 60)
        assert progress["inserted"] > 0 and progress["rejected"] == 0
    finally:
        codes = [stop(p) for p in reversed(procs)]
    assert codes[0] == 0  # the learner stops cleanly on SIGTERM
    assert any((tmp_path / "learner" / "checkpoints").iterdir())  # and checkpoints on the way out


def test_an_actor_waiting_for_ever_for_a_router_stops_on_sigterm(tmp_path, endpoint):
    proc = script(
        "gvf-actor",
        [f"transport.connect=[{endpoint}]", "transport.connect_timeout_s=-1", f"hydra.run.dir={tmp_path}"],
        tmp_path / "actor.log",
    )
    log = tmp_path / "actor.log"
    try:
        # its first failed attempt is logged after the signal handlers are in place (a slow start
        # signalled before that dies of SIGTERM's default: -15)
        deadline = time.monotonic() + 120
        while "waiting for one" not in (log.read_text() if log.exists() else "") and proc.poll() is None:
            assert time.monotonic() < deadline, log.read_text()[-2000:]
            time.sleep(0.5)
        time.sleep(2.0)
        assert proc.poll() is None  # still waiting: nobody listens there
    finally:
        code = stop(proc, timeout=10)
    assert code == 0, log.read_text()[-2000:]
