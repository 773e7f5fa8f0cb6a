"""docs/wire-vectors.json, the language-neutral test vectors, read from Python: headers by a
small pure-Python decoder of the 48-byte header and by the Rust codec (`hetcomm.decode_frame`),
payloads by hetcomm's decoder (`hetcomm.unpack`)."""

from __future__ import annotations

import json
import struct
import zlib

import pytest

import hetcomm
from conftest import ROOT, Wheels

VECTORS = json.loads((ROOT / "docs" / "wire-vectors.json").read_text())
HEADER = struct.Struct("<2sBBBBBBHHHHIQIQII")
ACK_STATUS = {0: "delivered", 1: "inbox_full", 2: "unknown_module"}
FLAG_HEADER_CRC = 0x04  # the CRC covers the 48 header bytes only


def py_decode(frame: bytes):
    """The decoder of docs/wire-format.md, checks in the documented order."""
    if len(frame) < 48:
        raise ValueError("TooShort")
    (magic, version, kind, flags, priority, transport, _reserved, src_sys, src_mod, dst_sys,
     dst_mod, incarnation, seq, message_type, timestamp, payload_len, crc) = HEADER.unpack_from(frame)
    if magic != b"HC":
        raise ValueError("BadMagic")
    if version != 1:
        raise ValueError("BadVersion")
    if payload_len > 16 * 1024 * 1024:
        raise ValueError("TooLong")
    if payload_len != len(frame) - 48:
        raise ValueError("LengthMismatch")
    if kind not in (0, 1):
        raise ValueError("BadKind")
    if flags & ~0x07:
        raise ValueError("BadFlags")
    covered = b"" if flags & FLAG_HEADER_CRC else frame[48:]
    if zlib.crc32(frame[:44] + b"\0\0\0\0" + covered) != crc:
        raise ValueError("BadChecksum")
    header = {
        "kind": kind, "flags": flags, "priority": priority, "transport": transport,
        "source": {"system": src_sys, "module": src_mod},
        "destination": {"system": dst_sys, "module": dst_mod},
        "incarnation": incarnation, "seq": seq, "message_type": message_type,
        "timestamp": timestamp, "payload_len": payload_len,
    }
    return header, frame[48:]


def py_encode(h, payload: bytes) -> bytes:
    head = HEADER.pack(b"HC", 1, h["kind"], h["flags"], h["priority"], h["transport"], 0,
                       h["source"]["system"], h["source"]["module"],
                       h["destination"]["system"], h["destination"]["module"],
                       h["incarnation"], h["seq"], h["message_type"], h["timestamp"], len(payload), 0)
    crc = zlib.crc32(head if h["flags"] & FLAG_HEADER_CRC else head + payload)
    return head[:44] + struct.pack("<I", crc) + payload


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
    elif v["payload_json"] is None and payload != b"\xc0":
        # No JSON form: not exactly one MessagePack value (e.g. zero bytes).
        with pytest.raises(hetcomm.DecodeError):
            hetcomm.unpack(payload)
    else:
        assert as_json(hetcomm.unpack(payload)) == v["payload_json"]


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
