#!/usr/bin/env python3
"""Writes seed corpora for the link-layer and security fuzz targets from docs/wire-vectors.json.

    cd fuzz && python3 seed_corpus.py

Creates corpus/udp_reassembly/, corpus/udp_datagrams/, corpus/stream_records/,
corpus/stream_driven/ and corpus/secured_frames/ (all gitignored), in the input layouts the targets document (fuzz_targets/*.rs).
"""
import json
import os
import struct

HERE = os.path.dirname(os.path.abspath(__file__))
VECTORS = json.load(open(os.path.join(HERE, "..", "docs", "wire-vectors.json")))
DEFAULT_MAX_FRAME = 16 * 1024 * 1024 + 48


def write(target, name, data):
    # udp_datagrams reads the same configuration and raw-datagram operations as
    # udp_reassembly, and stream_driven the same input as stream_records: same seeds.
    twin = {"udp_reassembly": "udp_datagrams", "stream_records": "stream_driven"}[target]
    for t in (target, twin):
        d = os.path.join(HERE, "corpus", t)
        os.makedirs(d, exist_ok=True)
        with open(os.path.join(d, "vec_" + name), "wb") as f:
            f.write(data)


# --- udp_reassembly -------------------------------------------------------------------------
# (udp_datagrams reads the same layout.)
# Config byte 0: UdpConfig::default() (32 MiB limit, max_frame 16 MiB + 48).
# Config byte 1 + u16 datagram-payload parameter + u16 max_message_bytes + u16 limit + u8
# timeout: a small configuration; payload parameter 0 gives 21-byte datagrams, so max_frame is
# min(48 + max_message_bytes, limit).
# Then a byte: bit 0 builds udp_reassembly's reassembler `with_fleet` (udp_datagrams ignores it).
def udp_config(max_frame, fleet=0):
    if max_frame == DEFAULT_MAX_FRAME:
        return b"\x00" + bytes([fleet])
    assert max_frame <= 0xFFFF
    return b"\x01" + struct.pack("<HHHB", 0, max(max_frame - 48, 0), max_frame, 200) + bytes([fleet])


def raw(datagram, system_mode=1, src=0):
    """Op 0: a raw datagram from source `src`, whose fleet system is SystemId(1) (mode 1)."""
    op = (system_mode << 6) | (src << 4)
    return bytes([op]) + struct.pack("<H", len(datagram)) + datagram


def h(s):
    return bytes.fromhex(s)


for v in VECTORS["udp_datagrams"]:
    write("udp_reassembly", "dgram_" + v["name"], udp_config(DEFAULT_MAX_FRAME) + raw(h(v["datagram_hex"])))
for v in VECTORS["udp_fragmented_frames"]:
    frags = [h(x) for x in v["fragments_hex"]]
    cfg = udp_config(DEFAULT_MAX_FRAME)
    write("udp_reassembly", "frag_" + v["name"], cfg + b"".join(raw(f) for f in frags))
    write("udp_reassembly", "frag_rev_" + v["name"], cfg + b"".join(raw(f) for f in reversed(frags)))
for v in VECTORS["udp_reassembly"]:
    ops = b"".join(raw(h(x)) for x in v["datagrams_hex"])
    write("udp_reassembly", "reasm_" + v["name"], udp_config(v["max_frame"]) + ops)
for v in VECTORS["udp_fragment_errors"]:
    write("udp_reassembly", "err_" + v["name"], udp_config(v["max_frame"]) + raw(h(v["datagram_hex"])))
# The suspected amplification: one 276-byte datagram, count 65535, total 16 776 960.
amp = struct.pack("<2sBBHHHHII", b"HF", 1, 0, 1, 0, 65535, 0, 1, 65535 * 256) + bytes(256)
write("udp_reassembly", "amplification_first_fragment", udp_config(DEFAULT_MAX_FRAME) + raw(amp))
write("udp_reassembly", "amplification_unknown_source", udp_config(DEFAULT_MAX_FRAME, 1) + raw(amp, system_mode=0))


# --- stream_records -------------------------------------------------------------------------
# flags, u16 parameter, u8 number of read sizes, u16 read sizes, stream.
def stream_input(stream, max_frame=DEFAULT_MAX_FRAME, flags=0, reads=()):
    if max_frame == DEFAULT_MAX_FRAME:
        param = 0
    else:
        flags |= 1 << 3  # max_message_bytes = parameter
        param = max_frame - 48
    return bytes([flags]) + struct.pack("<HB", param, len(reads)) + b"".join(
        struct.pack("<H", r) for r in reads
    ) + stream


HELLO_1 = h("484c010001000000")
CUTS = (1, 0, 3, 7, 2, 5, 1, 8, 0, 13, 1, 64)
for v in VECTORS["stream_records"]:
    s = h(v["stream_hex"])
    write("stream_records", "rec_" + v["name"], stream_input(HELLO_1 + s, v["max_frame"]))
    write("stream_records", "rec_cut_" + v["name"], stream_input(HELLO_1 + s, v["max_frame"], reads=CUTS))
    write("stream_records", "rec_anon_" + v["name"], stream_input(s, v["max_frame"], flags=1 << 1))
one_record = h(VECTORS["stream_records"][0]["stream_hex"])
for v in VECTORS["stream_hellos"]:
    write("stream_records", "hello_" + v["name"], stream_input(h(v["hello_hex"]) + one_record))


