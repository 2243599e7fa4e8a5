"""deploy/zenoh: the router and client configs load in Zenoh, TLS and mutual TLS really work on
loopback (certificates from deploy/make_test_certs.sh, skipped without openssl), and gvfctl talks
to a plain TCP router. Every session is closed and every process joined in `finally`."""

from __future__ import annotations

import json
import queue
import shutil
import stat
import subprocess
import threading
from pathlib import Path

import pytest
import zenoh

from common.config.transport import TransportConfig
from common.keys import Keys
from common.transport.zenoh_backend import open_router, zenoh_config
from common.wire import Control, decode
from tests.deploy_helpers import (  # noqa: F401  (certs is a fixture)
    DEPLOY,
    PY,
    ZENOH_DIR,
    certs,
    client,
    free_port,
    gvfctl,
    patched,
    refused,
    round_trip,
    router_process,
)

# --- Zenoh configs ----------------------------------------------------------------------------

JSON5_FILES = sorted(p.name for p in ZENOH_DIR.glob("*.json5"))


def test_the_four_configs_exist():
    assert set(JSON5_FILES) >= {"router.json5", "client.json5", "router-tls.json5", "client-tls.json5"}


@pytest.mark.parametrize("name", JSON5_FILES)
def test_json5_loads_in_zenoh_and_through_the_transport_config(name, tmp_path):
    # certificate files need not exist to load; they are read when a TLS link opens
    conf = zenoh.Config.from_file(str(ZENOH_DIR / name))  # unknown keys would be refused here
    mode = "router" if name.startswith("router") else "client"
    assert json.loads(conf.get_json("mode")) == mode
    assert json.loads(conf.get_json("scouting/multicast/enabled")) is False
    assert json.loads(conf.get_json("transport/link/rx/max_message_size")) == TransportConfig().max_message_size
    endpoints = json.loads(conf.get_json("listen/endpoints" if mode == "router" else "connect/endpoints"))
    assert endpoints and all(e.endswith(":7447") for e in endpoints)
    # the way gvf-router / gvf-learner / gvf-actor load it: file first, then the transport fields
    if mode == "router":
        cfg = TransportConfig(zenoh_config_file=str(ZENOH_DIR / name), router_listen=["tcp/127.0.0.1:0"])
        built = zenoh_config(cfg, mode="router", listen=cfg.router_listen, connect=[])
    else:
        built = zenoh_config(TransportConfig(zenoh_config_file=str(ZENOH_DIR / name)))
    assert json.loads(built.get_json("mode")) == mode


def test_tls_configs_name_every_certificate(certs, tmp_path):
    for name, keys in {
        "router-tls.json5": (
            "root_ca_certificate",
            "listen_private_key",
            "listen_certificate",
            "connect_private_key",
            "connect_certificate",
        ),
        "client-tls.json5": ("root_ca_certificate", "connect_private_key", "connect_certificate"),
    }.items():
        conf = zenoh.Config.from_file(str(patched(name, certs, tmp_path)))
        tls = json.loads(conf.get_json("transport/link/tls"))
        assert tls["enable_mtls"] is True and tls["verify_name_on_connect"] is True
        assert json.loads(conf.get_json("transport/link/protocols")) == ["tls"]
        for key in keys:
            assert Path(tls[key]).is_file(), f"{name}: {key} -> {tls[key]}"


# --- TLS on loopback --------------------------------------------------------------------------


def test_mutual_tls_round_trip_and_what_it_refuses(certs, tmp_path):
    router_conf = patched("router-tls.json5", certs, tmp_path)
    client_conf = patched("client-tls.json5", certs, tmp_path)
    no_cert = tmp_path / "no-cert.json5"
    no_cert.write_text(client_conf.read_text().replace("enable_mtls: true", "enable_mtls: false"))
    port = free_port()
    # 127.0.0.2 is loopback too, but not a name in the router certificate
    with router_process(router_conf, [f"tls/127.0.0.1:{port}", f"tls/127.0.0.2:{port}"]):
        assert round_trip(client_conf, f"tls/127.0.0.1:{port}") == b"over tls"
        assert round_trip(client_conf, f"tls/localhost:{port}") == b"over tls"
        assert refused(no_cert, f"tls/127.0.0.1:{port}"), "mTLS router let in a client without certificate"
        assert refused(client_conf, f"tls/127.0.0.2:{port}"), "client accepted a certificate not naming the host"
        assert refused(None, f"tcp/127.0.0.1:{port}"), "plain TCP reached the TLS port"
        ping = gvfctl("ping", "--connect", f"tls/127.0.0.1:{port}", "--config", str(client_conf))
        assert ping.returncode == 0, ping.stderr
    # a client config that names a tcp/ endpoint fails instead of going unencrypted
    assert refused(client_conf, f"tcp/127.0.0.1:{free_port()}")


