"""A bounded outbox drained by one thread, so the simulator never waits on the network for
longer than `timeout`: a Zenoh BLOCK put may stall while the network is congested."""

from __future__ import annotations

import logging
import queue
import threading

log = logging.getLogger(__name__)


class Sender:
    """`send(publisher, payload)` from the acting loop; a daemon thread does the puts."""

    def __init__(self, capacity: int, timeout: float) -> None:
        self._q: queue.Queue = queue.Queue(maxsize=capacity)
        self.timeout = timeout
        self.dropped = 0
        self.sent = 0
        self.errors = 0
        self._thread = threading.Thread(target=self._run, name="sender", daemon=True)
        self._thread.start()

    def send(self, publisher, payload: bytes) -> bool:
        """Queue a put; when the queue stays full past the timeout, drop the oldest and count it."""
        try:
            self._q.put((publisher, payload), timeout=self.timeout)
            return True
        except queue.Full:
            try:
                self._q.get_nowait()
                self.dropped += 1
            except queue.Empty:
                pass
            self._q.put_nowait((publisher, payload))
            return False

    def _run(self) -> None:
        while True:
            item = self._q.get()
            if item is None:
                return
            publisher, payload = item
            try:
                publisher.put(payload)
                self.sent += 1
            except Exception as err:  # noqa: BLE001  a closed or broken session must not kill the actor
                self.errors += 1
                if self.errors == 1:
                    log.warning("send failed (%s); counting further failures silently", err)

    def close(self, timeout: float = 5.0) -> None:
        """Send what is queued (up to `timeout`), then stop the thread."""
        try:
            self._q.put(None, timeout=timeout)
        except queue.Full:
            return
        self._thread.join(timeout)
