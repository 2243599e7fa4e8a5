#!/usr/bin/env python3
"""Write the Zenoh config of a run's router with mutual TLS and access control, default deny:
each role may do only what `WIRING` (common/keys.py) gives it, identified by the common name of
its certificate (deploy/make_test_certs.sh makes one per role and per actor).

    python deploy/make_acl.py --run exp1 --actors h1-a0 h1-a1 --certs /etc/gvf/tls > router-acl.json5
    gvf-router transport.zenoh_config_file=router-acl.json5 'transport.router_listen=[tls/0.0.0.0:7447]'

Rights (router's view: ingress = from the client, egress = to it), all under gvf/<run>/:
- actor NAME (gvf-actor-NAME): put transitions/NAME and episodes/NAME, its token alive/actor/NAME;
  subscribe to (and receive) weights, tracks, flow, control; query weights and receive the reply.
- learner (gvf-learner): put weights, tracks, flow; serve the weights queryable; subscribe to
  (and receive) transitions/*, episodes/*, control; its token alive/learner/learner; watch the
  actors' tokens.
- evaluator (gvf-evaluator): subscribe to (and receive) weights.
- operator (gvf-operator, gvfctl): put control; watch and list every token; gvfctl ping's keys.
Anything else (another actor's transitions, weights from an actor, control from anyone but the
operator, a client without a certificate of the run's CA) is refused by the router.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run as a script from a checkout

from common.keys import ROUTES, Keys, check_name  # noqa: E402

PING = "gvf-ping/**"  # deploy/gvfctl.py ping's keys, outside every run
SUBSCRIBE = ["declare_subscriber"]


def rule(rid: str, messages: list[str], flow: str, keys: list[str]) -> dict:
    return {"id": rid, "permission": "allow", "messages": messages, "flows": [flow], "key_exprs": keys}


def acl(run: str, actors: list[str]) -> dict:
    """The access_control block for run `run` and these actor names (see the module docstring)."""
    root = Keys(run).root
    k = {name: f"{root}/{r.key}" for name, r in ROUTES.items()}
    to_actors = [f"{root}/{name}" for name in ("weights", "tracks", "flow", "control")]
    rules = [
        rule("actor-receive", SUBSCRIBE + ["query"], "ingress", to_actors),
        rule("actor-delivered", ["put", "reply"], "egress", to_actors),
        # a declared publisher sends only once it hears of a matching subscriber (the learner's
        # wildcard ones): let those declarations through; the puts stay limited to the own name
        rule("actor-matched", SUBSCRIBE, "egress", [f"{root}/transitions/*", f"{root}/episodes/*"]),
        rule(
            "learner-publish",
            ["put", "declare_queryable", "reply"],
            "ingress",
            [f"{root}/weights", f"{root}/tracks", f"{root}/flow"],
        ),
        rule("learner-asked", ["query"], "egress", [f"{root}/weights"]),
        rule("learner-matched", SUBSCRIBE, "egress", [f"{root}/weights", f"{root}/tracks", f"{root}/flow"]),
        rule(
            "learner-receive", SUBSCRIBE, "ingress", [f"{root}/transitions/*", f"{root}/episodes/*", f"{root}/control"]
        ),
        rule(
            "learner-delivered", ["put"], "egress", [f"{root}/transitions/*", f"{root}/episodes/*", f"{root}/control"]
        ),
        rule("learner-token", ["liveliness_token"], "ingress", [f"{root}/alive/learner/learner"]),
        rule(
            "learner-watch", ["declare_liveliness_subscriber", "liveliness_query"], "ingress", [f"{root}/alive/actor/*"]
        ),
        rule("learner-watched", ["liveliness_token", "reply"], "egress", [f"{root}/alive/actor/*"]),
        rule("evaluator-receive", SUBSCRIBE, "ingress", [f"{root}/weights"]),
        rule("evaluator-delivered", ["put"], "egress", [f"{root}/weights"]),
        rule("operator-control", ["put"], "ingress", [f"{root}/control"]),
        rule("operator-matched", SUBSCRIBE, "egress", [f"{root}/control", PING]),
        rule("operator-watch", ["declare_liveliness_subscriber", "liveliness_query"], "ingress", [f"{root}/alive/**"]),
        rule("operator-watched", ["liveliness_token", "reply"], "egress", [f"{root}/alive/**"]),
        rule("operator-ping-in", ["put"] + SUBSCRIBE, "ingress", [PING]),
        rule("operator-ping-out", ["put"], "egress", [PING]),
    ]
    subjects = [{"id": role, "cert_common_names": [f"gvf-{role}"]} for role in ("learner", "evaluator", "operator")]
    policies = [
        {"id": "learner", "subjects": ["learner"], "rules": [r["id"] for r in rules if r["id"].startswith("learner-")]},
        {"id": "evaluator", "subjects": ["evaluator"], "rules": ["evaluator-receive", "evaluator-delivered"]},
        {
            "id": "operator",
            "subjects": ["operator"],
            "rules": [r["id"] for r in rules if r["id"].startswith("operator-")],
        },
    ]
    for name in actors:
        check_name(name, "actor")
        own = [k["transitions"].replace("<actor>", name), k["episodes"].replace("<actor>", name)]
        rules.append(rule(f"actor-{name}-send", ["put"], "ingress", own))
        rules.append(rule(f"actor-{name}-token", ["liveliness_token"], "ingress", [f"{root}/alive/actor/{name}"]))
        subjects.append({"id": f"actor-{name}", "cert_common_names": [f"gvf-actor-{name}"]})
        policies.append(
            {
                "id": f"actor-{name}",
                "subjects": [f"actor-{name}"],
                "rules": [
                    "actor-receive",
                    "actor-delivered",
                    "actor-matched",
                    f"actor-{name}-send",
                    f"actor-{name}-token",
                ],
            }
        )
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects, "policies": policies}


def router_config(run: str, actors: list[str], certs: str) -> dict:
    """A whole router config: TLS only, mutual TLS with the run's CA, and `acl(run, actors)`."""
    c = Path(certs)
    return {
        "mode": "router",
        "listen": {"endpoints": ["tls/0.0.0.0:7447"]},
        "scouting": {"multicast": {"enabled": False}},
        "transport": {
            "unicast": {"max_sessions": 1000},
            "link": {
                "protocols": ["tls"],  # a plain tcp/ endpoint fails at start-up instead of opening
                "rx": {"max_message_size": 67108864},
                "tls": {
                    "root_ca_certificate": str(c / "ca.pem"),
                    "listen_private_key": str(c / "router.key"),
                    "listen_certificate": str(c / "router.pem"),
                    "enable_mtls": True,  # no certificate of the run's CA: no session
                    "connect_private_key": str(c / "router.key"),
                    "connect_certificate": str(c / "router.pem"),
                    "verify_name_on_connect": True,
                },
            },
        },
        "access_control": acl(run, actors),
    }


