"""Fake roles for the supervisor tests (tests/test_roles.py), imported by name as real roles are."""

import time

CALLS: dict[str, int] = {}


def crash_once(ctx):
    """A fake actor: crashes on its first start, then runs until stopped."""
    CALLS[ctx.cfg.actor.name] = CALLS.get(ctx.cfg.actor.name, 0) + 1
    if CALLS[ctx.cfg.actor.name] == 1:
        raise RuntimeError("first start crashes")
    ctx.stop.wait()


def finish(ctx):
    """A fake learner that is done at once (as at learner.max_updates)."""
    CALLS["learner"] = CALLS.get("learner", 0) + 1
    time.sleep(0.5)
    return {"updates": 7}


def wait_stop(ctx):
    ctx.stop.wait()
