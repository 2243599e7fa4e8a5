"""`gvf-train`: a whole run on one machine, and `gvf-router`.

Starts the roles of `common.roles` (a Zenoh router, the learner, `actors.count` actors and the
periodic evaluator) as spawned processes, or, with `transport=inproc`, as threads of this one
process over one in-process bus (debugging, fast tests). Either way one supervisor watches them:

- a crash (non-zero exit, a signal, an exception) is restarted after an exponential backoff; a
  crashed learner resumes from its checkpoint;
- a clean exit is final; a clean learner exit (`learner.max_updates`, a `stop` control message
  from `gvfctl stop`) ends the run and stops every other role;
- Ctrl-C, SIGTERM and `max_seconds` stop everything: actors and evaluator, then the learner
  (it checkpoints), then the router.
"""

from __future__ import annotations

import dataclasses
import logging
import threading
import time
from pathlib import Path

from common.config.run import RunConfig
from common.roles import ProcessRole, ThreadRole

log = logging.getLogger(__name__)
MAX_BACKOFF_S = 30.0
STOP_ORDER = ("actor", "evaluator", "learner", "router")


def actor_config(cfg: RunConfig, index: int) -> RunConfig:
    """The config of actor `index`: its own name and seed."""
    actor = dataclasses.replace(cfg.actor, name=f"actor-{index}", seed=cfg.actor.seed + 1000 * (index + 1) + cfg.seed)
    return dataclasses.replace(cfg, actor=actor)


def in_threads(cfg: RunConfig) -> bool:
    """`transport=inproc`: every role a thread of this process (the one serial switch)."""
    return cfg.transport.backend == "inproc"


@dataclasses.dataclass
class Child:
    """One supervised role and its restart schedule."""

    role: str
    name: str
    cfg: RunConfig
    handle: ThreadRole | ProcessRole | None = None
    restarts: int = 0
    next_start: float = 0.0
    done: bool = False
    """Exited cleanly: never restarted."""

    @property
    def alive(self) -> bool:
        return self.handle is not None and self.handle.alive()


class Supervisor:
    """Starts, watches, restarts and stops the roles of one run (see the module docstring)."""

    def __init__(self, cfg: RunConfig, run_dir: str) -> None:
        self.cfg, self.run_dir = cfg, run_dir
        self.threads = in_threads(cfg)
        self.bus = None
        if self.threads:
            from common.transport.inproc import Bus

            self.bus = Bus()
        self.children: list[Child] = []
        if not self.threads and cfg.transport.mode == "client":
            self.children.append(Child("router", "router", cfg))
        self.children.append(Child("learner", "learner", cfg))
        self.children += [Child("actor", f"actor-{i}", actor_config(cfg, i)) for i in range(cfg.actors.count)]
        if cfg.eval.every_updates > 0:
            self.children.append(Child("evaluator", "evaluator", cfg))
        self.ended: str | None = None
        """Why the run ended by itself (a role's clean exit), or None."""

    def start(self, child: Child) -> None:
        if self.threads:
            child.handle = ThreadRole(child.name, child.role, child.cfg, self.run_dir, self.bus)
        else:
            child.handle = ProcessRole(child.name, child.role, child.cfg, self.run_dir)
        child.handle.start()

    def start_all(self) -> None:
        for child in self.children:
            self.start(child)
            if child.role == "router":
                time.sleep(0.5)  # clients give up after transport.connect_timeout_s; give the router a head start

    def watch(self) -> bool:
        """Restart crashed roles after their backoff; True once a clean exit has ended the run."""
        from common.roles import spec_of

        now = time.monotonic()
        for child in self.children:
            if child.handle is None or child.done or child.handle.alive():
                continue
            code = child.handle.exitcode
            if code == 0:
                child.done = True
                log.info("%s exited cleanly", child.name)
                if spec_of(child.role).ends_run:
                    self.ended = f"{child.name} exited cleanly"
                continue
            if child.next_start == 0.0:
                backoff = min(MAX_BACKOFF_S, self.cfg.actors.restart_backoff_s * 2**child.restarts)
                child.next_start = now + backoff
                log.warning("%s crashed (exit %s); restarting in %.1f s", child.name, code, backoff)
            elif now >= child.next_start:
                child.restarts += 1
                child.next_start = 0.0
                if child.role == "learner":
                    child.cfg = dataclasses.replace(child.cfg, resume=True)
                self.start(child)
        return self.ended is not None

    def stop_all(self, timeout: float = 10.0) -> None:
        """Stop the roles in STOP_ORDER, each group given `timeout`; kill what is left."""
        for role in STOP_ORDER:
            group = [c for c in self.children if c.role == role and c.handle is not None]
            for c in group:
                c.handle.terminate()
            deadline = time.monotonic() + timeout
            for c in group:
                c.handle.join(max(0.1, deadline - time.monotonic()))
                if c.handle.alive():
                    log.warning("%s did not stop in %.0f s; killing it", c.name, timeout)
                    c.handle.kill()
                    c.handle.join(5)

    def learner_result(self) -> dict | None:
        """The learner's final counters when it ran in a thread (processes: progress.json)."""
        learner = next(c for c in self.children if c.role == "learner")
        return learner.handle.result if learner.handle is not None else None


def train(cfg: RunConfig, run_dir: str, stop: threading.Event) -> dict:
    """The body of `gvf-train` once the config is composed; returns the learner's last counters."""
    from common.progress import Progress

    sup = Supervisor(cfg, run_dir)
    progress = Progress(Path(run_dir), enabled=cfg.progress)
    start = time.monotonic()
    try:
        sup.start_all()
        with progress:
            while not stop.is_set():
                if cfg.max_seconds and time.monotonic() - start > cfg.max_seconds:
                    log.info("max_seconds=%s reached", cfg.max_seconds)
                    break
                if sup.watch():
                    log.info("run ended: %s", sup.ended)
                    break
                progress.update(sup.children)
                stop.wait(0.2 if sup.threads else 0.5)
    finally:
        sup.stop_all()
    result = sup.learner_result() or progress.read()
    ckpt = Path(cfg.learner.checkpoint_dir)
    progress.final(result, ckpt if ckpt.is_absolute() else Path(run_dir) / ckpt)
    log.info("run finished: %s", result)
    return result


def task(cfg) -> None:
    """Hydra task of `gvf-train`."""
    from hydra.core.hydra_config import HydraConfig

    from common.cli import stop_on_signals
    from common.config.run import to_objects

    run, _, _ = to_objects(cfg)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    train(run, HydraConfig.get().runtime.output_dir, stop_on_signals())


def main() -> None:
    from common.cli import hydra_entry

    hydra_entry(task)()


def router_main() -> None:
    from common.cli import role_main

    role_main("router")
