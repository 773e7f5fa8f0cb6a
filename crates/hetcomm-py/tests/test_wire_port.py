"""A port written from docs/wire-format.md alone (`docport`, standard library only) talking to
the Rust `hetcomm` CLI over real sockets on loopback: a 1 MiB message cut into UDP fragments
reaches `hetcomm listen` and comes back acknowledged; a UDP batch of two frames is delivered and
both acknowledged; TCP hello and records both ways, with the
acknowledgement on the other system's own connection; and the Rust sender's fragments and
records read by the port. If the document left out a byte, these fail."""

from __future__ import annotations

import json
import random
import socket
import string
import time
import tomllib

import pytest

import docport
from conftest import CLI, ip_fleet

# ip_fleet numbers systems in list order; its modules are Plan = 0, Act = 1, World = 2. The
# fleets are unsecured: the port speaks the frames of wire-format.md, not sealed ones.
TANGO, ENV = 0, 1
PLAN, ACT, WORLD = 0, 1, 2


def endpoints(fleet):
    eps = tomllib.loads(fleet.read_text())["transports"]["lan"]["endpoints"]
    return {name: (ep.rsplit(":", 1)[0], int(ep.rsplit(":", 1)[1])) for name, ep in eps.items()}


def listen(children, fleet, system, count):
    child = children([CLI, "listen", str(fleet), "--as", system, "--json", "--count", str(count),
                      "--timeout", "60"])
    child.wait_stderr(lambda l: l.startswith("listening as "))
    return child


def data_header(seq, flags, message_type, dst_module=WORLD, incarnation=0x5EED0001):
    return {
        "kind": docport.KIND_DATA, "flags": flags, "priority": 100, "transport": 0,
        "source": {"system": TANGO, "module": ACT},
        "destination": {"system": ENV, "module": dst_module},
        "incarnation": incarnation, "seq": seq, "message_type": message_type,
        "timestamp": int(time.time() * 1e6),
    }


def check_ack(frame, of):
    h, payload = docport.decode_frame(frame)
    assert h["kind"] == docport.KIND_ACK and h["flags"] == 0
    assert (h["source"], h["destination"]) == (of["destination"], of["source"])
    assert (h["incarnation"], h["seq"]) == (of["incarnation"], of["seq"])
    assert docport.ACK_STATUS[payload[0]] == "delivered" and len(payload) == 1


@pytest.mark.parametrize("datagram_payload", [docport.DEFAULT_DATAGRAM_PAYLOAD, 65000])
def test_a_1_mib_message_in_udp_fragments_reaches_rust(tmp_path, children, datagram_payload):
    fleet = ip_fleet(tmp_path, "udp", ["Tango", "Env"], secured=False)
    eps = endpoints(fleet)
    # Tango is this test: its socket at its fleet endpoint sends the fragments and gets the ACK.
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(eps["Tango"])
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 4 << 20)
    env = listen(children, fleet, "Env", 1)

    text = "".join(random.Random(7).choices(string.ascii_letters + string.digits, k=1 << 20))
    payload = docport.msgpack_str(text)
    assert len(payload) == 1_048_581
    header = data_header(1, docport.FLAG_ACK_REQUESTED, 4242)
    frame = docport.encode_frame(header, payload)
    assert len(frame) == 1_048_629

    # Like a router: no ACK in time, send the whole frame again (new message id, same seq;
    # the receiver drops the duplicate should both arrive).
    ack = None
    for attempt in range(1, 4):
        datagrams = docport.datagrams_for(frame, TANGO, 0x1000 + attempt, datagram_payload)
        expected = 723 if datagram_payload == 1472 else 17
        assert len(datagrams) == expected and all(len(d) <= datagram_payload for d in datagrams)
        for d in datagrams:
            sock.sendto(d, eps["Env"])
        sock.settimeout(5.0)
        try:
            ack, _ = sock.recvfrom(65536)
            break
        except socket.timeout:
            continue
    assert ack is not None, f"no acknowledgement; listener stderr: {env.stderr_lines}"
    check_ack(ack, header)

    line = json.loads(env.next_stdout(timeout=30))
    assert line["from_system"] == "Tango" and line["from_module"] == "Act"
    assert line["to_module"] == "World" and line["type"] == 4242
    assert line["size"] == len(payload) and line["payload"] == text
    assert env.wait(timeout=30) == 0
    summary = env.wait_stderr(lambda l: l.startswith("received "))
    assert "1 received" in summary and " 0 malformed" in summary, summary


def test_a_batch_from_python_reaches_rust_and_its_acks_come_back(tmp_path, children):
    fleet = ip_fleet(tmp_path, "udp", ["Tango", "Env"], secured=False)
    eps = endpoints(fleet)
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(eps["Tango"])
    env = listen(children, fleet, "Env", 2)

    wheels = data_header(1, docport.FLAG_ACK_REQUESTED, 1)
    command = data_header(2, docport.FLAG_ACK_REQUESTED, 0, dst_module=PLAN)
    frames = [docport.encode_frame(wheels, docport.msgpack_wheels(1.5, -1.5)),
              docport.encode_frame(command, b"\x81" + docport.msgpack_str("code") + b"\x03")]
    # Both frames in one batch datagram; resent whole until both ACKs are in (the receiver
    # drops duplicates).
    acks = {}
    for _ in range(5):
        sock.sendto(docport.encode_batch(frames), eps["Env"])
        sock.settimeout(5.0)
        try:
            while len(acks) < 2:
                d, src = sock.recvfrom(65536)
                assert src == eps["Env"]
                # The ACKs may come alone or batched by the Rust sender: both are documented.
                handling, got, tail = docport.split_datagram(d)
                assert handling in ("whole", "batch") and tail == b""
                for f in got:
                    acks[docport.decode_frame(f)[0]["seq"]] = f
        except socket.timeout:
            continue
        break
    assert len(acks) == 2, f"acknowledgements {sorted(acks)}; stderr: {env.stderr_lines}"
    check_ack(acks[1], wheels)
    check_ack(acks[2], command)

    lines = sorted((json.loads(env.next_stdout(timeout=30)) for _ in range(2)),
                   key=lambda l: l["id"]["seq"])
    assert lines[0]["payload"] == {"left": 1.5, "right": -1.5} and lines[0]["to_module"] == "World"
    assert lines[1]["payload"] == {"code": 3} and lines[1]["to_module"] == "Plan"
    assert env.wait(timeout=30) == 0
    summary = env.wait_stderr(lambda l: l.startswith("received "))
    assert " 0 malformed" in summary, summary
    sock.close()


