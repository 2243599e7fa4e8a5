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

A router mesh (one router per site, deploy/README.md "Router mesh") with the same rights: a router
is trusted with exactly the rights of the identities behind it (gvf-router-SITE).
- router A (the learner's site) lists each other site and its actors; site B's router may do what
  those actors may do, and no more (it cannot forward weights, control, or a chunk in another
  site's actor's name):
    python deploy/make_acl.py --run exp1 --actors a0 --site b=b-a0,b-a1 --router-cert router-a > router-a.json5
- router B lists its own actors (each still limited to its own name) and its upstream router A,
  which may do what the learner, the evaluator and the operator may do:
    python deploy/make_acl.py --run exp1 --actors b-a0 b-a1 --upstream a --router-cert router-b > router-b.json5
  and connects to A with `transport.router_connect=[tls/ROUTER_A_HOST:7447]` (its certificate router-b.pem).
A router of the run's CA that A does not list (or a client posing as one) is refused everything.
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


def acl(run: str, actors: list[str], sites: dict[str, list[str]] | None = None, upstream: str | None = None) -> dict:
    """The access_control block for run `run` and these actor names (see the module docstring); `sites`
    (site -> its actors) are the other routers of a mesh this one serves, `upstream` the site of the
    router this one connects to (the learner's)."""
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
    shared = ["actor-receive", "actor-delivered", "actor-matched"]
    check_mesh(actors, sites or {}, upstream)

    def actor_rules(name: str) -> list[str]:
        own = [k["transitions"].replace("<actor>", name), k["episodes"].replace("<actor>", name)]
        rules.append(rule(f"actor-{name}-send", ["put"], "ingress", own))
        rules.append(rule(f"actor-{name}-token", ["liveliness_token"], "ingress", [f"{root}/alive/actor/{name}"]))
        return [f"actor-{name}-send", f"actor-{name}-token"]

    for name in actors:
        subjects.append({"id": f"actor-{name}", "cert_common_names": [f"gvf-actor-{name}"]})
        policies.append({"id": f"actor-{name}", "subjects": [f"actor-{name}"], "rules": shared + actor_rules(name)})
    # a mesh: a neighbour router may do what the identities behind it may do (routers forward their declarations)
    for site, names in (sites or {}).items():
        subjects.append({"id": f"router-{site}", "cert_common_names": [f"gvf-router-{site}"]})
        own = [r for name in names for r in actor_rules(name)]
        # what a client never needs and a router does: the learner's queryable, declared onwards to the far site
        rules.append(rule(f"router-{site}-served", ["declare_queryable"], "egress", [f"{root}/weights"]))
        policies.append(
            {"id": f"router-{site}", "subjects": [f"router-{site}"], "rules": shared + own + [f"router-{site}-served"]}
        )
    if upstream is not None:
        subjects.append({"id": "upstream", "cert_common_names": [f"gvf-router-{upstream}"]})
        behind = [r["id"] for r in rules if r["id"].split("-")[0] in ("learner", "evaluator", "operator")]
        policies.append({"id": "upstream", "subjects": ["upstream"], "rules": behind})
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects, "policies": policies}


def check_mesh(actors: list[str], sites: dict[str, list[str]], upstream: str | None) -> None:
    """Refuse names that would give one identity's rights to two holders: an actor named twice
    (locally or at two sites), a site without actors, the upstream router also listed as a site."""
    seen: dict[str, str] = {}
    for where, names in [("--actors", actors), *((f"--site {site}", names) for site, names in sites.items())]:
        if where != "--actors":
            check_name(where.split()[1], "site")
            if not names:
                raise ValueError(f"{where} lists no actors")
        for name in names:
            check_name(name, "actor")
            if name in seen:
                places = f"twice in {where}" if seen[name] == where else f"in {seen[name]} and {where}"
                raise ValueError(f"actor {name!r} is {places}: each actor is at one place")
            seen[name] = where
    if upstream is not None:
        check_name(upstream, "site")
        if upstream in sites:
            raise ValueError(f"site {upstream!r} is both --upstream and --site")


def router_config(
    run: str,
    actors: list[str],
    certs: str,
    sites: dict[str, list[str]] | None = None,
    upstream: str | None = None,
    cert: str = "router",
) -> dict:
    """A whole router config: TLS only, mutual TLS with the run's CA, and `acl(run, actors, sites, upstream)`;
    `cert` names its certificate files (router-SITE in a mesh: the name its neighbours know it by)."""
    c = Path(certs)
    # in a mesh, no gossip: the links are exactly the configured ones (as deploy/zenoh/router-mesh-*.json5)
    scouting = {"multicast": {"enabled": False}, **({"gossip": {"enabled": False}} if sites or upstream else {})}
    return {
        "mode": "router",
        "listen": {"endpoints": ["tls/0.0.0.0:7447"]},
        "scouting": scouting,
        "transport": {
            "unicast": {"max_sessions": 1000},
            "link": {
                "protocols": ["tls"],  # a plain tcp/ endpoint fails at start-up instead of opening
                "rx": {"max_message_size": 67108864},
                "tls": {
                    "root_ca_certificate": str(c / "ca.pem"),
                    "listen_private_key": str(c / f"{cert}.key"),
                    "listen_certificate": str(c / f"{cert}.pem"),
                    "enable_mtls": True,  # no certificate of the run's CA: no session
                    "connect_private_key": str(c / f"{cert}.key"),
                    "connect_certificate": str(c / f"{cert}.pem"),
                    "verify_name_on_connect": True,
                },
            },
        },
        "access_control": acl(run, actors, sites, upstream),
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
    parser.add_argument(
        "--site", action="append", default=[], metavar="SITE=A1,A2", help="a mesh: another site's router and its actors"
    )
    parser.add_argument("--upstream", metavar="SITE", help="a mesh: the site of the router this one connects to")
    parser.add_argument(
        "--router-cert", default="router", help="the router's certificate files (router-SITE in a mesh)"
    )
    parser.add_argument("--client", help="instead, a client's config: learner, evaluator, operator or actor-NAME")
    parser.add_argument("--certs", default="/etc/gvf/tls", help="folder of the certificates (make_test_certs.sh)")
    args = parser.parse_args(argv)
    if args.client:
        print(json.dumps(client_config(args.client, args.certs), indent=2))
        return 0
    if not args.run or not (args.actors or args.site):
        parser.error("the router's config needs --run and --actors or --site (or give --client)")
    check_name(args.run, "run")
    sites = {}
    for entry in args.site:
        site, _, names = entry.partition("=")
        if not site or not names:
            parser.error(f"--site takes SITE=ACTOR1,ACTOR2, got {entry!r}")
        if site in sites:
            parser.error(f"--site {site} is given twice")
        sites[site] = names.split(",")
    try:
        config = router_config(args.run, args.actors, args.certs, sites, args.upstream, args.router_cert)
    except ValueError as err:
        parser.error(str(err))
    print(json.dumps(config, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
