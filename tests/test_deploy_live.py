"""deploy/, run for real (opt-in): `-m multihost` runs the guide's network-namespace recipe (root
only); `-m slow` runs the systemd units' command lines over mutual TLS."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import time
from pathlib import Path

import pytest

from tests.deploy_helpers import DEPLOY, PY, REPO, UNITS, certs, expand, free_port, parse_env, parse_unit, patched  # noqa: F401  (certs is a fixture)

# --- opt-in: namespaces (root) and the units' command lines run for real ------------------------


def _root_and_ip() -> str | None:
    if os.geteuid() != 0:
        return "needs root to create network namespaces"
    if shutil.which("ip") is None:
        return "iproute2 (ip) not installed"
    return None


@pytest.mark.multihost
@pytest.mark.slow
@pytest.mark.skipif(_root_and_ip() is not None, reason=_root_and_ip() or "")
def test_netns_recipe_round_trip():
    """deploy/netns.sh: a router in one namespace, clients in the two others, through the veth bridge."""
    prefix = f"gvft{os.getpid() % 100000}"
    netns = str(DEPLOY / "netns.sh")
    router = None
    try:
        subprocess.run(["bash", netns, "up", prefix], check=True, capture_output=True, timeout=60)
        router = subprocess.Popen(
            [
                "ip",
                "netns",
                "exec",
                f"{prefix}-r",
                PY,
                str(DEPLOY / "gvfctl.py"),
                "router",
                "--listen",
                "tcp/192.0.2.1:7447",
            ],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        time.sleep(1.0)
        holder = subprocess.Popen(
            [
                "ip",
                "netns",
                "exec",
                f"{prefix}-a",
                PY,
                "-c",
                "import sys, zenoh; from common.config.transport import TransportConfig as T;"
                "from common.transport.zenoh_backend import zenoh_config as z;"
                "s = zenoh.open(z(T(connect=['tcp/192.0.2.1:7447'])));"
                "t = s.liveliness().declare_token('gvf/netns/alive/actor/a0');"
                "print('up', flush=True); sys.stdin.read(); s.close()",
            ],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
        )
        try:
            assert holder.stdout.readline().strip() == "up"
            for ns in ("l", "a"):
                out = subprocess.run(
                    [
                        "ip",
                        "netns",
                        "exec",
                        f"{prefix}-{ns}",
                        PY,
                        str(DEPLOY / "gvfctl.py"),
                        "ping",
                        "--connect",
                        "tcp/192.0.2.1:7447",
                    ],
                    capture_output=True,
                    text=True,
                    timeout=60,
                )
                assert out.returncode == 0, out.stderr
            out = subprocess.run(
                [
                    "ip",
                    "netns",
                    "exec",
                    f"{prefix}-l",
                    PY,
                    str(DEPLOY / "gvfctl.py"),
                    "alive",
                    "--connect",
                    "tcp/192.0.2.1:7447",
                    "--run",
                    "netns",
                ],
                capture_output=True,
                text=True,
                timeout=60,
            )
            assert "gvf/netns/alive/actor/a0" in out.stdout.split()
        finally:
            holder.communicate("", timeout=20)
    finally:
        if router is not None:
            router.send_signal(signal.SIGINT)
            try:
                router.wait(20)
            except subprocess.TimeoutExpired:
                router.kill()
                router.wait(10)
        subprocess.run(["bash", netns, "down", prefix], capture_output=True, timeout=60)


def _run_unit(name: str, env: dict[str, str], log: Path, instance: str = "3") -> subprocess.Popen:
    argv = expand(parse_unit(UNITS / name)["Service"]["ExecStart"][0], env, instance)
    return subprocess.Popen(
        argv,
        env={**os.environ, **env, "OMP_NUM_THREADS": "1", "PYTHONUNBUFFERED": "1"},
        stdout=open(log, "wb"),
        stderr=subprocess.STDOUT,
    )


@pytest.mark.slow
def test_unit_command_lines_run_over_mutual_tls(certs, tmp_path):
    """ExecStart of the three units, expanded as systemd would, run a router, a learner and an actor."""
    port = free_port()
    env = {
        **parse_env(UNITS / "gvf.env.example"),
        "VENV": str(Path(PY).parent.parent),
        "RUN": "unitcheck",
        "OUTPUT_DIR": str(tmp_path / "out"),
        "ROUTER": f"tls/127.0.0.1:{port}",
        "ROUTER_LISTEN": f"tls/127.0.0.1:{port}",
        "ROUTER_ZENOH_CONFIG": str(patched("router-tls.json5", certs, tmp_path)),
        "CLIENT_ZENOH_CONFIG": str(patched("client-tls.json5", certs, tmp_path)),
        "CHECKPOINT_DIR": str(tmp_path / "ckpt"),
        "NUM_ENVS": "2",
        "RUN_ARGS": "scale=small scale.warmup=64 scale.batch_size=32 scale.buffer_size=5000",
        "LEARNER_ARGS": "learner.device=cpu learner.publish_every=5 learner.samples_per_insert=4",
        "ACTOR_ARGS": "actor.chunk_len=16",
    }
    procs = []
    try:
        procs.append(_run_unit("gvf-router.service", env, tmp_path / "router.log"))
        procs.append(_run_unit("gvf-learner.service", env, tmp_path / "learner.log"))
        procs.append(_run_unit("gvf-actor@.service", env, tmp_path / "actor.log"))
        progress = Path(env["OUTPUT_DIR"]) / "unitcheck" / "learner" / "progress.json"
        deadline = time.monotonic() + 240
        ok = False
        while time.monotonic() < deadline and not ok:
            time.sleep(1.0)
            assert all(p.poll() is None for p in procs), (tmp_path / "learner.log").read_text()[-2000:]
            try:
                p = json.loads(progress.read_text())
                ok = p["updates"] > 0 and p["actors_alive"] == 1 and p["actors_seen"] == ["actor-3"]
            except (FileNotFoundError, json.JSONDecodeError, KeyError):
                pass
        assert ok, (tmp_path / "learner.log").read_text()[-2000:]
    finally:
        codes = []
        for proc in reversed(procs):  # KillSignal=SIGINT, as systemd stops them
            proc.send_signal(signal.SIGINT)
            try:
                codes.append(proc.wait(60))
            except subprocess.TimeoutExpired:
                proc.kill()
                codes.append(proc.wait(10))
    assert codes == [0, 0, 0]
    assert any(Path(env["CHECKPOINT_DIR"]).iterdir())  # the learner checkpointed into CHECKPOINT_DIR
