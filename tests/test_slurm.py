"""deploy/slurm/ against a real SLURM cluster (`make slurm`: one node, this machine).

A router and a learner run here on 127.0.0.1; the actors run as a 2-task SLURM job array, once
through Hydra's submitit launcher (deploy/slurm/actors.yaml) and once with plain sbatch
(deploy/slurm/actors.sbatch). Each case checks that both actors join the learner (liveliness),
that their chunks land in its replay (progress.json), and that the jobs end when stopped.
Measured times are printed as one JSON line per case (`pytest -s` shows them).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import time
from contextlib import contextmanager
from datetime import datetime
from pathlib import Path

import pytest

from common.keys import Keys
from tests.deploy_helpers import DEPLOY, REPO, client
from tests.helpers import BIN, TINY, free_port, script, stop

# generous bounds, each wait ends when its event happens: with a training run holding both cores
# (this file at nice 19) a Python start takes minutes and the file took 19-27 min
pytestmark = [pytest.mark.slow, pytest.mark.timeout(1800)]
WAIT_S = 600

NAMES = ["actor-0", "actor-1"]
# the actors' part of the experiment: the learner's scale, one env per 1-CPU task, short chunks
ACTOR_ARGS = ["scale=small", "actor.num_envs=1", "actor.chunk_len=16"]
JOB_TIMEOUT_MIN = 30  # a leftover task is killed by SLURM even if the test's clean-up fails


def _cluster_problem() -> str | None:
    if shutil.which("sinfo") is None or shutil.which("sbatch") is None:
        return "SLURM not installed: `make slurm` sets up a one-node cluster on this machine"
    out = subprocess.run(["sinfo", "-h", "-o", "%T %C"], capture_output=True, text=True, timeout=30)
    if out.returncode != 0 or not out.stdout.strip():
        return f"SLURM cluster down ({out.stderr.strip() or 'no nodes'}): start it with `make slurm`"
    idle_cpus = sum(int(line.split()[1].split("/")[1]) for line in out.stdout.splitlines())
    if idle_cpus < len(NAMES):
        return f"SLURM cluster has {idle_cpus} idle CPUs, the test needs {len(NAMES)} (`squeue` shows who holds them)"
    return None


@pytest.fixture(scope="module")
def cluster():
    problem = _cluster_problem()
    if problem:
        pytest.skip(problem)


def squeue(*args: str) -> list[str]:
    """Ids of the queued jobs (array tasks) that `args` select."""
    out = subprocess.run(["squeue", "-h", "-o", "%i", *args], capture_output=True, text=True, timeout=30)
    return out.stdout.split()  # an unknown (purged) job id fails: nothing is queued


def wait_until(what: str, predicate, timeout: float, poll: float = 0.2):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(poll)
    raise AssertionError(f"timed out after {timeout:.0f} s waiting for {what}")


def progress(run_dir: Path) -> dict:
    try:
        return json.loads((run_dir / "progress.json").read_text())
    except (FileNotFoundError, json.JSONDecodeError):
        return {}


def alive_actors(endpoint: str, run: str) -> list[str]:
    """Names of the actors whose liveliness tokens the router holds (as `gvfctl.py alive` lists them)."""
    with client(None, endpoint) as session:
        replies = session.liveliness().get(Keys(run).all_alive("actor"), timeout=5)
        return sorted(str(r.ok.key_expr).rsplit("/", 1)[-1] for r in replies if r.ok is not None)


@pytest.fixture(scope="module")
def router(cluster, tmp_path_factory):
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    logs = tmp_path_factory.mktemp("router")
    proc = script("gvf-router", [f"transport.router_listen=[{endpoint}]", f"hydra.run.dir={logs}"], logs / "router.log")
    try:
        wait_until("the router", lambda: "listening" in (logs / "router.log").read_text(), WAIT_S)
        yield endpoint
    finally:
        stop(proc)


@contextmanager
def learner(endpoint: str, run: str, tmp_path: Path):
    run_dir = tmp_path / "learner"
    common = [*TINY, "scale=small", f"transport.connect=[{endpoint}]", f"run={run}"]
    proc = script("gvf-learner", [*common, f"hydra.run.dir={run_dir}"], tmp_path / "learner.log")
    try:
        wait_until("the learner's first progress", lambda: progress(run_dir) or proc.poll() is not None, WAIT_S)
        assert proc.poll() is None, (tmp_path / "learner.log").read_text()[-3000:]
        yield proc, run_dir
    finally:
        stop(proc)


def watch_actors(endpoint: str, run: str, run_dir: Path, jobs: list[str], t_submit: float) -> dict:
    """Wait for both tasks (squeue `jobs` selects them) to run, both actors to be alive and both
    actors' chunks in the replay; returns the seconds from submission to each."""
    times = {}
    wait_until("both array tasks running", lambda: len(squeue("-t", "RUNNING", *jobs)) == 2, WAIT_S)
    times["job_start_s"] = time.monotonic() - t_submit
    out = subprocess.run(["squeue", "-h", "-o", "%V %S", *jobs], capture_output=True, text=True, timeout=30)
    queued = [
        datetime.fromisoformat(start) - datetime.fromisoformat(sub)
        for sub, start in map(str.split, out.stdout.splitlines())
    ]
    times["slurm_queued_s"] = max(q.total_seconds() for q in queued)  # SLURM's own submit-to-start (1 s resolution)
    wait_until("both actors alive at the router", lambda: alive_actors(endpoint, run) == NAMES, WAIT_S, poll=1.0)
    times["alive_s"] = time.monotonic() - t_submit
    seen = wait_until(
        "chunks of both actors in the replay",
        lambda: (p := progress(run_dir)).get("actors_seen") == NAMES and p["inserted"] > 0 and p,
        WAIT_S,
        poll=0.5,
    )
    times["chunks_s"] = time.monotonic() - t_submit
    assert seen["actors_alive"] == 2 and seen["rejected"] == 0 and seen["lost_chunks"] == 0
    return times


