"""LaneDrive-v0: gymnasium API, ground truth on hand-built poses, camera, determinism, vector env."""

import math

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import actors.envs  # noqa: F401  (registers LaneDrive-v0)
from actors.envs.camera import ground_points
from actors.envs.lane_drive import LaneDriveEnv, LaneDriveVectorEnv
from actors.envs.tracks import build_centreline

STADIUM = build_centreline(
    "stadium",
    [
        {"type": "straight", "length": 100.0},
        {"type": "arc", "radius": 30.0, "angle": math.pi},
        {"type": "straight", "length": 100.0},
        {"type": "arc", "radius": 30.0, "angle": math.pi},
    ],
)


@pytest.mark.parametrize(
    "kwargs",
    [
        {},
        {"track": "test", "direction": "cw", "lighting": False},
        {"track": "procedural", "lane_width": 4.0},
        {"track": "alder", "damage": {"gap_fraction": 0.3, "fade_fraction": 0.3, "distractors_per_100m": 2.0}},
    ],
)
def test_check_env_passes(kwargs):
    env = gym.make("LaneDrive-v0", **kwargs)
    check_env(env.unwrapped, skip_render_check=True)
    obs, info = env.reset(seed=0)
    assert obs["image"].shape == (2, 64, 128) and obs["image"].dtype == np.uint8
    assert {"alpha", "beta", "speed", "track", "progress"} <= set(info)


def _env_on(track, **kwargs):
    env = LaneDriveEnv(lighting=False, random_start=False, **kwargs)
    env.reset(seed=0, options={"track": track})
    return env


@pytest.mark.parametrize("lateral, yaw", [(1.5, 0.1), (-2.4, -0.3), (0.0, 0.0)])
def test_alpha_beta_on_a_straight(lateral, yaw):
    env = _env_on(STADIUM)  # the first segment runs from the origin along +x
    env.sim.set_pose(0, 40.0, lateral, yaw)
    info = env.sim.info(0)
    assert info["alpha"] == pytest.approx(lateral / 3.0, abs=1e-6)
    assert info["beta"] == pytest.approx(yaw, abs=1e-6)


@pytest.mark.parametrize("phi, lateral, yaw", [(0.7, 1.5, 0.05), (2.0, -1.2, -0.2)])
def test_alpha_beta_on_an_arc(phi, lateral, yaw):
    env = _env_on(STADIUM)  # first arc: centre (100, 30), radius 30, turning left
    r = 30.0 - lateral  # left of the centre line is towards the arc's centre
    env.sim.set_pose(0, 100.0 + r * math.sin(phi), 30.0 - r * math.cos(phi), phi + yaw)
    info = env.sim.info(0)
    assert info["alpha"] == pytest.approx(lateral / 3.0, abs=0.01)
    assert info["beta"] == pytest.approx(yaw, abs=0.01)
    assert info["curvature"] == pytest.approx(1 / 30.0)


def test_alpha_sign_follows_driving_direction():
    env = _env_on("alder", direction="cw")
    env.sim.place(0, 50.0, 1.2, 0.0)
    assert env.sim.info(0)["alpha"] == pytest.approx(0.4, abs=1e-3)


def _marking_column(image: np.ndarray) -> float:
    bright = image[4:16] > 180  # rows seeing 8-20 m ahead, where both markings are in view
    return float(np.nonzero(bright)[1].mean())


def test_camera_markings_move_opposite_to_the_car():
    env = _env_on(STADIUM)
    env.sim.set_pose(0, 20.0, 0.0, 0.0)
    centre = env.sim.frames[0, 0].copy()
    env.sim.set_pose(0, 20.0, 1.5, 0.0)
    left = env.sim.frames[0, 0].copy()
    env.sim.set_pose(0, 20.0, -1.5, 0.0)
    right = env.sim.frames[0, 0].copy()
    assert _marking_column(left) > _marking_column(centre) + 5 > _marking_column(right) + 10
    # Centred on a straight the picture is symmetric about the middle column.
    assert abs(_marking_column(centre) - 64) < 2


@pytest.mark.parametrize("height", [1.5, 3.0])
def test_a_higher_camera_sees_further_and_both_markings_to_the_bottom_row(height):
    fwd, _ = ground_points(height)
    assert fwd.reshape(64, 128)[0, 64] == pytest.approx(40 * height + 1.0)  # 2.5 rows below the horizon
    env = _env_on(STADIUM, camera_height=height)
    env.sim.set_pose(0, 20.0, 0.0, 0.0)
    bottom = env.sim.frames[0, 0][60:] > 180
    # 1.5 m: the bottom rows see 2-3 m ahead, where the 6 m lane is wider than the view
    assert bottom.any() == (height == 3.0)


