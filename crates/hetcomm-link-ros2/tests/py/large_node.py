#!/usr/bin/env python3
"""A ROS 2 node written with Cyclone DDS's Python package (no ROS 2 install) that publishes or
reads large messages, for tests/large_messages.rs and benchmarks/ros-large.sh:
`sensor_msgs/msg/Image` (640x480 rgb8, 921,600 bytes of pixels) or `sensor_msgs/msg/PointCloud2`
(100,000 points of x, y, z, intensity: 1.6 MB), on DDS as ROS 2 names them (topic
`rt/<topic>`, type `sensor_msgs::msg::dds_::Image_`).

Message K carries `frame_id = "K"` and the bytes `(i + K) % 251` for i = 0, 1, ...: a reader
checks every byte of every message against that (one comparison of the whole buffer).

    python large_node.py read --domain 7 --topic /t/image --type image --count 90
        prints `ready` once its reader exists, then for each message
        `K ok|bad LATENCY_MS ARRIVAL_S` (latency from the header's stamp to its arrival,
        wall clock; arrival in seconds of the wall clock), and `done` after --count
        messages or --seconds
    python large_node.py publish --domain 7 --topic /t/image --type image --count 90 --hz 30
        waits for a matched reader, publishes, then prints `sent N SECONDS`

QoS: ROS 2's defaults (reliable, volatile, keep last) with a depth of --count, so that a
reader that is slow for a moment loses nothing. Both ends may be this node (the baseline of
benchmarks/ros-large.sh) or one may be hetcomm.
"""

import argparse
import os
import sys
import time
from dataclasses import dataclass, field

if "CYCLONEDDS_URI" not in os.environ:
    os.environ["CYCLONEDDS_URI"] = (
        "<CycloneDDS><Domain id='any'><General>"
        "<Interfaces><NetworkInterface address='127.0.0.1'/></Interfaces>"
        "<AllowMulticast>false</AllowMulticast></General>"
        "<Discovery><ParticipantIndex>auto</ParticipantIndex>"
        "<MaxAutoParticipantIndex>40</MaxAutoParticipantIndex>"
        "<Peers><Peer address='127.0.0.1'/></Peers></Discovery>"
        # A 1.6 MB sample arrives as one burst of fragments: Cyclone's default socket
        # buffer (the kernel's 208 KiB) overflows, and the writer resends whole samples.
        "<Internal><SocketReceiveBufferSize max='4MB'/></Internal>"
        "</Domain></CycloneDDS>"
    )

import cyclonedds.idl.annotations as annotate  # noqa: E402
from cyclonedds.core import Policy, Qos  # noqa: E402
from cyclonedds.domain import DomainParticipant  # noqa: E402
from cyclonedds.idl import IdlStruct  # noqa: E402
from cyclonedds.idl._machinery import BytesMachine  # noqa: E402
from cyclonedds.idl.types import int32, sequence, uint8, uint32  # noqa: E402
from cyclonedds.pub import DataWriter  # noqa: E402
from cyclonedds.sub import DataReader  # noqa: E402
from cyclonedds.topic import Topic  # noqa: E402
from cyclonedds.util import duration  # noqa: E402

WIDTH, HEIGHT = 640, 480
POINTS = 100_000
SIZES = {"image": WIDTH * HEIGHT * 3, "cloud": POINTS * 16}


