"""The real actor loop (actors.actor.run_actor) on a fake env (tests.fakes.CountingVectorEnv)
over the in-process transport, with a fake learner on the same bus."""

import threading

from actors.actor import run_actor
from common import wire
from common.config.transport import TransportConfig
from common.keys import Keys
from common.networks import make_policy
from common.transport.inproc import InprocTransport
from tests.fakes import CountingVectorEnv

ENDS = [1000, 13]  # car 0 never ends in these tests, car 1 every 13 steps


class FakeLearner:
    """The learner's side of the wire: serves weights, collects what the actor sends."""

    def __init__(self, cfg, bus, version=3):
        self.t, self.keys = InprocTransport(TransportConfig(backend="inproc"), bus), Keys(cfg.run)
        tensors = {k: v.numpy() for k, v in make_policy(cfg.agent, cfg.scale).state_dict().items()}
        self.t.serve_latest(self.keys.weights).update(wire.encode(wire.Weights(version, tensors, epoch=1)))
        self.chunks_in = self.t.subscribe(self.keys.all_transitions, capacity=10_000)
        self.episodes_in = self.t.subscribe(self.keys.all_episodes, capacity=10_000)

    def chunks(self):
        return [wire.decode(r.payload) for r in self.chunks_in.drain()]

    def episodes(self):
        return [wire.decode(r.payload) for r in self.episodes_in.drain()]


def start_actor(cfg, bus, stop, made):
    def factory(cfg, sampler):
        made["sampler"] = sampler
        made["env"] = CountingVectorEnv(
            ENDS, on_episode_end=lambda i, info: sampler.record(str(info["track"]), int(info["steps"]))
        )
        return made["env"]

    result = {}
    t = InprocTransport(cfg.transport, bus)
    thread = threading.Thread(target=lambda: result.update(run_actor(cfg, t, stop, env_factory=factory)))
    thread.start()
    return thread, result


def actor_chunks(cfg, bus):
    """The chunks and episode summaries of an actor that runs to `actor.max_env_steps`."""
    learner = FakeLearner(cfg, bus)
    thread, stats = start_actor(cfg, bus, threading.Event(), {})
    thread.join(60)
    return learner.chunks(), learner.episodes(), stats
