"""Multi-host: router, learner and two actors in three network namespaces joined by veth through
a bridge, so every message really crosses network interfaces. Needs root (skipped otherwise).

    [ns R: gvf-router, bridge 192.0.2.1] --veth-- [ns L: gvf-learner 192.0.2.2]
                                         --veth-- [ns A: gvf-actor x2 192.0.2.3]

The addresses exist only inside the namespaces this test makes and deletes.
"""

import json
import os
import shutil
import subprocess
import time

import pytest

from tests.deploy_helpers import rx_bytes
from tests.helpers import BIN, TINY, stop

pytestmark = pytest.mark.multihost


def ip(*args, ns=None):
    cmd = ["ip", *(["-n", ns] if ns else []), *args]
    subprocess.run(cmd, check=True, capture_output=True, timeout=10)


@pytest.fixture
def namespaces():
    if os.geteuid() != 0 or shutil.which("ip") is None:
        pytest.skip("needs root and iproute2 to create network namespaces")
    tag = f"{os.getpid() % 100000}"
    r, ln, a = f"gvfr{tag}", f"gvfl{tag}", f"gvfa{tag}"
    try:
        for ns in (r, ln, a):
            ip("netns", "add", ns)
            ip("link", "set", "lo", "up", ns=ns)
    except subprocess.CalledProcessError as err:
        for ns in (r, ln, a):
            subprocess.run(["ip", "netns", "del", ns], capture_output=True)
        pytest.skip(f"cannot create network namespaces here: {err.stderr.decode().strip()}")
    try:
        ip("link", "add", "br0", "type", "bridge", ns=r)
        ip("addr", "add", "192.0.2.1/24", "dev", "br0", ns=r)
        ip("link", "set", "br0", "up", ns=r)
        for ns, host in ((ln, 2), (a, 3)):
            inner, outer = f"v{ns}", f"b{ns}"
            ip("link", "add", inner, "type", "veth", "peer", "name", outer)
            ip("link", "set", inner, "netns", ns)
            ip("link", "set", outer, "netns", r)
            ip("link", "set", outer, "master", "br0", ns=r)
            ip("link", "set", outer, "up", ns=r)
            ip("addr", "add", f"192.0.2.{host}/24", "dev", inner, ns=ns)
            ip("link", "set", inner, "up", ns=ns)
        yield r, ln, a
    finally:
        for ns in (r, ln, a):
            subprocess.run(["ip", "netns", "del", ns], capture_output=True)


def in_ns(ns, name, args, log):
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONUNBUFFERED": "1"}
    return subprocess.Popen(
        ["ip", "netns", "exec", ns, str(BIN / name), *args], stdout=open(log, "wb"), stderr=subprocess.STDOUT, env=env
    )


def test_router_learner_and_two_actors_in_three_namespaces(namespaces, tmp_path):
    r, ln, a = namespaces
    endpoint = "tcp/192.0.2.1:7447"
    common = [*TINY, f"transport.connect=[{endpoint}]", "run=multihost"]
    procs = []
    try:
        procs.append(
            in_ns(
                r,
                "gvf-router",
                [f"transport.router_listen=[{endpoint}]", f"hydra.run.dir={tmp_path}/router"],
                tmp_path / "router.log",
            )
        )
        time.sleep(1.0)
        procs.append(in_ns(ln, "gvf-learner", [*common, f"hydra.run.dir={tmp_path}/learner"], tmp_path / "learner.log"))
        actors = [
            in_ns(
                a,
                "gvf-actor",
                [*common, f"actor.name=far-{i}", "actor.max_env_steps=2000", f"hydra.run.dir={tmp_path}/a{i}"],
                tmp_path / f"actor{i}.log",
            )
            for i in range(2)
        ]
        procs += actors
        for i, proc in enumerate(actors):
            proc.wait(240)
            assert proc.returncode == 0, (tmp_path / f"actor{i}.log").read_text()[-2000:]
            stats = json.loads((tmp_path / f"actor{i}.log").read_text().strip().splitlines()[-1])
            assert stats["env_steps"] >= 2000 and stats["policy_version"] > 0  # weights crossed back
        progress = json.loads((tmp_path / "learner" / "progress.json").read_text())
        assert progress["updates"] > 0 and progress["actors_seen"] == ["far-0", "far-1"]
        assert rx_bytes(ln, f"v{ln}") > 1_000_000  # the transitions really came in over the learner's veth
    finally:
        for proc in reversed(procs):
            stop(proc)


