"""The secured router (deploy/make_acl.py): mutual TLS with one identity per role and Zenoh access
control, default deny, on 127.0.0.1. An intruder holding an actor's identity cannot publish
weights, control, flow or another actor's transitions; a client without a certificate of the
run's CA cannot connect; the real learner and actor still train through it."""

from __future__ import annotations

import json
import time

import pytest

from common import wire
from common.keys import Keys
from tests.deploy_helpers import acl_writer, client, collect, drain, free_port, refused, router_process
from tests.helpers import TINY, script, stop

RUN = "acl"
ACTORS = ["actor-0", "actor-1"]


@pytest.fixture(scope="module")
def secured(tmp_path_factory):
    """Certificates per role and actor, the router's config and each client's (as files)."""
    out = tmp_path_factory.mktemp("acl")
    write = acl_writer(out, ACTORS=" ".join(ACTORS))

    files = {"router": write("router", "--run", RUN, "--actors", *ACTORS)}
    for identity in ("learner", "evaluator", "operator", "client", *(f"actor-{a}" for a in ACTORS)):
        files[identity] = write(identity, "--client", identity)
    return files


def test_each_identity_may_do_only_what_its_role_may(secured):
    keys, ep = Keys(RUN), f"tls/127.0.0.1:{free_port()}"
    with router_process(secured["router"], [ep]):
        learner, honest = client(secured["learner"], ep), client(secured["actor-actor-0"], ep)
        intruder, operator = client(secured["actor-actor-1"], ep), client(secured["operator"], ep)
        evaluator = client(secured["evaluator"], ep)
        try:
            chunks = collect(learner, keys.all_transitions)
            control = collect(learner, keys.control)
            to_actor = {name: collect(honest, getattr(keys, name)) for name in ("weights", "flow", "control", "tracks")}
            to_evaluator = collect(evaluator, keys.weights)
            learner.declare_queryable(keys.weights, lambda q: q.reply(keys.weights, b"served"))
            time.sleep(1.0)  # the router learns the subscriptions
            honest.put(keys.transitions("actor-0"), b"own")
            intruder.put(keys.transitions("actor-1"), b"its own")
            for key in (keys.transitions("actor-0"), keys.weights, keys.flow, keys.tracks, keys.control):
                intruder.put(key, b"forged")  # none of these is an actor-1 right
            intruder.liveliness().declare_token(keys.alive("learner", "learner"))
            operator.put(keys.control, wire.encode(wire.Control("stop")))
            learner.put(keys.weights, b"real")
            time.sleep(1.5)
            assert sorted(drain(chunks)) == [
                (keys.transitions("actor-0"), b"own"),
                (keys.transitions("actor-1"), b"its own"),
            ]
            assert [p for _, p in drain(control)] == [wire.encode(wire.Control("stop"))]  # the operator's only
            assert [p for _, p in drain(to_actor["weights"])] == [b"real"] and drain(to_evaluator) == [
                (keys.weights, b"real")
            ]
            assert drain(to_actor["flow"]) == drain(to_actor["tracks"]) == []
            assert [p for _, p in drain(to_actor["control"])] == [wire.encode(wire.Control("stop"))]
            assert [r.ok.payload.to_bytes() for r in honest.get(keys.weights, timeout=3) if r.ok] == [b"served"]
            alive = [str(r.ok.key_expr) for r in operator.liveliness().get(keys.all_alive(), timeout=2) if r.ok]
            assert keys.alive("learner", "learner") not in alive  # the intruder's forged token never got out
        finally:
            for s in (learner, honest, intruder, operator, evaluator):
                s.close()
        assert refused(None, ep)  # no TLS at all
        plain = json.loads(secured["client"].read_text())
        plain["transport"]["link"]["tls"].pop("connect_certificate")
        plain["transport"]["link"]["tls"].pop("connect_private_key")
        plain["transport"]["link"]["tls"]["enable_mtls"] = False
        nocert = secured["client"].with_name("nocert.json5")
        nocert.write_text(json.dumps(plain))
        assert refused(nocert, ep)  # TLS without a client certificate of the run's CA


def test_the_real_learner_and_actor_train_through_the_secured_router_and_ignore_the_intruder(secured, tmp_path):
    keys, ep = Keys(RUN), f"tls/127.0.0.1:{free_port()}"
    common = [*TINY, f"transport.connect=[{ep}]", f"run={RUN}"]
    with router_process(secured["router"], [ep]):
        learner = script(
            "gvf-learner",
            [*common, f"transport.zenoh_config_file={secured['learner']}", f"hydra.run.dir={tmp_path}/learner"],
            tmp_path / "learner.log",
        )
        actor = script(
            "gvf-actor",
            [
                *common,
                f"transport.zenoh_config_file={secured['actor-actor-0']}",
                "actor.name=actor-0",
                f"hydra.run.dir={tmp_path}/actor",
            ],
            tmp_path / "actor.log",
        )
        try:
            progress = tmp_path / "learner" / "progress.json"
            deadline = time.monotonic() + 150
            while time.monotonic() < deadline and not (
                progress.exists() and json.loads(progress.read_text() or "{}").get("updates", 0) > 0
            ):
                time.sleep(0.5)
            with client(secured["actor-actor-1"], ep) as intruder:
                for _ in range(5):
                    intruder.put(keys.control, wire.encode(wire.Control("stop")))
                    intruder.put(keys.flow, wire.encode(wire.Control("pause")))
                time.sleep(3)
            before = json.loads(progress.read_text())["updates"]
            time.sleep(8)
            after = json.loads(progress.read_text())
            assert learner.poll() is None and actor.poll() is None  # neither obeyed the intruder's stop
            assert after["updates"] > before > 0 and after["actors_seen"] == ["actor-0"] and after["rejected"] == 0
        finally:
            stop(actor)
            stop(learner)
