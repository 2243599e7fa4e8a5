"""An access-controlled router mesh (deploy/make_acl.py --site / --upstream) on 127.0.0.1: router A
(the learner's site) and router B (a site of actors) joined over mutual TLS, each with default-deny
rules. B's actors train A's learner and receive its weights, control and query replies; an
intruder at B holding an actor's identity still reaches only its own keys; router A alone stops a
router B without any rules from forwarding more than B's actors may send; a router of the run's
CA that A does not list forwards nothing, beside a listed one that does."""

from __future__ import annotations

import json
import subprocess
import time

import pytest

from common import wire
from common.keys import Keys
from tests.deploy_helpers import DEPLOY, PY, acl_writer, client, collect, drain, free_port, router_process
from tests.helpers import TINY, script, stop

RUN = "meshacl"
FAR = ["b0", "b1"]


@pytest.fixture(scope="module")
def mesh_files(tmp_path_factory):
    """Certificates (routers a, b and c; actors b0, b1) and every router's and client's config file."""
    out = tmp_path_factory.mktemp("meshacl")
    write = acl_writer(out, ACTORS=" ".join(["a0", *FAR]), ROUTERS="a b c")

    far = ["--actors", *FAR, "--upstream", "a"]
    files = {
        "router-a": write(
            "router-a", "--run", RUN, "--actors", "a0", "--site", f"b={','.join(FAR)}", "--router-cert", "router-a"
        ),
        "router-b": write("router-b", "--run", RUN, *far, "--router-cert", "router-b"),
        "router-c": write("router-c", "--run", RUN, *far, "--router-cert", "router-c"),  # not in A's list
    }
    open_b = json.loads(files["router-b"].read_text())
    open_b["access_control"]["enabled"] = False  # a compromised or misconfigured site router
    files["router-b-open"] = out / "router-b-open.json5"
    files["router-b-open"].write_text(json.dumps(open_b))
    for identity in ("learner", "evaluator", "operator", *(f"actor-{a}" for a in FAR)):
        files[identity] = write(identity, "--client", identity)
    return files


def test_the_far_site_reaches_only_what_its_actors_may(mesh_files):
    keys, ep_a, ep_b = Keys(RUN), f"tls/127.0.0.1:{free_port()}", f"tls/127.0.0.1:{free_port()}"
    with router_process(mesh_files["router-a"], [ep_a]), router_process(mesh_files["router-b"], [ep_b], [ep_a]):
        learner, operator = client(mesh_files["learner"], ep_a), client(mesh_files["operator"], ep_a)
        honest, intruder = client(mesh_files["actor-b0"], ep_b), client(mesh_files["actor-b1"], ep_b)
        try:
            chunks = collect(learner, keys.all_transitions)
            control = collect(learner, keys.control)
            to_actor = {name: collect(honest, getattr(keys, name)) for name in ("weights", "flow", "control")}
            learner.declare_queryable(keys.weights, lambda q: q.reply(keys.weights, b"served"))
            token = honest.liveliness().declare_token(keys.alive("actor", "b0"))
            time.sleep(2.0)  # the routers link and learn the subscriptions
            honest.put(keys.transitions("b0"), b"own")
            intruder.put(keys.transitions("b1"), b"its own")
            for key in (keys.transitions("b0"), keys.weights, keys.flow, keys.control):
                intruder.put(key, b"forged")
            operator.put(keys.control, wire.encode(wire.Control("stop")))
            learner.put(keys.weights, b"real")
            time.sleep(1.5)
            assert sorted(drain(chunks)) == [(keys.transitions("b0"), b"own"), (keys.transitions("b1"), b"its own")]
            assert [p for _, p in drain(control)] == [wire.encode(wire.Control("stop"))]  # the operator's only
            assert [p for _, p in drain(to_actor["weights"])] == [b"real"] and drain(to_actor["flow"]) == []
            assert [p for _, p in drain(to_actor["control"])] == [wire.encode(wire.Control("stop"))]
            assert [r.ok.payload.to_bytes() for r in honest.get(keys.weights, timeout=3) if r.ok] == [b"served"]
            alive = [str(r.ok.key_expr) for r in learner.liveliness().get(keys.all_alive("actor"), timeout=2) if r.ok]
            assert alive == [keys.alive("actor", "b0")]  # the far actor's token reaches the learner's site
            token.undeclare()
        finally:
            for s in (learner, operator, honest, intruder):
                s.close()


