"""docs/wire-vectors.json, the language-neutral test vectors, read from Python: headers by a
small pure-Python decoder of the 48-byte header and by the Rust codec (`hetcomm.decode_frame`),
payloads by hetcomm's decoder (`hetcomm.unpack`); the link sections (UDP datagrams, batches,
fragments and reassembly, stream hellos and records) by `docport`, a port of the whole
document to pure Python that uses nothing of hetcomm."""

from __future__ import annotations

import json
import random

import pytest

import docport
import hetcomm
from conftest import ROOT, Wheels

VECTORS = json.loads((ROOT / "docs" / "wire-vectors.json").read_text())
ACK_STATUS = docport.ACK_STATUS
# The decoder and encoder of docs/wire-format.md (checks in the documented order), written
# from the document alone.
py_decode = docport.decode_frame
py_encode = docport.encode_frame


def as_json(value):
    """The JSON form of a decoded payload (payload::to_json's conventions: bin → array of
    bytes, non-string keys printed as strings, ext → {"ext", "data"})."""
    if isinstance(value, bytes):
        return list(value)
    if isinstance(value, tuple) and len(value) == 2 and isinstance(value[1], bytes):
        return {"ext": value[0], "data": list(value[1])}
    if isinstance(value, list):
        return [as_json(v) for v in value]
    if isinstance(value, dict):
        return {(k if isinstance(k, str) else json.dumps(as_json(k))): as_json(v) for k, v in value.items()}
    return value


@pytest.mark.parametrize("v", VECTORS["valid"], ids=[v["name"] for v in VECTORS["valid"]])
def test_valid_vector(v):
    frame = bytes.fromhex(v["frame_hex"])
    header, payload = py_decode(frame)
    assert header == v["header"]
    assert payload.hex() == v["payload_hex"]
    rust_header, rust_payload = hetcomm.decode_frame(frame)
    assert rust_header == v["header"] and rust_payload == payload
    assert py_encode(header, payload) == frame
    if header["kind"] == 1:
        assert ACK_STATUS.get(payload[0]) == v.get("ack_status")
        status, first, last = docport.decode_ack(header, payload)
        assert (status, last) == (v["ack_status"], header["seq"])
        assert first == v.get("ack_first", header["seq"])
    elif v["payload_json"] is None and payload != b"\xc0":
        # No JSON form: not exactly one MessagePack value (e.g. zero bytes).
        with pytest.raises(hetcomm.DecodeError):
            hetcomm.unpack(payload)
    else:
        assert as_json(hetcomm.unpack(payload)) == v["payload_json"]


def test_ack_ranges_outside_the_rules_are_refused():
    h = {"seq": 5}
    for first in (5, 6):
        with pytest.raises(ValueError):
            docport.decode_ack(h, b"\x00" + first.to_bytes(8, "little"))
    with pytest.raises(ValueError):
        docport.decode_ack({"seq": 5000}, b"\x00" + (5000 - 4096).to_bytes(8, "little"))
    assert docport.decode_ack({"seq": 5000}, b"\x00" + (5000 - 4095).to_bytes(8, "little")) \
        == ("delivered", 905, 5000)
    with pytest.raises(ValueError):
        docport.decode_ack(h, b"\x00\x00")


@pytest.mark.parametrize("v", VECTORS["invalid"], ids=[v["name"] for v in VECTORS["invalid"]])
def test_invalid_vector(v):
    frame = bytes.fromhex(v["frame_hex"])
    with pytest.raises(ValueError) as e:
        py_decode(frame)
    assert str(e.value) == v["error"]
    with pytest.raises(ValueError) as e:
        hetcomm.decode_frame(frame)
    assert str(e.value).split(":")[0] == v["error"]


def test_worked_example_as_a_python_message():
    v = next(v for v in VECTORS["valid"] if v["name"] == "data_struct_wheels")
    payload = bytes.fromhex(v["payload_hex"])
    assert hetcomm.pack(Wheels(-10.0, 10.0)) == payload
    from hetcomm import _types

    assert _types.decode_message(1, hetcomm.unpack(payload), payload, None) == Wheels(-10.0, 10.0)


