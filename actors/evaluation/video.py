"""A short video of one test lap: the top-down view around the car beside its camera image
(scaled up), as an animated GIF written by imageio (its pillow plugin: no ffmpeg needed), since
people would rather watch a drive than read its metrics."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from actors.envs.sim import LaneDriveSim
from actors.envs.topdown import SIZE, render_topdown
from actors.evaluation.evaluate import PolicyFn
from common.config.env import NOISE_FREE, EnvConfig

CONTROL_HZ = 10


def frame(sim: LaneDriveSim) -> np.ndarray:
    """(SIZE/2, SIZE/2 + 128, 3) uint8: top-down view at half size | the camera's current frame
    (what the policy sees), centred vertically; half size keeps a lap's GIF near a megabyte."""
    camera = sim.frames[0, 0]  # (64, 128)
    half = SIZE // 2
    panel = np.zeros((half, camera.shape[1], 3), np.uint8)
    top = (half - camera.shape[0]) // 2
    panel[top : top + camera.shape[0]] = camera[..., None]
    return np.concatenate([render_topdown(sim, 0)[::2, ::2], panel], axis=1)


def record_lap(
    policy: PolicyFn, track: str, direction: str = "ccw", every: int = 3, max_steps: int = 1200, **env_kwargs
) -> tuple[list[np.ndarray], bool]:
    """Frames of one noise-free lap (every `every`-th step) from the start line, and whether it was completed."""
    sim = LaneDriveSim(EnvConfig.from_kwargs(**{**env_kwargs, **NOISE_FREE}), 1)
    sim.reset(0, np.random.default_rng(0), {"track": track, "direction": direction, "random_start": False})
    frames, lapped = [], False
    for step in range(max_steps):
        if step % every == 0:
            frames.append(frame(sim))
        info = sim.info(0)
        action = np.asarray(policy(sim.observation(), {k: np.array([v]) for k, v in info.items()}), np.float32).reshape(
            1, 2
        )
        terminated, truncated = sim.step(action)
        lapped = bool(sim.info(0)["lap_completed"])
        if terminated[0] or truncated[0] or lapped:
            frames.append(frame(sim))
            break
    return frames, lapped


def write_video(frames: list[np.ndarray], path: str | Path, every: int = 3) -> Path:
    """An animated GIF at `every`x real time (one frame per `every` control steps, 100 ms each)."""
    import imageio.v3 as iio

    path = Path(path)
    iio.imwrite(path, np.stack(frames), extension=".gif", duration=1000 // CONTROL_HZ, loop=0)
    return path
