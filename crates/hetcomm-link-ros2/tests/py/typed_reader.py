#!/usr/bin/env python3
"""A DDS reader of typed samples, with Cyclone DDS's Python package (no ROS 2 install): the
foreign node of the one-shot bridge tests (crates/hetcomm-cli/tests/ros2_send.rs) and of the
`dds` kind's test (tests/dds_kind.rs).

    python3 typed_reader.py --domain 7 --topic rt/t/cmd_vel --type twist --seconds 60

`--type twist` reads ROS 2's `geometry_msgs/msg/Twist` (DDS type
`geometry_msgs::msg::dds_::Twist_`) and prints `linear.x` of each sample as an integer;
`--type command` reads a plain DDS type of its own, IDL

    module fleet { struct Command { double speed; double turn; string note; }; };

(DDS type `fleet::Command`) and prints `speed note` of each sample. QoS: reliable,
volatile, keep last 1000 (ROS 2's defaults but the depth). `--answer TOPIC` also writes a
`fleet::Command` with speed doubled and note "answer" on that topic for each one read.
Prints `ready` once its reader exists; exits after `--seconds` or when stdin closes.
"""

import argparse
import os
import select
import sys
import time
from dataclasses import dataclass

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
from cyclonedds.idl.types import float64  # noqa: E402
from cyclonedds.pub import DataWriter  # noqa: E402
from cyclonedds.sub import DataReader  # noqa: E402
from cyclonedds.topic import Topic  # noqa: E402
from cyclonedds.util import duration  # noqa: E402


@dataclass
@annotate.final
class Vector3(IdlStruct, typename="geometry_msgs::msg::dds_::Vector3_"):
    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0


@dataclass
@annotate.final
class Twist(IdlStruct, typename="geometry_msgs::msg::dds_::Twist_"):
    linear: Vector3 = None
    angular: Vector3 = None


@dataclass
@annotate.final
class Command(IdlStruct, typename="fleet::Command"):
    speed: float64 = 0.0
    turn: float64 = 0.0
    note: str = ""


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--domain", type=int, default=0)
    ap.add_argument("--topic", required=True)
    ap.add_argument("--type", choices=["twist", "command"], default="twist")
    ap.add_argument("--answer", default=None)
    ap.add_argument("--seconds", type=float, default=60)
    args = ap.parse_args()

    qos = Qos(
        Policy.Reliability.Reliable(duration(milliseconds=100)),
        Policy.Durability.Volatile,
        Policy.History.KeepLast(1000),
    )
    dp = DomainParticipant(args.domain)
    kind = Twist if args.type == "twist" else Command
    reader = DataReader(dp, Topic(dp, args.topic, kind, qos=qos), qos=qos)
    writer = None
    if args.answer:
        writer = DataWriter(dp, Topic(dp, args.answer, Command, qos=qos), qos=qos)
    print("ready", flush=True)
    end = time.monotonic() + args.seconds
    while time.monotonic() < end:
        if select.select([sys.stdin], [], [], 0)[0] and not sys.stdin.read(1):
            break
        for s in reader.take(N=256):
            if not isinstance(s, kind):
                continue  # an InvalidSample: a writer went away (a one-shot sender exited)
            if args.type == "twist":
                print(int(s.linear.x), flush=True)
            else:
                print(f"{s.speed:g} {s.note}", flush=True)
                if writer is not None:
                    writer.write(Command(speed=s.speed * 2, turn=s.turn, note="answer"))
        time.sleep(0.005)


if __name__ == "__main__":
    main()
