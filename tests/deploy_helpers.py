"""Helpers shared by the deploy tests: certificates, a router in a spawned process, clients, gvfctl."""

from __future__ import annotations

import multiprocessing as mp
import queue
import re
import shutil
import socket
import subprocess
import sys
import time
from contextlib import contextmanager
from pathlib import Path

import pytest
import zenoh

from common.config.transport import TransportConfig
from common.transport.zenoh_backend import open_router, zenoh_config

REPO = Path(__file__).resolve().parents[1]
DEPLOY = REPO / "deploy"
ZENOH_DIR = DEPLOY / "zenoh"
UNITS = DEPLOY / "systemd"
CTX = mp.get_context("spawn")
CONSOLE_SCRIPTS = {"gvf-router", "gvf-learner", "gvf-actor", "gvf-train", "gvf-eval"}
CERT_DIR_IN_CONFIGS = "/etc/gvf/tls"
PY = sys.executable


# --- helpers ----------------------------------------------------------------------------------


def free_port(host: str = "127.0.0.1") -> int:
    with socket.socket() as s:
        s.bind((host, 0))
        return s.getsockname()[1]


def patched(name: str, certs: Path, dest: Path, **replace: str) -> Path:
    """deploy/zenoh/<name> with its certificate paths pointed at `certs` (and other text replaced)."""
    text = (ZENOH_DIR / name).read_text().replace(CERT_DIR_IN_CONFIGS, str(certs))
    for old, new in replace.items():
        assert old in text, f"{old!r} not in {name}"
        text = text.replace(old, new)
    path = dest / name
    path.write_text(text)
    return path


def _router(cfg: TransportConfig, ready, stop) -> None:
    """Child process: the run's router, as gvf-router opens it, until `stop`."""
    with open_router(cfg):
        ready.set()
        stop.wait(120)


@contextmanager
def router_process(config_file: Path | None, endpoints: list[str], connect: list[str] | None = None):
    """A router in a spawned process listening on `endpoints` (and joined to the routers at `connect`)."""
    ready, stop = CTX.Event(), CTX.Event()
    cfg = TransportConfig(
        router_listen=endpoints,
        router_connect=connect or [],
        zenoh_config_file=str(config_file) if config_file else None,
    )
    proc = CTX.Process(target=_router, args=(cfg, ready, stop), daemon=True)
    proc.start()
    try:
        assert ready.wait(30), "router did not start"
        yield
    finally:
        stop.set()
        proc.join(15)
        if proc.is_alive():
            proc.kill()
            proc.join(5)


def client(config_file: Path | None, endpoint: str, timeout_s: float = 10.0) -> zenoh.Session:
    cfg = TransportConfig(
        mode="client",
        connect=[endpoint],
        connect_timeout_s=timeout_s,
        zenoh_config_file=str(config_file) if config_file else None,
    )
    return zenoh.open(zenoh_config(cfg))


def acl_writer(out: Path, **env: str):
    """Test certificates in `out`/certs (make_test_certs.sh with `env`, e.g. ACTORS, ROUTERS; skips
    without openssl) and `write(name, *make_acl_args)`: make_acl.py's output as `out`/name.json5."""
    if shutil.which("openssl") is None:
        pytest.skip("openssl not installed: cannot make test certificates (apt-get install openssl)")
    certs = out / "certs"
    subprocess.run(
        ["bash", str(DEPLOY / "make_test_certs.sh"), str(certs)],
        check=True,
        capture_output=True,
        env={**env, "PATH": "/usr/bin:/bin"},
        timeout=60,
    )

    def write(name: str, *args: str) -> Path:
        text = subprocess.run(
            [PY, str(DEPLOY / "make_acl.py"), *args, "--certs", str(certs)],
            check=True,
            capture_output=True,
            text=True,
            timeout=60,
        ).stdout
        path = out / f"{name}.json5"
        path.write_text(text)
        return path

    return write


