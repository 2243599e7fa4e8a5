"""The learner's run log: scalars, progress.json, and the warning when tau loses support."""

import json
import logging

from learner.run_log import RunLog

RATES = {"updates_per_s": 10.0, "env_steps_per_s": 400.0, "ingest_fraction": 0.1, "train_fraction": 0.8}


def progress(updates: int, rho_bar: float | None) -> dict:
    return {"updates": updates, "replay": 100, "actors_alive": 2, "rho_bar": rho_bar}


def warnings(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.name == "learner.run_log" and r.levelno >= logging.WARNING]


def test_a_starved_rho_bar_is_said_once_and_its_recovery_once(tmp_path, caplog):
    caplog.set_level(logging.INFO, logger="learner.run_log")
    run_log = RunLog(tmp_path)
    try:
        run_log.write(progress(100, 1.7), {}, RATES)
        run_log.write(progress(200, None), {}, RATES)  # a learner without GVFs
        assert warnings(caplog) == []
        run_log.write(progress(300, 0.004), {}, RATES)
        run_log.write(progress(400, 1e-16), {}, RATES)
        said = warnings(caplog)
        assert len(said) == 1 and "update 300" in said[0] and "tau" in said[0]
        run_log.write(progress(500, 0.05), {}, RATES)  # not yet 10x the floor: still starved, nothing new
        run_log.write(progress(600, 0.2), {}, RATES)
        infos = [r.getMessage() for r in caplog.records if r.name == "learner.run_log" and r.levelno == logging.INFO]
        assert len(infos) == 1 and "update 600" in infos[0]
        run_log.write(progress(700, 0.001), {}, RATES)  # starved again: said again
        assert len(warnings(caplog)) == 2
    finally:
        run_log.close()
    assert json.loads((tmp_path / "progress.json").read_text())["updates"] == 700
