"""The one wiring diagram: every key expression of a run, who publishes it, who listens.

All keys live under `gvf/<run>/`. Payloads are the msgpack messages of `common.wire`. `WIRING`
is the table as data; roles declare through it what they publish and subscribe
(`Keys.publish(route, by=role, ...)`, `Keys.subscribe(route, by=role)`: a role not in the route's row
is refused), `docs/wire.md`'s table is tested against it, and `python -m common.keys [run]`
prints it. Roles are those of `common.roles` plus `gvfctl` (deploy/gvfctl.py, the operator).

`key_matches` implements the subset of Zenoh's key-expression matching (`*` one chunk, `**`
any number of chunks) that the in-process transport needs.
"""

from __future__ import annotations

import re
import sys
from dataclasses import dataclass

PREFIX = "gvf"
NAME_RE = re.compile(r"^[A-Za-z0-9_.\-]{1,64}$")
"""Run, actor and role names: one key chunk, no wildcards or Zenoh-reserved characters."""


def check_name(name: str, what: str = "name") -> str:
    """Return `name` if it can be one key chunk, else raise ValueError."""
    if not isinstance(name, str) or not NAME_RE.match(name) or name in (".", ".."):
        raise ValueError(f"{what} {name!r} must match {NAME_RE.pattern}")
    return name


@dataclass(frozen=True)
class Route:
    """One row of the wiring diagram; `key` below gvf/<run>/, with <actor> etc. as placeholders."""

    name: str
    key: str
    publishers: tuple[str, ...]
    subscribers: tuple[str, ...]
    message: str
    congestion: str
    priority: str
    """Zenoh priority: sessions and routers send a higher one first on a link, so a stop reaches a
    learner ahead of the transitions queued towards it and a pause goes out ahead of a weights
    broadcast (docs/wire.md); weights and transitions cross links in opposite directions."""
    note: str = ""


WIRING: tuple[Route, ...] = (
    Route("transitions", "transitions/<actor>", ("actor",), ("learner",), "TransitionChunk", "BLOCK", "data"),
    Route("episodes", "episodes/<actor>", ("actor",), ("learner",), "EpisodeSummary", "BLOCK", "data"),
    Route(
        "weights",
        "weights",
        ("learner",),
        ("actor", "evaluator"),
        "Weights",
        "BLOCK",
        "data_high",
        "also a queryable answered by the learner: actors fetch the latest at start-up",
    ),
    Route("tracks", "tracks", ("learner",), ("actor",), "TrackTable", "BLOCK", "data_high"),
    Route(
        "control",
        "control",
        ("gvfctl",),
        ("learner", "actor"),
        "Control",
        "BLOCK",
        "interactive_high",
        "stop / pause / resume from the operator",
    ),
    Route(
        "flow",
        "flow",
        ("learner",),
        ("actor",),
        "Control",
        "BLOCK",
        "interactive_high",
        "pause / resume: the learner's rate limit",
    ),
    Route(
        "alive",
        "alive/<role>/<name>",
        ("learner", "actor"),
        ("learner", "gvfctl"),
        "-",
        "-",
        "-",
        "liveliness tokens; the learner watches alive/actor/*, gvfctl alive/**",
    ),
)
ROUTES = {r.name: r for r in WIRING}


def route_of_key(key: str) -> Route | None:
    """The route a concrete key `gvf/<run>/...` belongs to, or None for a key outside the table."""
    parts = key.split("/")
    if len(parts) < 3 or parts[0] != PREFIX:
        return None
    rest = "/".join(parts[2:])
    return next((r for r in WIRING if key_matches(re.sub(r"<[a-z]+>", "*", r.key), rest)), None)


def route(name: str) -> Route:
    if name not in ROUTES:
        raise ValueError(f"no route {name!r} in the wiring table; routes are {sorted(ROUTES)}")
    return ROUTES[name]


