"""`learner.weights_dtype=float16`: the learner broadcasts half the bytes, an actor widens them to
float32 and acts with the learner's weights rounded to float16."""

import numpy as np
import torch

from actors.acting import Acting
from common import wire
from common.keys import Keys
from common.transport.inproc import Bus, InprocTransport
from learner.service import LearnerService
from tests.helpers import TINY, compose_run


def published(tmp_path, dtype: str) -> tuple[LearnerService, bytes]:
    cfg = compose_run([*TINY, "transport=inproc", f"learner.weights_dtype={dtype}"])
    bus = Bus()
    service = LearnerService(cfg, InprocTransport(bus=bus), tmp_path / dtype)
    service.open()  # publishes (and serves) the first weights
    payload = InprocTransport(bus=bus).fetch(Keys(cfg.run).publish("weights", "learner"), timeout=1.0)
    assert payload is not None
    return service, payload


def test_float16_weights_are_half_the_bytes_and_act_as_the_rounded_policy(tmp_path):
    _, full = published(tmp_path, "float32")
    service, half = published(tmp_path, "float16")
    assert len(half) < 0.55 * len(full)
    msg = wire.decode(half, expect=wire.Weights)
    assert {t.dtype for t in msg.tensors.values()} == {np.dtype(np.float16)}
    cfg = service.cfg
    acting = Acting(cfg.agent, cfg.scale, cfg.actor, 1, seed=0)
    assert acting.load(msg)
    own = service.core.broadcast_state_dict()
    for name, value in acting.policy.state_dict().items():
        assert value.dtype == torch.float32
        assert torch.equal(value, own[name].to(torch.float16).to(torch.float32))
    assert not all(torch.equal(acting.policy.state_dict()[n], own[n]) for n in own)  # rounded, not the float32 ones


def test_float64_weights_are_refused(tmp_path):
    service, _ = published(tmp_path, "float32")
    cfg = service.cfg
    acting = Acting(cfg.agent, cfg.scale, cfg.actor, 1, seed=0)
    tensors = {k: v.numpy().astype(np.float64) for k, v in service.core.broadcast_state_dict().items()}
    rejects = wire.RejectCounter()
    assert not acting.adopt(wire.Weights(1, tensors, epoch=1), rejects, "k")
    assert rejects.counts["weights"] == 1


def test_a_tensor_beyond_float16s_range_travels_as_float32():
    from learner.service import narrowed

    big = np.array([1.0, 7e4], np.float32)
    assert narrowed(big, "float16").dtype == np.float32 and narrowed(big[:1], "float16").dtype == np.float16
    assert narrowed(big, "float32") is big
