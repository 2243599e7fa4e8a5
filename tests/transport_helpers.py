"""What the transport tests share: a polling wait, a small transition chunk, and a real Zenoh
router on 127.0.0.1 as a module-scoped fixture (import `router_port` into a test module to use it).

The router runs in a 'spawn' child process (forking after zenoh init hangs).
"""

from __future__ import annotations

import multiprocessing as mp
import time

import numpy as np
import pytest

from common.config.transport import TransportConfig
from common.wire import TransitionChunk
from tests.helpers import free_port

CTX = mp.get_context("spawn")


def wait_for(predicate, timeout: float = 10.0, interval: float = 0.02) -> bool:
    """Poll `predicate` until true or `timeout` passes (a bound against hanging, not a timing)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(interval)
    return bool(predicate())


def small_chunk(seq: int) -> TransitionChunk:
    steps = 2
    return TransitionChunk(
        actor="a0",
        env=0,
        episode=1,
        seq=seq,
        policy_version=0,
        step0=2 * seq,
        frames=np.full((steps + 2, 64, 128), seq % 256, np.uint8),
        speed=np.zeros((steps + 1, 1)),
        last_action=np.zeros((steps + 1, 2)),
        action=np.zeros((steps, 2)),
        reward=np.ones(steps),
        terminated=np.zeros(steps, bool),
        truncated=np.zeros(steps, bool),
        alpha=np.zeros(steps + 1),
        beta=np.zeros(steps + 1),
    )


def client_cfg(port: int, **kw) -> TransportConfig:
    return TransportConfig(mode="client", connect=[f"tcp/127.0.0.1:{port}"], connect_timeout_s=5.0, **kw)


def _run_router(cfg: TransportConfig, ready) -> None:
    from common.transport.zenoh_backend import run_router

    run_router(cfg, ready=ready)


@pytest.fixture(scope="module")
def router_port():
    """A Zenoh router on 127.0.0.1 in a spawned process, stopped by SIGTERM at the end."""
    pytest.importorskip("zenoh")
    proc = None
    try:
        for _ in range(3):  # the free port can be taken between probe and bind
            port = free_port()
            ready = CTX.Event()
            cfg = TransportConfig(router_listen=[f"tcp/127.0.0.1:{port}"])
            proc = CTX.Process(target=_run_router, args=(cfg, ready), daemon=True)
            proc.start()
            if ready.wait(30):
                break
            proc.kill()
            proc.join()
        else:
            pytest.fail("the router did not start")
        yield port
        proc.terminate()
        proc.join(10)
        assert proc.exitcode == 0, "the router did not stop cleanly on SIGTERM"
    finally:
        if proc is not None and proc.is_alive():
            proc.kill()
            proc.join()