def test_python_talks_tcp_to_rust(tmp_path, children):
    fleet = ip_fleet(tmp_path, "tcp", ["Tango", "Env"], secured=False)
    eps = endpoints(fleet)
    # Connections are one-way: the ACKs come over Env's own connection to Tango's endpoint.
    acks_in = socket.create_server(eps["Tango"])
    acks_in.settimeout(20)
    env = listen(children, fleet, "Env", 2)

    wheels = data_header(1, docport.FLAG_ACK_REQUESTED | docport.FLAG_HEADER_CRC, 1)
    command = data_header(2, docport.FLAG_ACK_REQUESTED, 0, dst_module=PLAN)
    frames = [docport.encode_frame(wheels, docport.msgpack_wheels(-10.0, 10.0)),
              docport.encode_frame(command, b"\x81" + docport.msgpack_str("code") + b"\x02")]
    out = socket.create_connection(eps["Env"], timeout=10)
    # The hello and both records in one write: the reader splits them by the record headers.
    out.sendall(docport.encode_hello(TANGO) + b"".join(docport.encode_record(f) for f in frames))

    conn, _ = acks_in.accept()
    conn.settimeout(20)
    assert docport.decode_hello(docport.recv_exact(conn, 8)) == ENV
    acks = {docport.decode_frame(f)[0]["seq"]: f for f in (docport.recv_record(conn) for _ in range(2))}
    check_ack(acks[1], wheels)
    check_ack(acks[2], command)

    lines = sorted((json.loads(env.next_stdout()) for _ in range(2)), key=lambda l: l["id"]["seq"])
    assert lines[0]["payload"] == {"left": -10.0, "right": 10.0} and lines[0]["to_module"] == "World"
    assert lines[1]["payload"] == {"code": 2} and lines[1]["to_module"] == "Plan"
    assert env.wait(timeout=30) == 0
    # The accepting side never wrote on the connection Tango opened.
    out.setblocking(False)
    try:
        assert out.recv(1) == b"", "the acceptor wrote"
    except BlockingIOError:
        pass
    for s in (out, conn, acks_in):
        s.close()


def test_rust_fragments_and_acknowledged_by_python_over_udp(tmp_path, children):
    fleet = ip_fleet(tmp_path, "udp", ["Tango", "Env"], secured=False)
    eps = endpoints(fleet)
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(eps["Tango"])
    sock.settimeout(20)
    text = "x" * 100_000  # more than one 65 000-byte loopback datagram: 2 fragments
    send = children([CLI, "send", str(fleet), "--as", "Env", "--to", "Tango", "--module", "Plan",
                     "--type", "77", "--json", json.dumps(text)])
    r = docport.Reassembler()
    fragments = 0
    while True:
        d, src = sock.recvfrom(65536)
        assert src == eps["Env"]
        assert d.startswith(b"HF"), "a frame this large comes in fragments"
        fragments += 1
        frame = r.on_fragment(d, src, src_system=ENV)
        if frame is not None:
            break
    assert fragments == 2 and r.pending == 0
    h, payload = docport.decode_frame(frame)
    assert h["flags"] & docport.FLAG_ACK_REQUESTED and not h["flags"] & docport.FLAG_HEADER_CRC
    assert (h["source"]["system"], h["destination"], h["message_type"]) == (ENV, {"system": TANGO, "module": PLAN}, 77)
    assert payload == docport.msgpack_str(text)
    sock.sendto(docport.ack_for(h), eps["Env"])
    line = send.next_stdout(timeout=20)
    assert line.startswith("Tango: delivered"), line
    assert send.wait() == 0


def test_rust_records_and_acknowledged_by_python_over_tcp(tmp_path, children):
    fleet = ip_fleet(tmp_path, "tcp", ["Tango", "Env"], secured=False)
    eps = endpoints(fleet)
    server = socket.create_server(eps["Tango"])
    server.settimeout(20)
    send = children([CLI, "send", str(fleet), "--as", "Env", "--to", "Tango", "--module", "Plan",
                     "--type", "0", "--json", '{"code": 5}'])
    conn, _ = server.accept()
    conn.settimeout(20)
    assert docport.decode_hello(docport.recv_exact(conn, 8)) == ENV
    h, payload = docport.decode_frame(docport.recv_record(conn))
    # On TCP the sender's CRC covers the header only.
    assert h["flags"] == docport.FLAG_ACK_REQUESTED | docport.FLAG_HEADER_CRC
    assert payload == b"\x81" + docport.msgpack_str("code") + b"\x05"
    back = socket.create_connection(eps["Env"], timeout=10)
    back.sendall(docport.encode_hello(TANGO) + docport.encode_record(docport.ack_for(h)))
    line = send.next_stdout(timeout=20)
    assert line.startswith("Tango: delivered"), line
    assert send.wait() == 0
    for s in (back, conn, server):
        s.close()
