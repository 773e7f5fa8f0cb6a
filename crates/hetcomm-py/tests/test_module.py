"""The module API over the in-process transport: send / broadcast / tickets / outcomes,
polling, priorities, envelopes, callbacks, raw messages, statistics, closing."""

from __future__ import annotations

import os
import signal
import threading
import time

import pytest

import hetcomm
from conftest import INPROC_FLEET, Command, Wheels, udp_pair


def test_send_recv_and_envelope(fleet):
    plan = fleet.module("Alpha", "Plan")
    act = fleet.module("Charlie", "Act")
    assert (plan.name, plan.system, plan.address) == ("Plan", "Alpha", (0, 0))
    before = time.time()
    ticket = plan.send("Charlie", "Act", Command(code=1))
    assert ticket.destination == "Charlie"
    outcome = ticket.wait()
    assert outcome.kind == "delivered" and outcome.delivered and outcome.is_success
    assert outcome.attempts == 1 and outcome.latency is not None and outcome.latency >= 0
    assert outcome.reason is None and not outcome.failed
    assert str(outcome).startswith("delivered to the inbox (attempts: 1, ")
    assert ticket.try_outcome() == outcome and ticket.done

    assert act.has_message() and act.pending() == 1 and act.next_type() == 0
    received = act.recv(timeout=5)
    message, env = received
    assert message == Command(code=1) and received.message is not None
    assert env.source_system == "Alpha" and env.source_module == "Plan"
    assert env.source == (0, 0) and env.destination == (1, 1)
    assert env.message_type == 0 and env.priority == 100
    assert env.message_id == (0, 1) and not env.is_broadcast
    assert before - 1 <= env.timestamp <= time.time() + 1
    assert env.timestamp_us // 1_000_000 == int(env.timestamp)
    assert env.received_at_us >= env.timestamp_us
    assert not act.has_message() and act.next_type() is None and act.try_recv() is None


def test_priorities_order_the_inbox(fleet):
    plan = fleet.module("Alpha", "Plan")
    act = fleet.module("Charlie", "Act")
    for code, prio in [(1, None), (2, hetcomm.PRIORITY_LOWEST), (3, 200), (4, hetcomm.PRIORITY_HIGHEST)]:
        plan.send("Charlie", "Act", Command(code), priority=prio).wait()
    got = [(r.message.code, r.envelope.priority) for r in iter(act.try_recv, None)]
    assert got == [(4, 255), (3, 200), (1, 100), (2, 0)]
    with pytest.raises(ValueError, match="priority must be 0..=255"):
        plan.send("Charlie", "Act", Command(1), priority=256)


def test_message_ids_count_per_destination(fleet):
    plan = fleet.module("Alpha", "Plan")
    act = fleet.module("Charlie", "Act")
    for i in range(3):
        plan.send("Charlie", "Act", Command(i)).wait()
    assert [act.recv(timeout=5).envelope.message_id for _ in range(3)] == [(0, 1), (0, 2), (0, 3)]


def test_broadcast(fleet):
    plan = fleet.module("Alpha", "Plan")
    bt = plan.broadcast("Act", Wheels(1.0, 1.0), priority=150)
    assert sorted(bt.destinations) == ["Charlie", "Tango"] and len(bt) == 2
    outcomes = bt.wait(timeout=5)
    assert set(outcomes) == {"Charlie", "Tango"}
    assert all(o.delivered for o in outcomes.values())
    assert [t.destination for t in bt.tickets] == bt.destinations
    for system in ("Charlie", "Tango"):
        msg, env = fleet.module(system, "Act").recv(timeout=5)
        assert msg == Wheels(1.0, 1.0) and env.is_broadcast and env.priority == 150
    # A system whose every pair is X reaches nobody.
    assert fleet.module("Lonely", "Act").broadcast("Act", Wheels(0, 0)).wait() == {}


def test_failed_outcome_when_the_inbox_is_full():
    toml = INPROC_FLEET.replace(
        "World = 2", 'World = { id = 2, inbox_capacity = 1, overflow = "drop-newest" }'
    )
    with hetcomm.LocalFleet.from_toml(toml, "full.toml") as f:
        plan = f.module("Alpha", "Plan")
        assert plan.send("Charlie", "World", Command(1)).wait().delivered
        o = plan.send("Charlie", "World", Command(2)).wait(timeout=10)
        assert o is not None and o.failed and not o.is_success and not o.delivered
        assert o.kind == "failed" and o.reason_code == "inbox_full" and o.latency is None
        assert o.reason == "destination inbox full"
        assert str(o) == "failed: destination inbox full (attempts: 1)"
        stats = f.system("Charlie").module("World").inbox_stats()
        assert stats["dropped_newest"] == 1 and stats["len"] == 1