def job_state(job_id: str) -> str:
    out = subprocess.run(["scontrol", "-o", "show", "job", job_id], capture_output=True, text=True, timeout=30)
    return " ".join(sorted({w.split("=")[1] for w in out.stdout.split() if w.startswith("JobState=")}))


def test_submitit_launcher_runs_the_actor_array_until_gvfctl_stop(router, tmp_path):
    try:
        import hydra_plugins.hydra_submitit_launcher  # noqa: F401
    except ImportError:
        pytest.skip("hydra-submitit-launcher not installed: `make slurm` installs it (pip install -e '.[slurm]')")
    run = f"slurm-submitit-{os.getpid()}"
    sweep = tmp_path / "multirun"
    with learner(router, run, tmp_path) as (learner_proc, run_dir):
        t_submit = time.monotonic()
        submitter = script(
            "gvf-actor",
            [
                "--multirun",
                "--config-dir",
                "deploy",
                "+slurm=actors",
                f"transport.connect=[{router}]",
                f"run={run}",
                *ACTOR_ARGS,
                "hydra.launcher.cpus_per_task=1",
                "hydra.launcher.mem_gb=2",
                f"hydra.launcher.timeout_min={JOB_TIMEOUT_MIN}",
                f"hydra.sweep.dir={sweep}",
                "actor.seed=range(0,2)",
            ],
            tmp_path / "submit.log",
        )
        name = f"gvf-actor-{run}"  # hydra.launcher.name in actors.yaml
        try:
            times = watch_actors(router, run, run_dir, ["-n", name], t_submit)
            t_stop = time.monotonic()
            out = subprocess.run(
                [str(BIN / "python"), str(DEPLOY / "gvfctl.py"), "stop", "--connect", router, "--run", run],
                capture_output=True,
                text=True,
                timeout=WAIT_S,
            )
            assert out.returncode == 0, out.stderr
            wait_until("the array tasks to end", lambda: not squeue("-n", name), WAIT_S)
            times["jobs_end_after_stop_s"] = time.monotonic() - t_stop
            # every task returned (submitit wrote its result) and the waiting submitter exits 0
            assert submitter.wait(WAIT_S) == 0, (tmp_path / "submit.log").read_text()[-3000:]
            results = sorted(p.name for p in sweep.glob(".submitit/*/*_result.pkl"))
            assert len(results) == 2, results
            assert learner_proc.wait(WAIT_S) == 0  # the same stop ended the learner cleanly
        finally:
            subprocess.run(["scancel", "-n", name], capture_output=True, timeout=30)
            stop(submitter)
    print(json.dumps({"case": "submitit", **{k: round(v, 1) for k, v in times.items()}}))


def test_sbatch_array_runs_two_actors_until_scancel(router, tmp_path):
    run = f"slurm-sbatch-{os.getpid()}"
    env = {
        **os.environ,
        "ROUTER": router,
        "RUN": run,
        "NUM_ENVS": "1",
        "VENV": str(BIN.parent),
        "RUN_ARGS": " ".join(ACTOR_ARGS),
        "OMP_NUM_THREADS": "1",
    }
    cmd = [
        "sbatch",
        "--parsable",
        "--array=0-1",
        "--cpus-per-task=1",
        "--mem=2G",
        f"--time={JOB_TIMEOUT_MIN}",
        f"--chdir={tmp_path}",  # the tasks' outputs (logs, Hydra dirs) go here, not into the checkout
        str(REPO / "deploy" / "slurm" / "actors.sbatch"),
    ]
    with learner(router, run, tmp_path) as (_, run_dir):
        t_submit = time.monotonic()
        out = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=60)
        assert out.returncode == 0, out.stderr
        job = out.stdout.strip().split(";")[0]
        try:
            times = watch_actors(router, run, run_dir, ["-j", job], t_submit)
            t_stop = time.monotonic()
            subprocess.run(["scancel", job], check=True, timeout=30)
            wait_until("the array tasks to end", lambda: not squeue("-j", job), WAIT_S)
            times["jobs_end_after_stop_s"] = time.monotonic() - t_stop
            assert set(job_state(job).split()) <= {"CANCELLED"}, job_state(job)
            for i, name in enumerate(NAMES):
                log = (tmp_path / f"gvf-actor-{job}_{i}.out").read_text()
                assert "restarting" not in log, log[-3000:]  # a cancelled actor is not restarted
                assert "signal SIGTERM: stopping" in log, log[-3000:]  # scancel reached the actor through srun
                assert (tmp_path / "outputs" / run / name).is_dir()  # hydra.run.dir the script names
        finally:
            subprocess.run(["scancel", job], capture_output=True, timeout=30)
    print(json.dumps({"case": "sbatch", **{k: round(v, 1) for k, v in times.items()}}))
