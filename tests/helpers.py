"""Test helpers: composing run configs, free ports, and running console scripts."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
from pathlib import Path

from common.cli import compose_run  # noqa: F401  (the tests' way to compose conf/)

BIN = Path(sys.executable).parent
ROOT = Path(__file__).resolve().parents[1]

# A config small enough for tests on 2 cores: tiny warm-up and frequent weights.
TINY = [
    "scale.warmup=64",
    "scale.batch_size=32",
    "scale.buffer_size=5000",
    "actor.num_envs=2",
    "actor.chunk_len=16",
    "learner.publish_every=5",
    "learner.samples_per_insert=4",
    "learner.checkpoint_every=50",
    "learner.torch_threads=1",  # leave a core to the actor and router of a test run
]


INPROC = ["transport=inproc", "progress=false", "actors.count=1"]


def run_inproc(overrides: list[str], run_dir, watchdog_s: float = 120.0) -> tuple[dict, bool]:
    """gvf-train with every role a thread of this process (INPROC + TINY + `overrides`); returns
    its result and whether it ended by itself (learner.max_updates) before the watchdog."""
    import threading

    from common.launch import train

    stop = threading.Event()
    watchdog = threading.Timer(watchdog_s, stop.set)  # only if the run does not end by itself
    watchdog.start()
    try:
        result = train(compose_run([*TINY, *INPROC, *overrides]), str(run_dir), stop)
    finally:
        watchdog.cancel()
    return result, not stop.is_set()


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def script(name: str, args: list[str], log: Path) -> subprocess.Popen:
    """Start a console script with its output in `log` (no shell)."""
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONUNBUFFERED": "1"}
    return subprocess.Popen([str(BIN / name), *args], stdout=open(log, "wb"), stderr=subprocess.STDOUT, env=env)


def stop(proc: subprocess.Popen, timeout: float = 20.0) -> int:
    """SIGTERM, wait, then SIGKILL; returns the exit code."""
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(10)
    return proc.returncode


def run_bench(name: str, args: list[str], timeout: float) -> dict:
    """Run `bench/<name>.py` with `args` (one torch thread per process) and return the JSON object
    of its last line; a non-zero exit fails with the end of its stderr."""
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONUNBUFFERED": "1"}
    proc = subprocess.run(
        [sys.executable, str(ROOT / "bench" / f"{name}.py"), *args],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])
