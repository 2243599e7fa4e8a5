"""`gvf-collect`: log driving data for the offline half of the paper (appendix "Data
collection"): `collect.workers` processes each drive `collect.cars` LaneDrive cars on the
training roads with the random-walk pure-pursuit controller (`actors.controllers.random_walk`,
built anew for each episode) and append shards to one dataset (`common.dataset`).

    gvf-collect collect.out=datasets/lanedrive collect.transitions=100000 collect.workers=2

The controller's noise is in its targets, not its actions, so its action density is unknown:
`log_mu` is NaN and Algorithm 2 estimates mu with the discriminator, as the paper did. With
`collect.action_noise` > 0 each action is drawn from a normal around the controller's, truncated
to the box (independent per dimension and step), and its density is known and stored. Why it
exists: on LaneDrive the controller's targets lie a pure-pursuit look-ahead (16 m) ahead, so its
random walk of the targets moves the steering by ~0.002 a step, where the Jackal's targets a few
centimetres ahead made the same walk swing its steering; without noise the data holds about one
action per state, and BCQ, which can only choose among the actions the data supports, has no
choice to make (measured: its VAE's KL fell to 1e-7, and GVF-BCQ imitated the controller's
last-action habit off the road within 1-2 s, docs/results-offline.md).
Appending again with another `seed` adds episodes; the same seed twice is refused (its
episodes would repeat).
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import queue
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np
import torch
from tensordict import TensorDict

from actors.controllers.random_walk import for_lane_drive, lane_drive_pose
from actors.envs.lane_drive import LaneDriveVectorEnv
from common.dataset import FIELDS, DatasetError, DatasetWriter, _read_manifest
from common.density import log_truncated_normal

log = logging.getLogger(__name__)
EPISODE_BITS = 32  # episode id = (writer id << 32) | episode count of that writer


def writer_name(seed: int, worker: int) -> str:
    return f"s{seed}w{worker}"


class ShardBuffer:
    """Steps of `cars` cars accumulated as arrays until a shard's worth is written."""

    def __init__(self) -> None:
        self.steps: list[dict[str, np.ndarray]] = []
        self.count = 0

    def add(self, step: dict[str, np.ndarray]) -> None:
        self.steps.append(step)
        self.count += len(step["action"])

    def take(self, limit: int | None = None) -> tuple[TensorDict, list[str]]:
        """The buffered steps (at most `limit` transitions) as a shard TensorDict and its road list."""
        cols = {k: np.concatenate([s[k] for s in self.steps]) for k in self.steps[0]}
        if limit is not None:
            cols = {k: v[:limit] for k, v in cols.items()}
        names = cols.pop("track_name")
        tracks = sorted(set(names.tolist()))
        index = {name: i for i, name in enumerate(tracks)}
        cols["track"] = np.array([index[n] for n in names], np.int16).reshape(-1, 1)
        td = TensorDict(
            {k: torch.from_numpy(np.ascontiguousarray(v)).to(FIELDS[k][0]) for k, v in cols.items()},
            batch_size=[len(cols["action"])],
        )
        self.steps, self.count = [], 0
        return td, tracks


def _step_record(obs, info, action, next_obs, reward, terminated, truncated, next_info, episode, step) -> dict:
    """One env step of every car as the dataset's columns (next state from final_obs where a car reset)."""
    n = len(action)
    next_frame = next_obs["image"][:, :1].copy()
    next_speed, next_alpha, next_beta = next_obs["speed"].copy(), next_info["alpha"].copy(), next_info["beta"].copy()
    done = terminated | truncated
    for i in np.flatnonzero(done):
        final, final_info = next_info["final_obs"][i], next_info["final_info"]
        next_frame[i] = final["image"][:1]
        next_speed[i] = final["speed"]
        next_alpha[i], next_beta[i] = final_info["alpha"][i], final_info["beta"][i]
    col = lambda x: np.asarray(x, np.float32).reshape(n, 1)  # noqa: E731
    return {
        "image": obs["image"].copy(),
        "speed": col(obs["speed"]),
        "last_action": obs["last_action"].astype(np.float32),
        "alpha": col(info["alpha"]),
        "beta": col(info["beta"]),
        "action": action.astype(np.float32),
        "next_frame": next_frame,
        "next_speed": col(next_speed),
        "next_alpha": col(next_alpha),
        "next_beta": col(next_beta),
        "reward": col(reward),
        "terminated": terminated.reshape(n, 1).astype(bool),
        "truncated": truncated.reshape(n, 1).astype(bool),
        "track_name": np.asarray(info["track"]),
        "episode": episode.reshape(n, 1).copy(),
        "step": step.reshape(n, 1).astype(np.int32),
    }


def truncated_normal(rng: np.random.Generator, mean: np.ndarray, std: float) -> np.ndarray:
    """Samples of N(mean, std^2) truncated to [-1, 1], per element (redrawn until inside)."""
    out = mean + std * rng.standard_normal(mean.shape)
    bad = np.abs(out) > 1.0
    while bad.any():
        out[bad] = mean[bad] + std * rng.standard_normal(int(bad.sum()))
        bad = np.abs(out) > 1.0
    return out.astype(np.float32)


