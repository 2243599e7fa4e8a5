"""The MPC baseline (actors.controllers.mpc): its model predicts LaneDrive, and it follows the lane."""

from __future__ import annotations

import numpy as np

from actors.controllers.mpc import HORIZON, MPCController, _road
from actors.envs.sim import LaneDriveSim
from actors.evaluation.evaluate import evaluate, summary
from common.config.env import EnvConfig


def _sim(track: str, lateral: float = 0.0, yaw: float = 0.0, bend: bool = False) -> LaneDriveSim:
    """A car on `track` at 30 m, or with `bend` 20 m before its tightest bend."""
    sim = LaneDriveSim(EnvConfig.from_kwargs(lighting=False), 1)
    sim.reset(0, np.random.default_rng(0), {"track": track, "direction": "ccw", "random_start": False})
    tr = sim.tracks[0]
    station = float(np.argmax(np.abs(tr.curvature)) * tr.spacing - 20.0) % tr.length if bend else 30.0
    sim.place(0, station, lateral, yaw)
    return sim


def _state(info: dict) -> dict:
    return {
        "e": np.array([info["alpha"] * info["lane_half_width"]]),
        "psi": np.array([info["beta"]]),
        "v": np.array([info["speed"]]),
        "delta": np.array([info["steer"]]),
        "s": np.array([info["station"]]),
        "half": np.array([info["lane_half_width"]]),
        "u0": np.array([0.0]),
        "roads": [_road(info["track"])],
    }


def test_the_models_rollout_predicts_the_simulators_lane_offset():
    """A steering plan rolled out by the model drives the lane offsets LaneDrive drives (sum of alpha^2
    over the 15 steps within 2%), on a straight and into bends."""
    mpc = MPCController(target_speed=10.0)
    for track, bend in (("alder", False), ("fjord", True), ("dune", True)):
        sim = _sim(track, lateral=0.5, bend=bend)
        plan = np.array([0.3, -0.2, 0.1, 0.0, -0.1])
        start = _state(sim.info(0))
        alphas = []
        for j in range(HORIZON):
            for _ in range(mpc.hold):
                sim.step(np.array([[plan[j], -1.0]]))
                alphas.append(sim.alpha[0])
        # the model's last e, from the cost of a plan with only that term: run it with w_psi = 0
        probe = MPCController(target_speed=10.0, w_psi=0.0, w_du=0.0)
        predicted = probe.rollout_cost(plan[None, None], start)[0, 0]
        simulated = float(np.sum(np.square(alphas)))
        assert abs(predicted - simulated) < 0.02 * simulated, (track, predicted, simulated)


def test_mpc_steers_back_toward_the_centre():
    for lateral, sign in ((2.0, -1.0), (-2.0, 1.0)):  # left of the centre: steer right
        sim = _sim("alder", lateral=lateral)
        action = MPCController(target_speed=10.0).act({k: np.array([v]) for k, v in sim.info(0).items()})
        assert action.shape == (1, 2) and np.sign(action[0, 0]) == sign


def test_mpc_laps_held_out_roads_at_a_slow_target_speed():
    mpc = MPCController(target_speed=10.3)
    results = evaluate(lambda obs, info: mpc.act(info), "test", ("ccw", "cw"), tracks=["dune", "karst"])
    m = summary(results)
    assert m["lap_completed"] == 1.0 and m["near_out_of_lane"] < 0.01, m
    assert abs(m["average_speed"] - 10.3) < 0.3
