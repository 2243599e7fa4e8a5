"""Schema of a whole run (Hydra's root config) and of the actor, learner and launcher roles.

`conf/config.yaml` composes it from the groups env, agent, scale and transport; `register()`
stores every schema in Hydra's ConfigStore so that each YAML file is checked against its
dataclass (a misspelt or mistyped field is refused with the field's name).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Optional

from omegaconf import MISSING

from common.config.agent import AgentConfig, ScaleConfig
from common.config.env import EnvConfig
from common.config.transport import ZENOH_WAIT_BEFORE_CLOSE_S, TransportConfig
from common.wire_quant import WEIGHTS_DTYPES


@dataclass
class ActorConfig:
    """One actor process: several simulator instances, batched acting, OU exploration."""

    name: str = "actor-0"
    """Unique name of this actor on the wire (key gvf/<run>/transitions/<name>)."""
    num_envs: int = 4
    """Simulator instances stepped together in this process."""
    chunk_len: int = 32
    """Steps per transition chunk (a chunk also ends with its episode)."""
    seed: int = 0
    """Seed of the simulators and the exploration noise (the launcher offsets it per actor)."""
    ou_theta: float = 1.0
    """OU mean reversion (paper: 1.0)."""
    ou_sigma: float = 0.1
    """OU noise scale (paper: 0.1)."""
    ou_dt: float = 0.01
    """OU time step (paper: 0.01); theta * dt = 1 makes the noise white: Gaussian with std sigma * sqrt(dt)."""
    ou_steer_theta: Optional[float] = None
    """The steering's own OU mean reversion (None: ou_theta); 100 (theta * dt = 1) makes only the
    steering's noise white, the target speed (acting through a 1-s lag) keeping the slow OU."""
    ou_steer_sigma: Optional[float] = None
    """The steering's own OU noise scale (None: ou_sigma)."""
    ou_speed_theta: Optional[float] = None
    """The target speed's own OU mean reversion (None: ou_theta)."""
    ou_speed_sigma: Optional[float] = None
    """The target speed's own OU noise scale (None: ou_sigma): wider, the replay holds drives through
    the same bends at more than one speed, which the critic needs to learn what the speed costs there."""
    send_queue: int = 256
    """Chunks waiting for the network before the oldest is dropped (and counted)."""
    send_timeout_s: float = 0.5
    """Longest the simulator waits for room in the send queue."""
    weights_poll_s: float = 1.0
    """How often an actor without weights asks the learner for them."""
    max_env_steps: int = 0
    """Stop after this many env steps in total (0: run until stopped)."""
    torch_threads: int = 1
    """Torch threads for acting (actors share cores with their simulators)."""
    track_split: str = "train"
    """Roads for priority track sampling: 'train', 'test' or 'all' (procedural roads bypass it)."""


@dataclass
class ActorsConfig:
    """How many actors the single-machine launcher starts."""

    count: int = 2
    """Actor processes started by gvf-train."""
    restart_backoff_s: float = 1.0
    """First wait before restarting a crashed actor; doubles per crash, capped at 30 s."""


