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


def run_role(body: Callable[[threading.Event], T]) -> T | None:
    """Run a role with logging and a stop event set by SIGINT/SIGTERM; being stopped while still
    waiting for a router is a clean exit (None), not a crash."""
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    stop = stop_on_signals()
    try:
        return body(stop)
    except ConnectionError:
        if not stop.is_set():
            raise
        logging.getLogger(__name__).info("stopped while waiting for a router")
        return None


def hydra_entry(task: Callable, config_name: str = "config") -> Callable[[], None]:
    """A console-script `main()` that composes conf/ and calls `task(cfg)`."""
    import hydra

    from common.config.run import register

    def main() -> None:
        register()
        hydra.main(config_path=CONF_DIR, config_name=config_name, version_base="1.3")(task)()

    return main
