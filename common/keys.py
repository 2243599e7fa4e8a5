"""The one wiring diagram: every Zenoh key expression of a run, who publishes it, who listens.

All keys live under `gvf/<run>/`. Payloads are the msgpack messages of `common.wire`.

    key                                   publisher    subscribers         message            cc
    gvf/<run>/transitions/<actor>         each actor   learner             TransitionChunk    BLOCK
    gvf/<run>/episodes/<actor>            each actor   learner, launcher   EpisodeSummary     BLOCK
    gvf/<run>/weights                     learner      every actor         Weights            BLOCK
      (also a queryable answered by the learner with the latest Weights: actors `fetch` at start-up)
    gvf/<run>/tracks                      learner      every actor         TrackTable         BLOCK
    gvf/<run>/control                     launcher     learner, actors     Control            BLOCK
    gvf/<run>/flow                        learner      every actor         Control            BLOCK
      (pause / resume: the learner's rate limit, so that actors do not outrun samples-per-insert)
    gvf/<run>/alive/<role>/<name>         liveliness token of every process; learner and launcher watch
                                          gvf/<run>/alive/** to know who is alive (role: actor, learner, ...)

`python -m common.keys [run]` prints this table for a run. `key_matches` implements the subset
of Zenoh's key-expression matching (`*` one chunk, `**` any number of chunks) that the
in-process transport needs.
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
    """One row of the wiring diagram."""

    key: str
    publisher: str
    subscribers: str
    message: str
    congestion: str
    note: str = ""


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

    def last_chunk(self, key: str) -> str:
        """The final chunk of a concrete key, e.g. the actor name of a transitions key."""
        return key.rsplit("/", 1)[-1]

    def routes(self) -> list[Route]:
        """The wiring diagram of this run, one Route per key."""
        r = self.root
        return [
            Route(f"{r}/transitions/<actor>", "each actor", "learner", "TransitionChunk", "BLOCK"),
            Route(f"{r}/episodes/<actor>", "each actor", "learner, launcher", "EpisodeSummary", "BLOCK"),
            Route(self.weights, "learner", "every actor", "Weights", "BLOCK",
                  "also a queryable: actors fetch the latest at start-up"),
            Route(self.tracks, "learner", "every actor", "TrackTable", "BLOCK"),
            Route(self.control, "launcher", "learner, actors", "Control", "BLOCK"),
            Route(self.flow, "learner", "every actor", "Control", "BLOCK",
                  "pause / resume: the learner's rate limit"),
            Route(f"{r}/alive/<role>/<name>", "every process (liveliness)", "learner, launcher",
                  "-", "-", "watch " + self.all_alive()),
        ]


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
    keys = Keys(argv[0] if argv else "default")
    for r in keys.routes():
        print(f"{r.key:<42} {r.publisher:<30} -> {r.subscribers:<18} "
              f"{r.message:<16} {r.congestion:<6} {r.note}")


if __name__ == "__main__":
    main()
