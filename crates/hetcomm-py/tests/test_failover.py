"""Failover from Python (docs/failover.md): a pair's transports changed while running,
refusals that change nothing, and the path switches seen by several consumers: two watches
(iterators), `path_changes()` and the stats."""

from __future__ import annotations

import pytest

import hetcomm
from conftest import free_ports


def two_transport_fleet() -> str:
    u1, u2, u3, u4 = free_ports("udp", 4)
    return f"""
[systems]
A = 0
B = 1
[modules]
M = 0
[transports.wifi]
kind = "udp"
security = "none"
endpoints = {{ A = "127.0.0.1:{u1}", B = "127.0.0.1:{u2}" }}
[transports.radio]
kind = "udp"
security = "none"
endpoints = {{ A = "127.0.0.1:{u3}", B = "127.0.0.1:{u4}" }}
[table]
columns = ["A", "B"]
A = ["X", "wifi,radio"]
B = ["wifi,radio", "X"]
"""


def send(a, n: int) -> str:
    t = a.send_raw("B", "M", 9, bytes([n]))
    o = t.wait(5.0)
    assert o.delivered, o
    return t.transport


def test_transports_switch_at_run_time_and_every_consumer_sees_each_switch():
    with hetcomm.LocalFleet.from_toml(two_transport_fleet(), "failover.toml") as f:
        a_sys = f.system("A")
        a = a_sys.module("M")
        f.system("B").module("M")
        watch = a_sys.watch_paths()
        other = a_sys.watch_paths()
        assert [p["transport"] for p in a_sys.paths("B")] == ["wifi", "radio"]
        assert send(a, 0) == "wifi"
        a_sys.set_transports("B", ["radio"])
        assert send(a, 1) == "radio"
        first = watch.recv(2.0)
        assert (first["to"], first["from"], first["now"], first["number"]) == ("B", "wifi", "radio", 1)
        a_sys.set_transports("B", ["wifi", "radio"])
        assert send(a, 2) == "wifi"
        rest = [(s["from"], s["now"]) for s in watch]
        assert rest == [("radio", "wifi")]
        assert [(s["from"], s["now"]) for s in other] == [("wifi", "radio"), ("radio", "wifi")]
        assert [(s["from"], s["now"]) for s in a_sys.path_changes()] == [
            ("wifi", "radio"),
            ("radio", "wifi"),
        ]
        assert a_sys.path_changes() == []
        stats = a_sys.stats()
        assert stats["router"]["path_changes"] == 2
        assert [s["number"] for s in stats["path_switches"]] == [1, 2]
        assert watch.try_recv() is None and watch.dropped() == 0
        # Refused with the reason; nothing changes.
        with pytest.raises(ValueError, match="lists `wifi,radio`"):
            a_sys.set_transports("B", ["lan"])
        with pytest.raises(ValueError, match="no system `Zulu`"):
            a_sys.set_transports("Zulu", ["wifi"])
        assert send(a, 3) == "wifi"
        assert a_sys.path_changes() == []
