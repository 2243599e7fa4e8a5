"""`learner.weights_dtype`: with float16 the learner broadcasts half the bytes, an actor widens them
to float32 and acts with the learner's weights rounded to float16; with uint8 a quarter, and the
actor acts with the learner's weights within half a quantization step."""

import numpy as np
import torch

from actors.acting import Acting
from common import wire
from common.keys import Keys
from common.transport.inproc import Bus, InprocTransport
from common.wire_quant import floats, narrowed
from learner.service import LearnerService
from tests.helpers import TINY, compose_run


def published(tmp_path, dtype: str, *more: str) -> tuple[LearnerService, bytes]:
    cfg = compose_run([*TINY, "transport=inproc", f"learner.weights_dtype={dtype}", *more])
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


def test_uint8_weights_are_a_quarter_of_the_bytes_and_act_within_half_a_step(tmp_path):
    _, full = published(tmp_path, "float32", "learner.rho_at=actor")
    service, small = published(tmp_path, "uint8", "learner.rho_at=actor")
    assert len(small) < 0.3 * len(full)
    msg = wire.decode(small, expect=wire.Weights)
    own = service.core.broadcast_state_dict(with_behaviour=True)
    assert set(msg.tensors) == set(own) and any(n.startswith(wire.BEHAVIOUR) for n in own)
    quant = msg.quant
    assert quant and all(own[name].dim() >= 2 and msg.tensors[name].dtype == np.uint8 for name in quant)
    values = floats(msg.tensors, msg.quant)
    for name, value in own.items():
        got = torch.from_numpy(np.array(values[name]))
        if name not in quant:  # vectors travel as they are
            assert torch.equal(got, value), name
            continue
        step = torch.tensor(quant[name][:, 0]).reshape(-1, *[1] * (value.dim() - 1))
        assert (got - value).abs().le(step / 2 * 1.0001).all(), name
    cfg = service.cfg
    acting = Acting(cfg.agent, cfg.scale, cfg.actor, 1, seed=0)
    assert acting.load(msg) and acting.behaviour is not None
    for name, value in acting.policy.state_dict().items():
        assert torch.equal(value, torch.from_numpy(np.array(values[name])))
    for name, value in acting.behaviour.state_dict().items():
        assert torch.equal(value, torch.from_numpy(np.array(values[wire.BEHAVIOUR + name])))


def test_a_tensor_beyond_float16s_range_travels_as_float32():

    big = np.array([1.0, 7e4], np.float32)
    assert narrowed(big, "float16").dtype == np.float32 and narrowed(big[:1], "float16").dtype == np.float16
    assert narrowed(big, "float32") is big
