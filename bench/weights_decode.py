"""What an actor pays to decode each weights broadcast: `wire.decode` (msgpack and every check of
docs/wire.md) against msgpack's unpack alone of the same payload, the floor, in the same run; for
the learner's broadcast at the small scale in each `learner.weights_dtype`, without and with the
discriminator (`learner.rho_at=actor`).

    python bench/weights_decode.py [--seconds S]     # last line: JSON

Every actor decodes every broadcast: with 256 actors on one machine, 256 decodes per broadcast share
its cores with the router's delivery, so this cost shows in the weights latency of bench/scale.py.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import msgpack

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run as a script from anywhere

from common import wire  # noqa: E402
from common import wire_checks as chk  # noqa: E402
from common.cli import compose_run  # noqa: E402
from common.wire_quant import WEIGHTS_DTYPES, for_broadcast  # noqa: E402
from learner.core import LearningCore  # noqa: E402


def best_us(fn, seconds: float) -> float:
    """Microseconds per call, the best of batches of 50 over `seconds` (the least disturbed)."""
    best, end = float("inf"), time.perf_counter() + seconds
    while time.perf_counter() < end:
        t0 = time.perf_counter()
        for _ in range(50):
            fn()
        best = min(best, (time.perf_counter() - t0) / 50)
    return best * 1e6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=1.0, help="timing per case and side")
    args = parser.parse_args()
    cfg = compose_run(["learner.device=cpu"])
    core = LearningCore(cfg.agent, cfg.scale, seed=0)
    options = chk.unpack_options(wire.DEFAULT_LIMITS)
    cases = {}
    for behaviour in (False, True):
        state = {k: v.detach().cpu().numpy() for k, v in core.broadcast_state_dict(with_behaviour=behaviour).items()}
        for dtype in WEIGHTS_DTYPES:
            tensors, quant = for_broadcast(state, dtype)
            payload = wire.encode(wire.Weights(1, tensors, epoch=1, quant=quant))
            decode_us = best_us(lambda p=payload: wire.decode(p, expect=wire.Weights), args.seconds)
            unpack_us = best_us(lambda p=payload: msgpack.unpackb(p, **options), args.seconds)
            name = f"{dtype}{'+behaviour' if behaviour else ''}"
            cases[name] = {
                "bytes": len(payload),
                "tensors": len(tensors),
                "decode_us": round(decode_us, 1),
                "unpack_us": round(unpack_us, 1),
                "decode_over_unpack": round(decode_us / unpack_us, 2),
            }
            print(name, json.dumps(cases[name]), flush=True)
    print(json.dumps({"bench": "weights_decode", "scale": "small", "cases": cases}))


if __name__ == "__main__":
    main()
