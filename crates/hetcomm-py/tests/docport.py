"""A port of the hetcomm wire format written from docs/wire-format.md alone: frames, UDP
datagrams (whole, batches, fragments and their reassembly) and TCP streams (hello, records).

It uses nothing of hetcomm, only the standard library, so the tests that use it check the
document (and the Rust code against the document), not the Rust code against itself. Errors are
ValueErrors whose message is the name the document gives the error."""

from __future__ import annotations

import struct
import zlib
from typing import Dict, List, Optional, Tuple

# --- frames ("The header", "The checksum", "What the decoder checks, in order") ---------------

HEADER = struct.Struct("<2sBBBBBBHHHHIQIQII")  # 48 bytes
HEADER_LEN = 48
MAX_PAYLOAD = 16 * 1024 * 1024
FLAG_ACK_REQUESTED = 0x01
FLAG_BROADCAST = 0x02
FLAG_HEADER_CRC = 0x04
FLAG_BROADCAST_SEQ = 0x08
FLAG_TO_ALL = 0x10
TO_ALL_SYSTEM = 0xFFFF
KIND_DATA, KIND_ACK = 0, 1
ACK_STATUS = {0: "delivered", 1: "inbox_full", 2: "unknown_module"}


def decode_frame(frame: bytes) -> Tuple[dict, bytes]:
    """The eight checks in the documented order; the header as a dict and the payload."""
    if len(frame) < HEADER_LEN:
        raise ValueError("TooShort")
    (magic, version, kind, flags, priority, transport, _reserved, src_sys, src_mod, dst_sys,
     dst_mod, incarnation, seq, message_type, timestamp, payload_len, crc) = HEADER.unpack_from(frame)
    if magic != b"HC":
        raise ValueError("BadMagic")
    if version != 1:
        raise ValueError("BadVersion")
    if payload_len > MAX_PAYLOAD:
        raise ValueError("TooLong")
    if payload_len != len(frame) - HEADER_LEN:
        raise ValueError("LengthMismatch")
    if kind not in (KIND_DATA, KIND_ACK):
        raise ValueError("BadKind")
    if flags & ~0x1F:
        raise ValueError("BadFlags")
    covered = b"" if flags & FLAG_HEADER_CRC else frame[HEADER_LEN:]
    if zlib.crc32(frame[:44] + b"\0\0\0\0" + covered) != crc:
        raise ValueError("BadChecksum")
    header = {
        "kind": kind, "flags": flags, "priority": priority, "transport": transport,
        "source": {"system": src_sys, "module": src_mod},
        "destination": {"system": dst_sys, "module": dst_mod},
        "incarnation": incarnation, "seq": seq, "message_type": message_type,
        "timestamp": timestamp, "payload_len": payload_len,
    }
    return header, frame[HEADER_LEN:]


def encode_frame(h: dict, payload: bytes) -> bytes:
    head = HEADER.pack(b"HC", 1, h["kind"], h["flags"], h["priority"], h["transport"], 0,
                       h["source"]["system"], h["source"]["module"],
                       h["destination"]["system"], h["destination"]["module"],
                       h["incarnation"], h["seq"], h["message_type"], h["timestamp"], len(payload), 0)
    crc = zlib.crc32(head if h["flags"] & FLAG_HEADER_CRC else head + payload)
    return head[:44] + struct.pack("<I", crc) + payload


def ack_for(data_header: dict, status: int = 0, me: Optional[int] = None) -> bytes:
    """The ACK frame of a data frame ("The ACK frame"): flags keep only FLAG_BROADCAST_SEQ;
    the source of the ACK of a native broadcast (FLAG_TO_ALL) is `me`, the acknowledging
    system, not 65535."""
    source = dict(data_header["destination"])
    if data_header["flags"] & FLAG_TO_ALL:
        if me is None:
            raise ValueError("the ACK of a native broadcast names the acknowledging system")
        source["system"] = me
    h = dict(data_header, kind=KIND_ACK, flags=data_header["flags"] & FLAG_BROADCAST_SEQ,
             source=source, destination=data_header["source"])
    return encode_frame(h, bytes([status]))


ACK_RANGE_MAX = 4096


