"""Message classes and the payload encoding: registration, byte-exact encoding as Rust writes
it, lenient decoding as Rust reads, nested types, unknown types."""

from __future__ import annotations

import enum
from dataclasses import dataclass, field
from typing import Dict, List, Optional

import pytest

import hetcomm
from conftest import Command, Wheels

# Bytes from docs/wire-format.md ("How each Rust shape is written"), asserted there against
# rmp-serde by crates/hetcomm-core/tests/payload_shapes.rs.
WHEELS_BYTES = bytes.fromhex("82a46c656674cbc024000000000000a57269676874cb4024000000000000")


class Mode(enum.Enum):
    Stop = 0
    Explore = 1


@dataclass
class Point:
    x: float
    y: float


@hetcomm.message(id=100)
@dataclass
class Status:
    name: str
    pose: Point
    path: List[Point]
    mode: Mode
    fault: Optional[str]
    counters: Dict[str, int]
    raw: bytes
    battery: float = 1.0
    tags: List[str] = field(default_factory=list)


def test_decorator_registers_with_the_id():
    assert Wheels.__hetcomm_id__ == 1
    assert hetcomm.registered(1) is Wheels
    assert hetcomm.registered(0) is Command
    assert hetcomm.registered_types()[100] is Status


def test_two_classes_with_one_id_raise_naming_both():
    with pytest.raises(hetcomm.TypeConflictError) as e:

        @hetcomm.message(id=1)
        @dataclass
        class OtherWheels:
            speed: float

    msg = str(e.value)
    assert msg == (
        "message type id 1 is claimed by both `conftest.Wheels` and "
        "`test_messages.test_two_classes_with_one_id_raise_naming_both.<locals>.OtherWheels`: "
        "give one of them another id"
    )
    assert isinstance(e.value, hetcomm.HetcommError)
    assert hetcomm.registered(1) is Wheels


def test_redefining_the_same_class_replaces_it():
    def define():
        @hetcomm.message(id=101)
        @dataclass
        class Again:
            a: int

        return Again

    first, second = define(), define()
    assert first is not second
    assert hetcomm.registered(101) is second
    hetcomm.unregister(101)
    assert hetcomm.registered(101) is None


def test_message_needs_a_dataclass():
    with pytest.raises(TypeError, match="not a dataclass"):

        @hetcomm.message(id=102)
        class Plain:
            pass


def test_invalid_ids():
    with pytest.raises(ValueError):
        hetcomm.message(id=-1)(Point)
    with pytest.raises(ValueError):
        hetcomm.message(id=2**32)(Point)


def test_encoding_is_byte_identical_to_rust():
    assert hetcomm.pack(Wheels(left=-10.0, right=10.0)) == WHEELS_BYTES
    # Shapes of the table in docs/wire-format.md.
    cases = [
        (None, "c0"),
        (True, "c3"),
        (5, "05"),
        (200, "ccc8"),
        (-1, "ff"),
        (-100, "d09c"),
        (2**64 - 1, "cfffffffffffffffff"),
        (-(2**63), "d38000000000000000"),
        (1.0, "cb3ff0000000000000"),
        ("é", "a2c3a9"),
        ("hi", "a26869"),
        ([1, 2, 255], "930102ccff"),
        ((1, "a", True), "9301a161c3"),
        (b"\x01\x02\xff", "c40301 02ff".replace(" ", "")),
        ({1: "a", 2: "b"}, "8201a16102a162"),
        (Mode.Stop, "a453746f70"),
        ({"Go": {"x": 3}}, "81a2476f81a17803"),
    ]
    for value, hex_ in cases:
        assert hetcomm.pack(value).hex() == hex_, value


def test_unencodable_values_raise_encode_error():
    with pytest.raises(hetcomm.EncodeError, match="does not fit in 64 bits"):
        hetcomm.pack(2**64)
    with pytest.raises(hetcomm.EncodeError, match="objects of type `object`"):
        hetcomm.pack({"a": object()})
    loop: list = []
    loop.append(loop)
    with pytest.raises(hetcomm.EncodeError, match="nested deeper"):
        hetcomm.pack(loop)


def test_unpack_and_roundtrip():
    assert hetcomm.unpack(WHEELS_BYTES) == {"left": -10.0, "right": 10.0}
    value = {"a": [1, -2, 3.5, None, True, "s", b"\x00"], "b": {"c": 2**64 - 1}}
    assert hetcomm.unpack(hetcomm.pack(value)) == value
    # f32 reads as a float; ext as (type, bytes); unhashable keys become tuples.
    assert hetcomm.unpack(bytes.fromhex("ca3f000000")) == 0.5
    assert hetcomm.unpack(bytes.fromhex("d40501")) == (5, b"\x01")
    assert hetcomm.unpack(bytes.fromhex("81920102c3")) == {(1, 2): True}


def test_unpack_rejects_trailing_and_truncated():
    with pytest.raises(hetcomm.DecodeError, match="1 trailing bytes"):
        hetcomm.unpack(bytes.fromhex("c0c0"))
    with pytest.raises(hetcomm.DecodeError):
        hetcomm.unpack(b"")
    with pytest.raises(hetcomm.DecodeError):
        hetcomm.unpack(bytes.fromhex("82a1"))


def status() -> Status:
    return Status(
        name="scout-1",
        pose=Point(1.5, -2.0),
        path=[Point(0.0, 0.0), Point(1.0, 2.0)],
        mode=Mode.Explore,
        fault=None,
        counters={"rx": 300, "tx": 70000},
        raw=b"\x00\x7f\x80\xff",
        battery=0.75,
        tags=["lidar", "gps"],
    )


