"""The processes of bench/transport.py other than the learner: the synthetic actor (producer),
the actors of the weight broadcast, the router, and the helpers that start and stop them.
Spawned processes import their target from here (the repository root is on their sys.path)."""

from __future__ import annotations

import json
import multiprocessing as mp
import socket
import struct
import time
from dataclasses import replace

import numpy as np

from common import wire
from common.config.transport import TransportConfig
from common.keys import Keys

EPISODE_STEPS = 1200
"""LaneDrive truncates an episode at 1200 steps: the synthetic episode ends there too."""
SEQ_MARK, EPISODE_MARK = 0x5E90_0000_0000_0001, 0x5E90_0000_0000_0002
"""Placeholder seq / episode: msgpack writes ints >= 2**32 as 0xcf + 8 bytes, patched per put."""
ACTOR = "bench-0"


# --- the synthetic actor ---------------------------------------------------------------------


def episode_payloads(
    chunk_len: int, frame_shape: tuple[int, int], seed: int, log_mu: bool = False
) -> list[tuple[bytes, int, int]]:
    """One synthetic episode as encoded chunks, each with the offsets of its seq and episode.

    Frames are consecutive (chunk k+1 starts with the last two frames of chunk k) and random;
    the other fields are random finite floats; only the last chunk ends (truncated). With
    `log_mu` each chunk carries an actor's log mu_hat (`learner.rho_at=actor`).
    """
    rng = np.random.default_rng(seed)
    n_chunks = max(EPISODE_STEPS // chunk_len, 1)
    steps = n_chunks * chunk_len
    frames = rng.integers(0, 256, (steps + 2, *frame_shape), dtype=np.uint8)
    speed = rng.random((steps + 1, 1), dtype=np.float32)
    action = rng.uniform(-1, 1, (steps + 1, 2)).astype(np.float32)
    reward = rng.random(steps, dtype=np.float32)
    alpha, beta = rng.uniform(-1, 1, (2, steps + 1)).astype(np.float32)
    log_mus = rng.uniform(-3, 1, steps).astype(np.float32)
    out = []
    for k in range(n_chunks):
        s, T = k * chunk_len, chunk_len
        truncated = np.zeros(T, bool)
        truncated[-1] = k == n_chunks - 1
        chunk = wire.TransitionChunk(
            actor=ACTOR,
            env=0,
            episode=EPISODE_MARK,
            seq=SEQ_MARK,
            policy_version=0,
            step0=s,
            frames=frames[s : s + T + 2],
            speed=speed[s : s + T + 1],
            last_action=action[s : s + T + 1],
            action=action[s + 1 : s + T + 1],
            reward=reward[s : s + T],
            terminated=np.zeros(T, bool),
            truncated=truncated,
            alpha=alpha[s : s + T + 1],
            beta=beta[s : s + T + 1],
        )
        if log_mu:
            chunk = replace(chunk, log_mu=log_mus[s : s + T], behaviour_version=0)
        payload = wire.encode(chunk)
        offsets = []
        for name, mark in ((b"seq", SEQ_MARK), (b"episode", EPISODE_MARK)):
            needle = bytes([0xA0 | len(name)]) + name + b"\xcf" + struct.pack(">Q", mark)
            if payload.count(needle) != 1:
                raise RuntimeError(f"cannot locate {name!r} in the encoded chunk")
            offsets.append(payload.index(needle) + len(needle) - 8)
        out.append((payload, *offsets))
    return out


def stamp(payload: bytes, seq_at: int, episode_at: int, seq: int, episode: int) -> bytearray:
    """A copy of `payload` carrying `seq` and `episode` (still valid msgpack: uint64 fields)."""
    buf = bytearray(payload)
    struct.pack_into(">Q", buf, seq_at, seq)
    struct.pack_into(">Q", buf, episode_at, episode)
    return buf


def credit_key(run: str) -> str:
    """Where the paced learner says how far it got: the next seq it expects from the producer."""
    return f"{Keys(run).root}/bench/credit"


def producer_main(
    tcfg: TransportConfig, runs: list[str], chunk_len: int, frame_shape: tuple[int, int], commands, results, halt, ready
) -> None:
    """On ("send", run, window, log_mu): publish the synthetic episode on `run` until `halt`.

    window 0: flat out (as fast as BLOCK puts go); window W: at most W chunks ahead of the
    learner's last credit, so that the learner's inbox never overflows. log_mu: the chunks
    carry an actor's log mu_hat.
    """
    from common.transport.zenoh_backend import ZenohTransport

    pools = {flag: episode_payloads(chunk_len, frame_shape, seed=1, log_mu=flag) for flag in (False, True)}
    pool = pools[False]
    with ZenohTransport(tcfg) as t:
        pubs = {run: t.publisher(Keys(run).transitions(ACTOR)) for run in runs}
        # a bare zenoh publisher on the same key only to ask whether anyone subscribes yet
        probes = {run: t.session.declare_publisher(Keys(run).transitions(ACTOR)) for run in runs}
        credits = {run: t.subscribe(credit_key(run), capacity=1, overflow="drop_old") for run in runs}
        seqs = dict.fromkeys(runs, 0)  # one stream per key: the learner counts gaps per actor
        results.put(len(pool[0][0]))
        ready.set()
        while (cmd := commands.get())[0] == "send":
            _, run, window, log_mu = cmd
            pool = pools[log_mu]
            pub, deadline = pubs[run], time.monotonic() + 10.0
            while not probes[run].matching_status.matching and time.monotonic() < deadline:
                time.sleep(0.002)  # puts before the router knows the subscriber would vanish
            start, acked = seqs[run], seqs[run]  # the learner drained the previous phase
            while not halt.is_set():
                seq = seqs[run]
                while window and seq - acked >= window and not halt.is_set():
                    if (r := credits[run].get(timeout=0.05)) is not None:
                        acked = max(acked, int(r.payload))
                if halt.is_set():
                    break
                payload, seq_at, episode_at = pool[seq % len(pool)]
                pub.put(stamp(payload, seq_at, episode_at, seq, seq // len(pool)))
                seqs[run] = seq + 1
            results.put(seqs[run] - start)


class Producer:
    """The producer process and its command channel."""

    def __init__(
        self, ctx, tcfg: TransportConfig, runs: list[str], chunk_len: int, frame_shape: tuple[int, int]
    ) -> None:
        self.commands, self.results = ctx.Queue(), ctx.Queue()
        self.halt, self.ready = ctx.Event(), ctx.Event()
        self.process = ctx.Process(
            target=producer_main,
            name="producer",
            daemon=True,
            args=(tcfg, runs, chunk_len, frame_shape, self.commands, self.results, self.halt, self.ready),
        )
        self.process.start()

    def start(self, run: str, window: int = 0, log_mu: bool = False) -> None:
        self.halt.clear()
        self.commands.put(("send", run, window, log_mu))

    def stop(self, timeout: float = 30.0) -> int:
        """Halt and return how many chunks were put in this phase."""
        self.halt.set()
        return self.results.get(timeout=timeout)

    def close(self) -> None:
        self.halt.set()
        self.commands.put(("quit",))


# --- the actors of the weight broadcast -----------------------------------------------------


def ack_key(run: str, actor: str = "*") -> str:
    return f"{Keys(run).root}/bench/ack/{actor}"


def weights_actor_main(tcfg: TransportConfig, run: str, name: str, agent, scale, actor_cfg, join, ready, stop) -> None:
    """Build the acting policy, subscribe to the weights once `join` is set, ack each load."""
    import torch

    from actors.acting import Acting
    from actors.weights_client import WeightsClient
    from common.transport.zenoh_backend import ZenohTransport

    torch.set_num_threads(1)
    acting = Acting(agent, scale, actor_cfg, n_envs=1, seed=0)
    rejects = wire.RejectCounter()
    with ZenohTransport(tcfg) as t:
        acks = t.publisher(ack_key(run, name))
        ready.set()
        while not join.wait(0.2):
            if stop.is_set():
                return
        # as the real actor (actors.weights_client): capacity 1, a newer broadcast replaces an unread one
        weights = WeightsClient(t, Keys(run), "actor", acting, rejects, fetch=False)
        while not stop.is_set():
            if (msg := weights.poll(timeout=0.2)) is None:
                continue
            received, loaded = weights.received_at, time.time()
            acks.put(
                json.dumps(
                    {
                        "actor": name,
                        "version": msg.version,
                        "received": received,
                        "loaded": loaded,
                        "policy_version": acting.version,
                    }
                ).encode()
            )


def broadcast_latency(pub, acks, payload_of, actors: list[str], broadcasts: int, first_version: int) -> dict:
    """Publish `broadcasts` Weights versions on `pub` and time each until every actor acked it on `acks`."""
    version = first_version

    def one(timeout: float) -> dict | None:
        nonlocal version
        version += 1
        payload = payload_of(version)
        got: dict[str, dict] = {}
        start, t0 = time.time(), time.perf_counter()
        pub.put(payload)
        while len(got) < len(actors) and time.perf_counter() - t0 < timeout:
            if (r := acks.get(timeout=0.05)) is not None:
                ack = json.loads(r.payload)
                if ack["version"] == version:
                    got[ack["actor"]] = ack
        rtt = time.perf_counter() - t0
        if len(got) < len(actors):
            return None
        return {
            "loaded_ms": (max(a["loaded"] for a in got.values()) - start) * 1e3,
            "received_ms": (max(a["received"] for a in got.values()) - start) * 1e3,
            "rtt_ms": rtt * 1e3,
        }

    # the first broadcasts wait for new subscriptions to reach the router: not timed
    deadline = time.monotonic() + 30.0
    while one(timeout=0.5) is None:
        if time.monotonic() > deadline:
            raise RuntimeError(f"actors {actors} never acked a broadcast")
    samples, missed = [], 0
    for _ in range(broadcasts):
        s = one(timeout=5.0)
        if s is None:
            missed += 1
        else:
            samples.append(s)
        time.sleep(0.02)

    def q(key: str, p: float) -> float:
        return float(np.percentile([s[key] for s in samples], p)) if samples else float("nan")

    return {
        "median_ms": q("loaded_ms", 50),
        "p90_ms": q("loaded_ms", 90),
        "received_median_ms": q("received_ms", 50),
        "rtt_median_ms": q("rtt_ms", 50),
        "rtt_p90_ms": q("rtt_ms", 90),
        "broadcasts": len(samples),
        "missed": missed,
        "last_version": version,
    }


# --- processes ------------------------------------------------------------------------------


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def router_main(tcfg: TransportConfig, stop, ready) -> None:
    from common.transport.zenoh_backend import run_router

    run_router(tcfg, stop=stop, ready=ready)


def start_router(ctx, tcfg: TransportConfig, stop) -> tuple[TransportConfig, mp.Process]:
    """A router on a free port in its own process; returns the clients' config and the process."""
    for _ in range(3):  # the free port can be taken between probe and bind
        endpoint = f"tcp/127.0.0.1:{free_port()}"
        router_cfg = replace(tcfg, router_listen=[endpoint], router_connect=[])
        ready = ctx.Event()
        proc = ctx.Process(target=router_main, args=(router_cfg, stop, ready), name="router", daemon=True)
        proc.start()
        if ready.wait(30):
            return replace(tcfg, mode="client", connect=[endpoint], listen=[]), proc
        proc.kill()
        proc.join()
    raise RuntimeError("the zenoh router did not start")


def wait_all(events, what: str, timeout: float = 120.0) -> None:
    deadline = time.monotonic() + timeout
    for e in events:
        if not e.wait(max(deadline - time.monotonic(), 0.0)):
            raise RuntimeError(f"{what} did not start within {timeout:.0f} s")


def stop_process(proc: mp.Process, timeout: float = 10.0) -> None:
    proc.join(timeout)
    if proc.is_alive():
        proc.terminate()
        proc.join(5)
    if proc.is_alive():
        proc.kill()
        proc.join()
