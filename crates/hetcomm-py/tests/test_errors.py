"""Errors are Python exceptions: a base HetcommError, one subclass per kind, and the same
messages as the Rust library (checked against the `hetcomm` CLI where it prints them)."""

from __future__ import annotations

import pytest

import hetcomm
from conftest import CLI, INPROC_FLEET, Command, cli, udp_pair

BAD_FLEET = """\
[systems]
Alpha = 0
Bravo = 0

[modules]
Plan = 0

[transports.lan]
kind = "udpp"

[table]
columns = ["Alpha", "Bravo"]
Alpha = ["X", "lan"]
Bravo = ["lan", "X"]
"""

KINDS = [
    "ConfigError", "UnknownSystemError", "UnknownModuleError", "NoRouteError", "TooLargeError",
    "BackpressureError", "EncodeError", "DecodeError", "WrongTypeError", "RecvTimeout", "ClosedError",
    "TypeConflictError", "TransportUnavailableError", "TransportError",
]


def test_hierarchy():
    for name in KINDS:
        cls = getattr(hetcomm, name)
        assert issubclass(cls, hetcomm.HetcommError), name
    assert issubclass(hetcomm.RecvTimeout, TimeoutError)
    assert issubclass(hetcomm.UnknownSystemError, LookupError)


def test_bad_fleet_file_raises_config_error_located_like_the_cli(tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text(BAD_FLEET)
    with pytest.raises(hetcomm.ConfigError) as e:
        hetcomm.Comm.open(str(path), "Alpha")
    msg = str(e.value)
    assert msg.startswith(f"{path}:3:9: ")  # Bravo's duplicate id, line 3 column 9
    assert f"{path}:9:8: unknown transport kind `udpp`" in msg
    assert "help: did you mean `udp`?" in msg
    # The same text as the Rust CLI prints for the same file.
    validate = cli("validate", str(path))
    assert validate.returncode == 2
    assert validate.stderr.strip() == msg
    # Structured too.
    first = e.value.errors[0]
    assert (first["file"], first["line"], first["column"]) == (str(path), 3, 9)
    assert [(x["line"], x["column"]) for x in e.value.errors] == [(3, 9), (9, 8)]
    with pytest.raises(hetcomm.ConfigError) as e2:
        hetcomm.LocalFleet.open_file(path)
    assert str(e2.value) == msg
    with pytest.raises(hetcomm.ConfigError) as e3:
        hetcomm.LocalFleet.from_toml(BAD_FLEET, "inline.toml")
    assert str(e3.value) == msg.replace(str(path), "inline.toml")


def test_missing_file_is_a_config_error(tmp_path):
    with pytest.raises(hetcomm.ConfigError, match=r"missing\.toml: cannot read the fleet file"):
        hetcomm.Comm.open(tmp_path / "missing.toml", "Alpha")


def test_unknown_system_and_module(fleet, tmp_path):
    path = tmp_path / "fleet.toml"
    path.write_text(INPROC_FLEET)
    expected = "no system named `Zulu` in the fleet (systems: Alpha, Charlie, Tango, Lonely)"
    with pytest.raises(hetcomm.UnknownSystemError) as e:
        hetcomm.Comm.open(path, "Zulu")
    assert str(e.value) == expected
    r = cli("send", str(path), "--as", "Zulu", "--to", "Alpha", "--module", "Plan", "--type", "0", "--json", "{}")
    assert "`--as Zulu`" in r.stderr and "has no such system; systems: Alpha, Charlie, Tango, Lonely" in r.stderr
    with pytest.raises(hetcomm.UnknownSystemError, match="^" + expected.replace("(", r"\(").replace(")", r"\)") + "$"):
        fleet.system("Zulu")
    with pytest.raises(hetcomm.UnknownModuleError) as e:
        fleet.system("Alpha").module("Nav")
    assert str(e.value) == "no module named `Nav` in the fleet (modules: Plan, Act, World)"
    plan = fleet.module("Alpha", "Plan")
    with pytest.raises(hetcomm.UnknownSystemError) as e:
        plan.send("Zulu", "Act", Command(1))
    assert str(e.value) == "no system named `Zulu` in the fleet"
    with pytest.raises(hetcomm.UnknownModuleError) as e:
        plan.send("Charlie", "Nav", Command(1))
    assert str(e.value) == "no module named `Nav` in the fleet"
    with pytest.raises(hetcomm.UnknownModuleError):
        plan.broadcast("Nav", Command(1))


def test_no_route(fleet):
    with pytest.raises(hetcomm.NoRouteError) as e:
        fleet.module("Alpha", "Plan").send("Lonely", "Act", Command(1))
    assert str(e.value) == (
        "no traffic allowed from `Alpha` to `Lonely`: the communication table says X for this pair"
    )


def test_too_large():
    toml = udp_pair("max_message_bytes = 100")
    with hetcomm.Comm.from_toml(toml, "A", "small.toml") as a:
        with pytest.raises(hetcomm.TooLargeError) as e:
            a.module("M").send_raw("B", "M", 5, bytes(200))
    assert str(e.value) == "message to `B` is 248 bytes with its header, over the transport's limit of 148 bytes"


def test_backpressure_when_the_window_is_full():
    import socket

    # A peer socket that nobody reads: no acknowledgement ever comes back.
    silent = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    silent.bind(("127.0.0.1", 0))
    port = silent.getsockname()[1]
    toml = udp_pair("max_in_flight = 3", b=f"127.0.0.1:{port}")
    try:
        with hetcomm.Comm.from_toml(toml, "A", "window.toml") as a:
            m = a.module("M")
            tickets = [m.send_raw("B", "M", 5, b"hello?") for _ in range(3)]
            with pytest.raises(hetcomm.BackpressureError) as e:
                m.send_raw("B", "M", 5, b"hello?")
            assert all(t.try_outcome() is None for t in tickets)
            router = a.stats()["router"]
            assert (router["sends"], router["backpressured"]) == (3, 1)
    finally:
        silent.close()
    assert str(e.value) == (
        "sends to `B` awaiting their outcome fill the transport's window (max_in_flight = 3 "
        "sends, or max_in_flight_bytes): nothing was sent; wait for an earlier outcome and send again"
    )


def test_transport_unavailable():
    toml = """
[systems]
A = 0
B = 1
[modules]
M = 0
[transports.bus]
kind = "mqtt"
[table]
columns = ["A", "B"]
A = ["X", "bus"]
B = ["bus", "X"]
"""
    with pytest.raises(hetcomm.TransportUnavailableError) as e:
        hetcomm.LocalFleet.from_toml(toml, "mqtt.toml")
    assert str(e.value).startswith("transport `bus` is of kind `mqtt`, which is not available yet in this build: ")


def test_transport_error_when_the_port_is_taken():
    import socket

    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    toml = udp_pair(a=f"127.0.0.1:{port}")
    try:
        with pytest.raises(hetcomm.TransportError) as e:
            hetcomm.Comm.from_toml(toml, "A", "taken.toml")
        assert str(e.value).startswith("cannot open transport `lan` for system `A`: ")
    finally:
        s.close()


def test_recv_timeout(fleet):
    act = fleet.module("Charlie", "Act")
    with pytest.raises(hetcomm.RecvTimeout) as e:
        act.recv(timeout=0.05)
    assert str(e.value) == "no message within 50ms"
    with pytest.raises(TimeoutError):
        act.recv_raw(timeout=0.0)
    with pytest.raises(ValueError, match="invalid timeout"):
        act.recv(timeout=-1)


def test_closed():
    comm = hetcomm.Comm.from_toml(INPROC_FLEET, "Alpha", "closed.toml")
    comm.close()
    for use in (lambda: comm.endpoints, lambda: comm.module("Plan"), comm.stats):
        with pytest.raises(hetcomm.ClosedError) as e:
            use()
        assert str(e.value) == "the system is closed"


def test_type_conflict_names_both():
    from dataclasses import dataclass

    with pytest.raises(hetcomm.TypeConflictError, match=r"message type id 0 is claimed by both `conftest.Command` and `test_errors.*Dup`"):

        @hetcomm.message(id=0)
        @dataclass
        class Dup:
            x: int


def test_cli_is_there():
    assert cli("--help").returncode == 0, CLI


def test_an_unreadable_fleet_file_has_no_made_up_position(tmp_path):
    missing = tmp_path / "nowhere.toml"
    with pytest.raises(hetcomm.ConfigError) as e:
        hetcomm.LocalFleet.open_file(missing)
    [only] = e.value.errors
    assert only["file"] == str(missing) and only["line"] is None and only["column"] is None
    assert ":1:1" not in str(e.value)
