"""Blocking calls release the GIL: other Python threads run while one waits."""

from __future__ import annotations

import threading
import time

import pytest

import hetcomm
from conftest import Command, udp_pair


def count_while(block) -> int:
    """Runs `block()` on this thread while another thread increments a counter; returns how
    many increments happened during the block."""
    state = {"n": 0, "stop": False}

    def spin():
        while not state["stop"]:
            state["n"] += 1

    t = threading.Thread(target=spin)
    t.start()
    time.sleep(0.05)  # let it start
    before = state["n"]
    try:
        block()
    finally:
        during = state["n"] - before
        state["stop"] = True
        t.join()
    return during


def test_recv_releases_the_gil(fleet):
    act = fleet.module("Charlie", "Act")

    def block():
        start = time.monotonic()
        with pytest.raises(hetcomm.RecvTimeout):
            act.recv(timeout=1.0)
        assert time.monotonic() - start >= 0.95

    # A thread holding the GIL for the whole second would let the counter move only at the
    # interpreter's switch interval (5 ms): a few hundred steps at most. Released, it runs
    # freely: hundreds of thousands.
    assert count_while(block) > 100_000


def test_recv_wakes_for_a_message_sent_by_another_python_thread(fleet):
    plan = fleet.module("Alpha", "Plan")
    act = fleet.module("Charlie", "Act")
    sender = threading.Timer(0.2, lambda: plan.send("Charlie", "Act", Command(3)))
    sender.start()
    start = time.monotonic()
    msg, env = act.recv(timeout=10)
    assert msg == Command(3) and time.monotonic() - start < 5
    sender.join()


def test_ticket_wait_releases_the_gil():
    # A UDP peer that never answers: the ticket stays pending through its retries.
    toml = udp_pair(extra="attempts = 3", b="127.0.0.1:9")
    with hetcomm.Comm.from_toml(toml, "A", "gil-ticket.toml") as a:
        ticket = a.module("M").send("B", "M", Command(1))
        assert count_while(lambda: ticket.wait(timeout=0.5)) > 50_000


def test_callbacks_run_while_the_main_thread_waits(fleet):
    plan = fleet.module("Alpha", "Plan")
    act = fleet.module("Charlie", "Act")
    got = []
    act.on(Command, lambda r: got.append(r.message.code))
    threading.Timer(0.1, lambda: [plan.send("Charlie", "Act", Command(i)) for i in range(5)]).start()
    other = fleet.module("Charlie", "World")
    with pytest.raises(hetcomm.RecvTimeout):
        other.recv(timeout=1.0)  # blocks; the callback thread needs the GIL meanwhile
    assert got == [0, 1, 2, 3, 4]
