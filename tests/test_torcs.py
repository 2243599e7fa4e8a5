"""TORCS lockstep protocol (issue 15, stage 2).

The first tests drive a stand-in peer (actors/envs/torcs/fake_torcs.py) and run everywhere: framing,
race files, timeouts and relaunching. The rest drive the real TORCS and skip until `make torcs`
has built it.
"""

from __future__ import annotations

import math
import os
import signal
import xml.etree.ElementTree as ET

import pytest

from actors.envs.torcs.fake_torcs import FakeTorcsLauncher
from actors.envs.torcs.protocol import STEP_SECONDS, TorcsError, TorcsProcess, find_install
from actors.envs.torcs.race import RaceSpec, find_category, race_xml


def _yaw_change(a: float, b: float) -> float:
    return (b - a + math.pi) % (2 * math.pi) - math.pi


def _drive(torcs: TorcsProcess, steps: int, steer: float, speed: float):
    for _ in range(steps):
        state = torcs.step(steer, speed)
    return state


# -- race files --------------------------------------------------------------------------------


def test_race_file_poses_the_car_and_names_our_robot():
    spec = RaceSpec("g-track-1", "road", start=123.5, to_middle=-1.25, yaw=0.1)
    root = ET.fromstring(race_xml(spec))
    grid = {a.get("name"): float(a.get("val")) for a in root.iterfind(".//section[@name='Starting Grid']/attnum")}
    assert grid["gvf start distance"] == 123.5 and grid["gvf start to middle"] == -1.25
    assert grid["gvf start yaw"] == pytest.approx(0.1) and grid["rows"] == 1
    track = root.find(".//section[@name='Tracks']/section[@name='1']")
    assert {a.get("name"): a.get("val") for a in track} == {"name": "g-track-1", "category": "road"}
    drivers = root.find(".//section[@name='Drivers']/section[@name='1']")
    assert {a.get("name"): a.get("val") for a in drivers}["module"] == "gvfdrive"
    with pytest.raises(ValueError):
        race_xml(RaceSpec("g-track-1", "road", start=float("nan")))


# -- the protocol against the stand-in peer ------------------------------------------------------


@pytest.fixture
def fake(tmp_path):
    with TorcsProcess(FakeTorcsLauncher(), workdir=tmp_path, start_timeout=20.0, step_timeout=5.0) as torcs:
        yield torcs


def test_fake_step_is_one_tenth_of_a_second_and_echoes_the_action(fake):
    first = fake.reset(RaceSpec("straight", "road", start=50.0, to_middle=1.0))
    assert first.step == 0 and first.x == 50.0 and first.to_middle == 1.0
    state = fake.step(0.25, 10.0)
    assert state.step == 1 and state.time - first.time == pytest.approx(STEP_SECONDS)
    assert (state.steer, state.target_speed) == (0.25, 10.0)


def test_fake_killed_peer_is_relaunched_on_the_same_race(fake):
    fake.reset(RaceSpec("straight", "road", start=10.0))
    _drive(fake, 3, 0.0, 10.0)
    os.kill(fake.proc.pid, signal.SIGKILL)
    state = fake.step(0.0, 10.0)
    assert state.step == 0 and state.x == 10.0 and fake.relaunches == 1 and fake.launches == 2
    assert fake.step(0.0, 10.0).step == 1


def test_fake_hung_peer_is_killed_and_relaunched(fake, monkeypatch):
    monkeypatch.setenv("GVF_FAKE_TORCS_HANG_AT", "2")
    fake.step_timeout = 1.0
    fake.reset(RaceSpec("straight", "road"))
    hung = fake.proc
    assert fake.step(0.0, 5.0).step == 1
    assert fake.step(0.0, 5.0).step == 0 and fake.relaunches == 1 and hung.poll() is not None


def test_fake_broken_start_raises_after_retries(tmp_path):
    class Broken(FakeTorcsLauncher):
        def launch_args(self, race_file, local_dir):
            argv, cwd, env = super().launch_args(race_file, local_dir)
            return argv[:1] + ["-c", "raise SystemExit(3)"], cwd, env

    with TorcsProcess(Broken(), workdir=tmp_path, max_attempts=2) as torcs:
        with pytest.raises(TorcsError, match="2 times"):
            torcs.reset(RaceSpec("straight", "road"))


# -- the real TORCS (after `make torcs`) ----------------------------------------------------------

needs_torcs = pytest.mark.skipif(find_install() is None, reason="TORCS is not built: run `make torcs`")


@pytest.fixture
def torcs(tmp_path):
    with TorcsProcess(workdir=tmp_path) as process:
        yield process


@needs_torcs
def test_torcs_step_moves_simulated_time_by_a_tenth(torcs):
    first = torcs.reset(RaceSpec("g-track-1", "road", start=50.0))
    assert first.step == 0 and first.lap == 0 and first.track_length > 1000
    assert abs(first.to_middle) < 0.1 and abs(first.dist_from_start - 50.0) < 1.0
    times = [first.time] + [torcs.step(0.0, 10.0).time for _ in range(20)]
    assert all(b - a == pytest.approx(STEP_SECONDS, abs=1e-6) for a, b in zip(times, times[1:]))


@needs_torcs
def test_torcs_applies_the_action_sent(torcs):
    install = find_install()
    category = find_category("g-track-1", install.data_dir)
    torcs.reset(RaceSpec("g-track-1", category, start=50.0))
    before = _drive(torcs, 30, 0.0, 12.0)
    assert before.speed == pytest.approx(12.0, abs=1.0) and (before.steer, before.target_speed) == (0.0, 12.0)
    left = _drive(torcs, 3, 0.4, 12.0)
    assert left.steer == pytest.approx(0.4) and _yaw_change(before.yaw, left.yaw) > 0.02
    right = _drive(torcs, 6, -0.4, 12.0)
    assert right.steer == pytest.approx(-0.4) and _yaw_change(left.yaw, right.yaw) < -0.02


@needs_torcs
def test_torcs_pose_from_the_race_file(torcs):
    state = torcs.reset(RaceSpec("g-track-1", "road", start=300.0, to_middle=2.0, yaw=0.2))
    assert state.dist_from_start == pytest.approx(300.0, abs=1.0)
    assert state.to_middle == pytest.approx(2.0, abs=0.1) and state.angle == pytest.approx(-0.2, abs=0.02)


@needs_torcs
def test_torcs_reset_moves_to_another_road(torcs):
    first = torcs.reset(RaceSpec("g-track-1", "road", start=10.0))
    other = torcs.reset(RaceSpec("a-speedway", "oval", start=20.0))
    assert other.step == 0 and other.track_length != first.track_length and torcs.launches == 2


@needs_torcs
def test_torcs_killed_process_is_relaunched(torcs):
    torcs.reset(RaceSpec("g-track-1", "road", start=50.0))
    _drive(torcs, 5, 0.0, 10.0)
    pid = torcs.proc.pid
    os.kill(pid, signal.SIGKILL)
    state = torcs.step(0.0, 10.0)
    assert state.step == 0 and torcs.relaunches == 1 and torcs.proc.pid != pid
    assert _drive(torcs, 3, 0.0, 10.0).step == 3
