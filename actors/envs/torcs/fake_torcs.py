"""A stand-in for TORCS that speaks the robot's side of the lockstep protocol, so the Python side
(protocol.py: launching, framing, timeouts, relaunching) is tested on machines without ``make torcs``.

It reads the start pose from the race file, drives a kinematic bicycle on a straight road along x
(5 sub-steps of 0.02 s per control step, as the robot's 5 calls), and answers exactly like
gvfdrive.cpp: a state, then a blocking read of the action, exit on end of file or on quit.
``GVF_FAKE_TORCS_HANG_AT=n`` makes it stop answering at step n (a hung TORCS).

    python -m actors.envs.torcs.fake_torcs race.xml
"""

from __future__ import annotations

import math
import os
import sys
import time
import xml.etree.ElementTree as ET
from pathlib import Path

from actors.envs.torcs.protocol import (
    ACTION,
    ACTION_MAGIC,
    COMMAND_QUIT,
    PROTOCOL_VERSION,
    STATE,
    STATE_MAGIC,
)

ROAD_LENGTH = 1000.0
ROAD_WIDTH = 12.0
WHEELBASE = 2.6
MAX_WHEEL_ANGLE = 0.366  # rad: car1-trb1's steer lock, so steer = 1 turns as hard as in TORCS
CALLS_PER_STEP, CALL_DT = 5, 0.02


class FakeTorcsLauncher:
    """``Launcher`` for TorcsProcess that starts this module instead of torcs-bin."""

    def launch_args(self, race_file: Path, local_dir: Path) -> tuple[list[str], Path, dict[str, str]]:
        root = Path(__file__).resolve().parents[3]
        return [sys.executable, "-m", "actors.envs.torcs.fake_torcs", str(race_file)], root, {}


def _grid_value(race: ET.Element, name: str) -> float:
    node = race.find(f".//section[@name='Starting Grid']/attnum[@name='{name}']")
    return float(node.get("val", "0")) if node is not None else 0.0


def _read_exact(fd: int, n: int) -> bytes | None:
    data = b""
    while len(data) < n:
        chunk = os.read(fd, n - len(data))
        if not chunk:
            return None
        data += chunk
    return data


def main(argv: list[str]) -> int:
    race = ET.parse(argv[1]).getroot()
    fd_in, fd_out = (int(v) for v in os.environ["GVF_TORCS_FDS"].split(","))
    hang_at = int(os.environ.get("GVF_FAKE_TORCS_HANG_AT", "-1"))
    x = _grid_value(race, "gvf start distance")
    y = _grid_value(race, "gvf start to middle")
    yaw = _grid_value(race, "gvf start yaw")
    v = 0.0  # TORCS starts every race from rest (its prestart brakes)
    t, raced, step, steer, target = CALL_DT, 0.0, 0, 0.0, 0.0
    while True:
        if step == hang_at:
            time.sleep(3600)
        angle = (-yaw + math.pi) % (2 * math.pi) - math.pi
        to_left, to_right = ROAD_WIDTH / 2 - y, ROAD_WIDTH / 2 + y
        doubles = (t, x, y, 0.0, yaw % (2 * math.pi), v, 0.0, 0.0, y, to_left, to_right, angle)
        doubles += (x % ROAD_LENGTH, raced, ROAD_LENGTH, 0.0, ROAD_WIDTH, steer, target, 0.0, 0.0)
        ints = (0, 3, int(x // ROAD_LENGTH), 0, 1, 0)
        os.write(fd_out, STATE.pack(STATE_MAGIC, PROTOCOL_VERSION, step, *doubles, *ints))
        msg = _read_exact(fd_in, ACTION.size)
        if msg is None:
            return 0
        magic, command, steer, target = ACTION.unpack(msg)
        if magic != ACTION_MAGIC or command == COMMAND_QUIT:
            return 0
        steer, target = max(-1.0, min(1.0, steer)), max(0.0, target)
        for _ in range(CALLS_PER_STEP):
            v += (target - v) * 0.1  # a first-order lag standing in for the speed controller
            yaw += v / WHEELBASE * math.tan(steer * MAX_WHEEL_ANGLE) * CALL_DT
            x += v * math.cos(yaw) * CALL_DT
            y += v * math.sin(yaw) * CALL_DT
            raced += v * CALL_DT
            t += CALL_DT
        step += 1


if __name__ == "__main__":
    sys.exit(main(sys.argv))
