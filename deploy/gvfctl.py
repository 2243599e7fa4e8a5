#!/usr/bin/env python3
"""Operator's tool for a run spread over machines: check the network, see who is alive, stop a run.

    python deploy/gvfctl.py ping  --connect tcp/ROUTER:7447            # router reachable, routing works
    python deploy/gvfctl.py alive --connect tcp/ROUTER:7447 --run exp1 [--watch]
    python deploy/gvfctl.py stop  --connect tcp/ROUTER:7447 --run exp1 # Control 'stop' to every process
    python deploy/gvfctl.py router --listen tcp/0.0.0.0:7447           # a bare router, for network checks

Run it with the project's Python (`.venv/bin/python`): it builds its Zenoh session exactly as
gvf-learner and gvf-actor do (`common.transport.zenoh_backend.zenoh_config`: the `--config` JSON5 file
first, e.g. deploy/zenoh/client-tls.json5 with `--connect tls/ROUTER:7447`, then the endpoints).

- `ping` opens two client sessions and sends a few messages from one to the other; they can
  only meet through the router, so an answer proves reachability, TLS and routing.
- `alive` lists the liveliness tokens under gvf/<run>/alive/** (every learner, actor, launcher).
- `stop`, `pause`, `resume` publish a wire `Control` message on gvf/<run>/control.
- `router` runs a Zenoh router with the same code as gvf-router, without the Hydra config:
  handy to test a firewall or certificates before deploying. Stop it with Ctrl-C.

Exit status 0 on success, 1 when the check fails (nobody answers, nobody listens), 2 on usage errors.
"""

from __future__ import annotations

import argparse
import queue
import signal
import sys
import threading
import time
import uuid

import zenoh

from common.config.transport import TransportConfig
from common.keys import Keys
from common.transport.zenoh_backend import run_router, zenoh_config, zenoh_priority
from common.wire import Control, encode

PING_PREFIX = "gvf-ping"
"""Ping keys live outside gvf/<run>/ so that no run's subscriber ever sees them."""


def transport_config(args: argparse.Namespace) -> TransportConfig:
    """The TransportConfig a client of `args.connect` would use (as learner and actors do)."""
    return TransportConfig(
        mode="client", connect=list(args.connect), zenoh_config_file=args.config, connect_timeout_s=args.timeout
    )


def open_session(args: argparse.Namespace) -> zenoh.Session:
    try:
        return zenoh.open(zenoh_config(transport_config(args)))
    except zenoh.ZError as exc:
        raise SystemExit(f"cannot reach the router at {args.connect}: {exc}") from None


def cmd_ping(args: argparse.Namespace) -> int:
    key = f"{PING_PREFIX}/{uuid.uuid4().hex}"
    received: queue.Queue[bytes] = queue.Queue()
    with open_session(args) as sender, open_session(args) as receiver:
        receiver.declare_subscriber(key, lambda sample: received.put(sample.payload.to_bytes()))
        pub = sender.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK)
        deadline = time.monotonic() + args.timeout
        # the router tells the sender about the subscriber asynchronously: wait for it
        while not pub.matching_status.matching:
            if time.monotonic() > deadline:
                print(f"FAIL: connected to {args.connect}, but messages are not routed back", file=sys.stderr)
                return 1
            time.sleep(0.01)
        rtts = []
        for i in range(args.count):
            t0 = time.perf_counter()
            pub.put(str(i).encode())
            try:
                if received.get(timeout=args.timeout) != str(i).encode():
                    print("FAIL: wrong payload came back", file=sys.stderr)
                    return 1
            except queue.Empty:
                print(f"FAIL: message {i} did not come back within {args.timeout} s", file=sys.stderr)
                return 1
            rtts.append((time.perf_counter() - t0) * 1e3)
        pub.undeclare()
    print(
        f"ok: {args.connect} routes messages; round trip "
        f"min {min(rtts):.2f} ms, max {max(rtts):.2f} ms over {len(rtts)}"
    )
    return 0


