"""Tango as a plain MQTT robot: a small rover that speaks MQTT JSON (paho-mqtt 2, MQTT 5) and
not hetcomm, the follower of examples/mqtt/leader-follower-mqtt.toml's demonstration, written
from docs/mqtt.md ("Plain MQTT JSON clients") alone.

  python tango_rover.py --broker 127.0.0.1:1883 [--prefix tango] [--seconds 60] [--period 0.05]

* subscribes to `<prefix>/cmd_vel`: a JSON object shaped like `geometry_msgs/Twist`
  (`{"linear": {"x": …, "y": …, "z": …}, "angular": {…}}`), and drives a unicycle model with
  the last command (forward speed `linear.x`, turn rate `angular.z`);
* publishes its odometry on `<prefix>/odom` every --period seconds: a JSON object shaped like
  `nav_msgs/Odometry` (`pose.pose.position`, `pose.pose.orientation` as a quaternion,
  `twist.twist`), as a ROS base would;
* after --seconds: disconnects and exits 0.

It prints one line per second (`t=…  x=…  y=…  heading=…  cmds=…`).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import threading
import time

import paho.mqtt.client as mqtt


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--broker", required=True, help="host:port")
    ap.add_argument("--prefix", default="tango", help="topic prefix, e.g. tango")
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--period", type=float, default=0.05, help="odometry period (s)")
    a = ap.parse_args()
    host, port = a.broker.rsplit(":", 1)
    lock = threading.Lock()
    command = {"v": 0.0, "w": 0.0, "n": 0}
    ready = threading.Event()

    def on_connect(c, _userdata, _flags, reason, _props):
        if reason.is_failure:
            print(f"connect refused: {reason}", file=sys.stderr)
            return
        c.subscribe([(f"{a.prefix}/cmd_vel", 1)])

    def on_subscribe(_c, _userdata, _mid, _codes, _props):
        ready.set()

    def on_message(_c, _userdata, msg):
        try:
            m = json.loads(msg.payload)
            v, w = float(m["linear"]["x"]), float(m["angular"]["z"])
        except (ValueError, KeyError, TypeError):
            print(f"not a Twist on {msg.topic}", flush=True)
            return
        with lock:
            command.update(v=v, w=w, n=command["n"] + 1)

    client = mqtt.Client(
        mqtt.CallbackAPIVersion.VERSION2,
        client_id=f"tango-rover-{a.prefix.replace('/', '-')}",
        protocol=mqtt.MQTTv5,
    )
    client.on_connect = on_connect
    client.on_subscribe = on_subscribe
    client.on_message = on_message
    client.connect(host, int(port), keepalive=10)
    client.loop_start()
    if not ready.wait(10):
        print("not connected within 10 s", file=sys.stderr)
        return 1
    x = y = heading = 0.0
    start = last = time.monotonic()
    next_print, next_odom = start + 1.0, start
    while (now := time.monotonic()) - start < a.seconds:
        with lock:
            v, w, cmds = command["v"], command["w"], command["n"]
        dt, last = now - last, now
        x += v * math.cos(heading) * dt
        y += v * math.sin(heading) * dt
        heading = math.atan2(math.sin(heading + w * dt), math.cos(heading + w * dt))
        if now >= next_odom:
            next_odom = now + a.period
            odom = {
                "pose": {
                    "pose": {
                        "position": {"x": x, "y": y, "z": 0.0},
                        "orientation": {
                            "x": 0.0,
                            "y": 0.0,
                            "z": math.sin(heading / 2),
                            "w": math.cos(heading / 2),
                        },
                    }
                },
                "twist": {
                    "twist": {
                        "linear": {"x": v, "y": 0.0, "z": 0.0},
                        "angular": {"x": 0.0, "y": 0.0, "z": w},
                    }
                },
            }
            client.publish(f"{a.prefix}/odom", json.dumps(odom), qos=0)
        if now >= next_print:
            next_print += 1.0
            print(
                f"t={now - start:.0f}  x={x:.2f}  y={y:.2f}  "
                f"heading={math.degrees(heading):.1f}  cmds={cmds}",
                flush=True,
            )
        time.sleep(0.005)
    client.disconnect()
    client.loop_stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
