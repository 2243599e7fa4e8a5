"""How a policy drives when its weights cross the wire in each `learner.weights_dtype`: every
checkpoint's policy is encoded as the learner broadcasts it (float32, float16, uint8), decoded and
loaded by an actor's `Acting` (the evaluator's path), and driven on the test roads, against the
float32 drive of the same checkpoint in the same run.

    python bench/weights_precision.py CKPT [CKPT ...]     # last line: JSON

Per checkpoint and precision: laps of the test laps, offcenteredness (mean abs(alpha)),
near-out-of-lane, reward per second, angular jerkiness, and the payload's bytes; then per
precision the largest change from float32 over the checkpoints.
"""

from __future__ import annotations

import argparse
import json

import torch

from actors.acting import Acting
from actors.evaluation.evaluate import evaluate, summary
from actors.evaluation.policies import known_config, network_policy
from common import checkpoint, wire
from common.config.agent import AgentConfig, ScaleConfig
from common.config.run import ActorConfig
from common.wire_quant import WEIGHTS_DTYPES, for_broadcast

METRICS = ("lap_completed", "offcenteredness", "near_out_of_lane", "reward_per_s", "jerkiness_angular")


def drive(path: str) -> dict:
    state = checkpoint.load(path)
    agent, scale = known_config(AgentConfig, state["agent"]), known_config(ScaleConfig, state["scale"])
    float32 = {name: t.detach().cpu().numpy() for name, t in state["policy"].items()}
    out = {}
    for dtype in WEIGHTS_DTYPES:
        tensors, quant = for_broadcast(float32, dtype)
        payload = wire.encode(wire.Weights(1, tensors, epoch=1, quant=quant))
        acting = Acting(agent, scale, ActorConfig(), 1, seed=0, deployed=True)
        if not acting.load(wire.decode(payload, expect=wire.Weights)):
            raise RuntimeError(f"{path}: the {dtype} weights were not loaded")
        drives = evaluate(network_policy(acting.policy, agent.representation == "lowdim"))
        mean = summary(drives)
        out[dtype] = {
            "laps": round(mean["lap_completed"] * len(drives)),
            **{k: round(mean[k], 4) for k in METRICS[1:]},
            "bytes": len(payload),
        }
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("checkpoints", nargs="+")
    args = parser.parse_args()
    torch.set_num_threads(1)
    runs = {}
    for path in args.checkpoints:
        runs[path] = drive(path)
        print(path, json.dumps(runs[path]), flush=True)
    worst = {
        dtype: {
            k: round(max(abs(r[dtype][k] - r["float32"][k]) for r in runs.values()), 4) for k in ("laps", *METRICS[1:])
        }
        for dtype in WEIGHTS_DTYPES
        if dtype != "float32"
    }
    print(json.dumps({"checkpoints": runs, "largest_change_from_float32": worst}))


if __name__ == "__main__":
    main()