@dataclass(frozen=True)
class Keys:
    """Key expressions of one run (`gvf/<run>/...`)."""

    run: str

    def __post_init__(self) -> None:
        check_name(self.run, "run")

    @property
    def root(self) -> str:
        return f"{PREFIX}/{self.run}"

    def transitions(self, actor: str) -> str:
        """Where actor `actor` puts its TransitionChunks."""
        return f"{self.root}/transitions/{check_name(actor, 'actor')}"

    @property
    def all_transitions(self) -> str:
        """What the learner subscribes to for every actor's chunks."""
        return f"{self.root}/transitions/*"

    def episodes(self, actor: str) -> str:
        """Where actor `actor` puts its EpisodeSummaries."""
        return f"{self.root}/episodes/{check_name(actor, 'actor')}"

    @property
    def all_episodes(self) -> str:
        return f"{self.root}/episodes/*"

    @property
    def weights(self) -> str:
        """Learner's weight broadcast, and the queryable answering with the latest weights."""
        return f"{self.root}/weights"

    @property
    def tracks(self) -> str:
        """Learner's global track table (n_i per track) for priority track sampling."""
        return f"{self.root}/tracks"

    @property
    def control(self) -> str:
        """Launcher's stop / pause / resume commands."""
        return f"{self.root}/control"

    @property
    def flow(self) -> str:
        """Learner's pause / resume to the actors: its samples-per-insert rate limit."""
        return f"{self.root}/flow"

    def alive(self, role: str, name: str) -> str:
        """Liveliness token of one process, e.g. alive('actor', 'a3')."""
        return f"{self.root}/alive/{check_name(role, 'role')}/{check_name(name, 'name')}"

    def all_alive(self, role: str | None = None) -> str:
        """What to watch to see every live process (or every live process of one role)."""
        if role is None:
            return f"{self.root}/alive/**"
        return f"{self.root}/alive/{check_name(role, 'role')}/*"

    def publish(self, name: str, by: str, /, **fields: str) -> str:
        """The concrete key role `by` publishes route `name` on; refused if the wiring table says
        `by` does not publish it (e.g. publish('transitions', 'actor', actor='a3'))."""
        r = route(name)
        if by not in r.publishers:
            raise ValueError(f"role {by!r} does not publish {name!r} (publishers: {', '.join(r.publishers)})")
        return self._fill(r.key, fields, wildcard=False)

    def subscribe(self, name: str, by: str) -> str:
        """The key expression role `by` subscribes to for route `name` (placeholders become `*`);
        refused if the wiring table says `by` does not listen to it."""
        r = route(name)
        if by not in r.subscribers:
            raise ValueError(f"role {by!r} does not subscribe to {name!r} (subscribers: {', '.join(r.subscribers)})")
        return self._fill(r.key, {}, wildcard=True)

    def _fill(self, key: str, fields: dict, wildcard: bool) -> str:
        parts = []
        for part in key.split("/"):
            if part.startswith("<"):
                field = part[1:-1]
                if wildcard:
                    part = "*"
                elif field not in fields:
                    raise ValueError(f"key {key!r} needs {field}=")
                else:
                    part = check_name(fields[field], field)
            parts.append(part)
        return f"{self.root}/{'/'.join(parts)}"


def _chunks_match(pattern: list[str], key: list[str]) -> bool:
    if not pattern:
        return not key
    head = pattern[0]
    if head == "**":
        # `**` swallows zero or more chunks
        return any(_chunks_match(pattern[1:], key[i:]) for i in range(len(key) + 1))
    if not key:
        return False
    if head == "*" or head == key[0]:
        return _chunks_match(pattern[1:], key[1:])
    return False


def key_matches(pattern: str, key: str) -> bool:
    """Whether concrete `key` is matched by `pattern` (chunks, `*` and `**` only)."""
    return _chunks_match(pattern.split("/"), key.split("/"))


def main(argv: list[str] | None = None) -> None:
    """Print the wiring diagram of a run."""
    argv = sys.argv[1:] if argv is None else argv
    root = Keys(argv[0] if argv else "default").root
    for r in WIRING:
        print(
            f"{root + '/' + r.key:<38} {', '.join(r.publishers):<16} -> {', '.join(r.subscribers):<18} "
            f"{r.message:<16} {r.congestion:<6} {r.priority:<16} {r.note}"
        )


if __name__ == "__main__":
    main()
