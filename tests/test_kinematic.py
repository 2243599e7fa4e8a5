"""The kinematic controller laps every held-out road in both directions: the simulator's sanity check."""

import pytest

from actors.controllers.kinematic import KinematicController, drive_lap
from actors.envs.lane_drive import LaneDriveEnv
from actors.envs.tracks import track_names


@pytest.mark.parametrize("direction", ["ccw", "cw"])
@pytest.mark.parametrize("track", track_names("test"))
def test_kinematic_controller_laps_test_tracks(track, direction):
    env = LaneDriveEnv(track=track, direction=direction, random_start=False)
    result = drive_lap(env, KinematicController(), seed=0)
    assert result["lap_completed"], result
    assert result["max_abs_alpha"] < 0.75, result


def test_kinematic_controller_drives_a_damaged_procedural_road():
    env = LaneDriveEnv(track="procedural", damage={"gap_fraction": 0.5}, random_start=False)
    result = drive_lap(env, KinematicController(), seed=3)
    assert result["lap_completed"] and result["max_abs_alpha"] < 0.75, result
