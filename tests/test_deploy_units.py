"""deploy/: the systemd units, SLURM files, scripts and guide are well-formed and run the
project's console scripts with overrides the config accepts (tests/test_deploy_live.py runs them)."""

from __future__ import annotations

import os
import re
import shutil
import subprocess

import pytest
import yaml
from omegaconf import open_dict

from tests.deploy_helpers import CONSOLE_SCRIPTS, DEPLOY, REPO, UNIT_SCRIPTS, UNITS, expand, parse_env, parse_unit

# --- systemd units ----------------------------------------------------------------------------


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