@dataclass
class LearnerConfig:
    """The learner service: ingest, rate-limited training, weight broadcast, checkpoints."""

    device: str = "auto"
    """'cpu', 'cuda' or 'auto' (cuda when available)."""
    samples_per_insert: float = 8.0
    """Sampled transitions per inserted transition (rate limit; the learner neither starves nor overfits)."""
    publish_every: int = 50
    """Broadcast the acting weights every this many updates."""
    checkpoint_every: int = 2000
    """Checkpoint every this many updates (and at shutdown)."""
    checkpoint_dir: str = "checkpoints"
    """Where checkpoints are written (relative paths are under the run directory)."""
    checkpoint_replay: bool = False
    """Also save the replay buffer in checkpoints (large)."""
    track_table_every_s: float = 5.0
    """Publish the global track table this often."""
    ingest_batch: int = 64
    """Most chunks decoded and inserted per loop iteration."""
    max_tracks: int = 1024
    """Most roads in the global track table; episode summaries naming more are refused (kind 'track')."""
    max_chunk_bytes: int = 16 * 1024 * 1024
    """Largest transition chunk accepted; bigger ones are counted (kind 'size') and dropped."""
    inbox_chunks: int = 512
    """Chunks waiting to be ingested before new ones are dropped (and counted); bounds memory."""
    inbox_wait_s: float = 0.0
    """A chunk that finds the inbox full waits this long for room before it is dropped (0: drop at once,
    counted). Zenoh's reader stalls meanwhile, so BLOCK actors slow down instead of losing chunks, but
    everything else to the learner waits too: off by default, as at 256 actors 1 s starved the weights
    and acks (p99 1.2-5.6 s) and lost more chunks than it saved (README, capacity). < 5 s (zenoh's
    wait_before_close)."""
    max_updates: int = 0
    """Stop after this many updates (0: run until stopped)."""
    torch_threads: int = 2
    """Torch threads on CPU."""
    max_owed_updates: int = 64
    """Ask the actors to pause while the data (ingested or in the inbox) is more than this many updates ahead of samples_per_insert (or of the warm-up); 0: never."""
    flow_refresh_s: float = 1.0
    """Seconds between repeats of the learner's pause / resume (late actors learn it; a stale pause expires)."""
    rho_at: str = "learner"
    """Where log mu_hat of rho = tau / mu_hat is computed at insert: 'learner' (Algorithm 1), or 'actor':
    the weights carry the discriminator and actors send log mu_hat in each chunk (GVF variants only)."""
    weights_dtype: str = "float32"
    """Precision of the broadcast weights: 'float32', 'float16' (half the bytes to every actor), or 'uint8'
    (a quarter: 8-bit codes with a scale per row, `common.wire_quant`); actors act in float32."""


@dataclass
class EvalConfig:
    """Evaluation without exploration noise: `gvf-eval`, and periodically during training."""

    split: str = "test"
    """Roads driven: 'test', 'train' or 'all'."""
    directions: list = field(default_factory=lambda: ["ccw", "cw"])
    """Driving directions, each road once per direction."""
    damaged: bool = False
    """Evaluate with damaged lane markings (the env.damage of env=lanedrive_damaged if unset)."""
    every_updates: int = 0
    """gvf-train: evaluate the broadcast policy every this many learner updates (0: never)."""
    validation_tracks: list = field(default_factory=lambda: [f"procedural:{seed}" for seed in range(9001, 9007)])
    """gvf-train: roads (neither train nor test) on which the periodic evaluator picks its best policy."""
    online_too: bool = False
    """gvf-train with `scale.policy_average`: each evaluation also drives the online policy on the same
    roads, recorded under 'online' in eval.jsonl (the average against the policy it averages, same run)."""
    video: bool = False
    """gvf-eval: also write lap.gif, one lap of the first road (top-down view beside the camera image)."""
    runs: Optional[str] = None
    """gvf-eval: a run (or multirun) folder whose eval.jsonl files give learning curves."""
    out_dir: Optional[str] = None
    """gvf-eval: where reports go (default: Hydra's run folder)."""


@dataclass
class CollectConfig:
    """`gvf-collect`: logged data from the random-walk controller for offline learning (common.dataset)."""

    out: str = "datasets/lanedrive"
    """Dataset folder (created, or appended to with a new seed)."""
    transitions: int = 100_000
    """Transitions to collect in all."""
    workers: int = 2
    """Collector processes."""
    cars: int = 4
    """LaneDrive cars stepped together in each process."""
    shard_size: int = 5_000
    """Transitions per shard file set (the unit that is written atomically)."""
    split: str = "train"
    """Roads driven: 'train' (the paper's), 'test' or 'all'."""
    action_noise: float = 0.15
    """Std of a truncated normal around each of the controller's actions (0: the paper's controller
    alone, with which GVF-BCQ lapped none of the test roads); its density is stored as log_mu
    (actors/collect.py says why it exists)."""


