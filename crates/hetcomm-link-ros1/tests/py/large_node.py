#!/usr/bin/env python3
"""A rospy node that publishes or reads large messages, for tests/large_messages.rs and
benchmarks/ros-large.sh: sensor_msgs/Image (640x480 rgb8, 921,600 bytes of pixels) or
sensor_msgs/PointCloud2 (100,000 points of x, y, z, intensity: 1.6 MB).

Message K carries `frame_id = "K"` and the bytes `(i + K) % 251` for i = 0, 1, ...: a reader
checks every byte of every message against that (one comparison of the whole buffer).

    python3 large_node.py read --topic /t/image --type image --count 90
        prints `ready` once subscribed, then for each message `K ok|bad LATENCY_MS ARRIVAL_S`
        (latency from the header's stamp to its arrival, wall clock; arrival in seconds of
        the wall clock), and `done` after --count messages or --seconds
    python3 large_node.py publish --topic /t/image --type image --count 90 --hz 30
        waits for a subscriber, publishes, then prints `sent N SECONDS`

Both ends may be rospy (the baseline of benchmarks/ros-large.sh) or one may be hetcomm.
"""

import argparse
import sys
import time

import rospy
from sensor_msgs.msg import Image, PointCloud2, PointField

WIDTH, HEIGHT = 640, 480
POINTS = 100_000
SIZES = {"image": WIDTH * HEIGHT * 3, "cloud": POINTS * 16}


def pattern(size):
    """Bytes (i % 251) for i up to size + 251: message K's data is pattern[K % 251:][:size]."""
    return bytes(i % 251 for i in range(251)) * (size // 251 + 2)


def message(kind, k, base):
    size = SIZES[kind]
    data = base[k % 251 : k % 251 + size]
    if kind == "image":
        m = Image(height=HEIGHT, width=WIDTH, encoding="rgb8", is_bigendian=0, step=WIDTH * 3)
    else:
        fields = [
            PointField(name=n, offset=4 * i, datatype=PointField.FLOAT32, count=1)
            for i, n in enumerate(["x", "y", "z", "intensity"])
        ]
        m = PointCloud2(height=1, width=POINTS, fields=fields, is_bigendian=False)
        m.point_step, m.row_step, m.is_dense = 16, 16 * POINTS, True
    m.header.frame_id = str(k)
    m.data = data
    return m


def read(args, cls, base):
    size = SIZES[args.type]
    got = [0]

    def on_message(m):
        now = time.time()
        k = int(m.header.frame_id)
        ok = m.data == base[k % 251 : k % 251 + size]
        latency = (now - m.header.stamp.to_sec()) * 1000
        print(f"{k} {'ok' if ok else 'bad'} {latency:.2f} {now:.6f}", flush=True)
        got[0] += 1

    rospy.Subscriber(args.topic, cls, on_message, queue_size=args.count, buff_size=1 << 26)
    print("ready", flush=True)
    end = time.monotonic() + args.seconds
    while got[0] < args.count and time.monotonic() < end and not rospy.is_shutdown():
        time.sleep(0.01)
    print("done", flush=True)


def publish(args, cls, base):
    pub = rospy.Publisher(args.topic, cls, queue_size=args.count)
    end = time.monotonic() + args.seconds
    while pub.get_num_connections() < 1:
        if time.monotonic() > end:
            sys.exit("nobody subscribed")
        time.sleep(0.05)
    messages = [message(args.type, k, base) for k in range(args.count)]
    start = time.monotonic()
    for k, m in enumerate(messages):
        # On the 30 Hz grid from the first message: a late one does not delay the rest.
        delay = start + k / args.hz - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        m.header.stamp = rospy.Time.now()
        pub.publish(m)
    print(f"sent {args.count} {time.monotonic() - start:.3f}", flush=True)
    # Keep the connection while the last messages drain.
    time.sleep(args.linger)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("mode", choices=["read", "publish"])
    ap.add_argument("--topic", required=True)
    ap.add_argument("--type", choices=sorted(SIZES), default="image")
    ap.add_argument("--count", type=int, default=90)
    ap.add_argument("--hz", type=float, default=30)
    ap.add_argument("--seconds", type=float, default=60)
    ap.add_argument("--linger", type=float, default=2)
    args = ap.parse_args()
    cls = Image if args.type == "image" else PointCloud2
    base = pattern(SIZES[args.type])
    rospy.init_node(f"hetcomm_large_{args.mode}", anonymous=True, disable_signals=True)
    (read if args.mode == "read" else publish)(args, cls, base)


if __name__ == "__main__":
    main()