# Expanded streams (flags bit 7) with records over the 16 KiB direct-read threshold.
def lit(b):
    out = b""
    while b:
        out += bytes([min(len(b), 128) - 1]) + b[:128]
        b = b[128:]
    return out


def run(byte, blocks):
    return bytes([0x80 | (blocks - 1), byte])


def record_header(n):
    return b"HR\x01\x00" + struct.pack("<I", n)


big = lit(HELLO_1 + record_header(20000)) + run(0xAB, 39) + lit(bytes(range(32)))
write("stream_records", "big_one", stream_input(big, flags=0x80))
write("stream_records", "big_one_handout", stream_input(big, flags=0x81))
write("stream_records", "big_one_cut", stream_input(big, flags=0x81, reads=(5, 0, 9, 3000, 17000, 1)))
two = big + lit(record_header(40000)) + run(0x11, 78) + lit(bytes(64)) + lit(one_record)
write("stream_records", "big_two_then_small", stream_input(two, flags=0x80, reads=(100, 20000)))
write("stream_records", "big_two_handout", stream_input(two, flags=0x81))
write("stream_records", "big_truncated", stream_input(lit(HELLO_1 + record_header(30000)) + run(1, 20), flags=0x81))
print("seeded", *(f"{t}: {len(os.listdir(os.path.join(HERE, 'corpus', t)))}" for t in ("udp_reassembly", "udp_datagrams", "stream_records", "stream_driven")))


# --- secured_frames -------------------------------------------------------------------------
# A configuration byte (bit 0: in-memory sessions; bits 1-2: data from systems 1 / 3; bits
# 3-4: ACKs from 1 / 3; bit 5: system 3 has no key), then operations (fuzz_targets/
# secured_frames.rs, `run`): a byte whose low 3 bits choose the operation and high 4 bits how
# the frame is fed, then the operation's arguments.
def sec_write(name, data):
    d = os.path.join(HERE, "corpus", "secured_frames")
    os.makedirs(d, exist_ok=True)
    with open(os.path.join(d, "vec_" + name), "wb") as f:
        f.write(data)


NO_MUTATION = b"\x00\x00\x00"  # mutation 0, position 0


def inner(payload=b"", sel=0, source=1, destination=2):
    """An inner frame; sel bit 0: with `source`, bit 1: with `destination`, bit 2: an ACK."""
    ids = (bytes([source]) if sel & 1 else b"") + (bytes([destination]) if sel & 2 else b"")
    return bytes([sel]) + ids + struct.pack("<H", 7) + bytes([len(payload)]) + payload


def sec_handshake(p, index, timestamp, seed):  # op 0: the played system p (0: 1, 1: 3) initiates
    return b"\x00" + bytes([p]) + struct.pack("<IHB", index, timestamp, seed) + NO_MUTATION


def sec_answer(p, index, seed):  # op 1: the layer's initiation to p answered
    return b"\x01" + bytes([p]) + struct.pack("<IB", index, seed) + NO_MUTATION


def sec_seal(p, session=0, payload=b"", sel=0, how=0, mutation=NO_MUTATION):  # op 2
    return bytes([2 | how << 4, p, session]) + inner(payload, sel) + mutation


def sec_send(p, payload=b"", how=0):  # op 4: the layer sends to p
    return bytes([4 | how << 4, 0, p]) + inner(payload)


def sec_again(i, mutation=NO_MUTATION):  # op 5: an earlier frame again
    return b"\x05" + struct.pack("<H", i) + mutation


ALL = 0x1E  # over the link, data and ACKs from 1 and 3
sec_write("in_memory", bytes([ALL | 1]) + sec_seal(0, payload=b"hello") + sec_again(0)
          + sec_send(0, b"back") + sec_seal(1, payload=b"x" * 20, how=1)
          + sec_seal(0, payload=b"flip", mutation=b"\x01\x19\x00"))
sec_write("over_the_link", bytes([ALL]) + sec_handshake(0, 0x11223344, 5, 1) + sec_seal(0, payload=b"data")
          + sec_send(0, b"ack") + sec_send(1, b"queued") + sec_answer(1, 0x55667788, 2)
          + sec_seal(1, payload=b"three", how=2) + sec_again(0) + sec_again(1)
          + sec_handshake(0, 0x11223345, 4, 3))
sec_write("table", bytes([0x02]) + sec_handshake(0, 9, 1, 1) + sec_seal(0, sel=1) + sec_seal(0, sel=4)
          + sec_handshake(1, 10, 1, 1))
for v in VECTORS["secured_frames"]["received"]:
    f = h(v["secured_hex"])[:127]
    sec_write("raw_" + v["name"], bytes([ALL]) + b"\x07" + bytes([len(f)]) + f)
# Three handshakes from system 1: frames of the session before the current one still open, those
# of the one before that no longer do; then system 3's and the layer's handshakes cross.
sec_write("rekey", bytes([ALL]) + sec_handshake(0, 1, 1, 1) + sec_seal(0, 0, b"one")
          + sec_handshake(0, 2, 2, 2) + sec_seal(0, 0, b"old") + sec_seal(0, 1, b"new")
          + sec_handshake(0, 3, 3, 3) + sec_seal(0, 0, b"gone") + sec_seal(0, 1, b"previous")
          + sec_seal(0, 2, b"current") + sec_send(0, b"out") + sec_send(1, b"wait")
          + sec_handshake(1, 4, 1, 4) + sec_answer(1, 5, 5) + sec_seal(1, 0, b"three"))