@dataclass
class OfflineConfig:
    """`gvf-offline`: Algorithm 2 then BCQ (GVF-BCQ), or BCQ on images (E2E-BCQ), from a dataset."""

    dataset: str = "datasets/lanedrive"
    """Dataset folder written by gvf-collect."""
    method: str = "gvf_bcq"
    """'gvf_bcq' (GVFs and g by Algorithm 2, then BCQ on phi) or 'e2e_bcq' (BCQ on images, as many updates)."""
    gvf_updates: int = 20_000
    """Algorithm 2 updates (the paper: 5M, the first half of its updates)."""
    bcq_updates: int = 20_000
    """BCQ updates after them (the paper: 5M); E2E-BCQ makes gvf_updates + bcq_updates."""
    loading: str = "recorded"
    """'recorded': shards enter a growing FIFO replay in recorded order (shard order shuffled), as the
    paper loaded its rosbags; 'full': the whole dataset is in the replay before the first update."""
    replay: int = 0
    """Replay capacity for Algorithm 2 (0: the whole dataset; the paper: 0.5M of its 1.5M)."""
    start: int = 10_000
    """Transitions in the replay before the first update ('recorded'; the paper: 0.1M)."""
    load_fraction: float = 0.5
    """'recorded': the last transition enters the replay at this fraction of gvf_updates."""
    lr: float = 1e-4
    """BCQ's learning rate (the paper: 1e-4; the GVFs' and g's are the scale's)."""
    mirror: float = 0.0
    """Fraction of every BCQ minibatch mirrored left-right, GVF-BCQ and E2E-BCQ alike (the paper
    augmented its Jackal data with flipped images; the GVFs follow `scale.mirror`); 0: none."""
    checkpoint_dir: str = "checkpoints/offline"
    """Where gvf-offline writes its checkpoints, under the run folder if relative (gvf-eval reads them)."""


@dataclass
class RunConfig:
    """A whole run: `gvf-train`, `gvf-learner`, `gvf-actor` and `gvf-router` all read this."""

    run: str = "default"
    """Run name: the key prefix gvf/<run>/ and the TensorBoard folder."""
    seed: int = 0
    """Seed of networks and simulators."""
    resume: bool = False
    """Learner: restore the latest checkpoint in learner.checkpoint_dir."""
    progress: bool = True
    """gvf-train: show a live progress display."""
    env: EnvConfig = field(default_factory=EnvConfig)
    agent: Any = MISSING
    scale: Any = MISSING
    transport: TransportConfig = field(default_factory=TransportConfig)
    actor: ActorConfig = field(default_factory=ActorConfig)
    actors: ActorsConfig = field(default_factory=ActorsConfig)
    learner: LearnerConfig = field(default_factory=LearnerConfig)
    eval: EvalConfig = field(default_factory=EvalConfig)
    collect: CollectConfig = field(default_factory=CollectConfig)
    offline: OfflineConfig = field(default_factory=OfflineConfig)
    checkpoint: Optional[str] = None
    """gvf-eval: a learner checkpoint file, or a folder to take the newest from."""
    policy: str = "checkpoint"
    """gvf-eval: 'checkpoint' (the network in `checkpoint`) or 'kinematic' (the classical controller)."""
    max_seconds: Optional[float] = None
    """Stop the run after this many seconds (None: until Ctrl-C)."""


def register() -> None:
    """Store the schemas in Hydra's ConfigStore (YAML files name them in their defaults)."""
    from hydra.core.config_store import ConfigStore

    from common.config import agent

    agent.register()
    store = ConfigStore.instance()
    store.store(name="run_schema", node=RunConfig)
    store.store(group="env", name="env_schema", node=EnvConfig)
    store.store(group="transport", name="transport_schema", node=TransportConfig)


RHO_AT = ("learner", "actor")


