"""Tiny stand-ins for the simulator, so the learner's tests need neither LaneDrive nor a network.

- `random_transitions`: LaneDrive-shaped transitions with random content (plumbing tests).
- `FakeLaneDrive`: N cars on smooth random roads, vectorised in numpy, with the LaneDrive
  observation contract (image uint8 (2, 64, 128) [t, t-1], speed (1,), last_action (2,))
  and info alpha / beta. Its camera draws the two lane edges in perspective, so alpha and
  beta (and the road ahead) are visible in the frames, as in the real simulator.
- `steering_controller`: a kinematic controller steering from alpha and beta.
- `collect`: run the fake with that controller plus OU noise and return transitions in the
  learner's input convention (see learner.replay), time-major per car.
"""

from __future__ import annotations

import numpy as np
import torch
from tensordict import TensorDict

from actors.exploration import OrnsteinUhlenbeck

H, W = 64, 128


def random_transitions(n: int, seed: int = 0, terminal_rate: float = 0.05) -> TensorDict:
    g = torch.Generator().manual_seed(seed)

    def u(*shape):
        return torch.rand(*shape, generator=g) * 2 - 1

    def frames(c):
        return torch.randint(0, 256, (n, c, H, W), generator=g, dtype=torch.uint8)

    return TensorDict(
        {
            "image": frames(2),
            "speed": torch.rand(n, 1, generator=g),
            "last_action": u(n, 2),
            "alpha": u(n, 1),
            "beta": 0.3 * u(n, 1),
            "action": u(n, 2),
            "next": {
                "image": frames(2),
                "speed": torch.rand(n, 1, generator=g),
                "alpha": u(n, 1),
                "beta": 0.3 * u(n, 1),
                "reward": u(n, 1),
                "terminated": torch.rand(n, 1, generator=g) < terminal_rate,
                "truncated": torch.zeros(n, 1, dtype=torch.bool),
            },
        },
        batch_size=[n],
    )


class FakeLaneDrive:
    """N cars; lane half-width 1 (alpha = lateral offset), heading error beta in rad."""

    dt, max_yaw_rate, max_speed, max_steps = 0.1, 1.0, 10.0, 400

    def __init__(self, n: int, seed: int = 0):
        self.n, self.rng = n, np.random.default_rng(seed)
        self.rows = np.linspace(0.0, 1.0, H)[:, None]  # 0 at the top (far), 1 at the bottom
        self.distance = 2.0 + 18.0 * (1.0 - self.rows) ** 2  # metres ahead seen by each row
        self.cols = np.arange(W)[None, None, :]
        self.reset(np.ones(n, dtype=bool))

    def reset(self, mask: np.ndarray) -> None:
        k = int(mask.sum())
        if not hasattr(self, "alpha"):
            z = np.zeros(self.n)
            self.alpha, self.beta, self.s, self.steps = z.copy(), z.copy(), z.copy(), z.copy()
            self.speed = np.full(self.n, 0.75)
            self.phase = np.zeros((self.n, 3))
            self.last_action = np.zeros((self.n, 2), np.float32)
            self.frame = np.zeros((self.n, H, W), np.uint8)
        self.alpha[mask] = self.rng.uniform(-0.3, 0.3, k)
        self.beta[mask] = self.rng.uniform(-0.1, 0.1, k)
        self.s[mask], self.steps[mask], self.speed[mask] = 0.0, 0.0, 0.75
        self.phase[mask] = self.rng.uniform(0, 2 * np.pi, (k, 3))
        self.last_action[mask] = 0.0
        self.frame[mask] = self.render()[mask]
        if not hasattr(self, "prev"):
            self.prev = self.frame.copy()
        self.prev[mask] = self.frame[mask]  # a fresh episode starts with two equal frames

    def curvature(self, s: np.ndarray) -> np.ndarray:
        """Smooth random road: curvature (1/m) at arc length s, per car (broadcast on s)."""
        p = self.phase.reshape(self.n, *([1] * (s.ndim - 1)), 3)
        waves = 0.03 * np.sin(s[..., None] / np.array([7.0, 13.0, 29.0]) + p)
        return waves.sum(-1)

    def render(self) -> np.ndarray:
        d = self.distance[None]  # (1, H, 1)
        kappa = self.curvature(self.s[:, None, None] + d)
        centre = (
            -self.alpha[:, None, None] - d * np.tan(self.beta)[:, None, None] + 0.5 * kappa * d**2
        )  # lane centre, lateral metres in the car frame
        scale = 40.0 / d  # pixels per metre at that distance
        image = np.zeros((self.n, H, W), np.uint8)
        for edge in (-1.0, 1.0):
            col = W / 2 + (centre + edge) * scale
            image[np.abs(self.cols - col) < 1.0 + 0.2 * scale] = 255
        return image

    def observation(self) -> dict[str, np.ndarray]:
        return {
            "image": np.stack([self.frame, self.prev], 1),
            "speed": self.speed[:, None].astype(np.float32),  # fraction of max speed
            "last_action": self.last_action.copy(),
        }

    def info(self) -> dict[str, np.ndarray]:
        return {"alpha": self.alpha.astype(np.float32), "beta": self.beta.astype(np.float32)}

    def step(self, action: np.ndarray):
        action = np.clip(action, -1.0, 1.0).astype(np.float32)
        target = 0.5 + 0.25 * (action[:, 1] + 1.0)  # [-1, 1] -> [0.5, 1.0] of max speed
        self.speed += 0.5 * (target - self.speed)
        v = self.speed * self.max_speed
        self.beta += (action[:, 0] * self.max_yaw_rate - self.curvature(self.s) * v) * self.dt
        self.alpha += v * np.sin(self.beta) * self.dt
        self.s += v * self.dt
        self.steps += 1
        self.last_action = action
        self.prev, self.frame = self.frame, self.render()
        reward = (self.speed * (np.cos(self.beta) - np.abs(self.alpha))).astype(np.float32)
        terminated = np.abs(self.alpha) > 1.0
        truncated = ~terminated & (self.steps >= self.max_steps)
        return self.observation(), reward, terminated, truncated, self.info()


