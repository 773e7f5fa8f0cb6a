#!/usr/bin/env python3
"""Writes seed corpora for the link-layer fuzz targets from docs/wire-vectors.json.

    cd fuzz && python3 seed_corpus.py

Creates corpus/udp_reassembly/, corpus/udp_datagrams/, corpus/stream_records/ and
corpus/stream_driven/ (all gitignored), in the input layouts the targets document (fuzz_targets/*.rs).
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
