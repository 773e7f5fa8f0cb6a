#!/usr/bin/env python3
"""Tango as an external ROS 2 robot: a small rover written with Cyclone DDS's Python package
(PyPI `cyclonedds`), with nothing of ROS 2 or hetcomm installed.

It is a ROS 2 node as far as the wire is concerned: ROS 2 topic names (`rt/<topic>`), ROS 2
type names (`geometry_msgs::msg::dds_::Twist_`), CDR payloads, ROS 2's default QoS
(reliable, volatile, keep last 10). It

* subscribes to `<prefix>/cmd_vel` (`geometry_msgs/Twist`) and drives a unicycle model with
  the last command (forward speed `linear.x`, turn rate `angular.z`);
* publishes its odometry on `<prefix>/odom` (`nav_msgs/Odometry`) every `--period` seconds;
* answers every `std_msgs/String` on `<prefix>/say` with `"heard: <text>"` on
  `<prefix>/heard`;
* with `--garbage N`, also publishes N samples on `<prefix>/odom` that claim to be
  `nav_msgs/Odometry` but hold only a few bytes, and with `--wrong-type` a
  `std_msgs/String` publisher on `<prefix>/odom`: input hetcomm's bridge must count and
  report, not deliver;
* with `--odom-hash HASH` and `--cmd-vel-hash HASH`, offers `typehash=HASH;` in the
  USER_DATA of its odometry writer and its cmd_vel reader, as ROS 2 Iron and later do
  (REP 2011), so that a test can offer the real type hashes or wrong ones.

Discovery without multicast (loopback has none): unless CYCLONEDDS_URI is set, the script
configures Cyclone DDS with unicast peer 127.0.0.1 on the loopback interface.

    python3 examples/ros2/tango_rover.py --domain 0 --prefix /tango --seconds 30

It prints one line per second (`t=…  x=…  y=…  heading=…  cmds=…`) and exits after
`--seconds`.
"""

import argparse
import math
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
        "</Domain></CycloneDDS>"
    )

import cyclonedds.idl.annotations as annotate  # noqa: E402
from cyclonedds.core import Policy, Qos  # noqa: E402
from cyclonedds.domain import DomainParticipant  # noqa: E402
from cyclonedds.idl import IdlStruct  # noqa: E402
from cyclonedds.idl.types import array, float64, int8, int32, uint16, uint32  # noqa: E402
from cyclonedds.pub import DataWriter  # noqa: E402
from cyclonedds.sub import DataReader  # noqa: E402
from cyclonedds.topic import Topic  # noqa: E402
from cyclonedds.util import duration  # noqa: E402


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
class Vector3(IdlStruct, typename="geometry_msgs::msg::dds_::Vector3_"):
    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0


@dataclass
@annotate.final
class Point(IdlStruct, typename="geometry_msgs::msg::dds_::Point_"):
    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0


@dataclass
@annotate.final
class Quaternion(IdlStruct, typename="geometry_msgs::msg::dds_::Quaternion_"):
    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0
    w: float64 = 1.0


@dataclass
@annotate.final
class Twist(IdlStruct, typename="geometry_msgs::msg::dds_::Twist_"):
    linear: Vector3 = field(default_factory=Vector3)
    angular: Vector3 = field(default_factory=Vector3)


@dataclass
@annotate.final
class Pose(IdlStruct, typename="geometry_msgs::msg::dds_::Pose_"):
    position: Point = field(default_factory=Point)
    orientation: Quaternion = field(default_factory=Quaternion)


@dataclass
@annotate.final
class PoseWithCovariance(IdlStruct, typename="geometry_msgs::msg::dds_::PoseWithCovariance_"):
    pose: Pose = field(default_factory=Pose)
    covariance: array[float64, 36] = field(default_factory=lambda: [0.0] * 36)


@dataclass
@annotate.final
class TwistWithCovariance(IdlStruct, typename="geometry_msgs::msg::dds_::TwistWithCovariance_"):
    twist: Twist = field(default_factory=Twist)
    covariance: array[float64, 36] = field(default_factory=lambda: [0.0] * 36)


@dataclass
@annotate.final
class Odometry(IdlStruct, typename="nav_msgs::msg::dds_::Odometry_"):
    header: Header = field(default_factory=Header)
    child_frame_id: str = ""
    pose: PoseWithCovariance = field(default_factory=PoseWithCovariance)
    twist: TwistWithCovariance = field(default_factory=TwistWithCovariance)


@dataclass
@annotate.final
class String(IdlStruct, typename="std_msgs::msg::dds_::String_"):
    data: str = ""


