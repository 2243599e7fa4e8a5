"""What every Hydra entry point shares: the config folder, schema registration, and a stop
event set by SIGINT/SIGTERM so each role can shut down cleanly (close sessions, checkpoint)."""

from __future__ import annotations

import logging
import signal
import threading
from pathlib import Path
from typing import Callable, TypeVar

T = TypeVar("T")

CONF_DIR = str(Path(__file__).resolve().parents[1] / "conf")


def stop_on_signals() -> threading.Event:
    """An event set on the first SIGINT or SIGTERM; a second SIGINT interrupts as usual."""
    stop = threading.Event()

    def handler(signum, _frame):
        if stop.is_set() and signum == signal.SIGINT:
            raise KeyboardInterrupt
        logging.getLogger(__name__).info("signal %s: stopping", signal.Signals(signum).name)
        stop.set()

    signal.signal(signal.SIGINT, handler)
    signal.signal(signal.SIGTERM, handler)
    return stop


def compose_run(overrides: list[str] = ()):
    """The RunConfig that conf/ composes with `overrides`, validated: what every entry point sees
    (benches and tests use it instead of declaring configs of their own)."""
    from hydra import compose, initialize_config_dir

    from common.config.run import register, to_objects

    register()
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        return to_objects(compose("config", overrides=list(overrides)))[0]


def role_main(role: str, print_result: bool = False) -> None:
    """The console script of one role on its own (gvf-learner, gvf-actor, gvf-router): compose
    conf/, refuse a transport that cannot reach anyone, run the role until SIGINT/SIGTERM or its
    end. Being stopped while still waiting for a router is a clean exit, not a crash."""
    import json

    def task(cfg) -> None:
        from hydra.core.hydra_config import HydraConfig

        from common.config.run import to_objects
        from common.roles import check_standalone, run_role

        run, _, _ = to_objects(cfg)
        check_standalone(run, role)
        logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s")
        stop = stop_on_signals()
        try:
            result = run_role(role, run, HydraConfig.get().runtime.output_dir, stop)
        except ConnectionError:
            if not stop.is_set():
                raise
            logging.getLogger(__name__).info("stopped while waiting for a router")
            return
        if print_result and result is not None:
            print(json.dumps(result), flush=True)

    hydra_entry(task)()


def hydra_entry(task: Callable, config_name: str = "config") -> Callable[[], None]:
    """A console-script `main()` that composes conf/ and calls `task(cfg)`."""
    import hydra

    from common.config.run import register

    def main() -> None:
        register()
        hydra.main(config_path=CONF_DIR, config_name=config_name, version_base="1.3")(task)()

    return main
