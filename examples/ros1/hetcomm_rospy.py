#!/usr/bin/python3
"""Talk to a hetcomm system over ROS 1 from rospy, with nothing of hetcomm installed.

hetcomm's `ros1` transport carries one hetcomm frame (docs/wire-format.md: a 48-byte header
with a CRC-32, then a MessagePack payload) in the `data` of a `std_msgs/UInt8MultiArray`, on
a topic named after the destination system (`/<namespace>/<Name>`). This script plays a
system of the fleet (default: `Rospy`, id 2): it publishes one data frame to a hetcomm
system's topic, listens on its own topic, and prints the first data frame it gets back as
JSON. It exits 0 when a reply arrived, 1 on timeout.

Run it with /usr/bin/python3 (rospy is a Debian package):

    ROS_MASTER_URI=http://127.0.0.1:11311 ROS_HOSTNAME=127.0.0.1 \\
      /usr/bin/python3 examples/ros1/hetcomm_rospy.py --namespace interop \\
      --to Alpha --to-id 1 --me Rospy --me-id 2 --text hello

The frame is sent without an acknowledgement request (flags 0), to module `--to-module`
(default 2) from module `--me-module` (default 1), with message type `--type` (default 7)
and the payload `{"text": TEXT}`. It is re-published every 0.2 s until a reply arrives, since
ROS 1 drops what is published before the hetcomm side's subscriber has connected; hetcomm's
router drops the copies as duplicates (same origin, incarnation and seq).
"""

import argparse
import json
import os
import struct
import sys
import threading
import time
import zlib

import rospy
from std_msgs.msg import UInt8MultiArray

try:
    import msgpack  # Debian: python3-msgpack
except ImportError:  # hand-encode the tiny {str: str} maps this example uses
    msgpack = None

HEADER = struct.Struct("<2sBBBBBBHHHHIQIQII")  # 48 bytes, little-endian, no padding
assert HEADER.size == 48


def pack_str_map(d):
    if msgpack is not None:
        return msgpack.packb(d)
    out = bytearray([0x80 | len(d)])  # fixmap
    for k, v in d.items():
        for s in (k, v):
            b = s.encode()
            assert len(b) < 256
            out += bytes([0xA0 | len(b)]) if len(b) < 32 else bytes([0xD9, len(b)])
            out += b
    return bytes(out)


def unpack(payload):
    if msgpack is not None:
        return msgpack.unpackb(payload, raw=False)
    # Minimal reader: a fixmap of fixstr/str8 keys and values.
    d, i = {}, 1
    def read_str(i):
        t = payload[i]
        if t & 0xE0 == 0xA0:
            n, i = t & 0x1F, i + 1
        elif t == 0xD9:
            n, i = payload[i + 1], i + 2
        else:
            raise ValueError("unsupported MessagePack type 0x%02x" % t)
        return payload[i:i + n].decode(), i + n
    for _ in range(payload[0] & 0x0F):
        k, i = read_str(i)
        v, i = read_str(i)
        d[k] = v
    return d


def encode_frame(src, dst, message_type, payload, seq=1, flags=0):
    incarnation = int.from_bytes(os.urandom(4), "little")
    timestamp_us = int(time.time() * 1_000_000)
    head = HEADER.pack(b"HC", 1, 0, flags, 100, ord("R"), 0, src[0], src[1], dst[0], dst[1],
                       incarnation, seq, message_type, timestamp_us, len(payload), 0)
    crc = zlib.crc32(head + payload)
    return head[:44] + struct.pack("<I", crc) + payload


def decode_frame(frame):
    if len(frame) < 48:
        raise ValueError("TooShort")
    (magic, version, kind, flags, priority, transport, _reserved, src_sys, src_mod, dst_sys,
     dst_mod, incarnation, seq, message_type, timestamp_us, payload_len, crc) = HEADER.unpack_from(frame)
    if magic != b"HC" or version != 1:
        raise ValueError("not a hetcomm v1 frame")
    if payload_len != len(frame) - 48:
        raise ValueError("LengthMismatch")
    if zlib.crc32(frame[:44] + b"\0\0\0\0" + frame[48:]) != crc:
        raise ValueError("BadChecksum")
    payload = frame[48:]
    return {
        "kind": kind, "flags": flags, "priority": priority, "transport": transport,
        "source": [src_sys, src_mod], "destination": [dst_sys, dst_mod],
        "incarnation": incarnation, "seq": seq, "message_type": message_type,
        "timestamp_us": timestamp_us,
        "payload": unpack(payload) if kind == 0 else payload[0],
    }


def topic(namespace, name):
    ns = "/".join(s for s in (namespace or "").split("/") if s)
    return "/" + (ns + "/" if ns else "") + name


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--namespace", default="")
    p.add_argument("--to", default="Alpha", help="the hetcomm system's friendly name")
    p.add_argument("--to-id", type=int, default=1)
    p.add_argument("--to-module", type=int, default=2)
    p.add_argument("--me", default="Rospy", help="this script's friendly name in the fleet")
    p.add_argument("--me-id", type=int, default=2)
    p.add_argument("--me-module", type=int, default=1)
    p.add_argument("--type", type=int, default=7, help="message type id")
    p.add_argument("--text", default="hello from rospy")
    p.add_argument("--timeout", type=float, default=20.0)
    a = p.parse_args()

    replies = []
    got = threading.Event()

    def on_message(msg):
        data = bytes(msg.data)
        try:
            f = decode_frame(data)
        except ValueError as e:
            rospy.logwarn("dropping a malformed frame: %s", e)
            return
        if f["kind"] == 0:
            replies.append(f)
            got.set()

    rospy.init_node("hetcomm_rospy", anonymous=True, disable_signals=True)
    rospy.Subscriber(topic(a.namespace, a.me), UInt8MultiArray, on_message, queue_size=100)
    pub = rospy.Publisher(topic(a.namespace, a.to), UInt8MultiArray, queue_size=100)
    frame = encode_frame((a.me_id, a.me_module), (a.to_id, a.to_module), a.type,
                         pack_str_map({"text": a.text}))
    deadline = time.time() + a.timeout
    while not got.is_set() and time.time() < deadline:
        pub.publish(UInt8MultiArray(data=frame))
        got.wait(0.2)
    if not got.is_set():
        print("no reply within %.0f s" % a.timeout, file=sys.stderr)
        rospy.signal_shutdown("timeout")
        return 1
    print(json.dumps(replies[0]))
    sys.stdout.flush()
    rospy.signal_shutdown("done")
    return 0


if __name__ == "__main__":
    sys.exit(main())
