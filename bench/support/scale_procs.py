"""The processes of bench/scale.py other than the learner: emulated actors packed many to a
process, the routers of each topology, and the CPU / memory readings of a process.

An emulated actor is one Zenoh client session (its own link to the router) with one publisher
on gvf/<run>/transitions/<name> (congestion control BLOCK) and one subscriber on the weights
key. It replays a pre-encoded synthetic episode (`bench.support.transport_procs.episode_payloads`, the
actor's name, seq and episode written into each put) at a fixed rate, and acks every weights
version it decodes with the time.time() at which the sample arrived. It has no simulator and no
policy, and it is not an OS process of its own: up to --per-process of them share one spawned
process (one thread sends for all, on a schedule staggered across the whole fleet), so that
256 of them fit on a small machine. Spawned processes import their target from here.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import queue
import time
from dataclasses import replace
from pathlib import Path

from bench.support.transport_procs import ACTOR, episode_payloads, free_port, router_main, stamp
from common import wire
from common.config.transport import TransportConfig
from common.keys import Keys
from common.transport.inbox import BoundedInbox

MESH_CONFIGS = Path(__file__).resolve().parents[2] / "deploy" / "zenoh"
"""router-mesh-a.json5 / router-mesh-b.json5 there, when present, configure the mesh's routers."""
TOPOLOGIES = ("router", "mesh")


# --- what an emulated actor sends -------------------------------------------------------------


def actor_name(n_actors: int, i: int) -> str:
    """Names of one fleet have one width (the pool's name slot is fixed): e16-03, e256-007."""
    return f"e{n_actors}-{i:0{len(str(n_actors - 1))}d}"


def named_pool(
    chunk_len: int, frame_shape: tuple[int, int], width: int, log_mu: bool, seed: int = 1
) -> list[tuple[bytes, int, int, int]]:
    """The synthetic episode with a `width`-character actor name slot: (payload, seq_at, episode_at, name_at)."""
    old = b"\xa5actor" + bytes([0xA0 | len(ACTOR)]) + ACTOR.encode()
    new = b"\xa5actor" + bytes([0xA0 | width]) + b"x" * width
    if width > 31:
        raise ValueError(f"actor names of {width} characters do not fit a msgpack fixstr")
    out = []
    for payload, seq_at, episode_at in episode_payloads(chunk_len, frame_shape, seed, log_mu):
        if payload.count(old) != 1:
            raise RuntimeError("cannot locate the actor name in the encoded chunk")
        at = payload.index(old)
        shift = len(new) - len(old)
        out.append(
            (
                payload[:at] + new + payload[at + len(old) :],
                seq_at + shift * (seq_at > at),
                episode_at + shift * (episode_at > at),
                at + len(new) - width,
            )
        )
    return out


# --- a process of emulated actors ---------------------------------------------------------------


