"""The one way a process takes the learner's weights: the actor, the periodic evaluator and the
transport bench all use it. A capacity-1 subscription (a newer broadcast replaces an unread
one), the weights query while no policy is loaded yet, and adoption through `Acting` (a set
that does not fit the policy is counted by `rejects` and dropped)."""

from __future__ import annotations

import time

from actors.acting import Acting
from common import wire
from common.keys import Keys


class WeightsClient:
    def __init__(
        self,
        t,
        keys: Keys,
        role: str,
        acting: Acting,
        rejects: wire.RejectCounter,
        *,
        fetch_timeout_s: float = 1.0,
        fetch: bool = True,
    ) -> None:
        self.t, self.acting, self.rejects = t, acting, rejects
        self.key = keys.subscribe("weights", role)
        self.sub = t.subscribe(self.key, capacity=1, overflow="drop_old")
        self.fetch_timeout_s, self.fetch = fetch_timeout_s, fetch
        self.received_at: float | None = None
        """time.time() when the last payload arrived (before decoding)."""

    def poll(self, timeout: float = 0.0) -> wire.Weights | None:
        """Wait up to `timeout` for a broadcast (or ask the learner while no policy is loaded);
        returns the weights if they were adopted, else None."""
        got = self.sub.get(timeout=timeout)
        payload = got.payload if got is not None else None
        if payload is None and self.fetch and not self.acting.ready:
            payload = self.t.fetch(self.key, timeout=self.fetch_timeout_s)
        if payload is None:
            return None
        self.received_at = time.time()
        msg = self.rejects.decode(payload, expect=wire.Weights, key=self.key)
        if msg is not None and self.acting.adopt(msg, self.rejects, self.key):
            return msg
        return None