# slow (~57 s): the same ACL refusals run by default on loopback (test_deploy_acl.py, with the real
# learner and actor); here they are checked across namespaces as well
@pytest.mark.slow
def test_secured_router_across_namespaces_refuses_an_intruder_with_an_actor_identity(namespaces, tmp_path):
    """deploy/make_acl.py's router in ns R; the learner in ns L; an actor and an intruder holding
    another actor's certificate in ns A. The intruder's stop, pause and weights reach nobody."""
    r, ln, a = namespaces
    if shutil.which("openssl") is None:
        pytest.skip("openssl not installed (apt-get install openssl)")
    certs, endpoint = tmp_path / "certs", "tls/192.0.2.1:7447"
    env = {"ACTORS": "far-0 intruded", "PATH": "/usr/bin:/bin"}
    subprocess.run(
        ["bash", "deploy/make_test_certs.sh", str(certs), "192.0.2.1"], check=True, capture_output=True, env=env
    )

    def config(name, *args):
        text = subprocess.run(
            [str(BIN / "python"), "deploy/make_acl.py", *args, "--certs", str(certs)],
            check=True,
            capture_output=True,
            text=True,
        ).stdout
        (tmp_path / f"{name}.json5").write_text(text)
        return tmp_path / f"{name}.json5"

    router_cfg = config("router", "--run", "secured", "--actors", "far-0", "intruded")
    common = [*TINY, f"transport.connect=[{endpoint}]", "run=secured"]
    procs = []
    try:
        procs.append(
            in_ns(
                r,
                "gvf-router",
                [
                    f"transport.router_listen=[{endpoint}]",
                    f"transport.zenoh_config_file={router_cfg}",
                    f"hydra.run.dir={tmp_path}/router",
                ],
                tmp_path / "router.log",
            )
        )
        time.sleep(1.5)
        procs.append(
            in_ns(
                ln,
                "gvf-learner",
                [
                    *common,
                    f"transport.zenoh_config_file={config('learner', '--client', 'learner')}",
                    f"hydra.run.dir={tmp_path}/learner",
                ],
                tmp_path / "learner.log",
            )
        )
        actor = in_ns(
            a,
            "gvf-actor",
            [
                *common,
                f"transport.zenoh_config_file={config('actor', '--client', 'actor-far-0')}",
                "actor.name=far-0",
                "actor.max_env_steps=3000",
                f"hydra.run.dir={tmp_path}/a0",
            ],
            tmp_path / "actor.log",
        )
        procs.append(actor)
        intruder_cfg = config("intruder", "--client", "actor-intruded")
        script = (
            "import sys, time, zenoh\n"
            "from common import wire\n"
            "from common.config.transport import TransportConfig\n"
            "from common.transport.zenoh_backend import zenoh_config\n"
            f"cfg = TransportConfig(mode='client', connect=['{endpoint}'], zenoh_config_file='{intruder_cfg}')\n"
            "with zenoh.open(zenoh_config(cfg)) as s:\n"
            "    for _ in range(60):\n"
            "        s.put('gvf/secured/control', wire.encode(wire.Control('stop')))\n"
            "        s.put('gvf/secured/flow', wire.encode(wire.Control('pause')))\n"
            "        s.put('gvf/secured/weights', b'forged')\n"
            "        time.sleep(0.5)\n"
        )
        intruder = subprocess.Popen(
            ["ip", "netns", "exec", a, str(BIN / "python"), "-c", script],
            stdout=open(tmp_path / "intruder.log", "wb"),
            stderr=subprocess.STDOUT,
        )
        procs.append(intruder)
        actor.wait(240)
        assert actor.returncode == 0, (tmp_path / "actor.log").read_text()[-2000:]
        stats = json.loads((tmp_path / "actor.log").read_text().strip().splitlines()[-1])
        assert (
            stats["env_steps"] >= 3000 and stats["policy_version"] > 0 and stats["rejected"] == 0
        )  # no forged weights arrived
        # its stop would have ended the actor at once, before max_env_steps, and the learner too
        assert procs[1].poll() is None
        progress = json.loads((tmp_path / "learner" / "progress.json").read_text())
        assert progress["updates"] > 0 and progress["actors_seen"] == ["far-0"]
    finally:
        for proc in reversed(procs):
            stop(proc)
