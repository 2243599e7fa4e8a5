"""deploy/: the systemd units, SLURM files, scripts and guide are well-formed and run the
project's console scripts with overrides the config accepts. `-m multihost` adds the guide's
network-namespace recipe (root only); `-m slow` runs the units' command lines over mTLS for real."""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import time
from pathlib import Path

import pytest
import yaml
from omegaconf import open_dict

from tests.deploy_helpers import CONSOLE_SCRIPTS, DEPLOY, PY, REPO, UNITS, certs, free_port, patched  # noqa: F401  (certs is a fixture)

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


UNIT_SCRIPTS = {
    "gvf-router.service": "gvf-router",
    "gvf-learner.service": "gvf-learner",
    "gvf-actor@.service": "gvf-actor",
}


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
    assert (
        cfg.hydra.run.dir
        == f"{env['OUTPUT_DIR']}/{env['RUN']}/"
        + {"gvf-router.service": "router", "gvf-learner.service": "learner", "gvf-actor@.service": "actor-3"}[name]
    )
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
    units = [
        str(tmp_path / "gvf-router.service"),
        str(tmp_path / "gvf-learner.service"),
        str(tmp_path / "gvf-actor@3.service"),
    ]
    out = subprocess.run(["systemd-analyze", "verify", "--man=no", *units], capture_output=True, text=True, timeout=60)
    problems = [
        line
        for line in (out.stdout + out.stderr).splitlines()
        if str(tmp_path) in line and not re.search(r"Unknown key '(RestartSteps|RestartMaxDelaySec)'", line)
    ]
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
    stub.write_text(
        "#!/usr/bin/env bash\n"
        'n=$(($(cat "$CALLS" 2>/dev/null || echo 0) + 1)); echo $n > "$CALLS"\n'
        'printf "%s\\n" "$@" > "$ARGS"\n'
        '[ "$n" -gt 1 ]\n'
    )
    stub.chmod(0o755)
    env = {
        **os.environ,
        "PATH": f"{stub.parent}:{os.environ['PATH']}",
        "CALLS": str(tmp_path / "calls"),
        "ARGS": str(tmp_path / "args"),
        "SLURM_ARRAY_TASK_ID": "5",
        "SLURM_CPUS_PER_TASK": "4",
        "ROUTER": "tls/router.example.org:7447",
        "RUN": "exp1",
        "VENV": "/opt/gvf/venv",
        "ZENOH_CONFIG": "/etc/gvf/zenoh/client-tls.json5",
        "RUN_ARGS": "agent=gvf_ddpg scale=paper",
        "RESTART_BACKOFF_S": "1",
    }
    out = subprocess.run(
        ["bash", str(DEPLOY / "slurm" / "actors.sbatch")],
        env=env,
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 0, out.stderr
    assert (tmp_path / "calls").read_text().strip() == "2"  # failed once, restarted, then stopped
    argv = (tmp_path / "args").read_text().splitlines()
    assert argv[:3] == ["--ntasks=1", "--cpus-per-task=4", "/opt/gvf/venv/bin/gvf-actor"]
    for override in (
        "run=exp1",
        "transport.connect=[tls/router.example.org:7447]",
        "actor.name=actor-5",
        "actor.seed=5",
        "transport.zenoh_config_file=/etc/gvf/zenoh/client-tls.json5",
        "agent=gvf_ddpg",
        "scale=paper",
    ):
        assert override in argv


def test_slurm_launcher_config():
    data = yaml.safe_load((DEPLOY / "slurm" / "actors.yaml").read_text())
    assert (DEPLOY / "slurm" / "actors.yaml").read_text().startswith("# @package _global_")
    assert {"override /hydra/launcher": "submitit_slurm"} in data["defaults"]
    launcher = data["hydra"]["launcher"]
    assert {"partition", "cpus_per_task", "timeout_min", "array_parallelism", "max_num_timeout", "name"} <= set(
        launcher
    )
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
        cfg = compose(
            "config",
            overrides=[
                f"hydra.searchpath=[file://{search}]",
                "+slurm=actors",
                "actor.seed=7",
                "transport.connect=[tcp/router.example.org:7447]",
                "run=exp1",
            ],
            return_hydra_config=True,
        )
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
    for section in (
        "Topology",
        "Firewall",
        "Start each role by hand",
        "With systemd",
        "With SLURM",
        "With TLS",
        "Check that it works",
        "Stop",
        "Resume the learner",
        "Try it on one machine with network namespaces",
    ):
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
