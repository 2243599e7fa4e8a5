"""deploy/: the Zenoh configs load and TLS / mutual TLS really work; the systemd units, SLURM files
and scripts are well-formed and run the project's console scripts with overrides the config accepts.

The TLS tests make certificates with deploy/make_test_certs.sh (skipped without openssl), run a
router in a 'spawn' child (forking after zenoh init hangs) on 127.0.0.1 with the router config's
certificate paths pointed at them, and connect clients built exactly as learner and actors build
theirs (`common.zenoh_transport.zenoh_config`). Every session is closed and every process joined
in `finally`. `-m multihost` adds the network-namespace recipe of deploy/README.md (root only);
`-m slow` runs the systemd units' command lines (router, learner, actor over mTLS) for real.
"""

from __future__ import annotations

import json
import multiprocessing as mp
import os
import queue
import re
import shutil
import signal
import socket
import stat
import subprocess
import sys
import threading
import time
from contextlib import contextmanager
from pathlib import Path

import pytest
import yaml
import zenoh
from omegaconf import open_dict

from common.config.transport import TransportConfig
from common.keys import Keys
from common.wire import Control, decode
from common.zenoh_transport import open_router, zenoh_config

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
def router_process(config_file: Path | None, endpoints: list[str]):
    ready, stop = CTX.Event(), CTX.Event()
    cfg = TransportConfig(router_listen=endpoints, zenoh_config_file=str(config_file) if config_file else None)
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
    cfg = TransportConfig(mode="client", connect=[endpoint], connect_timeout_s=timeout_s,
                          zenoh_config_file=str(config_file) if config_file else None)
    return zenoh.open(zenoh_config(cfg))


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
    for name, keys in {"router-tls.json5": ("root_ca_certificate", "listen_private_key", "listen_certificate",
                                            "connect_private_key", "connect_certificate"),
                       "client-tls.json5": ("root_ca_certificate", "connect_private_key", "connect_certificate")}.items():
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
    cfg = TransportConfig(zenoh_config_file=str(patched("router-tls.json5", certs, tmp_path)),
                          router_listen=[f"tcp/127.0.0.1:{free_port()}"])
    with pytest.raises(zenoh.ZError, match="(?i)protocol"):
        open_router(cfg).close()


def test_make_test_certs_names_and_reuses_the_ca(tmp_path):
    if shutil.which("openssl") is None:
        pytest.skip("openssl not installed")
    out = tmp_path / "c"
    script = str(DEPLOY / "make_test_certs.sh")
    subprocess.run(["bash", script, str(out), "router.example.org", "192.0.2.1"], check=True, capture_output=True, timeout=60)
    ca = (out / "ca.pem").read_bytes()
    san = subprocess.run(["openssl", "x509", "-in", str(out / "router.pem"), "-noout", "-ext", "subjectAltName"],
                         check=True, capture_output=True, text=True).stdout
    for name in ("DNS:localhost", "IP Address:127.0.0.1", "DNS:router.example.org", "IP Address:192.0.2.1"):
        assert name in san
    for cert in ("router.pem", "client.pem"):
        subprocess.run(["openssl", "verify", "-CAfile", str(out / "ca.pem"), str(out / cert)], check=True, capture_output=True)
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
        watch = subprocess.Popen([PY, str(DEPLOY / "gvfctl.py"), "alive", "--watch", "--connect", endpoint,
                                  "--run", "deploytest"], stdout=subprocess.PIPE, text=True)
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


# --- systemd units ----------------------------------------------------------------------------

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


UNIT_SCRIPTS = {"gvf-router.service": "gvf-router", "gvf-learner.service": "gvf-learner",
                "gvf-actor@.service": "gvf-actor"}


def test_the_units_and_env_example_exist():
    assert {p.name for p in UNITS.glob("*.service")} == set(UNIT_SCRIPTS)
    assert (UNITS / "gvf.env.example").is_file()


@pytest.mark.parametrize("name", sorted(UNIT_SCRIPTS))
def test_unit_has_the_required_settings(name):
    unit = parse_unit(UNITS / name)
    service = unit["Service"]
    one = {key: values[-1] for key, values in service.items()}
    assert unit["Unit"]["Description"] and unit["Install"]["WantedBy"] == ["multi-user.target"]
    assert one["EnvironmentFile"] == "/etc/gvf/gvf.env"
    assert one["Restart"] == "on-failure" and float(one["RestartSec"]) > 0
    assert {"RestartSteps", "RestartMaxDelaySec"} <= set(one)  # the backoff grows (systemd >= 254)
    assert one["KillSignal"] in ("SIGINT", "SIGTERM") and int(one["TimeoutStopSec"]) > 0
    assert unit["Unit"].get("StartLimitIntervalSec") == ["0"]  # restarts never run out
    assert "network-online.target" in unit["Unit"]["After"][0]


