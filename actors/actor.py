"""The actor loop: several simulators, batched acting with OU noise, priority track sampling,
transition chunks and episode summaries out, weights and the global track table in.

    weights <- fetch (query) until the learner answers
    loop: act on all envs, step them together, add each step to its env's chunk,
          send full/ended chunks and episode summaries, adopt newer weights and track tables;
          wait while the launcher (control) or the learner's rate limit (flow) says pause.

The simulator never waits on the network longer than `actor.send_timeout_s` (see `Sender`);
when the learner is gone the actor keeps its last weights, keeps sending (puts go nowhere)
and adopts new weights as soon as a learner publishes again.

The simulators are LaneDrive's, or TORCS's with env.id=TorcsDrive-v0 (`actors.envs.simulators`); on TORCS
the sampled roads are roads.json's train roads less its validation roads.
"""

from __future__ import annotations

import logging
import threading
import time
import zlib

import numpy as np
import torch

from actors.acting import Acting
from actors.chunker import ChunkBuilder
from actors.envs.simulators import known_roads, road_names, vector_env
from actors.sender import Sender
from actors.track_sampling import PriorityTrackSampler
from actors.weights_client import WeightsClient
from common import wire
from common.config.run import RunConfig
from common.keys import Keys
from common.wire_rules import check_tracks

log = logging.getLogger(__name__)
ROLE = "actor"
SAMPLED = ("train", "test", "all")


def actor_seed(seed: int, name: str) -> int:
    """Actors started with the same seed but different names must not drive the same roads and noise."""
    return (seed * 1_000_003 + zlib.crc32(name.encode())) % 2**31


def make_env(cfg: RunConfig, sampler: PriorityTrackSampler):
    """The actor's simulators (LaneDrive, or TORCS with env.id=TorcsDrive-v0). At each reset the sampler
    draws the car's next road, having first recorded the steps of the episode that just ended (a named or
    procedural road bypasses it)."""
    sampled = cfg.env.track in SAMPLED
    return vector_env(
        cfg.env,
        cfg.actor.num_envs,
        track_chooser=(lambda i: sampler.sample()) if sampled else None,
        on_episode_end=lambda i, info: sampler.record(str(info["track"]), int(info["steps"])),
    )


def _one(obs: dict, i: int) -> dict:
    return {k: v[i] for k, v in obs.items()}


