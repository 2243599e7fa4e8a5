"""Faults during a run, with real processes over real Zenoh on 127.0.0.1: hostile input on the
transitions key, a learner killed and resumed, a router restarted, an actor killed under gvf-train."""

import json
import os
import re
import signal
import subprocess
import sys
import time

import msgpack
import numpy as np
import zenoh

from common import wire
from common.config.run import LearnerConfig
from learner.service import PAUSE_REFRESHES
from tests.helpers import TINY, free_port, script, stop

# longer than a flow pause lives, so an actor the learner paused just before the kill sends into the outage too
OUTAGE_S = PAUSE_REFRESHES * LearnerConfig().flow_refresh_s + 1.5


def read_json(path):
    try:
        return json.loads(path.read_text())
    except (FileNotFoundError, json.JSONDecodeError):
        return None


def wait_for(path, predicate, timeout, what=""):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = read_json(path)
        if value is not None and predicate(value):
            return value
        time.sleep(0.3)
    raise AssertionError(f"timed out waiting for {what or path}: last {read_json(path)}")


class Run:
    """Router, learner and actors of one run as separate console-script processes."""

    def __init__(self, tmp_path, extra=()):
        self.tmp, self.endpoint = tmp_path, f"tcp/127.0.0.1:{free_port()}"
        self.args = [*TINY, f"transport.connect=[{self.endpoint}]", "run=faults", *extra]
        self.procs = {}

    def router(self):
        self.procs["router"] = script(
            "gvf-router",
            [f"transport.router_listen=[{self.endpoint}]", f"hydra.run.dir={self.tmp}/router"],
            self.tmp / "router.log",
        )
        time.sleep(1.0)

    def learner(self, *extra, name="learner"):
        args = [*self.args, f"hydra.run.dir={self.tmp}/learner", f"learner.checkpoint_dir={self.tmp}/ckpt", *extra]
        self.procs[name] = script("gvf-learner", args, self.tmp / f"{name}.log")

    def actor(self, name="actor-0", *extra):
        args = [*self.args, f"actor.name={name}", f"hydra.run.dir={self.tmp}/{name}", *extra]
        self.procs[name] = script("gvf-actor", args, self.tmp / f"{name}.log")

    def start(self):
        """Router, learner and one actor, until the learner has trained."""
        self.router()
        self.learner()
        self.actor()
        wait_for(self.progress, lambda p: p["updates"] > 0, 150, "first updates")

    @property
    def progress(self):
        return self.tmp / "learner" / "progress.json"

    def close(self):
        for name in [n for n in self.procs if n.startswith("actor")] + [
            n for n in self.procs if not n.startswith("actor")
        ]:
            stop(self.procs[name])


def valid_chunk_map(actor="evil", steps=4):
    rng = np.random.default_rng(0)
    chunk = wire.TransitionChunk(
        actor=actor,
        env=0,
        episode=0,
        seq=0,
        policy_version=0,
        step0=0,
        frames=rng.integers(0, 255, (steps + 2, 64, 128), dtype=np.uint8),
        speed=np.full((steps + 1, 1), 0.5, np.float32),
        last_action=np.zeros((steps + 1, 2), np.float32),
        action=np.zeros((steps, 2), np.float32),
        reward=np.zeros(steps, np.float32),
        terminated=np.zeros(steps, bool),
        truncated=np.zeros(steps, bool),
        alpha=np.zeros(steps + 1, np.float32),
        beta=np.zeros(steps + 1, np.float32),
    )
    return msgpack.unpackb(wire.encode(chunk), raw=False)


def hostile_payloads():
    pack = lambda m: msgpack.packb(m, use_bin_type=True)  # noqa: E731
    version = valid_chunk_map()
    version["v"] = 99
    shape = valid_chunk_map()
    shape["frames"]["shape"] = [6, 64, 64]
    nan = valid_chunk_map()
    reward = np.frombuffer(nan["reward"]["data"], np.float32).copy()
    reward[1] = np.nan
    nan["reward"]["data"] = reward.tobytes()
    big = valid_chunk_map()
    big["frames"]["data"] = bytes(20 * 1024 * 1024)  # over the learner's 16 MiB chunk limit
    return {
        "decode": b"\x93garbage\xff\x00",
        "version": pack(version),
        "shape": pack(shape),
        "nonfinite": pack(nan),
        "size": pack(big),
    }