@dataclass
@annotate.final
class Time(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: int32 = 0
    nanosec: uint32 = 0


@dataclass
@annotate.final
class Header(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: Time = field(default_factory=Time)
    frame_id: str = ""


@dataclass
@annotate.final
class Image(IdlStruct, typename="sensor_msgs::msg::dds_::Image_"):
    header: Header = field(default_factory=Header)
    height: uint32 = 0
    width: uint32 = 0
    encoding: str = ""
    is_bigendian: uint8 = 0
    step: uint32 = 0
    # sequence<uint8>, read and written whole as bytes (see `whole_bytes`).
    data: sequence[uint8] = field(default_factory=list)


@dataclass
@annotate.final
class PointField(IdlStruct, typename="sensor_msgs::msg::dds_::PointField_"):
    name: str = ""
    offset: uint32 = 0
    datatype: uint8 = 0
    count: uint32 = 0


@dataclass
@annotate.final
class PointCloud2(IdlStruct, typename="sensor_msgs::msg::dds_::PointCloud2_"):
    header: Header = field(default_factory=Header)
    height: uint32 = 0
    width: uint32 = 0
    fields: sequence[PointField] = field(default_factory=list)
    is_bigendian: bool = False
    point_step: uint32 = 0
    row_step: uint32 = 0
    data: sequence[uint8] = field(default_factory=list)
    is_dense: bool = False


def whole_bytes(kind):
    """Reads and writes `kind`'s `data` (sequence<uint8>) as one `bytes`, with the package's
    own machine for `bytes` (same CDR: a uint32 length, then the bytes). Its machine for
    sequence<uint8> packs and unpacks one int at a time, which held this node to 13 images a
    second; `data: bytes` cannot be declared (the package builds no XTypes type for it)."""
    kind.__idl__.populate()
    for machine in (kind.__idl__.v1_machine, kind.__idl__.v2_machine):
        machine.members_machines["data"] = BytesMachine()


def pattern(size):
    """Bytes (i % 251) for i up to size + 251: message K's data is pattern[K % 251:][:size]."""
    return bytes(i % 251 for i in range(251)) * (size // 251 + 2)


def message(kind, k, base):
    size = SIZES[kind]
    data = base[k % 251 : k % 251 + size]
    header = Header(frame_id=str(k))
    if kind == "image":
        return Image(header=header, height=HEIGHT, width=WIDTH, encoding="rgb8", step=WIDTH * 3,
                     data=data)
    fields = [PointField(name=n, offset=4 * i, datatype=7, count=1)
              for i, n in enumerate(["x", "y", "z", "intensity"])]
    return PointCloud2(header=header, height=1, width=POINTS, fields=fields, point_step=16,
                       row_step=16 * POINTS, data=data, is_dense=True)


def stamp_now():
    ns = time.time_ns()
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def read(args, dp, topic, qos, base):
    size = SIZES[args.type]
    reader = DataReader(dp, topic, qos=qos)
    print("ready", flush=True)
    got = 0
    end = time.monotonic() + args.seconds
    while got < args.count and time.monotonic() < end:
        for m in reader.take(N=64):
            if not hasattr(m, "header"):
                continue  # an InvalidSample: the writer went away, no data
            now = time.time()
            k = int(m.header.frame_id)
            ok = m.data == base[k % 251 : k % 251 + size]
            sent = m.header.stamp.sec + m.header.stamp.nanosec * 1e-9
            print(f"{k} {'ok' if ok else 'bad'} {(now - sent) * 1000:.2f} {now:.6f}", flush=True)
            got += 1
        time.sleep(0.001)
    print("done", flush=True)


def publish(args, dp, topic, qos, base):
    writer = DataWriter(dp, topic, qos=qos)
    end = time.monotonic() + args.seconds
    while writer.get_matched_subscriptions() == []:
        if time.monotonic() > end:
            sys.exit("no reader matched")
        time.sleep(0.05)
    messages = [message(args.type, k, base) for k in range(args.count)]
    start = time.monotonic()
    for k, m in enumerate(messages):
        # On the 30 Hz grid from the first message: a late one does not delay the rest.
        delay = start + k / args.hz - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        m.header.stamp = stamp_now()
        writer.write(m)
    print(f"sent {args.count} {time.monotonic() - start:.3f}", flush=True)
    # Keep the writer while the last samples are acknowledged.
    time.sleep(args.linger)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("mode", choices=["read", "publish"])
    ap.add_argument("--domain", type=int, default=0)
    ap.add_argument("--topic", required=True)
    ap.add_argument("--type", choices=sorted(SIZES), default="image")
    ap.add_argument("--count", type=int, default=90)
    ap.add_argument("--hz", type=float, default=30)
    ap.add_argument("--seconds", type=float, default=60)
    ap.add_argument("--linger", type=float, default=2)
    args = ap.parse_args()
    kind = Image if args.type == "image" else PointCloud2
    qos = Qos(
        Policy.Reliability.Reliable(duration(milliseconds=100)),
        Policy.Durability.Volatile,
        Policy.History.KeepLast(args.count),
    )
    dp = DomainParticipant(args.domain)
    topic = Topic(dp, "rt" + args.topic, kind, qos=qos)
    whole_bytes(kind)
    base = pattern(SIZES[args.type])
    (read if args.mode == "read" else publish)(args, dp, topic, qos, base)


if __name__ == "__main__":
    main()
