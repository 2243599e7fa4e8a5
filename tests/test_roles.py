"""The role contract (common.roles), the supervisor's exit rules (common.launch) and the wiring
table (common.keys) against docs/wire.md."""

import re
import time
from pathlib import Path

import pytest

from common import roles
from common.keys import WIRING, Keys
from common.launch import Supervisor
from common.roles import RoleSpec, check_standalone
from tests.fake_roles import CALLS
from tests.helpers import TINY, compose_run

ROOT = Path(__file__).resolve().parents[1]


def _fake_roles(monkeypatch, learner):
    CALLS.clear()
    monkeypatch.setattr(
        roles,
        "ROLES",
        {
            "learner": RoleSpec("learner", learner, ends_run=True),
            "actor": RoleSpec("actor", "tests.fake_roles:crash_once"),
            "evaluator": RoleSpec("evaluator", "tests.fake_roles:wait_stop"),
        },
    )


def test_a_crashed_role_is_restarted_and_a_clean_learner_exit_ends_the_run(monkeypatch, tmp_path):
    _fake_roles(monkeypatch, "tests.fake_roles:finish")
    cfg = compose_run([*TINY, "transport=inproc", "actors.count=1", "actors.restart_backoff_s=0.05"])
    sup = Supervisor(cfg, str(tmp_path))
    sup.start_all()
    deadline = time.monotonic() + 10
    while not sup.watch() and time.monotonic() < deadline:
        time.sleep(0.02)
    sup.stop_all(timeout=2)
    assert sup.ended == "learner exited cleanly" and CALLS["learner"] == 1  # never restarted
    assert CALLS["actor-0"] == 2  # the crash was restarted, once
    assert sup.learner_result() == {"updates": 7}
    assert not any(c.alive for c in sup.children)


def test_a_role_that_keeps_running_is_neither_restarted_nor_ends_the_run(monkeypatch, tmp_path):
    _fake_roles(monkeypatch, "tests.fake_roles:wait_stop")
    sup = Supervisor(compose_run([*TINY, "transport=inproc", "actors.count=0"]), str(tmp_path))
    sup.start_all()
    for _ in range(20):
        assert not sup.watch()
        time.sleep(0.01)
    sup.stop_all(timeout=2)
    assert CALLS == {} and not any(c.alive for c in sup.children)


def test_process_mode_starts_a_router_and_thread_mode_does_not(tmp_path):
    assert [c.role for c in Supervisor(compose_run(["actors.count=1"]), str(tmp_path)).children] == [
        "router",
        "learner",
        "actor",
    ]
    threads = Supervisor(compose_run(["actors.count=1", "transport=inproc", "eval.every_updates=5"]), str(tmp_path))
    assert [c.role for c in threads.children] == ["learner", "actor", "evaluator"] and threads.bus is not None


def test_a_standalone_role_with_the_inproc_transport_is_refused_naming_the_field():
    with pytest.raises(ValueError, match=r"transport.backend=inproc"):
        check_standalone(compose_run(["transport=inproc"]), "learner")
    check_standalone(compose_run([]), "learner")  # the Zenoh default is fine


def test_unknown_role_is_refused():
    with pytest.raises(ValueError, match="unknown role 'trainer'"):
        roles.spec_of("trainer")


def test_every_registered_role_resolves_to_a_function():
    for name in roles.ROLES:
        assert callable(roles.role_function(name))


def test_roles_declare_keys_through_the_wiring_table():
    k = Keys("exp1")
    assert k.publish("transitions", "actor", actor="a3") == "gvf/exp1/transitions/a3"
    assert k.subscribe("transitions", "learner") == "gvf/exp1/transitions/*"
    assert k.publish("alive", "learner", role="learner", name="learner") == "gvf/exp1/alive/learner/learner"
    with pytest.raises(ValueError, match="role 'actor' does not publish 'weights'"):
        k.publish("weights", "actor")
    with pytest.raises(ValueError, match="role 'evaluator' does not subscribe to 'control'"):
        k.subscribe("control", "evaluator")
    with pytest.raises(ValueError, match="needs actor="):
        k.publish("transitions", "actor")


def test_wire_doc_table_matches_the_wiring_table():
    text = (ROOT / "docs" / "wire.md").read_text()
    rows = re.findall(r"^\| `gvf/<run>/([^`]+)` \| ([^|]+) \| ([^|]+) \| [^|]+ \| ([^|]+) \| ([^|]+) \|$", text, re.M)
    doc = [
        (key, *(tuple(x.strip() for x in col.split(",")) for col in (pub, sub)), cc.strip(), prio.strip())
        for key, pub, sub, cc, prio in rows
    ]
    assert doc == [(r.key, r.publishers, r.subscribers, r.congestion, r.priority) for r in WIRING]


def test_thread_role_reports_crash_and_clean_exit(monkeypatch, tmp_path):
    _fake_roles(monkeypatch, "tests.fake_roles:finish")
    cfg = compose_run([*TINY, "transport=inproc"])
    from common.transport.inproc import Bus

    bus = Bus()
    clean = roles.ThreadRole("learner", "learner", cfg, tmp_path, bus)
    crash = roles.ThreadRole("actor-0", "actor", cfg, tmp_path, bus)
    for handle in (clean, crash):
        handle.start()
        handle.join(5)
    assert (clean.exitcode, clean.result, crash.exitcode) == (0, {"updates": 7}, 1)


def test_thread_role_imports_its_module_in_the_starting_thread(monkeypatch, tmp_path):
    # roles' first imports of torch from parallel threads can fail: the supervisor's thread imports them first
    import sys
    import threading

    (tmp_path / "late_role.py").write_text(
        "import threading\nIMPORTED_IN = threading.current_thread().name\ndef run(ctx):\n    return {}\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setattr(roles, "ROLES", {"learner": RoleSpec("learner", "late_role:run", ends_run=True)})
    cfg = compose_run([*TINY, "transport=inproc"])
    from common.transport.inproc import Bus

    try:
        handle = roles.ThreadRole("learner", "learner", cfg, tmp_path, Bus())
        assert sys.modules["late_role"].IMPORTED_IN == threading.current_thread().name
        handle.start()
        handle.join(5)
        assert handle.exitcode == 0
    finally:
        sys.modules.pop("late_role", None)