@pytest.mark.parametrize("name", sorted(UNIT_SCRIPTS))
def test_unit_runs_its_console_script_only(name):
    unit = parse_unit(UNITS / name)
    execs = {k: v for k, v in unit["Service"].items() if k.startswith("Exec")}
    assert list(execs) == ["ExecStart"] and len(execs["ExecStart"]) == 1
    argv = execs["ExecStart"][0].split()
    # systemd refuses a variable as the program: env(1) runs the venv's script
    assert argv[0] == "/usr/bin/env" and argv[1] == "${VENV}/bin/" + UNIT_SCRIPTS[name]
    mentioned = set(re.findall(r"\bgvf-[a-z]+\b", " ".join(argv)))
    assert mentioned <= CONSOLE_SCRIPTS


def test_units_use_only_variables_the_env_example_defines():
    env = parse_env(UNITS / "gvf.env.example")
    for name in UNIT_SCRIPTS:
        text = (UNITS / name).read_text()
        used = set(re.findall(r"\$\{(\w+)\}", text)) | set(re.findall(r"\$([A-Za-z_]\w*)", text))
        assert used <= set(env), f"{name} uses undefined {used - set(env)}"


def test_learner_resumes_and_actor_instances_are_unique():
    learner = parse_unit(UNITS / "gvf-learner.service")["Service"]["ExecStart"][0].split()
    assert "resume=true" in learner and "learner.checkpoint_dir=${CHECKPOINT_DIR}" in learner
    actor = parse_unit(UNITS / "gvf-actor@.service")["Service"]["ExecStart"][0].split()
    assert "actor.name=actor-%i" in actor and "actor.seed=%i" in actor


@pytest.mark.parametrize("name", sorted(UNIT_SCRIPTS))
def test_unit_command_line_composes_with_the_run_config(name):
    """The overrides a unit passes, expanded with the example settings, compose with conf/."""
    from hydra import compose, initialize_config_dir
    from hydra.core.override_parser.overrides_parser import OverridesParser

    from common.cli import CONF_DIR
    from common.config.run import register, to_objects

    env = parse_env(UNITS / "gvf.env.example")
    overrides = expand(parse_unit(UNITS / name)["Service"]["ExecStart"][0], env)[2:]
    OverridesParser.create().parse_overrides(overrides)
    register()
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        cfg = compose("config", overrides=overrides, return_hydra_config=True)
    assert cfg.hydra.run.dir == f"{env['OUTPUT_DIR']}/{env['RUN']}/" + {
        "gvf-router.service": "router", "gvf-learner.service": "learner", "gvf-actor@.service": "actor-3"}[name]
    with open_dict(cfg):
        del cfg["hydra"]
    run, _, _ = to_objects(cfg)
    assert run.run == env["RUN"]
    if name == "gvf-router.service":
        assert run.transport.router_listen == [env["ROUTER_LISTEN"]]
        assert run.transport.zenoh_config_file == env["ROUTER_ZENOH_CONFIG"]
    else:
        assert run.transport.mode == "client" and run.transport.connect == [env["ROUTER"]]
        assert run.transport.zenoh_config_file == env["CLIENT_ZENOH_CONFIG"]
    if name == "gvf-learner.service":
        assert run.resume and run.learner.checkpoint_dir == env["CHECKPOINT_DIR"]
    if name == "gvf-actor@.service":
        assert (run.actor.name, run.actor.seed, run.actor.num_envs) == ("actor-3", 3, int(env["NUM_ENVS"]))


@pytest.mark.skipif(shutil.which("systemd-analyze") is None, reason="systemd-analyze not installed")
def test_systemd_analyze_verify(tmp_path):
    for path in UNITS.glob("*.service"):
        shutil.copy(path, tmp_path)
    units = [str(tmp_path / "gvf-router.service"), str(tmp_path / "gvf-learner.service"),
             str(tmp_path / "gvf-actor@3.service")]
    out = subprocess.run(["systemd-analyze", "verify", "--man=no", *units],
                         capture_output=True, text=True, timeout=60)
    problems = [line for line in (out.stdout + out.stderr).splitlines()
                if str(tmp_path) in line and not re.search(r"Unknown key '(RestartSteps|RestartMaxDelaySec)'", line)]
    assert not problems, "\n".join(problems)


# --- scripts and SLURM ------------------------------------------------------------------------