def test_there_are_vectors():
    assert len(VECTORS["valid"]) >= 8 and len(VECTORS["invalid"]) >= 8


# --- the links (docs/wire-format.md, "On the links"), read by docport alone ---------------------

def by_name(section):
    return pytest.mark.parametrize("v", VECTORS[section], ids=[v["name"] for v in VECTORS[section]])


def unhex_all(hexes):
    return [bytes.fromhex(h) for h in hexes]


@by_name("udp_datagrams")
def test_udp_datagram_vector(v):
    d = bytes.fromhex(v["datagram_hex"])
    handling, frames, tail = docport.split_datagram(d)
    assert handling == v["handling"]
    assert frames == unhex_all(v["frames_hex"])
    assert tail.hex() == v["dropped_tail_hex"]
    if not tail and handling == "batch":
        # What a sender writes: the batch header, then each frame as a record.
        assert docport.encode_batch(frames) == d
    if handling == "whole":
        assert frames == [d] and docport.datagrams_for(d, 1, 0) == [d]


@by_name("udp_fragmented_frames")
def test_udp_fragmented_vector(v):
    frame = bytes.fromhex(v["frame_hex"])
    expected = unhex_all(v["fragments_hex"])
    sent = docport.datagrams_for(frame, v["sender"], v["message_id"], v["datagram_payload"])
    assert sent == expected
    assert all(len(d) <= v["datagram_payload"] for d in sent)
    # Any arrival order reassembles to the frame.
    shuffled = list(expected)
    random.Random(v["name"]).shuffle(shuffled)
    r = docport.Reassembler()
    out = [f for f in (r.on_fragment(d, "peer", v["sender"]) for d in shuffled) if f is not None]
    assert out == [frame] and r.pending == 0


@by_name("udp_reassembly")
def test_udp_reassembly_vector(v):
    r = docport.Reassembler(v["max_frame"])
    frames, rejected = [], 0
    for d in unhex_all(v["datagrams_hex"]):
        try:
            f = r.on_fragment(d, "peer")
        except ValueError:
            rejected += 1
            continue
        if f is not None:
            frames.append(f)
    assert frames == unhex_all(v["frames_hex"])
    assert rejected == v["rejected"]
    assert r.duplicates == v["duplicates"]
    assert r.pending == v["pending"]


@by_name("udp_fragment_errors")
def test_udp_fragment_error_vector(v):
    with pytest.raises(ValueError) as e:
        docport.parse_fragment(bytes.fromhex(v["datagram_hex"]), v["max_frame"])
    assert str(e.value) == v["error"]


def test_a_fragment_naming_another_sender_is_refused():
    v = VECTORS["udp_fragmented_frames"][0]
    first = bytes.fromhex(v["fragments_hex"][0])
    with pytest.raises(ValueError, match="WrongSender"):
        docport.Reassembler().on_fragment(first, "peer", src_system=v["sender"] + 1)


@by_name("stream_hellos")
def test_stream_hello_vector(v):
    h = bytes.fromhex(v["hello_hex"])
    assert docport.decode_hello(h) == v["system"]
    if v["system"] is not None:
        assert docport.encode_hello(v["system"]) == h


@by_name("stream_records")
def test_stream_records_vector(v):
    stream = bytes.fromhex(v["stream_hex"])
    frames, end = docport.read_records(stream, v["max_frame"])
    assert frames == unhex_all(v["frames_hex"])
    assert end == v["end"]
    if end == "clean":
        assert b"".join(docport.encode_record(f) for f in frames) == stream


def test_link_vectors_cover_the_document():
    assert {v["handling"] for v in VECTORS["udp_datagrams"]} == {"whole", "batch", "dropped"}
    assert any(v["dropped_tail_hex"] for v in VECTORS["udp_datagrams"])
    assert {v["error"] for v in VECTORS["udp_fragment_errors"]} == {"Truncated", "BadHeader", "BadGeometry", "BadLength"}
    assert {v["end"] for v in VECTORS["stream_records"]} == {"clean", "cut", "bad"}
    assert any(v["system"] is None for v in VECTORS["stream_hellos"])
    assert len(VECTORS["udp_reassembly"]) >= 5 and len(VECTORS["udp_fragmented_frames"]) >= 3