def test_nested_dataclasses_enums_bytes_roundtrip(fleet):
    a = fleet.module("Alpha", "Plan")
    b = fleet.module("Charlie", "Plan")
    assert a.send("Charlie", "Plan", status()).wait().delivered
    got = b.recv(timeout=5).message
    assert got == status()
    assert isinstance(got.pose, Point) and isinstance(got.path[1], Point)
    assert got.mode is Mode.Explore


def build(cls, payload_value):
    """Decodes a payload as Rust would send it (via the registry)."""
    from hetcomm import _types

    return _types.decode_message(cls.__hetcomm_id__, payload_value, hetcomm.pack(payload_value), None)


def test_decoding_is_as_lenient_as_rust():
    # Keys in any order, unknown keys ignored.
    assert build(Wheels, {"right": 2.0, "extra": [1], "left": 1.0}) == Wheels(1.0, 2.0)
    # A struct written as an array of its fields.
    assert build(Wheels, [1.0, 2.0]) == Wheels(1.0, 2.0)
    # An int for a float field becomes a float.
    w = build(Wheels, {"left": 1, "right": -2})
    assert w == Wheels(1.0, -2.0) and isinstance(w.left, float)
    # Missing Optional field → None; missing field with a default → the default.
    s = build(Status, {"name": "n", "pose": [0, 0], "path": [], "mode": "Stop",
                       "counters": {}, "raw": [1, 2, 255]})
    assert s.fault is None and s.battery == 1.0 and s.tags == []
    assert s.raw == b"\x01\x02\xff"  # Rust Vec<u8> is an array of ints
    assert s.mode is Mode.Stop
    # Unit variant as {"Name": nil} or as its index.
    assert build(Status, {**s.__dict__, "pose": [0, 0], "raw": b"", "mode": {"Explore": None}}).mode is Mode.Explore
    assert build(Status, {**s.__dict__, "pose": [0, 0], "raw": b"", "mode": 1}).mode is Mode.Explore


def test_missing_field_is_a_decode_error():
    with pytest.raises(hetcomm.DecodeError, match="cannot decode payload as Wheels: missing field `right`"):
        build(Wheels, {"left": 1.0})
    with pytest.raises(hetcomm.DecodeError, match="expected a map of fields"):
        build(Wheels, 5)
    with pytest.raises(hetcomm.DecodeError, match="not a variant of Mode"):
        build(Status, {**status().__dict__, "pose": [0, 0], "path": [], "mode": "Fly"})


@hetcomm.message(id=103)
@dataclass
class Meters:
    """Matches a Rust newtype struct `struct Meters(f64)`: the payload is the bare float."""

    value: float

    def to_payload(self):
        return self.value

    @classmethod
    def from_payload(cls, data):
        return cls(float(data))


def test_custom_payload_hooks(fleet):
    a = fleet.module("Alpha", "Plan")
    b = fleet.module("Charlie", "Plan")
    a.send("Charlie", "Plan", Meters(1.5)).wait()
    raw = b.recv_raw(timeout=5)
    assert raw.payload.hex() == "cb3ff8000000000000"  # docs: Meters(1.5)
    assert raw.decode() == Meters(1.5)
    assert raw.type_id == 103 and raw.data() == 1.5


def test_unknown_type_gives_an_unknown_message(fleet):
    a = fleet.module("Alpha", "Plan")
    b = fleet.module("Charlie", "Plan")
    payload = hetcomm.pack({"code": 1, "text": "hello"})
    a.send_raw("Charlie", "Plan", 7, payload).wait()
    msg, env = b.recv(timeout=5)
    assert isinstance(msg, hetcomm.UnknownMessage)
    assert (msg.type_id, msg.data, msg.payload) == (7, {"code": 1, "text": "hello"}, payload)
    assert env.message_type == 7
    # Not one MessagePack value: data is None, the bytes are kept.
    a.send_raw("Charlie", "Plan", 8, b"\xc0\xc0").wait()
    msg = b.recv(timeout=5).message
    assert (msg.type_id, msg.data, msg.payload) == (8, None, b"\xc0\xc0")
    # Forwarding an unknown message sends it unchanged.
    c = fleet.module("Tango", "Plan")
    b.send("Tango", "Plan", hetcomm.UnknownMessage(7, None, payload)).wait()
    fwd = c.recv_raw(timeout=5)
    assert (fwd.type_id, fwd.payload) == (7, payload)


def test_registered_type_with_bad_payload_raises_decode_error(fleet):
    a = fleet.module("Alpha", "Plan")
    b = fleet.module("Charlie", "Plan")
    a.send_raw("Charlie", "Plan", 1, hetcomm.pack({"left": 1.0})).wait()
    with pytest.raises(hetcomm.DecodeError, match="missing field `right`"):
        b.recv(timeout=5)
    a.send_raw("Charlie", "Plan", 1, b"").wait()
    with pytest.raises(hetcomm.DecodeError, match="cannot decode payload as Wheels"):
        b.recv(timeout=5)
    assert not b.has_message()  # consumed, as in Rust


def test_sending_a_non_message_raises_type_error(fleet):
    a = fleet.module("Alpha", "Plan")
    with pytest.raises(TypeError, match="not an instance of a message class"):
        a.send("Charlie", "Plan", Point(1, 2))
    with pytest.raises(TypeError):
        a.send("Charlie", "Plan", {"left": 1})
