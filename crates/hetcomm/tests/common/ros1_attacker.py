#!/usr/bin/env python3
"""The attacker of hetcomm's security tests on a ROS 1 transport (tests/common/attack.rs).

An ordinary rospy node (not a hetcomm link: its name does not start with `hetcomm_`, so the
hetcomm links on the master take it for a foreign program) that records what is published
on a topic and publishes raw frames, each as the `data` of a std_msgs/UInt8MultiArray, the
way docs/wire-format.md says the ros1 link carries frames.

Commands on standard input, one per line, each answered on standard output with `OK` (or
`ERR <why>`):

    sub TOPIC          subscribe; every message with data is then printed as `F <hex>`
    pub TOPIC HEX...   publish each frame, once every subscriber of TOPIC is connected

Run with /usr/bin/python3 and ROS_MASTER_URI set.
"""
import sys
import threading
import time

import rosgraph
import rospy
from std_msgs.msg import UInt8MultiArray

LOCK = threading.Lock()


def say(line):
    with LOCK:
        sys.stdout.write(line + "\n")
        sys.stdout.flush()


def on_message(msg):
    if msg.data:
        say("F " + bytes(msg.data).hex())


def subscribers(topic):
    """The nodes other than this one that the master lists as subscribers of `topic`."""
    _, subs, _ = rosgraph.Master(rospy.get_name()).getSystemState()
    for name, nodes in subs:
        if name == topic:
            return [n for n in nodes if n != rospy.get_name()]
    return []


def wait_connected(pub, topic, timeout=20.0):
    deadline = time.time() + timeout
    while time.time() < deadline:
        n = len(subscribers(topic))
        if n and pub.get_num_connections() >= n:
            return
        time.sleep(0.01)
    raise RuntimeError("no subscriber of %s connected within %ss" % (topic, timeout))


def main():
    rospy.init_node("eve_attacker", anonymous=True, disable_signals=True)
    pubs, subs = {}, []
    say("READY")
    for line in sys.stdin:
        parts = line.split()
        if not parts:
            continue
        try:
            if parts[0] == "sub":
                subs.append(
                    rospy.Subscriber(parts[1], UInt8MultiArray, on_message, queue_size=100000)
                )
            elif parts[0] == "pub":
                topic = parts[1]
                if topic not in pubs:
                    pubs[topic] = rospy.Publisher(
                        topic, UInt8MultiArray, queue_size=100000, tcp_nodelay=True
                    )
                wait_connected(pubs[topic], topic)
                for frame in parts[2:]:
                    pubs[topic].publish(UInt8MultiArray(data=bytes.fromhex(frame)))
            else:
                raise ValueError("unknown command %r" % parts[0])
            say("OK")
        except Exception as e:  # noqa: BLE001 - reported to the test
            say("ERR %s" % e)


if __name__ == "__main__":
    main()
