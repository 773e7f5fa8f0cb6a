#!/usr/bin/env python3
"""A plain ROS 2 / DDS program on the `ros2` transport's topics, with Cyclone DDS's Python
package: it reads `std_msgs/msg/UInt8MultiArray` samples on `rt<ns>/B` (system B's topic) and
writes each one's `data` back, in a sample of its own, on `rt<ns>/A`. Used by
tests/python_interop.rs to check that a link's samples are what any DDS program reads and
writes.

    python3 frame_echo.py --domain 7 --namespace /ns --seconds 30

Prints `ready` once its reader and writer exist, and exits after `--seconds` or when its
standard input closes.
"""

import argparse
import os
import select
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
        "</Domain></CycloneDDS>"
    )

import cyclonedds.idl.annotations as annotate  # noqa: E402
from cyclonedds.core import Policy, Qos  # noqa: E402
from cyclonedds.domain import DomainParticipant  # noqa: E402
from cyclonedds.idl import IdlStruct  # noqa: E402
from cyclonedds.idl.types import sequence, uint8, uint32  # noqa: E402
from cyclonedds.pub import DataWriter  # noqa: E402
from cyclonedds.sub import DataReader  # noqa: E402
from cyclonedds.topic import Topic  # noqa: E402
from cyclonedds.util import duration  # noqa: E402


@dataclass
@annotate.final
class MultiArrayDimension(IdlStruct, typename="std_msgs::msg::dds_::MultiArrayDimension_"):
    label: str = ""
    size: uint32 = 0
    stride: uint32 = 0


@dataclass
@annotate.final
class MultiArrayLayout(IdlStruct, typename="std_msgs::msg::dds_::MultiArrayLayout_"):
    dim: sequence[MultiArrayDimension] = field(default_factory=list)
    data_offset: uint32 = 0


@dataclass
@annotate.final
class UInt8MultiArray(IdlStruct, typename="std_msgs::msg::dds_::UInt8MultiArray_"):
    layout: MultiArrayLayout = field(default_factory=MultiArrayLayout)
    data: sequence[uint8] = field(default_factory=list)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--domain", type=int, required=True)
    ap.add_argument("--namespace", required=True)
    ap.add_argument("--seconds", type=float, default=30)
    args = ap.parse_args()

    qos = Qos(
        Policy.Reliability.Reliable(duration(milliseconds=100)),
        Policy.Durability.Volatile,
        Policy.History.KeepLast(1000),
    )
    dp = DomainParticipant(args.domain)
    reader = DataReader(dp, Topic(dp, f"rt{args.namespace}/B", UInt8MultiArray), qos=qos)
    writer = DataWriter(dp, Topic(dp, f"rt{args.namespace}/A", UInt8MultiArray), qos=qos)
    print("ready", flush=True)
    end = time.monotonic() + args.seconds
    while time.monotonic() < end:
        if select.select([sys.stdin], [], [], 0)[0] and not sys.stdin.read(1):
            break
        for sample in reader.take(N=100):
            if not isinstance(sample, UInt8MultiArray):
                continue  # an InvalidSample: a writer went away, no data
            # Echoed with a layout of our own: the link must skip over it.
            layout = MultiArrayLayout(dim=[MultiArrayDimension("bytes", len(sample.data), 1)])
            writer.write(UInt8MultiArray(layout=layout, data=sample.data))
        time.sleep(0.002)


if __name__ == "__main__":
    main()
