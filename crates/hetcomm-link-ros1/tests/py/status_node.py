"""A rospy node with a custom message type, hetcomm_test_msgs/Status (tests/msg), for
tests/custom_type.rs: no catkin build, the class is generated at start from the .msg files
(genmsg reads them, genpy makes the class, as rosbag does for recorded types).

It prints `MD5 <sum>` (genmsg's), publishes a fixed Status on <prefix>/status at 10 Hz, and
prints each Status it receives on <prefix>/command as one JSON line.

    ROS_HOSTNAME=127.0.0.1 /usr/bin/python3 status_node.py --prefix /p --msg-dir tests/msg
"""

import argparse
import json
import os
import sys
import time

import genmsg
import genmsg.msg_loader
import genpy.dynamic
import rospy


def status_class(msg_dir):
    search = {"hetcomm_test_msgs": [os.path.join(msg_dir, "hetcomm_test_msgs", "msg")]}
    for pkg in ("std_msgs", "geometry_msgs"):
        search[pkg] = [f"/usr/share/{pkg}/msg"]
    ctx = genmsg.MsgContext.create_default()
    spec = genmsg.msg_loader.load_msg_by_type(ctx, "hetcomm_test_msgs/Status", search)
    genmsg.msg_loader.load_depends(ctx, spec, search)
    text = genmsg.compute_full_text(ctx, spec)
    classes = genpy.dynamic.generate_dynamic("hetcomm_test_msgs/Status", text)
    return classes["hetcomm_test_msgs/Status"], classes["hetcomm_test_msgs/Part"], classes


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--prefix", required=True)
    ap.add_argument("--msg-dir", required=True)
    ap.add_argument("--seconds", type=float, default=60)
    args = ap.parse_args()
    Status, Part, classes = status_class(args.msg_dir)
    Vector3 = classes["geometry_msgs/Vector3"]
    print(f"MD5 {Status._md5sum}", flush=True)

    def on_command(msg):
        line = {
            "frame_id": msg.header.frame_id,
            "level": msg.level,
            "name": msg.name,
            "parts": [
                [p.name, p.temperature, p.ok, [p.offset.x, p.offset.y, p.offset.z]]
                for p in msg.parts
            ],
            "position": list(msg.position),
            "counters": list(msg.counters),
            "checked": [msg.checked.secs, msg.checked.nsecs],
            "uptime": [msg.uptime.secs, msg.uptime.nsecs],
        }
        print(json.dumps(line), flush=True)

    rospy.init_node("hetcomm_status_node", anonymous=True, disable_signals=True)
    rospy.Subscriber(args.prefix + "/command", Status, on_command)
    pub = rospy.Publisher(args.prefix + "/status", Status, queue_size=10)
    out = Status()
    out.header.frame_id = "base"
    out.level = Status.WARN
    out.name = "tango"
    out.parts = [
        Part(name="wheel", temperature=41.5, ok=True, offset=Vector3(1.0, 2.0, 3.0)),
        Part(name="arm", temperature=-3.25, ok=False, offset=Vector3(0.0, 0.0, -1.0)),
    ]
    out.position = [1.5, -2.0, 0.25]
    out.counters = [1, -2, 2**40]
    out.checked = rospy.Time(12, 34)
    out.uptime = rospy.Duration(5, 6)
    end = time.monotonic() + args.seconds
    while time.monotonic() < end:
        out.header.stamp = rospy.Time.now()
        pub.publish(out)
        time.sleep(0.1)
    rospy.signal_shutdown("done")


if __name__ == "__main__":
    sys.exit(main())