SCRIPTS = sorted([*DEPLOY.glob("*.sh"), *DEPLOY.glob("slurm/*.sbatch")])


@pytest.mark.parametrize("path", SCRIPTS, ids=lambda p: p.name)
def test_shell_scripts_parse(path):
    out = subprocess.run(["bash", "-n", str(path)], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    if shutil.which("shellcheck"):
        out = subprocess.run(["shellcheck", "-S", "warning", str(path)], capture_output=True, text=True)
        assert out.returncode == 0, out.stdout


def test_scripts_are_executable():
    for path in [*DEPLOY.glob("*.sh"), DEPLOY / "gvfctl.py"]:
        assert os.access(path, os.X_OK), path


def test_sbatch_script_runs_one_named_actor_and_restarts_it(tmp_path):
    """actors.sbatch with a stand-in `srun` that records its arguments and fails once."""
    stub = tmp_path / "bin" / "srun"
    stub.parent.mkdir()
    stub.write_text('#!/usr/bin/env bash\n'
                    'n=$(($(cat "$CALLS" 2>/dev/null || echo 0) + 1)); echo $n > "$CALLS"\n'
                    'printf "%s\\n" "$@" > "$ARGS"\n'
                    '[ "$n" -gt 1 ]\n')
    stub.chmod(0o755)
    env = {**os.environ, "PATH": f"{stub.parent}:{os.environ['PATH']}", "CALLS": str(tmp_path / "calls"),
           "ARGS": str(tmp_path / "args"), "SLURM_ARRAY_TASK_ID": "5", "SLURM_CPUS_PER_TASK": "4",
           "ROUTER": "tls/router.example.org:7447", "RUN": "exp1", "VENV": "/opt/gvf/venv",
           "ZENOH_CONFIG": "/etc/gvf/zenoh/client-tls.json5", "RUN_ARGS": "agent=gvf_ddpg scale=paper",
           "RESTART_BACKOFF_S": "1"}
    out = subprocess.run(["bash", str(DEPLOY / "slurm" / "actors.sbatch")], env=env, cwd=tmp_path,
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert (tmp_path / "calls").read_text().strip() == "2"  # failed once, restarted, then stopped
    argv = (tmp_path / "args").read_text().splitlines()
    assert argv[:3] == ["--ntasks=1", "--cpus-per-task=4", "/opt/gvf/venv/bin/gvf-actor"]
    for override in ("run=exp1", "transport.connect=[tls/router.example.org:7447]", "actor.name=actor-5",
                     "actor.seed=5", "transport.zenoh_config_file=/etc/gvf/zenoh/client-tls.json5",
                     "agent=gvf_ddpg", "scale=paper"):
        assert override in argv


def test_slurm_launcher_config():
    data = yaml.safe_load((DEPLOY / "slurm" / "actors.yaml").read_text())
    assert (DEPLOY / "slurm" / "actors.yaml").read_text().startswith("# @package _global_")
    assert {"override /hydra/launcher": "submitit_slurm"} in data["defaults"]
    launcher = data["hydra"]["launcher"]
    assert {"partition", "cpus_per_task", "timeout_min", "array_parallelism", "max_num_timeout", "name"} <= set(launcher)
    assert launcher["array_parallelism"] >= 64  # actors never finish: all must run at once
    assert data["hydra"]["sweeper"]["params"]["actor.seed"].startswith("range(")


def test_slurm_config_composes_one_actor_per_seed(tmp_path):
    """`gvf-actor -m --config-dir deploy +slurm=actors ...` as Hydra composes one job of the sweep."""
    from hydra import compose, initialize_config_dir

    from common.cli import CONF_DIR
    from common.config.run import register, to_objects

    search = DEPLOY
    try:
        import hydra_plugins.hydra_submitit_launcher  # noqa: F401
        with_launcher = True
    except ImportError:
        # without the plugin, compose the job's part: drop the launcher selection and settings
        with_launcher = False
        data = yaml.safe_load((DEPLOY / "slurm" / "actors.yaml").read_text())
        data["defaults"] = [d for d in data["defaults"] if "override /hydra/launcher" not in d]
        del data["hydra"]["launcher"]
        (tmp_path / "slurm").mkdir()
        (tmp_path / "slurm" / "actors.yaml").write_text("# @package _global_\n" + yaml.safe_dump(data))
        search = tmp_path
    register()
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        cfg = compose("config", overrides=[f"hydra.searchpath=[file://{search}]", "+slurm=actors", "actor.seed=7",
                                           "transport.connect=[tcp/router.example.org:7447]", "run=exp1"],
                      return_hydra_config=True)
    assert str(cfg.hydra.mode).endswith("MULTIRUN")
    if with_launcher:
        assert cfg.hydra.launcher._target_.endswith("SlurmLauncher") and cfg.hydra.launcher.name == "gvf-actor-exp1"
    with open_dict(cfg):
        del cfg["hydra"]
    run, _, _ = to_objects(cfg)
    assert run.actor.name == "actor-7" and run.transport.connect == ["tcp/router.example.org:7447"]
    assert run.transport.mode == "client" and run.transport.connect_timeout_s == -1


# --- the guide --------------------------------------------------------------------------------

def test_readme_names_only_real_files_and_commands():
    text = (DEPLOY / "README.md").read_text()
    for path in set(re.findall(r"\bdeploy/[\w./@-]*\w", text)):
        assert (REPO / path).exists(), path
    for name in re.findall(r"`((?:zenoh|systemd|slurm)/[\w.@-]+)`", text):
        assert (DEPLOY / name).exists(), name
    programs = set(re.findall(r"(?:^|[\s/])(gvf-[a-z]{4,})(?=\s)", text, re.M))  # not netns gvf-r
    assert programs <= CONSOLE_SCRIPTS, programs - CONSOLE_SCRIPTS
    subcommands = set(re.findall(r"gvfctl\.py (\w+)", text))
    assert subcommands <= {"ping", "alive", "stop", "pause", "resume", "router"}, subcommands
    for section in ("Topology", "Firewall", "Start each role by hand", "With systemd", "With SLURM", "With TLS",
                    "Check that it works", "Stop", "Resume the learner", "Try it on one machine with network namespaces"):
        assert section in text, section


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
        router = subprocess.Popen(["ip", "netns", "exec", f"{prefix}-r", PY, str(DEPLOY / "gvfctl.py"), "router",
                                   "--listen", "tcp/192.0.2.1:7447"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        time.sleep(1.0)
        holder = subprocess.Popen(["ip", "netns", "exec", f"{prefix}-a", PY, "-c",
                                   "import sys, zenoh; from common.config.transport import TransportConfig as T;"
                                   "from common.zenoh_transport import zenoh_config as z;"
                                   "s = zenoh.open(z(T(connect=['tcp/192.0.2.1:7447'])));"
                                   "t = s.liveliness().declare_token('gvf/netns/alive/actor/a0');"
                                   "print('up', flush=True); sys.stdin.read(); s.close()"],
                                  stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        try:
            assert holder.stdout.readline().strip() == "up"
            for ns in ("l", "a"):
                out = subprocess.run(["ip", "netns", "exec", f"{prefix}-{ns}", PY, str(DEPLOY / "gvfctl.py"), "ping",
                                      "--connect", "tcp/192.0.2.1:7447"], capture_output=True, text=True, timeout=60)
                assert out.returncode == 0, out.stderr
            out = subprocess.run(["ip", "netns", "exec", f"{prefix}-l", PY, str(DEPLOY / "gvfctl.py"), "alive",
                                  "--connect", "tcp/192.0.2.1:7447", "--run", "netns"],
                                 capture_output=True, text=True, timeout=60)
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
    return subprocess.Popen(argv, env={**os.environ, **env, "OMP_NUM_THREADS": "1", "PYTHONUNBUFFERED": "1"},
                            stdout=open(log, "wb"), stderr=subprocess.STDOUT)


@pytest.mark.slow
def test_unit_command_lines_run_over_mutual_tls(certs, tmp_path):
    """ExecStart of the three units, expanded as systemd would, run a router, a learner and an actor."""
    port = free_port()
    env = {**parse_env(UNITS / "gvf.env.example"),
           "VENV": str(Path(PY).parent.parent), "RUN": "unitcheck", "OUTPUT_DIR": str(tmp_path / "out"),
           "ROUTER": f"tls/127.0.0.1:{port}", "ROUTER_LISTEN": f"tls/127.0.0.1:{port}",
           "ROUTER_ZENOH_CONFIG": str(patched("router-tls.json5", certs, tmp_path)),
           "CLIENT_ZENOH_CONFIG": str(patched("client-tls.json5", certs, tmp_path)),
           "CHECKPOINT_DIR": str(tmp_path / "ckpt"), "NUM_ENVS": "2",
           "RUN_ARGS": "scale=small scale.warmup=64 scale.batch_size=32 scale.buffer_size=5000",
           "LEARNER_ARGS": "learner.device=cpu learner.publish_every=5 learner.samples_per_insert=4 learner.log_every=5",
           "ACTOR_ARGS": "actor.chunk_len=16"}
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