def test_ticket_wait_timeout_returns_none_for_pending():
    # A UDP peer that is not running never acknowledges: the outcome stays pending for a while.
    toml = udp_pair(extra="attempts = 2", b="127.0.0.1:9")
    with hetcomm.Comm.from_toml(toml, "A", "pending.toml") as a:
        t = a.module("M").send("B", "M", Command(1))
        assert t.wait(timeout=0.01) is None or t.done
        assert "Ticket to B" in repr(t)


def test_unconfirmed_outcome_when_frames_left_but_nobody_acknowledged():
    # Frames went out to a UDP port where nothing answers: the sender cannot know whether they
    # arrived, so the outcome is "unconfirmed", never "failed".
    toml = udp_pair(extra="attempts = 2", b="127.0.0.1:9")
    with hetcomm.Comm.from_toml(toml, "A", "unconfirmed.toml") as a:
        o = a.module("M").send("B", "M", Command(1)).wait(timeout=60)
        assert o is not None and o.kind == "unconfirmed", o
        assert o.unconfirmed and not o.failed and not o.delivered and not o.is_success
        assert o.reason_code == "no_acknowledgement" and o.attempts == 2
        assert "may or may not have arrived" in str(o)
        assert a.stats()["router"]["unconfirmed"] == 1


def test_callbacks(fleet):
    plan = fleet.module("Alpha", "Plan")
    act = fleet.module("Charlie", "Act")
    got = []
    done = threading.Event()

    def on_wheels(received):
        got.append((received.message, received.envelope.source_system, threading.current_thread() is threading.main_thread()))
        if len(got) == 2:
            done.set()

    act.on(Wheels, on_wheels)
    plan.send("Charlie", "Act", Wheels(1.0, 2.0)).wait()
    plan.send("Charlie", "Act", Command(5)).wait()  # no callback for Command: queued
    plan.send("Charlie", "Act", Wheels(3.0, 4.0)).wait()
    assert done.wait(5)
    assert got == [(Wheels(1.0, 2.0), "Alpha", False), (Wheels(3.0, 4.0), "Alpha", False)]
    assert act.pending() == 1 and act.recv(timeout=1).message == Command(5)


def test_on_any_and_on_raw(fleet):
    plan = fleet.module("Alpha", "Plan")
    act = fleet.module("Tango", "Act")
    anything, raws = [], []
    ev = threading.Event()
    act.on_raw(42, lambda raw: (raws.append((raw.type_id, raw.payload, raw.envelope.source_system)), ev.set()))
    act.on_any(lambda r: anything.append(r.message))
    plan.send("Tango", "Act", Command(1)).wait()
    plan.send_raw("Tango", "Act", 42, b"\xc0").wait()
    plan.send_raw("Tango", "Act", 43, hetcomm.pack([1])).wait()
    assert ev.wait(5)
    deadline = time.monotonic() + 5
    while len(anything) < 2 and time.monotonic() < deadline:
        time.sleep(0.01)
    assert raws == [(42, b"\xc0", "Alpha")]
    assert anything == [Command(1), hetcomm.UnknownMessage(43, [1], b"\x91\x01")]
    assert not act.has_message()


def test_callback_exceptions_are_reported_not_fatal(fleet):
    plan = fleet.module("Alpha", "Plan")
    act = fleet.module("Charlie", "Act")
    seen = []
    ev = threading.Event()
    reported = []
    old_hook = __import__("sys").unraisablehook
    __import__("sys").unraisablehook = lambda u: reported.append(u.exc_value)

    def cb(r):
        seen.append(r.message.code)
        if r.message.code == 1:
            raise RuntimeError("boom")
        ev.set()

    try:
        act.on(Command, cb)
        plan.send("Charlie", "Act", Command(1)).wait()
        plan.send("Charlie", "Act", Command(2)).wait()
        assert ev.wait(5)
    finally:
        __import__("sys").unraisablehook = old_hook
    assert seen == [1, 2]
    assert len(reported) == 1 and str(reported[0]) == "boom"


