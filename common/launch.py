"""`gvf-train`: a whole run on one machine, and `gvf-router`.

Starts a Zenoh router, the learner and `actors.count` actors as child processes (spawn: a
fork after zenoh is initialised hangs the child), restarts a crashed actor with exponential
backoff (and a crashed learner from its checkpoint), shows live progress, and stops
everything on Ctrl-C, SIGTERM, a 'stop' control message or `max_seconds`.
With `serial=true` the learner and the actors run as threads of this one process over the
in-process transport instead (debugging, fast tests).

Roles are named by "module:function" strings and imported in the child, so this module (in
`common`) never imports `actors` or `learner`: they meet only on the wire.
"""

from __future__ import annotations

import dataclasses
import importlib
import logging
import multiprocessing as mp
import threading
import time
from pathlib import Path

from common.config.run import RunConfig

log = logging.getLogger(__name__)
LEARNER = "learner.service:run_learner"
ACTOR = "actors.actor:run_actor"
EVALUATOR = "actors.evaluation.periodic:run_evaluator"
MAX_BACKOFF_S = 30.0


def resolve(target: str):
    module, name = target.split(":")
    return getattr(importlib.import_module(module), name)


def actor_config(cfg: RunConfig, index: int) -> RunConfig:
    """The config of actor `index`: its own name and seed."""
    actor = dataclasses.replace(cfg.actor, name=f"actor-{index}", seed=cfg.actor.seed + 1000 * (index + 1) + cfg.seed)
    return dataclasses.replace(cfg, actor=actor)