def collect(session: zenoh.Session, key: str) -> queue.Queue:
    """Every (key, payload) a subscriber on `key` receives, in a queue."""
    got: queue.Queue = queue.Queue()
    session.declare_subscriber(key, lambda s: got.put((str(s.key_expr), s.payload.to_bytes())))
    return got


def drain(q: queue.Queue) -> list:
    """What `q` holds now, in order."""
    out = []
    while not q.empty():
        out.append(q.get())
    return out


def round_trip(config_file: Path | None, endpoint: str) -> bytes:
    """One put from one client session to a subscriber in another, through the router."""
    got: queue.Queue[bytes] = queue.Queue()
    with client(config_file, endpoint) as sender, client(config_file, endpoint) as receiver:
        receiver.declare_subscriber("deploy-test/x", lambda s: got.put(s.payload.to_bytes()))
        pub = sender.declare_publisher("deploy-test/x", congestion_control=zenoh.CongestionControl.BLOCK)
        deadline = time.monotonic() + 10
        while not pub.matching_status.matching and time.monotonic() < deadline:
            time.sleep(0.01)
        pub.put(b"over tls")
        payload = got.get(timeout=10)
        pub.undeclare()
    return payload


def refused(config_file: Path | None, endpoint: str) -> bool:
    try:
        with client(config_file, endpoint, timeout_s=1.5):
            return False
    except zenoh.ZError:
        return True


def gvfctl(*args: str, timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run([PY, str(DEPLOY / "gvfctl.py"), *args], capture_output=True, text=True, timeout=timeout)


@pytest.fixture(scope="module")
def certs(tmp_path_factory) -> Path:
    if shutil.which("openssl") is None:
        pytest.skip("openssl not installed: cannot make test certificates (apt-get install openssl)")
    out = tmp_path_factory.mktemp("tls") / "certs"
    subprocess.run(["bash", str(DEPLOY / "make_test_certs.sh"), str(out)], check=True, capture_output=True, timeout=60)
    return out


def rx_bytes(ns: str, dev: str) -> int:
    """Bytes received so far on network device `dev` inside namespace `ns`."""
    out = subprocess.run(
        ["ip", "netns", "exec", ns, "cat", f"/sys/class/net/{dev}/statistics/rx_bytes"],
        capture_output=True,
        text=True,
        check=True,
    )
    return int(out.stdout)


def parse_unit(path: Path) -> dict[str, dict[str, list[str]]]:
    """systemd unit file -> {section: {key: [values]}}, continuation lines joined."""
    sections: dict[str, dict[str, list[str]]] = {}
    current, pending = None, ""
    for raw in path.read_text().splitlines():
        line = pending + raw.strip() if pending else raw.strip()
        if line.endswith("\\"):
            pending = line[:-1] + " "
            continue
        pending = ""
        if not line or line.startswith(("#", ";")):
            continue
        if line.startswith("["):
            current = sections.setdefault(line.strip("[]"), {})
            continue
        key, _, value = line.partition("=")
        current.setdefault(key.strip(), []).append(value.strip())
    return sections


def parse_env(path: Path) -> dict[str, str]:
    env = {}
    for line in path.read_text().splitlines():
        if line.strip() and not line.lstrip().startswith("#"):
            key, _, value = line.partition("=")
            env[key.strip()] = value.strip()
    return env


def expand(command: str, env: dict[str, str], instance: str = "3") -> list[str]:
    """An Exec line as systemd runs it: %i, `$VAR` words split at spaces, `${VAR}` in place."""
    argv = []
    for word in command.replace("%i", instance).split():
        if re.fullmatch(r"\$[A-Za-z_]\w*", word):
            argv += env[word[1:]].split()
        else:
            argv.append(re.sub(r"\$\{(\w+)\}", lambda m: env[m.group(1)], word))
    return argv


UNIT_SCRIPTS = {
    "gvf-router.service": "gvf-router",
    "gvf-learner.service": "gvf-learner",
    "gvf-actor@.service": "gvf-actor",
}