@dataclass
@annotate.final
class NotOdometry(IdlStruct, typename="nav_msgs::msg::dds_::Odometry_"):
    """Claims to be an Odometry; holds one byte (the bridge cannot decode it)."""

    junk: int8 = 7


# Unused by the rover, kept so the module documents every type of docs/ros-bridges.md.
@dataclass
@annotate.final
class NavSatStatus(IdlStruct, typename="sensor_msgs::msg::dds_::NavSatStatus_"):
    status: int8 = 0
    service: uint16 = 1


def ros2_qos(*extra):
    """ROS 2's default topic QoS: reliable, volatile, keep last 10 (and `extra` policies)."""
    return Qos(
        Policy.Reliability.Reliable(duration(seconds=1)),
        Policy.Durability.Volatile,
        Policy.History.KeepLast(10),
        *extra,
    )


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--domain", type=int, default=0)
    ap.add_argument("--prefix", default="/tango", help="topic prefix, e.g. /tango")
    ap.add_argument("--seconds", type=float, default=30.0)
    ap.add_argument("--period", type=float, default=0.05, help="odometry period (s)")
    ap.add_argument("--garbage", type=int, default=0)
    ap.add_argument("--wrong-type", action="store_true")
    ap.add_argument("--odom-hash", default=None, help="RIHS01_... to offer on odom")
    ap.add_argument("--cmd-vel-hash", default=None, help="RIHS01_... to offer on cmd_vel")
    args = ap.parse_args()

    dp = DomainParticipant(args.domain)
    qos = ros2_qos()

    def topic(name, ty):
        return Topic(dp, "rt" + args.prefix + "/" + name, ty, qos=qos)

    def offering(type_hash):
        if not type_hash:
            return qos
        return ros2_qos(Policy.Userdata(data=f"typehash={type_hash};".encode()))

    cmd_reader = DataReader(dp, topic("cmd_vel", Twist), qos=offering(args.cmd_vel_hash))
    say_reader = DataReader(dp, topic("say", String), qos=qos)
    odom_writer = DataWriter(dp, topic("odom", Odometry), qos=offering(args.odom_hash))
    heard_writer = DataWriter(dp, topic("heard", String), qos=qos)
    if args.garbage:
        # A second participant: one participant cannot hold two types under one topic name.
        dp_bad = DomainParticipant(args.domain)
        garbage_writer = DataWriter(
            dp_bad, Topic(dp_bad, "rt" + args.prefix + "/odom", NotOdometry, qos=qos), qos=qos
        )
    if args.wrong_type:
        dp_wrong = DomainParticipant(args.domain)
        wrong_writer = DataWriter(
            dp_wrong, Topic(dp_wrong, "rt" + args.prefix + "/odom", String, qos=qos), qos=qos
        )

    x = y = heading = 0.0
    v = w = 0.0
    cmds = said = 0
    start = last = time.monotonic()
    next_print = start + 1.0
    next_odom = start
    while time.monotonic() - start < args.seconds:
        for s in cmd_reader.take(N=100):
            if isinstance(s, Twist):
                v, w = s.linear.x, s.angular.z
                cmds += 1
        for s in say_reader.take(N=100):
            if isinstance(s, String):
                heard_writer.write(String(data="heard: " + s.data))
                said += 1
        now = time.monotonic()
        dt, last = now - last, now
        x += v * math.cos(heading) * dt
        y += v * math.sin(heading) * dt
        heading = math.atan2(math.sin(heading + w * dt), math.cos(heading + w * dt))
        if now >= next_odom:
            next_odom = now + args.period
            wall = time.time()
            odom = Odometry(
                header=Header(
                    stamp=Time(sec=int(wall), nanosec=int((wall % 1) * 1e9)), frame_id="odom"
                ),
                child_frame_id="base_link",
            )
            odom.pose.pose.position = Point(x=x, y=y, z=0.0)
            odom.pose.pose.orientation = Quaternion(
                z=math.sin(heading / 2), w=math.cos(heading / 2)
            )
            odom.twist.twist.linear.x = v
            odom.twist.twist.angular.z = w
            odom_writer.write(odom)
            if args.garbage:
                garbage_writer.write(NotOdometry())
                args.garbage -= 1
            if args.wrong_type:
                wrong_writer.write(String(data="not an odometry"))
        if now >= next_print:
            next_print = now + 1.0
            print(
                f"t={now - start:5.1f}  x={x:7.3f}  y={y:7.3f}  heading={heading:6.3f}  "
                f"cmds={cmds}  said={said}",
                flush=True,
            )
        time.sleep(0.005)
    return 0


if __name__ == "__main__":
    sys.exit(main())