def test_server_side_tls_round_trip(certs, tmp_path):
    off = {"enable_mtls: true": "enable_mtls: false"}
    router_conf = patched("router-tls.json5", certs, tmp_path, **off)
    client_conf = patched("client-tls.json5", certs, tmp_path, **off)
    port = free_port()
    with router_process(router_conf, [f"tls/127.0.0.1:{port}"]):
        assert round_trip(client_conf, f"tls/127.0.0.1:{port}") == b"over tls"


def test_tls_router_refuses_a_plain_tcp_listen_endpoint(certs, tmp_path):
    cfg = TransportConfig(
        zenoh_config_file=str(patched("router-tls.json5", certs, tmp_path)),
        router_listen=[f"tcp/127.0.0.1:{free_port()}"],
    )
    with pytest.raises(zenoh.ZError, match="(?i)protocol"):
        open_router(cfg).close()


def test_make_test_certs_names_and_reuses_the_ca(tmp_path):
    if shutil.which("openssl") is None:
        pytest.skip("openssl not installed")
    out = tmp_path / "c"
    script = str(DEPLOY / "make_test_certs.sh")
    subprocess.run(
        ["bash", script, str(out), "router.example.org", "192.0.2.1"], check=True, capture_output=True, timeout=60
    )
    ca = (out / "ca.pem").read_bytes()
    san = subprocess.run(
        ["openssl", "x509", "-in", str(out / "router.pem"), "-noout", "-ext", "subjectAltName"],
        check=True,
        capture_output=True,
        text=True,
    ).stdout
    for name in ("DNS:localhost", "IP Address:127.0.0.1", "DNS:router.example.org", "IP Address:192.0.2.1"):
        assert name in san
    for cert in ("router.pem", "client.pem"):
        subprocess.run(
            ["openssl", "verify", "-CAfile", str(out / "ca.pem"), str(out / cert)], check=True, capture_output=True
        )
    assert stat.S_IMODE((out / "client.key").stat().st_mode) == 0o600
    subprocess.run(["bash", script, str(out)], check=True, capture_output=True, timeout=60)
    assert (out / "ca.pem").read_bytes() == ca  # the CA is kept: old clients trust new certificates
    usage = subprocess.run(["bash", script], capture_output=True, text=True)
    assert usage.returncode == 2 and "usage" in usage.stderr


# --- gvfctl against a plain TCP router --------------------------------------------------------


def test_gvfctl_ping_alive_and_stop(tmp_path):
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    keys = Keys("deploytest")
    with router_process(ZENOH_DIR / "router.json5", [endpoint]):
        assert gvfctl("ping", "--connect", endpoint).returncode == 0
        watch = subprocess.Popen(
            [PY, str(DEPLOY / "gvfctl.py"), "alive", "--watch", "--connect", endpoint, "--run", "deploytest"],
            stdout=subprocess.PIPE,
            text=True,
        )
        lines: queue.Queue[str] = queue.Queue()
        threading.Thread(target=lambda: [lines.put(line) for line in watch.stdout], daemon=True).start()
        try:
            with client(ZENOH_DIR / "client.json5", endpoint) as session:
                token = session.liveliness().declare_token(keys.alive("actor", "a7"))
                controls: queue.Queue[bytes] = queue.Queue()
                sub = session.declare_subscriber(keys.control, lambda s: controls.put(s.payload.to_bytes()))
                alive = gvfctl("alive", "--connect", endpoint, "--run", "deploytest")
                assert alive.returncode == 0 and keys.alive("actor", "a7") in alive.stdout.split()
                assert lines.get(timeout=20).split()[1:] == ["+", keys.alive("actor", "a7")]
                stop = gvfctl("stop", "--connect", endpoint, "--run", "deploytest", "--reason", "test")
                assert stop.returncode == 0, stop.stderr
                assert decode(controls.get(timeout=10), expect=Control) == Control("stop", "test")
                sub.undeclare()
                token.undeclare()
                assert lines.get(timeout=20).split()[1:] == ["-", keys.alive("actor", "a7")]
        finally:
            watch.terminate()  # --watch ends on SIGTERM (and Ctrl-C) with status 0
            assert watch.wait(20) == 0
        # nobody alive, nobody listening: both say so with status 1
        assert gvfctl("alive", "--connect", endpoint, "--run", "deploytest", "--timeout", "1").returncode == 1
        assert gvfctl("stop", "--connect", endpoint, "--run", "deploytest", "--timeout", "0.5").returncode == 1
    assert gvfctl("ping", "--connect", endpoint, "--timeout", "1").returncode == 1  # router gone