def test_raw_send_and_receive(fleet):
    plan = fleet.module("Alpha", "Plan")
    act = fleet.module("Charlie", "Act")
    plan.send("Charlie", "Act", Wheels(-10.0, 10.0), priority=7).wait()
    raw = act.recv_raw(timeout=5)
    assert raw.type_id == 1 and raw.envelope.priority == 7
    assert raw.payload == hetcomm.pack(Wheels(-10.0, 10.0))
    assert raw.data() == {"left": -10.0, "right": 10.0}
    assert act.try_recv_raw() is None
    plan.broadcast_raw("Act", 9, b"\x01").wait()
    assert act.try_recv_raw().payload == b"\x01"
    with pytest.raises(ValueError):
        plan.send_raw("Charlie", "Act", -1, b"")


def test_stats(fleet):
    alpha = fleet.system("Alpha")
    plan = alpha.module("Plan")
    plan.send("Charlie", "Act", Command(1)).wait()
    s = alpha.stats()
    assert s["router"]["sends"] == 1 and s["router"]["delivered"] == 1
    assert set(s["inboxes"]) == {"Plan", "Act", "World"}
    assert set(s["links"]) == {"wired"}
    assert s["callback_failures"] == 0
    # In-process links never hold frames for batching.
    assert s["held_frames"] == 0
    charlie = fleet.system("Charlie")
    assert charlie.stats()["router"]["received"] == 1
    assert charlie.module("Act").inbox_stats()["accepted"] == 1
    assert charlie.module("Act").inbox_stats()["capacity"] == 1024


def test_comm_properties(fleet):
    alpha = fleet.system("Alpha")
    assert (alpha.name, alpha.id) == ("Alpha", 0)
    assert alpha.systems == ["Alpha", "Charlie", "Tango", "Lonely"]
    assert alpha.modules == ["Plan", "Act", "World"]
    assert alpha.endpoints == [("wired", None)]
    assert [c.name for c in fleet.systems] == alpha.systems


def test_comm_open_file_shares_inproc_between_systems(tmp_path):
    path = tmp_path / "fleet.toml"
    path.write_text(INPROC_FLEET)
    with hetcomm.Comm.open(path, "Alpha") as alpha, hetcomm.Comm.open(str(path), "Tango") as tango:
        assert alpha.module("Plan").send("Tango", "World", Command(9)).wait().delivered
        assert tango.module("World").recv(timeout=5).message == Command(9)


def test_local_fleet_open_file(tmp_path):
    path = tmp_path / "fleet.toml"
    path.write_text(INPROC_FLEET)
    f = hetcomm.LocalFleet.open_file(path)
    assert f.module("Alpha", "Plan").send("Charlie", "Plan", Command(2)).wait().delivered
    f.close()
    with pytest.raises(hetcomm.ClosedError):
        f.system("Alpha")


def test_closed_system_raises_closed_error(fleet):
    comm = hetcomm.Comm.from_toml(INPROC_FLEET, "Alpha", "closing.toml")
    comm.close()
    with pytest.raises(hetcomm.ClosedError, match="the system is closed"):
        comm.module("Plan")


def test_spin_runs_callbacks_until_its_timeout(fleet):
    act = fleet.module("Charlie", "Act")
    got = []
    act.on(Wheels, lambda r: got.append(r.message))
    plan = fleet.module("Alpha", "Plan")

    def sender():
        for i in range(3):
            plan.send("Charlie", "Act", Wheels(float(i), 0.0)).wait(timeout=5)
            time.sleep(0.05)

    threading.Thread(target=sender).start()
    started = time.monotonic()
    fleet.spin(timeout=0.6)
    elapsed = time.monotonic() - started
    assert 0.6 <= elapsed < 5, elapsed
    assert got == [Wheels(0.0, 0.0), Wheels(1.0, 0.0), Wheels(2.0, 0.0)]
    # A Comm spins too, and returns at once once its handle is closed.
    charlie = fleet.system("Charlie")
    charlie.spin(timeout=0.05)
    charlie.close()
    started = time.monotonic()
    charlie.spin()
    assert time.monotonic() - started < 1


def test_spin_is_interrupted_by_ctrl_c(fleet):
    # Ctrl-C arrives as SIGINT at the main thread: spin raises KeyboardInterrupt within a
    # slice instead of sleeping on. Python's own handler is put in place for the test: a
    # process started in the background by a non-interactive shell inherits SIGINT ignored,
    # and Python then leaves it ignored (a CI run launched with `&` hung here for that).
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        timer = threading.Timer(0.2, lambda: os.kill(os.getpid(), signal.SIGINT))
        timer.start()
        started = time.monotonic()
        with pytest.raises(KeyboardInterrupt):
            # Bounded, so a lost signal fails the test instead of hanging the suite.
            fleet.spin(timeout=10)
        assert time.monotonic() - started < 5
    finally:
        signal.signal(signal.SIGINT, previous)
