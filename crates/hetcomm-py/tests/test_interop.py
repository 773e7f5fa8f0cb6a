"""Rust ↔ Python interoperation.

Across processes: a Python system (this test process) and the Rust `hetcomm` CLI (`listen`
prints what a Rust receiver decoded; `send` encodes JSON as the Rust payload encoder does) over
UDP and TCP on loopback, both directions.

In one process: payloads encoded by Rust (the wire vectors, written by rmp-serde) go through
an in-process fleet and come out as Python message instances, and Python-encoded payloads are
byte for byte what Rust writes."""

from __future__ import annotations

import json

import pytest

import hetcomm
from conftest import CLI, ROOT, Command, Wheels, cli, ip_fleet

KINDS = ["udp", "tcp"]


def listen(children, fleet, system, *extra):
    child = children([CLI, "listen", str(fleet), "--as", system, "--json", *extra])
    child.wait_stderr(lambda l: l.startswith("listening as "))
    return child


@pytest.mark.parametrize("kind", KINDS)
def test_python_sends_to_rust(tmp_path, children, kind):
    fleet = ip_fleet(tmp_path, kind, ["Tango", "Env"])
    env = listen(children, fleet, "Env", "--count", "2", "--timeout", "20")
    with hetcomm.Comm.open(fleet, "Tango") as tango:
        act = tango.module("Act")
        o1 = act.send("Env", "World", Wheels(-10.0, 10.0), priority=180).wait(timeout=15)
        o2 = act.send("Env", "Plan", Command(code=2)).wait(timeout=15)
        assert o1 is not None and o1.delivered, o1
        assert o2 is not None and o2.delivered, o2
    lines = [json.loads(env.next_stdout()) for _ in range(2)]
    assert env.wait() == 0
    first, second = lines
    assert first["from_system"] == "Tango" and first["from_module"] == "Act"
    assert first["to_module"] == "World" and first["type"] == 1 and first["priority"] == 180
    assert first["payload"] == {"left": -10.0, "right": 10.0}
    assert first["size"] == 30  # byte-identical to the Rust Wheels payload
    assert second["type"] == 0 and second["payload"] == {"code": 2} and second["to_module"] == "Plan"


@pytest.mark.parametrize("kind", KINDS)
def test_rust_sends_to_python(tmp_path, kind):
    fleet = ip_fleet(tmp_path, kind, ["Charlie", "Tango"])
    with hetcomm.Comm.open(fleet, "Tango") as tango:
        plan = tango.module("Plan")
        sent = cli("send", str(fleet), "--as", "Charlie", "--to", "Tango", "--module", "Plan",
                   "--type", "0", "--json", '{"code": 1}', "--priority", "77")
        assert sent.returncode == 0, sent
        assert sent.stdout.startswith("Tango: delivered to the inbox (attempts: 1, "), sent.stdout
        msg, env = plan.recv(timeout=10)
        assert msg == Command(code=1) and isinstance(msg, Command)
        assert env.source_system == "Charlie" and env.source_module == "Plan"
        assert env.priority == 77 and env.message_type == 0
        # A type Python has no class for arrives as an UnknownMessage with the decoded data.
        sent = cli("send", str(fleet), "--as", "Charlie", "--to", "Tango", "--module", "Plan",
                   "--type", "4242", "--json", '{"text": "hello", "n": [1, 2.5]}')
        assert sent.returncode == 0, sent
        msg = plan.recv(timeout=10).message
        assert msg == hetcomm.UnknownMessage(4242, {"n": [1, 2.5], "text": "hello"}, msg.payload)


def test_broadcast_from_python_reaches_two_rust_processes(tmp_path, children):
    fleet = ip_fleet(tmp_path, "udp", ["Alpha", "Charlie", "Tango"])
    charlie = listen(children, fleet, "Charlie", "--count", "1", "--timeout", "20")
    tango = listen(children, fleet, "Tango", "--count", "1", "--timeout", "20")
    with hetcomm.Comm.open(fleet, "Alpha") as alpha:
        outcomes = alpha.module("Plan").broadcast("Plan", Command(0)).wait(timeout=15)
    assert set(outcomes) == {"Charlie", "Tango"} and all(o.delivered for o in outcomes.values())
    for child in (charlie, tango):
        line = json.loads(child.next_stdout())
        assert line["broadcast"] and line["payload"] == {"code": 0} and line["from_system"] == "Alpha"


def test_no_success_when_the_rust_peer_is_down(tmp_path):
    fleet = ip_fleet(tmp_path, "tcp", ["Alpha", "Bravo"])
    with hetcomm.Comm.open(fleet, "Alpha") as alpha:
        o = alpha.module("Plan").send("Bravo", "Plan", Command(1)).wait(timeout=30)
    # Refused at connect: failed. No secure session (only the handshake left): failed, for
    # want of a session. Taken by the link while it was still connecting, then no
    # acknowledgement: unconfirmed (the router cannot tell the frame never left the queue).
    assert o is not None and (o.failed or o.unconfirmed) and o.attempts >= 1, o
    assert not o.is_success and not o.delivered, o
    assert o.reason_code in ("unreachable", "no_session", "no_acknowledgement", "link"), o


def test_rust_encoded_payloads_decode_to_python_classes_in_process(fleet):
    """The Rust-written payloads of the wire vectors, carried by an in-process fleet."""
    vectors = json.loads((ROOT / "docs" / "wire-vectors.json").read_text())
    wheels = next(v for v in vectors["valid"] if v["name"] == "data_struct_wheels")
    plan = fleet.module("Alpha", "Plan")
    act = fleet.module("Charlie", "Act")
    plan.send_raw("Charlie", "Act", wheels["header"]["message_type"], bytes.fromhex(wheels["payload_hex"])).wait()
    assert act.recv(timeout=5).message == Wheels(-10.0, 10.0)
    # And the other way: what Python sends is what Rust writes for the same struct.
    plan.send("Charlie", "Act", Wheels(-10.0, 10.0)).wait()
    assert act.recv_raw(timeout=5).payload.hex() == wheels["payload_hex"]