def to_objects(cfg: Any) -> tuple[RunConfig, AgentConfig, ScaleConfig]:
    """A composed DictConfig as typed dataclass objects (validated)."""
    from omegaconf import OmegaConf

    from common.config.agent import actor_squash, check_agent, check_scale

    run = OmegaConf.to_object(cfg)
    run.env.validate()
    actor_squash(run.agent, run.scale)  # refuses a bad value naming the field
    check_scale(run.scale)
    check_agent(run.agent)
    a = run.actor
    # past 1 the Euler step overshoots the mean: the noise oscillates
    for name in ("ou_theta", "ou_steer_theta", "ou_speed_theta"):
        theta = getattr(a, name)
        if theta is not None and not 0.0 < theta * a.ou_dt <= 1.0:
            raise ValueError(f"actor.{name} * actor.ou_dt must be in (0, 1], got {theta} * {a.ou_dt}")
    for name in ("ou_sigma", "ou_steer_sigma", "ou_speed_sigma"):
        if (getattr(a, name) or 0.0) < 0:
            raise ValueError(f"actor.{name} must be >= 0, got {getattr(a, name)}")
    if run.learner.rho_at not in RHO_AT:
        raise ValueError(f"learner.rho_at must be one of {RHO_AT}, got {run.learner.rho_at!r}")
    if not 0.0 <= run.learner.inbox_wait_s < ZENOH_WAIT_BEFORE_CLOSE_S:
        raise ValueError(
            f"learner.inbox_wait_s must be in [0, {ZENOH_WAIT_BEFORE_CLOSE_S}) (zenoh closes a link blocked"
            f" that long), got {run.learner.inbox_wait_s}"
        )
    if run.learner.weights_dtype not in WEIGHTS_DTYPES:
        raise ValueError(f"learner.weights_dtype must be one of {WEIGHTS_DTYPES}, got {run.learner.weights_dtype!r}")
    check_offline(run)
    if run.eval.online_too and not run.scale.policy_average:
        raise ValueError(
            "eval.online_too needs scale.policy_average > 0 (without an average the online policy is the one driven)"
        )
    if run.learner.rho_at == "actor" and run.agent.representation != "predictive":
        raise ValueError(f"learner.rho_at=actor needs a GVF variant, agent {run.agent.name!r} has no discriminator")
    return run, run.agent, run.scale


SPLITS = ("train", "test", "all")
OFFLINE_METHODS = ("gvf_bcq", "e2e_bcq")
LOADINGS = ("recorded", "full")


def check_offline(run: RunConfig) -> None:
    """Refuse a bad collect.* or offline.* value, naming the field."""
    c, o = run.collect, run.offline
    for name, value in (
        ("transitions", c.transitions),
        ("workers", c.workers),
        ("cars", c.cars),
        ("shard_size", c.shard_size),
    ):
        if value < 1:
            raise ValueError(f"collect.{name} must be >= 1, got {value}")
    if not 0.0 <= c.action_noise <= 2.0:
        raise ValueError(f"collect.action_noise must be in [0, 2], got {c.action_noise}")
    if c.split not in SPLITS:
        raise ValueError(f"collect.split must be one of {SPLITS}, got {c.split!r}")
    if o.method not in OFFLINE_METHODS:
        raise ValueError(f"offline.method must be one of {OFFLINE_METHODS}, got {o.method!r}")
    if o.loading not in LOADINGS:
        raise ValueError(f"offline.loading must be one of {LOADINGS}, got {o.loading!r}")
    for name in ("gvf_updates", "bcq_updates", "replay", "start"):
        if getattr(o, name) < 0:
            raise ValueError(f"offline.{name} must be >= 0, got {getattr(o, name)}")
    if not o.lr > 0.0:
        raise ValueError(f"offline.lr must be > 0, got {o.lr}")
    if not 0.0 <= o.mirror <= 1.0:
        raise ValueError(f"offline.mirror must be in [0, 1], got {o.mirror}")
    if not 0.0 < o.load_fraction <= 1.0:
        raise ValueError(f"offline.load_fraction must be in (0, 1], got {o.load_fraction}")