def test_hostile_messages_are_counted_and_dropped_while_training_goes_on(tmp_path):
    # a learner that keeps up with one env, so its inbox has room and every hostile message reaches decode
    run = Run(tmp_path, ["learner.samples_per_insert=0.5", "actor.num_envs=1"])
    hostile = hostile_payloads()
    try:
        run.start()
        before = read_json(run.progress)["updates"]
        conf = zenoh.Config.from_json5(
            json.dumps(
                {
                    "mode": "client",
                    "connect": {"endpoints": [run.endpoint]},
                    "scouting": {"multicast": {"enabled": False}},
                }
            )
        )
        with zenoh.open(conf) as session:
            pub = session.declare_publisher(
                "gvf/faults/transitions/evil", congestion_control=zenoh.CongestionControl.BLOCK
            )
            deadline, p = time.monotonic() + 60, {}
            while time.monotonic() < deadline and not all(
                p.get("rejected_by_kind", {}).get(k, 0) >= 1 for k in hostile
            ):
                for payload in hostile.values():  # again, in case a busy learner's inbox dropped one
                    pub.put(payload)
                time.sleep(3.0)
                p = read_json(run.progress) or {}
            pub.undeclare()
        p = wait_for(
            run.progress,
            lambda p: all(p["rejected_by_kind"].get(k, 0) >= 1 for k in hostile) and p["updates"] > before + 5,
            60,
            "rejections",
        )
        assert "evil" not in p["actors_seen"]  # nothing of the hostile sender entered the replay
        assert p["actors_seen"] == ["actor-0"] and run.procs["learner"].poll() is None
    finally:
        run.close()


def test_learner_killed_and_resumed_from_checkpoint_while_actor_keeps_running(tmp_path):
    run = Run(tmp_path, ["learner.checkpoint_every=20"])
    try:
        run.start()
        wait_for(run.progress, lambda p: p["updates"] >= 45, 150, "updates before the kill")
        os.kill(run.procs["learner"].pid, signal.SIGKILL)
        run.procs["learner"].wait(10)
        saved = sorted(p.name for p in (tmp_path / "ckpt").iterdir() if p.suffix == ".pt")
        assert saved, "no checkpoint before the kill"
        at = int(re.search(r"(\d+)", saved[-1]).group(1))
        run.progress.unlink()
        run.learner("resume=true", name="learner2")
        p = wait_for(
            run.progress, lambda p: p["updates"] > at + 10 and p["inserted"] > 0, 150, "resumed learner training"
        )
        assert p["updates"] > at  # counted on from the checkpoint, not from 0
        assert run.procs["actor-0"].poll() is None  # the actor was never restarted: it reconnected by itself
        assert "resumed from" in (tmp_path / "learner2.log").read_text()
    finally:
        run.close()


def test_router_restart_resumes_traffic_and_lost_chunks_are_counted_exactly(tmp_path):
    run = Run(tmp_path)
    try:
        run.start()
        wait_for(run.progress, lambda p: p["chunks"] > 20, 120, "traffic before the restart")
        os.kill(run.procs["router"].pid, signal.SIGKILL)
        run.procs["router"].wait(10)
        time.sleep(OUTAGE_S)  # the actor keeps driving; its puts go nowhere
        run.router()
        chunks_now = read_json(run.progress)["chunks"]
        wait_for(run.progress, lambda p: p["chunks"] > chunks_now + 20, 90, "traffic after the restart")
        code = stop(run.procs.pop("actor-0"))
        assert code == 0
        stats = json.loads((tmp_path / "actor-0.log").read_text().strip().splitlines()[-1])
        assert stats["dropped"] == 0 and stats["send_errors"] == 0  # every chunk was handed to zenoh
        # the learner drains its inbox between training bursts: wait until everything that arrived is in
        p = wait_for(
            run.progress, lambda p: p["chunks"] + p["lost_chunks"] >= stats["chunks"], 90, "learner to ingest the rest"
        )
        assert p["lost_chunks"] > 0, p  # the outage lost something ...
        assert p["chunks"] + p["lost_chunks"] == stats["chunks"]  # ... and the counter accounts for exactly that
    finally:
        run.close()