def cmd_alive(args: argparse.Namespace) -> int:
    keys = Keys(args.run)
    with open_session(args) as session:
        if not args.watch:
            replies = session.liveliness().get(keys.all_alive(), timeout=args.timeout)
            alive = sorted(str(r.ok.key_expr) for r in replies if r.ok is not None)
            for key in alive:
                print(key)
            print(f"{len(alive)} alive in run {args.run!r}", file=sys.stderr)
            return 0 if alive else 1
        # history=True: first the tokens alive now, then every change
        sub = session.liveliness().declare_subscriber(keys.all_alive(), history=True)
        stop = threading.Event()
        for sig in (signal.SIGINT, signal.SIGTERM):  # also when started with SIGINT ignored (`&`)
            signal.signal(sig, lambda *_: stop.set())
        try:
            while not stop.is_set():
                sample = sub.try_recv()
                if sample is None:
                    stop.wait(0.1)  # poll, so that a signal is seen promptly
                    continue
                sign = "+" if sample.kind == zenoh.SampleKind.PUT else "-"
                print(f"{time.strftime('%H:%M:%S')} {sign} {sample.key_expr}", flush=True)
        finally:
            sub.undeclare()
        return 0


def cmd_control(args: argparse.Namespace) -> int:
    keys = Keys(args.run)
    payload = encode(Control(args.command, reason=args.reason))
    with open_session(args) as session:
        pub = session.declare_publisher(
            keys.control, congestion_control=zenoh.CongestionControl.BLOCK, priority=zenoh_priority(keys.control)
        )
        deadline = time.monotonic() + args.timeout
        while not pub.matching_status.matching and time.monotonic() < deadline:
            time.sleep(0.01)
        listening = pub.matching_status.matching
        pub.put(payload)
        pub.undeclare()
    if not listening:
        print(
            f"sent {args.command!r} on {keys.control}, but nothing subscribes to it (wrong --run, or nothing running?)",
            file=sys.stderr,
        )
        return 1
    print(f"sent {args.command!r} on {keys.control}")
    return 0


def cmd_router(args: argparse.Namespace) -> int:
    cfg = TransportConfig(router_listen=list(args.listen), zenoh_config_file=args.config)
    print(f"router listening on {args.listen} (Ctrl-C stops it)", file=sys.stderr, flush=True)
    run_router(cfg)
    return 0


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="gvfctl.py", description=__doc__.split("\n")[0])
    sub = p.add_subparsers(dest="cmd", required=True)

    def client(name: str, help: str) -> argparse.ArgumentParser:
        c = sub.add_parser(name, help=help)
        c.add_argument(
            "--connect",
            action="append",
            metavar="ENDPOINT",
            help="router endpoint, e.g. tcp/ROUTER:7447 or tls/ROUTER:7447 (repeatable; default tcp/127.0.0.1:7447)",
        )
        c.add_argument("--config", metavar="JSON5", help="Zenoh config file read first, e.g. client-tls.json5")
        c.add_argument("--timeout", type=float, default=5.0, help="seconds to wait for router and answers")
        c.add_argument("--run", default="default", help="run name (key prefix gvf/<run>/)")
        return c

    ping = client("ping", "round trip through the router")
    ping.add_argument("--count", type=int, default=3, help="messages to send")
    ping.set_defaults(fn=cmd_ping)
    alive = client("alive", "list the processes alive in a run")
    alive.add_argument("--watch", action="store_true", help="keep printing arrivals (+) and departures (-)")
    alive.set_defaults(fn=cmd_alive)
    for command in ("stop", "pause", "resume"):
        c = client(command, f"send Control {command!r} to every process of a run")
        c.add_argument("--reason", default="gvfctl", help="free text carried by the message")
        c.set_defaults(fn=cmd_control, command=command)
    router = sub.add_parser("router", help="a bare Zenoh router for network and certificate checks")
    router.add_argument(
        "--listen",
        action="append",
        metavar="ENDPOINT",
        help="endpoint to listen on (repeatable; default tcp/0.0.0.0:7447)",
    )
    router.add_argument("--config", metavar="JSON5", help="Zenoh config file read first, e.g. router-tls.json5")
    router.set_defaults(fn=cmd_router)
    return p


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    if getattr(args, "connect", "unset") is None:
        args.connect = ["tcp/127.0.0.1:7447"]
    if getattr(args, "listen", "unset") is None:
        args.listen = ["tcp/0.0.0.0:7447"]
    return args.fn(args)


if __name__ == "__main__":
    sys.exit(main())