def decode_ack(header: dict, payload: bytes) -> Tuple[str, int, int]:
    """An ACK's payload ("The ACK frame", "ACK ranges"): (status, first, last), the seqs
    first..=last it acknowledges. One byte acknowledges the header's seq alone; nine bytes
    are the status and `first` (u64 little-endian), first < seq and seq - first < 4096."""
    seq = header["seq"]
    if len(payload) == 1:
        first = seq
    elif len(payload) == 9:
        (first,) = struct.unpack_from("<Q", payload, 1)
        if first >= seq or seq - first >= ACK_RANGE_MAX:
            raise ValueError("BadAckRange")
    else:
        raise ValueError("BadAckPayload")
    if payload[0] not in ACK_STATUS:
        raise ValueError("BadAckStatus")
    return ACK_STATUS[payload[0]], first, seq


def peek_frame_len(d: bytes) -> Optional[int]:
    """Checks 1-4 on the first 48 bytes: the declared frame length, or None."""
    if len(d) < HEADER_LEN or d[:2] != b"HC" or d[2] != 1:
        return None
    payload_len = struct.unpack_from("<I", d, 40)[0]
    if payload_len > MAX_PAYLOAD:
        return None
    return HEADER_LEN + payload_len


# --- UDP ("Telling datagrams apart", "UDP batches", "UDP fragments") --------------------------

FRAGMENT = struct.Struct("<2sBBHHHHII")  # 20 bytes
FRAGMENT_HEADER_LEN = 20
DEFAULT_DATAGRAM_PAYLOAD = 1472
DEFAULT_MAX_FRAME = HEADER_LEN + MAX_PAYLOAD