def _pid(log, name, other_than=None):
    """The pid of the last start of role `name` in a gvf-train log (None if not (re)started yet)."""
    pids = [int(p) for p in re.findall(r"started %s \(pid (\d+)\)" % name, log.read_text())]
    pids = [p for p in pids if p != other_than]
    return pids[-1] if pids else None


def _wait_pid(log, name, other_than=None, timeout=60):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if (pid := _pid(log, name, other_than)) is not None:
            return pid
        time.sleep(0.3)
    raise AssertionError(f"{name} was not (re)started: {log.read_text()[-2000:]}")


def _wait_text(path, text, timeout):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if path.exists() and text in path.read_text():
            return
        time.sleep(0.3)
    raise AssertionError(f"{text!r} not in {path} after {timeout} s")


def _gone(pid):
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    return False


def _train_args(tmp_path, *extra):
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    return endpoint, [
        *TINY,
        f"transport.connect=[{endpoint}]",
        f"transport.router_listen=[{endpoint}]",
        "actors.restart_backoff_s=0.5",
        "progress=false",
        "run=train",
        f"hydra.run.dir={tmp_path}",
        *extra,
    ]


def test_gvf_train_restarts_a_killed_actor_resumes_a_killed_learner_and_gvfctl_stop_ends_it(tmp_path):
    endpoint, args = _train_args(tmp_path, "actors.count=2", "learner.checkpoint_every=20")
    log = tmp_path / "train.log"
    proc = script("gvf-train", args, log)
    try:
        progress = tmp_path / "progress.json"
        wait_for(progress, lambda p: p["updates"] > 0 and p["actors_alive"] == 2, 150, "training with 2 actors")
        actor = _pid(log, "actor-1")
        os.kill(actor, signal.SIGKILL)
        _wait_pid(log, "actor-1", other_than=actor)
        assert re.search(r"actor-1 crashed \(exit -9\); restarting", log.read_text())
        wait_for(
            progress,
            lambda p: p["updates"] >= 25 and p["actors_alive"] == 2,
            90,
            "a checkpoint after the actor's restart",
        )
        learner = _pid(log, "learner")
        os.kill(learner, signal.SIGKILL)
        _wait_pid(log, "learner", other_than=learner)
        assert re.search(r"learner crashed \(exit -9\); restarting", log.read_text())
        _wait_text(tmp_path / "logs" / "learner.log", "resumed from", 60)
        wait_for(progress, lambda p: p["updates"] >= 30, 90, "training after the learner resumed")
        pids = [int(p) for p in re.findall(r"started \S+ \(pid (\d+)\)", log.read_text())]
        out = subprocess.run(
            [sys.executable, "deploy/gvfctl.py", "stop", "--connect", endpoint, "--run", "train"],
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert out.returncode == 0, out.stderr
        proc.wait(60)
        text = log.read_text()
        assert proc.returncode == 0 and "learner exited cleanly" in text and "run ended" in text
        assert text.count("restarting") == 2  # the stop restarted nothing
        assert all(_gone(p) for p in pids)
    finally:
        stop(proc)


def test_gvf_train_ends_by_itself_at_max_updates_with_every_child_stopped(tmp_path):
    _, args = _train_args(
        tmp_path, "actors.count=1", "learner.max_updates=20", "eval.every_updates=10", "eval.directions=[ccw]"
    )
    proc = script("gvf-train", args, tmp_path / "train.log")
    try:
        proc.wait(240)
    finally:
        stop(proc)
    text = (tmp_path / "train.log").read_text()
    assert proc.returncode == 0, text[-3000:]
    assert "learner exited cleanly" in text and "restarting" not in text
    pids = [int(p) for p in re.findall(r"started \S+ \(pid (\d+)\)", text)]
    assert len(pids) == 4 and all(_gone(p) for p in pids)  # router, learner, actor, evaluator