def test_frames_stack_current_and_previous():
    env = _env_on("alder")
    obs0, _ = env.reset(seed=0, options={"track": "alder"})
    obs1, *_ = env.step(np.array([0.0, 1.0]))
    np.testing.assert_array_equal(obs1["image"][1], obs0["image"][0])
    assert not np.array_equal(obs1["image"][0], obs1["image"][1])


def _rollout(seed, n=150):
    env = gym.make("LaneDrive-v0", track="train")
    obs, info = env.reset(seed=seed)
    rng = np.random.default_rng(123)
    out = [(info["track"], info["alpha"])]
    for _ in range(n):
        obs, r, term, trunc, info = env.step(rng.uniform(-0.3, 0.3, 2).astype(np.float32))
        out.append((r, info["alpha"], info["beta"], obs["image"].sum()))
        if term or trunc:
            obs, info = env.reset()
            out.append((info["track"],))
    return out


def test_same_seed_same_trajectory():
    assert _rollout(5) == _rollout(5)
    assert _rollout(5) != _rollout(6)


def test_leaving_the_lane_terminates_and_rewards_follow_the_formula():
    env = _env_on(STADIUM)
    env.sim.set_pose(0, 20.0, 0.0, 0.0)
    _, r, term, trunc, info = env.step(np.array([0.0, 1.0]))
    assert r == pytest.approx(info["speed"] / 20.0 * (math.cos(info["beta"]) - abs(info["alpha"])))
    steps = 0
    while not term:
        _, r, term, trunc, info = env.step(np.array([1.0, 1.0]))
        steps += 1
        assert steps < 100 and not trunc
    assert abs(info["alpha"]) > 1.0


def test_truncation_at_max_steps():
    env = LaneDriveEnv(track="alder", max_steps=5, random_start=False)
    env.reset(seed=0)
    for _ in range(4):
        assert env.step(np.zeros(2))[3] is False
    assert env.step(np.zeros(2))[3] is True


def test_vector_env_steps_together_and_autoresets_in_the_same_step():
    envs = gym.make_vec("LaneDrive-v0", num_envs=4, vectorization_mode="vector_entry_point", track="train")
    assert isinstance(envs.unwrapped, LaneDriveVectorEnv)
    obs, info = envs.reset(seed=0)
    assert obs["image"].shape == (4, 2, 64, 128) and info["alpha"].shape == (4,)
    actions = np.tile([[0.0, 1.0]], (4, 1)).astype(np.float32)
    actions[0] = (1.0, 1.0)  # car 0 steers off the road
    for _ in range(100):
        obs, reward, term, trunc, info = envs.step(actions)
        if term[0]:
            break
    assert term[0] and info["_final_obs"][0]
    assert abs(info["final_info"]["alpha"][0]) > 1.0
    assert info["final_obs"][0]["image"].shape == (2, 64, 128)
    assert abs(info["alpha"][0]) < 1.0 and info["steps"][0] == 0  # already restarted
    envs.close()


def test_rgb_array_render():
    env = gym.make("LaneDrive-v0", render_mode="rgb_array")
    env.reset(seed=0)
    frame = env.render()
    assert frame.shape == (256, 256, 3) and frame.dtype == np.uint8
    assert (frame == (40, 90, 230)).all(axis=2).any()  # the car is drawn


@pytest.mark.parametrize(
    "kwargs, field",
    [
        ({"direction": "up"}, "direction"),
        ({"camera_height": 5.0}, "camera_height"),
        ({"lane_width": 50.0}, "lane_width"),
        ({"speed": 3}, "speed"),
        ({"damage": {"gap_fraction": 2.0}}, "gap_fraction"),
    ],
)
def test_bad_config_is_refused_naming_the_field(kwargs, field):
    with pytest.raises((ValueError, TypeError), match=field):
        LaneDriveEnv(**kwargs)


def test_non_finite_action_is_refused():
    env = LaneDriveEnv()
    env.reset(seed=0)
    with pytest.raises(ValueError, match="finite"):
        env.step(np.array([np.nan, 0.0]))


def test_vector_env_asks_the_track_chooser_at_every_reset():
    asked = []

    def choose(i):
        asked.append(i)
        return "brook"

    envs = LaneDriveVectorEnv(2, track_chooser=choose, direction="ccw", random_start=False)
    _, info = envs.reset(seed=0)
    assert asked == [0, 1] and list(info["track"]) == ["brook", "brook"]
    for _ in range(100):
        _, _, term, _, _ = envs.step(np.array([[1.0, 1.0], [0.0, -1.0]], np.float32))
        if term[0]:
            break
    assert asked == [0, 1, 0]