def steering_controller(info: dict[str, np.ndarray], k_alpha: float = 1.0, k_beta: float = 3.0) -> np.ndarray:
    """Steer back to the lane centre from alpha and beta; keep the middle target speed."""
    steer = np.clip(-k_alpha * info["alpha"] - k_beta * info["beta"], -1.0, 1.0)
    return np.stack([steer, np.zeros_like(steer)], -1).astype(np.float32)


def collect(n_envs: int, n_steps: int, seed: int = 0, sigma: float = 0.1) -> TensorDict:
    """Transitions (n_envs, n_steps) from the controller plus OU noise, learner convention."""
    env = FakeLaneDrive(n_envs, seed)
    noise = OrnsteinUhlenbeck(n_envs, 2, sigma=sigma, seed=seed)
    obs, info = env.observation(), env.info()
    steps = []
    for _ in range(n_steps):
        action = np.clip(steering_controller(info) + noise.sample(), -1.0, 1.0)
        next_obs, reward, terminated, truncated, next_info = env.step(action)
        steps.append(
            {
                **obs,
                "alpha": info["alpha"][:, None],
                "beta": info["beta"][:, None],
                "action": action,
                "next": {
                    **next_obs,
                    "alpha": next_info["alpha"][:, None],
                    "beta": next_info["beta"][:, None],
                    "reward": reward[:, None],
                    "terminated": terminated[:, None],
                    "truncated": truncated[:, None],
                },
            }
        )
        done = terminated | truncated
        if done.any():
            env.reset(done)
            noise.reset(done)
            next_obs, next_info = env.observation(), env.info()
        obs, info = next_obs, next_info
    td = TensorDict(_stack(steps), batch_size=[n_steps, n_envs])
    return td.transpose(0, 1).contiguous()


def _stack(steps: list[dict]) -> dict:
    """List over time of nested dicts of (n_envs, ...) arrays -> nested dict of tensors."""
    return {
        k: _stack([s[k] for s in steps]) if isinstance(v, dict) else torch.as_tensor(np.stack([s[k] for s in steps]))
        for k, v in steps[0].items()
    }


class CountingVectorEnv:
    """The LaneDriveVectorEnv contract (same-step autoreset, final_obs / final_info, on_episode_end)
    with content that tells what happened: every camera frame is filled with its step index in
    the episode (mod 256), alpha = step / 100, and car i's episodes end (terminated) after
    `episode_steps[i]` steps. For driving the real actor loop (actors.actor.run_actor) in tests."""

    def __init__(self, episode_steps: list[int], on_episode_end=None):
        self.num_envs = len(episode_steps)
        self.length = np.asarray(episode_steps)
        self.on_episode_end = on_episode_end
        self.t = np.zeros(self.num_envs, np.int64)
        self.last_action = np.zeros((self.num_envs, 2), np.float32)
        self.closed = False

    def _obs(self):
        image = np.empty((self.num_envs, 2, H, W), np.uint8)
        for i, t in enumerate(self.t):
            image[i, 0], image[i, 1] = t % 256, max(t - 1, 0) % 256
        return {
            "image": image,
            "speed": np.full((self.num_envs, 1), 0.5, np.float32),
            "last_action": self.last_action.copy(),
        }

    def _info(self):
        return {
            "alpha": self.t / 100.0,
            "beta": np.zeros(self.num_envs),
            "track": np.array(["alder"] * self.num_envs),
            "steps": self.t.copy(),
        }

    def reset(self, seed=None):
        self.t[:] = 0
        return self._obs(), self._info()

    def step(self, actions):
        self.t += 1
        self.last_action = np.asarray(actions, np.float32).copy()
        terminated = self.t >= self.length
        truncated = np.zeros(self.num_envs, bool)
        reward = np.ones(self.num_envs)
        info = self._info()
        if terminated.any():
            final = self._obs()
            info["final_obs"] = np.array(
                [{k: v[i] for k, v in final.items()} if terminated[i] else None for i in range(self.num_envs)],
                dtype=object,
            )
            info["final_info"] = {k: v.copy() for k, v in info.items() if k != "final_obs"}
            for i in np.flatnonzero(terminated):
                if self.on_episode_end is not None:
                    self.on_episode_end(int(i), {k: v[i] for k, v in info["final_info"].items()})
                self.t[i], self.last_action[i] = 0, 0.0
            info.update(self._info())
        return self._obs(), reward, terminated, truncated, info

    def close(self):
        self.closed = True