def collect_worker(
    root: str,
    seed: int,
    worker: int,
    quota: int,
    cars: int,
    shard_size: int,
    env_kwargs: dict,
    progress=None,
    action_noise: float = 0.0,
) -> int:
    """Drive `cars` cars with the random-walk controller until `quota` transitions are written."""
    torch.set_num_threads(1)
    rng = np.random.default_rng([seed, worker])
    writer = DatasetWriter(root, writer_name(seed, worker))
    env = LaneDriveVectorEnv(cars, **env_kwargs)
    obs, info = env.reset(seed=[int(s) for s in rng.integers(2**31, size=cars)])
    controllers = [for_lane_drive(env, rng, i) for i in range(cars)]
    writer_id = seed * 1000 + worker
    episode = (writer_id << EPISODE_BITS) + np.arange(cars, dtype=np.int64)
    next_episode = cars
    step = np.zeros(cars, np.int64)
    buffer, written = ShardBuffer(), 0
    while written < quota:
        action = np.stack([c.act(lane_drive_pose(env, i)) for i, c in enumerate(controllers)])
        log_mu = np.full((cars, 1), np.nan, np.float32)
        if action_noise > 0:
            mean, action = action, truncated_normal(rng, action.astype(np.float64), action_noise)
            log_mu = log_truncated_normal(torch.from_numpy(action), torch.from_numpy(mean), action_noise).numpy()
        next_obs, reward, terminated, truncated, next_info = env.step(action)
        record = _step_record(obs, info, action, next_obs, reward, terminated, truncated, next_info, episode, step)
        record["log_mu"] = log_mu.astype(np.float32)
        buffer.add(record)
        step += 1
        for i in np.flatnonzero(terminated | truncated):
            controllers[i] = for_lane_drive(env, rng, int(i))  # the car already stands on its next road
            episode[i], step[i] = (writer_id << EPISODE_BITS) + next_episode, 0
            next_episode += 1
        obs, info = next_obs, next_info
        if buffer.count >= min(shard_size, quota - written):
            td, tracks = buffer.take(quota - written)
            writer.append(td, tracks)
            written += len(td)
            if progress is not None:
                progress.put(len(td))
    return written


def _refuse_repeat(root: Path, seed: int) -> None:
    if (root / "manifest.json").exists():
        names = [s["name"] for s in _read_manifest(root)["shards"]]
        if any(n.startswith(f"shard-s{seed}w") for n in names):
            raise DatasetError(f"{root} already holds data collected with seed={seed}: append with another seed")


def collect(cfg, root: str | Path, show_progress: bool = True) -> dict:
    """Run `cfg.collect.workers` collector processes (spawn) into `root`; returns a summary."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    c = cfg.collect
    root = Path(root)
    _refuse_repeat(root, cfg.seed)
    env_kwargs = asdict(cfg.env)
    env_kwargs.pop("id")
    # no gusts: the random walk is the collection's own exploration (the paper's); gusts are the online learner's
    env_kwargs.update(track=c.split, direction="random", random_start=True, gust_rate=0.0)
    meta = {"controller": "random_walk", "action_noise": c.action_noise, "env": env_kwargs, "split": c.split}
    DatasetWriter(root, "init", meta=meta)
    quotas = [c.transitions // c.workers + (w < c.transitions % c.workers) for w in range(c.workers)]
    ctx = mp.get_context("spawn")
    counts = ctx.Queue()
    start = time.perf_counter()
    procs = [
        ctx.Process(
            target=collect_worker,
            args=(str(root), cfg.seed, w, q, c.cars, c.shard_size, env_kwargs, counts, c.action_noise),
            name=f"collector-{w}",
        )
        for w, q in enumerate(quotas)
        if q > 0
    ]
    for p in procs:
        p.start()
    done = 0
    columns = (TextColumn("collecting"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn())
    with Progress(*columns, disable=not show_progress) as bar:
        task = bar.add_task("collect", total=c.transitions)
        while any(p.is_alive() for p in procs) or not counts.empty():
            try:
                n = counts.get(timeout=0.5)
            except queue.Empty:
                continue
            done += n
            bar.update(task, completed=done)
    for p in procs:
        p.join()
    failed = [p.name for p in procs if p.exitcode != 0]
    if failed:
        raise RuntimeError(f"collector processes failed: {failed} (shards they finished are kept)")
    seconds = time.perf_counter() - start
    return {"transitions": done, "seconds": round(seconds, 2), "steps_per_s": round(done / seconds, 1)}


def task(cfg) -> None:
    from common.config.run import to_objects

    run, _, _ = to_objects(cfg)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    result = collect(run, run.collect.out, show_progress=run.progress)
    print(
        f"collected {result['transitions']:,} transitions in {result['seconds']:.0f} s "
        f"({result['steps_per_s']:,.0f}/s) into {Path(run.collect.out).resolve()}"
    )


def main() -> None:
    from common.cli import hydra_entry

    hydra_entry(task)()


if __name__ == "__main__":
    main()