def ceil_div(a: int, b: int) -> int:
    return -(-a // b)


BATCH_HEADER = b"HB\x01\x00"       # "HB", version 1, reserved 0
BATCH_LENGTH = struct.Struct("<I")  # in front of each frame of a batch


def split_datagram(d: bytes) -> Tuple[str, List[bytes], bytes]:
    """A datagram that does not start with "HF": ("whole" | "batch" | "dropped", frames,
    dropped tail)."""
    assert not d.startswith(b"HF"), "a fragment"
    if not d.startswith(b"HB"):
        return "whole", [d], b""
    if d[:4] != BATCH_HEADER:
        return "dropped", [], b""
    frames = []
    d = d[4:]
    while len(d) >= 4:
        (n,) = BATCH_LENGTH.unpack_from(d)
        if n > len(d) - 4:
            break
        frames.append(d[4:4 + n])
        d = d[4 + n:]
    return "batch", frames, d


def encode_batch(frames: List[bytes]) -> bytes:
    """A batch datagram holding `frames` (any bytes), as a sender writes it."""
    return BATCH_HEADER + b"".join(BATCH_LENGTH.pack(len(f)) + f for f in frames)


def datagrams_for(frame: bytes, sender: int, message_id: int,
                  datagram_payload: int = DEFAULT_DATAGRAM_PAYLOAD) -> List[bytes]:
    """What a sender puts on the wire for one frame: the frame itself when it fits and cannot be
    misread (it starts with neither "HF" nor "HB"), fragments otherwise."""
    misread = frame.startswith(b"HF") or frame.startswith(b"HB")
    if len(frame) <= datagram_payload and not misread:
        return [frame]
    return fragments(frame, sender, message_id, datagram_payload)


def fragments(frame: bytes, sender: int, message_id: int,
              datagram_payload: int = DEFAULT_DATAGRAM_PAYLOAD) -> List[bytes]:
    count = max(1, ceil_div(len(frame), datagram_payload - FRAGMENT_HEADER_LEN))
    chunk = ceil_div(len(frame), count)
    return [FRAGMENT.pack(b"HF", 1, 0, sender, i, count, 0, message_id & 0xFFFFFFFF, len(frame))
            + frame[i * chunk:(i + 1) * chunk] for i in range(count)]


def parse_fragment(d: bytes, max_frame: int):
    """The fragment checks 1-4: (sender, index, count, message_id, total, piece)."""
    if len(d) < FRAGMENT_HEADER_LEN:
        raise ValueError("Truncated")
    magic, version, reserved, sender, index, count, reserved2, message_id, total = FRAGMENT.unpack_from(d)
    if magic != b"HF" or version != 1 or reserved != 0 or reserved2 != 0:
        raise ValueError("BadHeader")
    if not (count >= 1 and index < count and 1 <= total <= max_frame and count <= total
            and (count - 1) * ceil_div(total, count) < total):
        raise ValueError("BadGeometry")
    chunk = ceil_div(total, count)
    start = index * chunk
    piece = d[FRAGMENT_HEADER_LEN:]
    if len(piece) != min(start + chunk, total) - start:
        raise ValueError("BadLength")
    return sender, index, count, message_id, total, piece


class Reassembler:
    """Reassembly as documented, without the timeout and memory bound (the tests hold little)."""

    def __init__(self, max_frame: int = DEFAULT_MAX_FRAME) -> None:
        self.max_frame = max_frame
        # (source address, sender, message id) -> [total, count, pieces by index]
        self.partial: Dict[tuple, list] = {}
        # Keys of messages completed (within the timeout, which this port does not model).
        self.completed: set = set()
        self.duplicates = 0

    @property
    def pending(self) -> int:
        return len(self.partial)

    def on_fragment(self, d: bytes, src=None, src_system: Optional[int] = None) -> Optional[bytes]:
        """The complete frame, or None; ValueError for a rejected fragment."""
        sender, index, count, message_id, total, piece = parse_fragment(d, self.max_frame)
        if src_system is not None and src_system != sender:
            raise ValueError("WrongSender")
        if count == 1:
            return piece
        key = (src, sender, message_id)
        p = self.partial.get(key)
        if p is not None and (p[0] != total or p[1] != count):
            del self.partial[key]
            raise ValueError("Inconsistent")
        if p is None:
            if key in self.completed:
                self.duplicates += 1      # a late duplicate: nothing is held for it
                return None
            p = self.partial[key] = [total, count, {}]
        if index in p[2]:
            self.duplicates += 1
            return None
        p[2][index] = piece              # held by what arrived, not by `total`
        if len(p[2]) < count:
            return None
        del self.partial[key]
        self.completed.add(key)
        return b"".join(p[2][i] for i in range(count))


# --- streams ("The hello", "Records") ----------------------------------------------------------

HELLO = struct.Struct("<2sBBHH")
RECORD = struct.Struct("<2sBBI")


def encode_hello(system: int) -> bytes:
    return HELLO.pack(b"HL", 1, 0, system, 0)


def decode_hello(h: bytes) -> Optional[int]:
    """The system a hello names, or None if it is refused (fleet membership aside)."""
    if len(h) != 8:
        return None
    magic, version, reserved, system, reserved2 = HELLO.unpack(h)
    ok = magic == b"HL" and version == 1 and reserved == 0 and reserved2 == 0
    return system if ok else None


def encode_record(frame: bytes) -> bytes:
    return RECORD.pack(b"HR", 1, 0, len(frame)) + frame


def record_length(head: bytes, max_frame: int) -> Optional[int]:
    """The frame length an 8-byte record header announces, or None if the reader refuses it."""
    magic, version, reserved, length = RECORD.unpack(head)
    if magic != b"HR" or version != 1 or reserved != 0 or length > max_frame:
        return None
    return length


def read_records(stream: bytes, max_frame: int = DEFAULT_MAX_FRAME) -> Tuple[List[bytes], str]:
    """A connection's bytes after the hello: the frames and how it ends ("clean", "cut", "bad")."""
    frames = []
    while stream:
        if len(stream) < 8:
            return frames, "cut"
        length = record_length(stream[:8], max_frame)
        if length is None:
            return frames, "bad"
        if len(stream) < 8 + length:
            return frames, "cut"
        frames.append(stream[8:8 + length])
        stream = stream[8 + length:]
    return frames, "clean"


def recv_exact(sock, n: int) -> bytes:
    """Exactly n bytes from a stream socket (ValueError if it ends first)."""
    out = bytearray()
    while len(out) < n:
        got = sock.recv(n - len(out))
        if not got:
            raise ValueError(f"stream ended after {len(out)} of {n} bytes")
        out += got
    return bytes(out)


def recv_record(sock, max_frame: int = DEFAULT_MAX_FRAME) -> bytes:
    length = record_length(recv_exact(sock, 8), max_frame)
    if length is None:
        raise ValueError("bad record header")
    return recv_exact(sock, length)


# --- MessagePack, the little the tests write by hand --------------------------------------------

def msgpack_str(s: str) -> bytes:
    """A str of any length (str 32 above 65535 bytes)."""
    b = s.encode()
    if len(b) < 32:
        return bytes([0xA0 | len(b)]) + b
    if len(b) < 256:
        return b"\xd9" + bytes([len(b)]) + b
    if len(b) < 65536:
        return b"\xda" + struct.pack(">H", len(b)) + b
    return b"\xdb" + struct.pack(">I", len(b)) + b


def msgpack_wheels(left: float, right: float) -> bytes:
    """{"left": left, "right": right} with float 64 values, as Rust writes Wheels."""
    return (b"\x82" + msgpack_str("left") + b"\xcb" + struct.pack(">d", left)
            + msgpack_str("right") + b"\xcb" + struct.pack(">d", right))
