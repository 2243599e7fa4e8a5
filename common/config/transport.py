"""Schema of the `transport` config group: how a process joins the run's Zenoh network.

One dataclass, registered in Hydra's ConfigStore by whoever composes the configs; every
field has a one-line docstring. The Zenoh session is built from it by
`common.transport.zenoh_backend.zenoh_config`; `backend: inproc` swaps Zenoh for the in-process
transport (`gvf-train transport=inproc`: every role a thread of one process; fast tests).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Dict, List, Optional

MiB = 1024 * 1024
ZENOH_WAIT_BEFORE_CLOSE_S = 5.0
"""zenoh's default `transport/link/tx/queue/congestion_control/block/wait_before_close`: a link blocked
this long under BLOCK is closed, so a receiver's callback must never wait as long."""


@dataclass
class TransportConfig:
    """How to reach the other processes of a run (Zenoh) and the limits on what crosses it."""

    backend: str = "zenoh"
    """'zenoh' (real network) or 'inproc' (every role a thread of one gvf-train process, and tests)."""

    mode: str = "client"
    """Zenoh mode of learner and actors: 'client' (talk through a router), 'peer' or 'router'."""

    listen: List[str] = field(default_factory=list)
    """Endpoints this session listens on, e.g. ['tcp/127.0.0.1:0']; peers need one, clients none."""

    connect: List[str] = field(default_factory=lambda: ["tcp/127.0.0.1:7447"])
    """Endpoints to connect to, e.g. ['tcp/ROUTER_HOST:7447'] or ['tls/ROUTER_HOST:7447']."""

    router_listen: List[str] = field(default_factory=lambda: ["tcp/127.0.0.1:7447"])
    """Endpoints the run's router listens on (gvf-router, gvf-train); use tcp/0.0.0.0:7447 for other hosts."""

    router_connect: List[str] = field(default_factory=list)
    """Other routers the run's router connects to (a mesh of routers across sites); usually empty."""

    connect_timeout_s: float = 10.0
    """How long opening a session waits for a `connect` endpoint (the router) to answer; -1 waits for ever."""

    multicast_scouting: bool = False
    """Discover peers by UDP multicast; off because endpoints are explicit and multicast leaks across runs."""

    max_message_size: int = 64 * MiB
    """Largest payload in bytes; Zenoh drops bigger ones silently, so publishers refuse them loudly."""

    shared_memory: bool = False
    """Zenoh's implicit shared memory between processes on one host (a 16 MiB /dev/shm pool per session)."""

    inbox_capacity: int = 4096
    """Default length of a subscriber's bounded queue; a sample arriving when full is counted and dropped."""

    query_timeout_s: float = 2.0
    """How long a `fetch` (e.g. of the latest weights) waits for an answer."""

    priorities: bool = True
    """Publish each route at its wiring-table priority (`common.keys`: control and flow, then weights
    and tracks, ahead of transitions); false: everything at Zenoh's default priority (data)."""

    zenoh_config_file: Optional[str] = None
    """Zenoh JSON5 config file read first (TLS certificates, auth, access control); fields above override it."""

    zenoh_overrides: Dict[str, str] = field(default_factory=dict)
    """Zenoh settings applied last: config path -> JSON5 value, e.g. {'transport/link/tx/lease': '3000'}."""