def actors_main(
    tcfg: TransportConfig,
    run: str,
    names: list[str],
    first: int,
    n_fleet: int,
    chunk_len: int,
    frame_shape: tuple[int, int],
    rate: float,
    commands,
    replies,
    acks,
    ready,
) -> None:
    """Open one session per name, then serve commands until ("quit",).

    ("send", log_mu, start): from time.time() `start`, every actor puts one chunk each 1/rate s,
    actor `first + i` of the `n_fleet` offset by (first + i) / (n_fleet * rate) s; ("stop",):
    stop sending and reply ("sent", chunks per actor, the most a put was behind schedule in s).
    Weights acks go to `acks` as lists of (name, version, arrival time.time()) all along.
    """
    import zenoh

    from common.transport.zenoh_backend import ZenohTransport

    keys, width = Keys(run), len(names[0])
    if any(len(n) != width for n in names):
        raise ValueError(f"names of one process must have one width: {names}")
    pools = {flag: named_pool(chunk_len, frame_shape, width, flag) for flag in (False, True)}
    # drop_old: a backlog of weights is worth its newest; the ones dropped show up as missed acks
    weights_in: BoundedInbox = BoundedInbox(8 * len(names), overflow="drop_old")
    rejects = wire.RejectCounter()
    sessions, subscribers = [], []  # kept referenced: a dropped subscriber may be undeclared
    try:
        for name in names:
            t = ZenohTransport(tcfg)
            sessions.append(t)

            def on_weights(sample, name=name) -> None:
                # stamp and copy only: a callback that lingers stalls the router's BLOCK puts
                weights_in.offer((name, time.time(), sample.payload.to_bytes()))

            callback = zenoh.handlers.Callback(on_weights, indirect=False)
            subscribers.append(t.session.declare_subscriber(keys.weights, callback))
        pubs = [t.publisher(keys.transitions(name)) for t, name in zip(sessions, names)]
        # puts made before the learner's subscription reaches this router would vanish
        probes = [t.session.declare_publisher(keys.transitions(name)) for t, name in zip(sessions, names)]
        deadline = time.monotonic() + 60.0
        while not all(p.matching_status.matching for p in probes):
            if time.monotonic() > deadline:
                raise RuntimeError(f"the learner's subscription never reached actors {names[0]}..{names[-1]}")
            time.sleep(0.01)
        for p in probes:
            p.undeclare()
        name_bytes = [n.encode() for n in names]
        seqs = [0] * len(names)
        sent = [0] * len(names)
        due: list[float] | None = None
        pool: list = []
        lag = 0.0
        ready.set()
        while True:
            try:
                cmd = commands.get_nowait()
            except queue.Empty:
                cmd = None
            if cmd is not None:
                if cmd[0] == "quit":
                    break
                if cmd[0] == "send":
                    _, log_mu, start = cmd
                    pool, sent, lag = pools[log_mu], [0] * len(names), 0.0
                    due = [start + (first + i) / (n_fleet * rate) for i in range(len(names))]
                elif cmd[0] == "stop":
                    due = None
                    replies.put(("sent", sent, lag))
            if got := weights_in.drain():
                acked = []
                for name, arrived, payload in got:
                    if (msg := rejects.decode(payload, expect=wire.Weights)) is not None:
                        acked.append((name, msg.version, arrived))
                acks.put(acked)
            if due is None:
                time.sleep(0.005)
                continue
            now = time.time()
            for i, when in enumerate(due):
                if when > now:
                    continue
                # behind schedule (a BLOCK put waited): send at once, the count stays the rate's
                lag = max(lag, now - when)
                payload, seq_at, episode_at, name_at = pool[seqs[i] % len(pool)]
                buf = stamp(payload, seq_at, episode_at, seqs[i], seqs[i] // len(pool))
                buf[name_at : name_at + width] = name_bytes[i]
                pubs[i].put(buf)
                seqs[i] += 1
                sent[i] += 1
                due[i] = when + 1.0 / rate
                now = time.time()
            time.sleep(min(0.005, max(0.0, min(due) - time.time())))
    finally:
        for t in sessions:
            t.close()


class ActorGroup:
    """One process of emulated actors and its command channel."""

    def __init__(self, ctx, tcfg, run, names, first, n_fleet, chunk_len, frame_shape, rate, acks) -> None:
        self.names = names
        self.commands, self.replies, self.ready = ctx.Queue(), ctx.Queue(), ctx.Event()
        self.process = ctx.Process(
            target=actors_main,
            name=f"actors-{names[0]}",
            daemon=True,
            args=(tcfg, run, names, first, n_fleet, chunk_len, frame_shape, rate)
            + (self.commands, self.replies, acks, self.ready),
        )
        self.process.start()

    def send(self, log_mu: bool, start: float) -> None:
        self.commands.put(("send", log_mu, start))

    def stop(self, timeout: float = 60.0) -> tuple[int, float]:
        """Stop sending; chunks put in the phase and the most a put was behind schedule (s)."""
        self.commands.put(("stop",))
        _, sent, lag = self.replies.get(timeout=timeout)
        return sum(sent), lag

    def quit(self) -> None:
        self.commands.put(("quit",))


def start_fleet(ctx, tcfg, run, n, per_process, chunk_len, frame_shape, rate, acks) -> list[ActorGroup]:
    names = [actor_name(n, i) for i in range(n)]
    return [
        ActorGroup(ctx, tcfg, run, names[i : i + per_process], i, n, chunk_len, frame_shape, rate, acks)
        for i in range(0, n, per_process)
    ]


# --- routers ---------------------------------------------------------------------------------


def start_router_at(ctx, tcfg: TransportConfig, stop, connect: list[str], config_file: str | None, name: str):
    """A router on a free 127.0.0.1 port joined to `connect`; returns its endpoint and process."""
    for _ in range(3):  # the free port can be taken between probe and bind
        endpoint = f"tcp/127.0.0.1:{free_port()}"
        router_cfg = replace(tcfg, router_listen=[endpoint], router_connect=connect, zenoh_config_file=config_file)
        ready = ctx.Event()
        proc = ctx.Process(target=router_main, args=(router_cfg, stop, ready), name=name, daemon=True)
        proc.start()
        if ready.wait(60):
            return endpoint, proc
        proc.kill()
        proc.join()
    raise RuntimeError(f"the zenoh router {name} did not start")


def start_topology(ctx, tcfg: TransportConfig, topology: str, stop):
    """Routers of `topology`: the learner's and the actors' client configs, and {name: process}.

    'router': one router for all. 'mesh': router A (the learner's) and router B (the actors'),
    B connected to A, with deploy/zenoh/router-mesh-{a,b}.json5 where present.
    """
    if topology not in TOPOLOGIES:
        raise ValueError(f"topology must be one of {TOPOLOGIES}, got {topology!r}")

    def config(site: str) -> str | None:
        path = MESH_CONFIGS / f"router-mesh-{site}.json5"
        return str(path) if topology == "mesh" and path.exists() else None

    def client(endpoint: str) -> TransportConfig:
        return replace(tcfg, mode="client", connect=[endpoint], listen=[])

    a, router_a = start_router_at(ctx, tcfg, stop, [], config("a"), "router-a")
    if topology == "router":
        return client(a), client(a), {"router": router_a}
    b, router_b = start_router_at(ctx, tcfg, stop, [a], config("b"), "router-b")
    return client(a), client(b), {"router_a": router_a, "router_b": router_b}


# --- readings of a process -------------------------------------------------------------------


def usage(pid: int) -> tuple[float, float]:
    """(CPU seconds, user + system, and resident MB) of process `pid` (psutil, else /proc)."""
    try:
        import psutil
    except ImportError:
        psutil = None
    if psutil is not None:
        p = psutil.Process(pid)
        times = p.cpu_times()
        return times.user + times.system, p.memory_info().rss / 2**20
    # /proc/<pid>/stat: fields 14 and 15 (utime, stime) in clock ticks, after the ")" of the name
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    cpu = (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    rss_kb = next(int(line.split()[1]) for line in Path(f"/proc/{pid}/status").open() if line.startswith("VmRSS:"))
    return cpu, rss_kb / 1024


def stop_all(procs: list[mp.Process], timeout: float = 10.0) -> None:
    """Join every process within `timeout` in all, then terminate (then kill) the ones left."""
    deadline = time.monotonic() + timeout
    for p in procs:
        p.join(max(0.0, deadline - time.monotonic()))
    for p in procs:
        if p.is_alive():
            p.terminate()
            p.join(5)
        if p.is_alive():
            p.kill()
            p.join()
