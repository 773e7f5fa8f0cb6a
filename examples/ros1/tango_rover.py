#!/usr/bin/env python3
"""Tango as an external ROS 1 robot: a small rospy rover, with nothing of hetcomm installed.

The ROS 1 twin of examples/ros2/tango_rover.py, with the same command line. It

* subscribes to `<prefix>/cmd_vel` (`geometry_msgs/Twist`) and drives a unicycle model with
  the last command (forward speed `linear.x`, turn rate `angular.z`);
* publishes its odometry on `<prefix>/odom` (`nav_msgs/Odometry`) every `--period` seconds;
* answers every `std_msgs/String` on `<prefix>/say` with `"heard: <text>"` on
  `<prefix>/heard`;
* with `--garbage N`, also publishes N messages on `<prefix>/odom` that claim to be
  `nav_msgs/Odometry` (right type name and MD5 sum) but hold only a few bytes: input
  hetcomm's bridge must count and report, not deliver. (A publisher of the wrong type needs
  a second node: `rostopic pub <prefix>/odom std_msgs/String ...`.)

It needs ROS 1's rospy and message packages (Debian: python3-rospy python3-geometry-msgs
python3-nav-msgs; run it with /usr/bin/python3) and a master (`ROS_MASTER_URI`, or
`--master`). `--domain` is accepted and ignored (ROS 1 has no domains), so that a launcher can
start either rover with the same arguments.

    ROS_HOSTNAME=127.0.0.1 /usr/bin/python3 examples/ros1/tango_rover.py --prefix /tango --seconds 30

It prints one line per second (`t=…  x=…  y=…  heading=…  cmds=…`) and exits after
`--seconds`.
"""

import argparse
import math
import os
import sys
import time

import genpy
import rospy
from geometry_msgs.msg import Twist
from nav_msgs.msg import Odometry
from std_msgs.msg import String


class NotOdometry(genpy.Message):
    """Claims to be a nav_msgs/Odometry (type and MD5 sum) but serializes to 3 bytes."""

    _type = Odometry._type
    _md5sum = Odometry._md5sum
    _full_text = Odometry._full_text
    _has_header = False
    __slots__ = []
    _slot_types = []

    def serialize(self, buff):
        buff.write(b"\x01\x02\x03")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--domain", type=int, default=0, help="ignored (ROS 1 has no domains)")
    ap.add_argument("--master", default=None, help="ROS master URI (default: ROS_MASTER_URI)")
    ap.add_argument("--prefix", default="/tango", help="topic prefix, e.g. /tango")
    ap.add_argument("--seconds", type=float, default=30.0)
    ap.add_argument("--period", type=float, default=0.05, help="odometry period (s)")
    ap.add_argument("--garbage", type=int, default=0)
    args = ap.parse_args()
    if args.master:
        os.environ["ROS_MASTER_URI"] = args.master
    os.environ.setdefault("ROS_HOSTNAME", "127.0.0.1")

    state = {"v": 0.0, "w": 0.0, "cmds": 0, "said": 0}

    def on_cmd(msg):
        state["v"], state["w"] = msg.linear.x, msg.angular.z
        state["cmds"] += 1

    rospy.init_node("tango_rover", anonymous=True, disable_signals=True)
    odom_pub = rospy.Publisher(args.prefix + "/odom", Odometry, queue_size=10)
    heard_pub = rospy.Publisher(args.prefix + "/heard", String, queue_size=10)

    def on_say(msg):
        heard_pub.publish(String(data="heard: " + msg.data))
        state["said"] += 1

    rospy.Subscriber(args.prefix + "/cmd_vel", Twist, on_cmd, queue_size=100)
    rospy.Subscriber(args.prefix + "/say", String, on_say, queue_size=100)

    x = y = heading = 0.0
    start = last = time.monotonic()
    next_print = start + 1.0
    next_odom = start
    while time.monotonic() - start < args.seconds and not rospy.is_shutdown():
        now = time.monotonic()
        dt, last = now - last, now
        v, w = state["v"], state["w"]
        x += v * math.cos(heading) * dt
        y += v * math.sin(heading) * dt
        heading = math.atan2(math.sin(heading + w * dt), math.cos(heading + w * dt))
        if now >= next_odom:
            next_odom = now + args.period
            odom = Odometry()
            odom.header.stamp = rospy.Time.now()
            odom.header.frame_id = "odom"
            odom.child_frame_id = "base_link"
            odom.pose.pose.position.x = x
            odom.pose.pose.position.y = y
            odom.pose.pose.orientation.z = math.sin(heading / 2)
            odom.pose.pose.orientation.w = math.cos(heading / 2)
            odom.twist.twist.linear.x = v
            odom.twist.twist.angular.z = w
            odom_pub.publish(odom)
            if args.garbage:
                odom_pub.publish(NotOdometry())
                args.garbage -= 1
        if now >= next_print:
            next_print = now + 1.0
            print(
                f"t={now - start:5.1f}  x={x:7.3f}  y={y:7.3f}  heading={heading:6.3f}  "
                f"cmds={state['cmds']}  said={state['said']}",
                flush=True,
            )
        time.sleep(0.005)
    rospy.signal_shutdown("done")
    return 0


if __name__ == "__main__":
    sys.exit(main())
