"""The role contract: every process kind of a run is one function with one signature, registered
by name in `ROLES`, and started the same way in a thread (`transport=inproc`) or a process.

    role(ctx: RoleContext) -> dict | None      # returns when ctx.stop is set or its work is done

A role never opens its own transport: `run_role` opens it from the config (Zenoh, or the
in-process `Bus` shared by the roles of one process), hands it over in the context and closes it.
What an exit means is one rule for all: a clean exit (the function returned; exit code 0) is
final, never restarted, and ends the whole run if `RoleSpec.ends_run` (the learner: its
`learner.max_updates`, or a `stop` control message); a crash (an exception, a non-zero exit code
or a signal) is restarted by the supervisor (`common.launch`).

Targets are "module:function" strings imported where the role runs, so `common` never imports
`actors` or `learner`: they meet only on the wire.
"""

from __future__ import annotations

import importlib
import logging
import multiprocessing as mp
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from common.config.run import RunConfig

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class RoleSpec:
    """One kind of process of a run."""

    name: str
    target: str
    """"module:function" of the role, called with a RoleContext."""
    ends_run: bool = False
    """A clean exit of this role ends the run (every other role is stopped)."""
    transport: bool = True
    """Whether the role is handed a transport (the router opens its own Zenoh router session)."""


ROLES: dict[str, RoleSpec] = {
    spec.name: spec
    for spec in (
        RoleSpec("router", "common.transport.zenoh_backend:router_role", transport=False),
        RoleSpec("learner", "learner.service:learner_role", ends_run=True),
        RoleSpec("actor", "actors.actor:actor_role"),
        RoleSpec("evaluator", "actors.evaluation.periodic:evaluator_role"),
    )
}


@dataclass
class RoleContext:
    """What every role is given."""

    cfg: RunConfig
    run_dir: Path
    stop: threading.Event
    transport: Any = None
    """A `common.transport.Transport` (None for a role with `transport=False`)."""


Role = Callable[[RoleContext], "dict | None"]


def role_function(name: str) -> Role:
    """The function of role `name`, imported now."""
    module, function = spec_of(name).target.split(":")
    return getattr(importlib.import_module(module), function)


def spec_of(name: str) -> RoleSpec:
    if name not in ROLES:
        raise ValueError(f"unknown role {name!r}; roles are {sorted(ROLES)}")
    return ROLES[name]


def check_standalone(cfg: RunConfig, role: str) -> None:
    """Refuse (naming the field) a role started on its own with a transport that cannot reach anyone."""
    if cfg.transport.backend == "inproc":
        raise ValueError(
            f"transport.backend=inproc puts every role in one process: gvf-{role} alone would talk "
            "to nobody; run `gvf-train transport=inproc`, or give this role transport=local"
        )


def run_role(name: str, cfg: RunConfig, run_dir: str | Path, stop: threading.Event, bus: Any = None) -> dict | None:
    """Run role `name` here until it returns: open its transport, call it, close the transport."""
    from common.transport import make_transport

    spec, fn = spec_of(name), role_function(name)
    ctx = RoleContext(cfg, Path(run_dir), stop)
    if not spec.transport:
        return fn(ctx)
    with make_transport(cfg.transport, bus, stop=stop) as t:
        ctx.transport = t
        return fn(ctx)


class ThreadRole:
    """A role in a thread of this process; exit code 0 when it returned, 1 when it raised."""

    def __init__(self, name: str, role: str, cfg: RunConfig, run_dir: str | Path, bus: Any) -> None:
        self.name, self.role = name, role
        role_function(
            role
        )  # imported here, in the starting thread: roles' first imports of torch in parallel threads can fail
        self.stop = threading.Event()
        self.exitcode: int | None = None
        self.result: dict | None = None
        self._thread = threading.Thread(target=self._body, args=(cfg, run_dir, bus), name=name, daemon=True)

    def _body(self, cfg: RunConfig, run_dir: str | Path, bus: Any) -> None:
        try:
            self.result = run_role(self.role, cfg, run_dir, self.stop, bus)
            self.exitcode = 0
        except BaseException:
            log.exception("%s crashed", self.name)
            self.exitcode = 1

    def start(self) -> None:
        self._thread.start()

    def alive(self) -> bool:
        return self._thread.is_alive()

    def terminate(self) -> None:
        self.stop.set()

    def kill(self) -> None:
        self.stop.set()  # a thread cannot be killed; a role polls its stop event

    def join(self, timeout: float | None = None) -> None:
        self._thread.join(timeout)


def _child(role: str, cfg: RunConfig, run_dir: str, log_name: str) -> None:
    """Body of a role's process: log to a file, stop on SIGINT/SIGTERM, run the role."""
    from common.cli import stop_on_signals

    Path(run_dir, "logs").mkdir(parents=True, exist_ok=True)
    logging.basicConfig(
        filename=str(Path(run_dir, "logs", f"{log_name}.log")),
        level=logging.INFO,
        format="%(asctime)s %(name)s %(levelname)s %(message)s",
    )
    run_role(role, cfg, run_dir, stop_on_signals())


class ProcessRole:
    """A role in a spawned process (a fork after zenoh is initialised hangs the child)."""

    CONTEXT = mp.get_context("spawn")

    def __init__(self, name: str, role: str, cfg: RunConfig, run_dir: str | Path) -> None:
        self.name, self.role = name, role
        self.result: dict | None = None
        self._proc = self.CONTEXT.Process(target=_child, args=(role, cfg, str(run_dir), name), name=name)

    def start(self) -> None:
        self._proc.start()
        log.info("started %s (pid %d)", self.name, self._proc.pid)

    @property
    def pid(self) -> int | None:
        return self._proc.pid

    @property
    def exitcode(self) -> int | None:
        return self._proc.exitcode

    def alive(self) -> bool:
        return self._proc.is_alive()

    def terminate(self) -> None:
        if self._proc.is_alive():
            self._proc.terminate()

    def kill(self) -> None:
        if self._proc.is_alive():
            self._proc.kill()

    def join(self, timeout: float | None = None) -> None:
        self._proc.join(timeout)
