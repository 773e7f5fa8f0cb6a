"""Secured fleets from Python (docs/security.md): a Python system and a Rust `hetcomm listen`
in another process exchange sealed frames; the security counters are in `stats()`; the private
key can be given as an argument; forged frames are refused and counted; a fleet without keys
does not open its network transport."""

from __future__ import annotations

import json
import shutil
import socket
import time

import pytest

import hetcomm
from conftest import CLI, Command, ip_fleet


def listen(children, fleet, system, *extra):
    child = children([CLI, "listen", str(fleet), "--as", system, "--json", *extra])
    child.wait_stderr(lambda l: l.startswith("listening as "))
    return child


def link_security(comm) -> dict:
    return comm.stats()["links"]["lan"]["security"]


@pytest.mark.parametrize("kind", ["udp", "tcp"])
def test_sealed_frames_between_python_and_rust_processes(tmp_path, children, kind):
    fleet = ip_fleet(tmp_path, kind, ["Tango", "Env"])
    env = listen(children, fleet, "Env", "--count", "1", "--timeout", "20")
    with hetcomm.Comm.open(fleet, "Tango") as tango:
        outcome = tango.module("Act").send("Env", "Plan", Command(code=3)).wait(timeout=15)
        assert outcome is not None and outcome.delivered, outcome
        sec = link_security(tango)
        assert sec["enabled"] is True
        assert sec["handshakes"] == 1
        assert sec["rejected_auth"] == 0 and sec["rejected_replay"] == 0
    line = json.loads(env.next_stdout())
    assert line["from_system"] == "Tango" and line["payload"] == {"code": 3}
    assert env.wait() == 0


def test_forged_frames_are_refused_and_counted(tmp_path):
    fleet = ip_fleet(tmp_path, "udp", ["Tango", "Env"])
    port = int(
        next(l for l in fleet.read_text().splitlines() if l.startswith("Tango = \"127.0.0.1:"))
        .split(":")[-1]
        .rstrip('"')
    )
    with hetcomm.Comm.open(fleet, "Tango") as tango:
        plan = tango.module("Plan")
        raw = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            # An unsecured hetcomm frame header claiming to come from Env, and a secured-looking
            # frame with a made-up session: neither opens.
            raw.sendto(b"HC\x01" + bytes(45) + b"payload", ("127.0.0.1", port))
            raw.sendto(b"HS\x01\x03" + (1).to_bytes(2, "little") + (0).to_bytes(2, "little")
                       + bytes(12) + bytes(32), ("127.0.0.1", port))
        finally:
            raw.close()
        deadline = time.monotonic() + 5
        while time.monotonic() < deadline:
            sec = link_security(tango)
            if sec["rejected_auth"] + sec["rejected_no_session"] >= 2:
                break
            time.sleep(0.02)
        assert sec["rejected_auth"] == 1, sec
        assert sec["rejected_no_session"] == 1, sec
        assert not plan.has_message()


def test_private_key_given_as_an_argument(tmp_path):
    fleet = ip_fleet(tmp_path, "udp", ["Tango", "Env"])
    keys = tmp_path / "keys-fleet"
    elsewhere = tmp_path / "secret" / "Tango.key"
    elsewhere.parent.mkdir()
    shutil.move(str(keys / "Tango.key"), str(elsewhere))
    with pytest.raises(hetcomm.TransportError) as e:
        hetcomm.Comm.open(fleet, "Tango")
    assert "no private key for system Tango" in str(e.value)
    with hetcomm.Comm.open(fleet, "Tango", private_key_file=elsewhere) as tango:
        assert tango.name == "Tango"
    # Another system's key is refused, naming both public keys.
    with pytest.raises(hetcomm.TransportError) as e:
        hetcomm.Comm.open(fleet, "Tango", private_key_file=keys / "Env.key")
    assert "does not belong to it" in str(e.value)
    # A file that is not a key: ValueError naming the file.
    bad = tmp_path / "bad.key"
    bad.write_text("not a key\n")
    bad.chmod(0o600)
    with pytest.raises(ValueError) as e:
        hetcomm.Comm.open(fleet, "Tango", private_key_file=bad)
    assert str(bad) in str(e.value)


def test_a_network_fleet_without_keys_does_not_open(tmp_path):
    fleet = ip_fleet(tmp_path, "udp", ["Tango", "Env"], secured=False)
    text = fleet.read_text().replace('security = "none"\n', "")
    fleet.write_text(text)
    with pytest.raises(hetcomm.TransportError) as e:
        hetcomm.Comm.open(fleet, "Tango")
    msg = str(e.value)
    assert "hetcomm keygen" in msg and 'security = "none"' in msg, msg