def test_router_a_alone_limits_a_site_router_without_rules_to_its_actors(mesh_files):
    keys, ep_a, ep_b = Keys(RUN), f"tls/127.0.0.1:{free_port()}", f"tls/127.0.0.1:{free_port()}"
    with router_process(mesh_files["router-a"], [ep_a]), router_process(mesh_files["router-b-open"], [ep_b], [ep_a]):
        learner, forger = client(mesh_files["learner"], ep_a), client(mesh_files["actor-b1"], ep_b)
        evaluator = client(mesh_files["evaluator"], ep_a)
        try:
            chunks, control = collect(learner, keys.all_transitions), collect(learner, keys.control)
            weights = collect(evaluator, keys.weights)
            time.sleep(2.0)
            for key in (keys.transitions("b0"), keys.transitions("a0"), keys.weights, keys.flow, keys.control):
                forger.put(key, b"forged")  # B's rules would stop all but its own; B has none
            learner.put(keys.weights, b"real")
            time.sleep(1.5)
            # another site-b actor's name passes (A cannot tell b0 from b1 behind B); a0 of site A does not
            assert drain(chunks) == [(keys.transitions("b0"), b"forged")] and drain(control) == []
            assert [p for _, p in drain(weights)] == [b"real"]  # the learner's weights only
        finally:
            for s in (learner, forger, evaluator):
                s.close()


def test_a_router_that_router_a_does_not_list_forwards_nothing(mesh_files):
    keys, ep_a = Keys(RUN), f"tls/127.0.0.1:{free_port()}"
    ep_b, ep_c = f"tls/127.0.0.1:{free_port()}", f"tls/127.0.0.1:{free_port()}"
    with (
        router_process(mesh_files["router-a"], [ep_a]),
        router_process(mesh_files["router-b"], [ep_b], [ep_a]),
        router_process(mesh_files["router-c"], [ep_c], [ep_a]),  # the same config as B, another certificate
    ):
        learner = client(mesh_files["learner"], ep_a)
        at_b, at_c = client(mesh_files["actor-b0"], ep_b), client(mesh_files["actor-b1"], ep_c)
        try:
            chunks = collect(learner, keys.all_transitions)
            weights = {"b": collect(at_b, keys.weights), "c": collect(at_c, keys.weights)}
            time.sleep(2.0)
            at_b.put(keys.transitions("b0"), b"through b")
            at_c.put(keys.transitions("b1"), b"through c")
            learner.put(keys.weights, b"real")
            time.sleep(1.5)
            assert drain(chunks) == [(keys.transitions("b0"), b"through b")]
            assert [p for _, p in drain(weights["b"])] == [b"real"] and drain(weights["c"]) == []
        finally:
            for s in (learner, at_b, at_c):
                s.close()


@pytest.mark.slow
def test_a_real_actor_at_the_far_site_trains_the_learner_through_the_secured_mesh(mesh_files, tmp_path):
    ep_a, ep_b = f"tls/127.0.0.1:{free_port()}", f"tls/127.0.0.1:{free_port()}"
    common = [*TINY, f"run={RUN}"]
    with router_process(mesh_files["router-a"], [ep_a]), router_process(mesh_files["router-b"], [ep_b], [ep_a]):
        learner = script(
            "gvf-learner",
            [
                *common,
                f"transport.connect=[{ep_a}]",
                f"transport.zenoh_config_file={mesh_files['learner']}",
                f"hydra.run.dir={tmp_path}/learner",
            ],
            tmp_path / "learner.log",
        )
        actor = script(
            "gvf-actor",
            [
                *common,
                f"transport.connect=[{ep_b}]",
                f"transport.zenoh_config_file={mesh_files['actor-b0']}",
                "actor.name=b0",
                f"hydra.run.dir={tmp_path}/actor",
            ],
            tmp_path / "actor.log",
        )
        try:
            progress = tmp_path / "learner" / "progress.json"
            deadline = time.monotonic() + 240
            state: dict = {}
            while time.monotonic() < deadline and state.get("updates", 0) == 0:
                time.sleep(0.5)
                state = json.loads(progress.read_text() or "{}") if progress.exists() else {}
            assert state.get("updates", 0) > 0, (tmp_path / "actor.log").read_text()[-2000:]
            assert state["actors_seen"] == ["b0"] and state["rejected"] == 0 and state["lost_chunks"] == 0
            assert learner.poll() is None and actor.poll() is None
        finally:
            stop(actor)
            stop(learner)


@pytest.mark.parametrize(
    "args",
    [
        ["--site", "b"],
        ["--site", "b="],
        ["--site", "b/x=a1"],
        ["--upstream", "a/b"],
        ["--site", "b=a0"],  # a0 is also a local actor
        ["--site", "a=a1", "--upstream", "a"],
    ],
)
def test_a_bad_site_is_refused_naming_it(args):
    done = subprocess.run(
        [PY, str(DEPLOY / "make_acl.py"), "--run", RUN, "--actors", "a0", *args],
        capture_output=True,
        text=True,
        timeout=60,
    )
    bad = args[1].split("=")[0] if args[0] == "--site" else args[1]
    assert done.returncode == 2 and bad in done.stderr.strip().splitlines()[-1], done.stderr