def run_actor(cfg: RunConfig, t, stop: threading.Event, env_factory=make_env) -> dict:
    """Run over transport `t` until `stop`, a 'stop' control message, or `actor.max_env_steps`;
    returns counters. `env_factory(cfg, sampler)` builds the simulators (tests pass a fake)."""
    a, keys = cfg.actor, Keys(cfg.run)
    torch.set_num_threads(a.torch_threads)
    seed = actor_seed(a.seed, a.name)
    rng = np.random.default_rng(seed)
    sampler = PriorityTrackSampler(road_names(cfg.env, a.track_split), rng)
    env = env_factory(cfg, sampler)
    sampled = cfg.env.track in SAMPLED  # named and procedural roads bypass priority track sampling
    roads = known_roads(cfg.env)
    acting = Acting(cfg.agent, cfg.scale, a, a.num_envs, seed=seed)
    sender = Sender(a.send_queue, a.send_timeout_s)
    rejects = wire.RejectCounter()

    stats = {"env_steps": 0, "episodes": 0, "chunks": 0, "weights_loaded": 0, "paused_s": 0.0}
    try:
        t.declare_alive(keys.publish("alive", ROLE, role=ROLE, name=a.name))
        weights = WeightsClient(t, keys, ROLE, acting, rejects, fetch_timeout_s=a.weights_poll_s)
        tracks_in = t.subscribe(keys.subscribe("tracks", ROLE), capacity=1, overflow="drop_old")
        control_in = t.subscribe(keys.subscribe("control", ROLE), capacity=16)
        flow_in = t.subscribe(keys.subscribe("flow", ROLE), capacity=1, overflow="drop_old")
        chunks_out = t.publisher(keys.publish("transitions", ROLE, actor=a.name))
        episodes_out = t.publisher(keys.publish("episodes", ROLE, actor=a.name))

        def poll_weights(block_s: float = 0.0) -> None:
            if weights.poll(timeout=block_s) is not None:
                stats["weights_loaded"] += 1

        paused = False
        flow_until = 0.0  # the learner's pause holds until then; it expires if the learner falls silent

        def poll_control() -> None:
            nonlocal paused, flow_until
            for r in control_in.drain(16):
                msg = rejects.decode(r.payload, expect=wire.Control, key=r.key)
                if msg is not None:
                    paused = msg.command == "pause" or (paused and msg.command != "resume")
                    if msg.command == "stop":
                        stop.set()
            if (r := flow_in.get(timeout=0)) is not None and (
                msg := rejects.decode(r.payload, expect=wire.Control, key=r.key)
            ):
                # the pause expires as the learner said (a pause without expiry holds until resume)
                flow_until = (time.monotonic() + (msg.expires_s or float("inf"))) if msg.command == "pause" else 0.0

        while not acting.ready and not stop.is_set():
            poll_weights(block_s=a.weights_poll_s)
            poll_control()
        log.info("actor %s: policy v%d, %d envs", a.name, acting.version, a.num_envs)

        obs, info = env.reset(seed=seed)
        chunks = ChunkBuilder(a.name, a.num_envs, a.chunk_len)
        for i in range(a.num_envs):
            chunks.start(i, _one(obs, i), float(info["alpha"][i]), float(info["beta"][i]), acting.version)
        returns = np.zeros(a.num_envs)
        while not stop.is_set():
            poll_control()
            if paused or time.monotonic() < flow_until:
                waited = time.monotonic()
                time.sleep(0.02)
                stats["paused_s"] += time.monotonic() - waited
                continue
            poll_weights()
            r = tracks_in.get(timeout=0)
            table = rejects.decode(r.payload, expect=wire.TrackTable, key=r.key) if r is not None and sampled else None
            if table is not None and rejects.obeys(lambda: check_tracks(table, roads), r.key):
                sampler.update(table.steps)
            actions = acting.act(obs, info)
            next_obs, reward, term, trunc, info = env.step(actions)
            returns += reward
            done = term | trunc
            for i in range(a.num_envs):
                src, inf = (info["final_obs"][i], info["final_info"]) if done[i] else (_one(next_obs, i), info)
                chunk = chunks.add(
                    i,
                    actions[i],
                    float(reward[i]),
                    bool(term[i]),
                    bool(trunc[i]),
                    float(inf["alpha"][i]),
                    float(inf["beta"][i]),
                    src,
                    acting.version,
                )
                if chunk is not None:
                    sender.send(chunks_out, wire.encode(acting.with_log_mu(chunk)))
                    stats["chunks"] += 1
                if done[i]:
                    name, steps = str(info["final_info"]["track"][i]), int(info["final_info"]["steps"][i])
                    summary = wire.EpisodeSummary(
                        a.name, i, int(chunks.episodes[i]) - 1, name, steps, float(returns[i]), acting.version
                    )
                    sender.send(episodes_out, wire.encode(summary))  # the env told the sampler before its draw
                    returns[i] = 0.0
                    stats["episodes"] += 1
                    chunks.start(i, _one(next_obs, i), float(info["alpha"][i]), float(info["beta"][i]), acting.version)
            acting.episode_ended(done)
            obs = next_obs
            stats["env_steps"] += a.num_envs
            if a.max_env_steps and stats["env_steps"] >= a.max_env_steps:
                break
    finally:
        sender.close()
        env.close()
    stats.update(
        dropped=sender.dropped, send_errors=sender.errors, rejected=rejects.total, policy_version=acting.version
    )
    log.info("actor %s stopped: %s", a.name, stats)
    return stats


def actor_role(ctx) -> dict:
    """The actor role (`common.roles`)."""
    return run_actor(ctx.cfg, ctx.transport, ctx.stop)


def main() -> None:
    from common.cli import role_main

    role_main("actor", print_result=True)  # last line: the actor's counters, for scripts and tests