def client_config(identity: str, certs: str) -> dict:
    """The Zenoh config of one client over mutual TLS with its own identity: `learner`,
    `evaluator`, `operator` or `actor-NAME` (the files make_test_certs.sh writes)."""
    c = Path(certs)
    return {
        "mode": "client",
        "scouting": {"multicast": {"enabled": False}},
        "transport": {
            "link": {
                "protocols": ["tls"],
                "rx": {"max_message_size": 67108864},
                "tls": {
                    "root_ca_certificate": str(c / "ca.pem"),
                    "enable_mtls": True,
                    "connect_private_key": str(c / f"{identity}.key"),
                    "connect_certificate": str(c / f"{identity}.pem"),
                    "verify_name_on_connect": True,
                },
            },
        },
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--run", help="the run name (key prefix gvf/<run>/): writes the router's config")
    parser.add_argument("--actors", nargs="+", default=[], help="every actor name the run may have")
    parser.add_argument("--client", help="instead, a client's config: learner, evaluator, operator or actor-NAME")
    parser.add_argument("--certs", default="/etc/gvf/tls", help="folder of the certificates (make_test_certs.sh)")
    args = parser.parse_args(argv)
    if args.client:
        print(json.dumps(client_config(args.client, args.certs), indent=2))
        return 0
    if not args.run or not args.actors:
        parser.error("the router's config needs --run and --actors (or give --client)")
    check_name(args.run, "run")
    print(json.dumps(router_config(args.run, args.actors, args.certs), indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
