"""The transport package: the interface (`interface`), the bounded inbox every receiver drains
(`inbox`), and its two implementations, in-process (`inproc`) and Zenoh (`zenoh_backend`).
The implementations import the interface, never the other way round; `make_transport` loads
the one a config names, so that `transport=inproc` and most tests never load zenoh."""

from __future__ import annotations

from common.config.transport import TransportConfig
from common.transport.interface import (
    AliveWatcher,
    LatestValue,
    Publisher,
    Received,
    Subscription,
    Token,
    Transport,
    check_congestion,
)

__all__ = [
    "AliveWatcher",
    "LatestValue",
    "Publisher",
    "Received",
    "Subscription",
    "Token",
    "Transport",
    "check_congestion",
    "make_transport",
]


def make_transport(cfg: TransportConfig, bus: object | None = None, stop: object | None = None) -> Transport:
    """The transport `cfg.backend` names; `bus` joins in-process transports of one process;
    `stop` (an Event) ends an endless wait for a router (connect_timeout_s < 0)."""
    if cfg.backend == "zenoh":
        from common.transport.zenoh_backend import ZenohTransport

        return ZenohTransport(cfg, stop)
    if cfg.backend == "inproc":
        from common.transport.inproc import Bus, InprocTransport

        if bus is not None and not isinstance(bus, Bus):
            raise TypeError(f"bus must be an inproc Bus, got {type(bus).__name__}")
        return InprocTransport(cfg, bus)
    raise ValueError(f"transport backend must be 'zenoh' or 'inproc', got {cfg.backend!r}")
