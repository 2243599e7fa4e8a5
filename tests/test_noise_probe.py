"""actors.evaluation.noise_probe: the paper's slow OU noise moves the car to an offset that goes
with the noise; white noise of the same size does not."""

from actors.evaluation.noise_probe import probe
from actors.evaluation.policies import kinematic_policy


def test_slow_ou_noise_goes_with_the_offset_and_white_noise_does_not():
    roads = {"tracks": ["sage", "moor"]}
    slow = probe(kinematic_policy(), theta=1.0, sigma=0.1, **roads)
    white = probe(kinematic_policy(), theta=100.0, sigma=0.75, **roads)
    assert abs(slow["noise_std"] - white["noise_std"]) < 0.02  # about the same size (0.07)
    assert len(slow["corr_per_drive"]) == 4 and slow["laps"] == white["laps"] == 4
    assert slow["corr_noise_alpha"] > 0.5 > 0.25 > white["corr_noise_alpha"]
    assert slow["mean_abs_alpha"] > white["mean_abs_alpha"]