def _child(role: str, cfg: RunConfig, run_dir: str, log_name: str) -> None:
    """Body of a child process: log to a file, stop on SIGINT/SIGTERM, run the role."""
    from common.cli import stop_on_signals

    Path(run_dir, "logs").mkdir(parents=True, exist_ok=True)
    logging.basicConfig(filename=str(Path(run_dir, "logs", f"{log_name}.log")), level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    stop = stop_on_signals()
    if role == "router":
        from common.zenoh_transport import run_router

        run_router(cfg.transport, stop)
    elif role == "learner":
        resolve(LEARNER)(cfg, None, run_dir, stop)
    elif role == "evaluator":
        resolve(EVALUATOR)(cfg, None, run_dir, stop)
    else:
        resolve(ACTOR)(cfg, None, stop)


@dataclasses.dataclass
class Child:
    """One supervised process and its restart schedule."""

    role: str
    name: str
    cfg: RunConfig
    proc: mp.Process | None = None
    restarts: int = 0
    next_start: float = 0.0


class Supervisor:
    """Starts, watches and restarts the processes of one run."""

    def __init__(self, cfg: RunConfig, run_dir: str) -> None:
        self.cfg, self.run_dir = cfg, run_dir
        self.ctx = mp.get_context("spawn")
        self.children: list[Child] = []
        if cfg.transport.backend == "zenoh" and cfg.transport.mode == "client":
            self.children.append(Child("router", "router", cfg))
        self.children.append(Child("learner", "learner", cfg))
        self.children += [Child("actor", f"actor-{i}", actor_config(cfg, i)) for i in range(cfg.actors.count)]
        if cfg.eval.every_updates > 0:
            self.children.append(Child("evaluator", "evaluator", cfg))

    def start(self, child: Child) -> None:
        child.proc = self.ctx.Process(target=_child, args=(child.role, child.cfg, self.run_dir, child.name), name=child.name, daemon=False)
        child.proc.start()
        log.info("started %s (pid %d)", child.name, child.proc.pid)

    def start_all(self) -> None:
        for child in self.children:
            self.start(child)
            if child.role == "router":
                time.sleep(0.5)  # clients give up after transport.connect_timeout_s; give the router a head start

    def watch(self) -> None:
        """Restart whatever has exited, after its backoff."""
        now = time.monotonic()
        for child in self.children:
            if child.proc is None or child.proc.is_alive():
                continue
            if child.next_start == 0.0:
                backoff = min(MAX_BACKOFF_S, self.cfg.actors.restart_backoff_s * 2**child.restarts)
                child.next_start = now + backoff
                log.warning("%s exited with %s; restarting in %.1f s", child.name, child.proc.exitcode, backoff)
            elif now >= child.next_start:
                child.restarts += 1
                child.next_start = 0.0
                if child.role == "learner":
                    child.cfg = dataclasses.replace(child.cfg, resume=True)
                self.start(child)

    def stop_all(self, timeout: float = 10.0) -> None:
        """SIGTERM every child (router last), wait, then kill what is left."""
        order = [c for c in self.children if c.role in ("actor", "evaluator")] + [c for c in self.children if c.role == "learner"] + [c for c in self.children if c.role == "router"]
        for group in (order[:-1], order[-1:]):
            for c in group:
                if c.proc is not None and c.proc.is_alive():
                    c.proc.terminate()
            deadline = time.monotonic() + timeout
            for c in group:
                if c.proc is not None:
                    c.proc.join(max(0.1, deadline - time.monotonic()))
                    if c.proc.is_alive():
                        log.warning("%s did not stop in %.0f s; killing it", c.name, timeout)
                        c.proc.kill()
                        c.proc.join(5)


def run_serial(cfg: RunConfig, run_dir: str, stop: threading.Event) -> dict:
    """Learner and actors as threads of this process over one in-process bus."""
    from common.inproc_transport import Bus
    from common.transport import make_transport

    bus = Bus()
    tcfg = dataclasses.replace(cfg.transport, backend="inproc")
    cfg = dataclasses.replace(cfg, transport=tcfg)
    result: dict = {}
    learner_t = make_transport(tcfg, bus)
    learner = threading.Thread(target=lambda: result.update(resolve(LEARNER)(cfg, learner_t, run_dir, stop)), name="learner")
    learner.start()
    actors = []
    roles = [(ACTOR, (actor_config(cfg, i),), f"actor-{i}") for i in range(cfg.actors.count)]
    if cfg.eval.every_updates > 0:
        roles.append((EVALUATOR, (cfg,), "evaluator"))
    for target, args, name in roles:
        t = make_transport(tcfg, bus)
        extra = (run_dir,) if target == EVALUATOR else ()
        th = threading.Thread(target=resolve(target), args=(*args, t, *extra, stop), name=name)
        th.start()
        actors.append((th, t))
    try:
        start = time.monotonic()
        while learner.is_alive() and not stop.is_set():
            if cfg.max_seconds and time.monotonic() - start > cfg.max_seconds:
                break
            time.sleep(0.1)
    finally:
        stop.set()
        for th, t in actors:
            th.join(30)
            t.close()
        learner.join(60)
        learner_t.close()
    return result


def train(cfg: RunConfig, run_dir: str, stop: threading.Event) -> None:
    """The body of `gvf-train` once the config is composed."""
    from common.progress import Progress

    if cfg.serial:
        run_serial(cfg, run_dir, stop)
        return
    sup = Supervisor(cfg, run_dir)
    progress = Progress(Path(run_dir), enabled=cfg.progress)
    start = time.monotonic()
    try:
        sup.start_all()
        with progress:
            while not stop.is_set():
                if cfg.max_seconds and time.monotonic() - start > cfg.max_seconds:
                    break
                sup.watch()
                progress.update(sup.children)
                stop.wait(0.5)
    finally:
        sup.stop_all()
    log.info("run finished: %s", progress.last)


def task(cfg) -> None:
    """Hydra task of `gvf-train`."""
    from hydra.core.hydra_config import HydraConfig

    from common.cli import stop_on_signals
    from common.config.run import to_objects

    run, _, _ = to_objects(cfg)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    train(run, HydraConfig.get().runtime.output_dir, stop_on_signals())


def router_task(cfg) -> None:
    """Hydra task of `gvf-router`: a Zenoh router from the python package."""
    from common.config.run import to_objects
    from common.zenoh_transport import run_router

    run, _, _ = to_objects(cfg)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    run_router(run.transport)


def main() -> None:
    from common.cli import hydra_entry

    hydra_entry(task)()


def router_main() -> None:
    from common.cli import hydra_entry

    hydra_entry(router_task)()
