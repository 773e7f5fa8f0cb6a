"""A VDA 5050-style AGV that speaks plain MQTT JSON (paho-mqtt 2, MQTT 5) and not hetcomm:
the robot of the `mqtt_bridge` in examples/mqtt/agv.toml, written from docs/mqtt.md ("Plain
MQTT JSON clients") alone.

  python agv.py --broker 127.0.0.1:1883 [--manufacturer acme] [--serial tango]
                [--seconds 60] [--period 0.5] [--garbage]

Topics: uagv/v2/<manufacturer>/<serial>/{order,instantActions} (subscribed),
…/state and …/connection (published; `connection` retained, with a last will of
CONNECTIONBROKEN). Fields: a subset of VDA 5050 2.0's, those the fleet file lists.

* an `order` sets the state's orderId, orderUpdateId and lastNodeId (its first node);
  `driving` is true while the order has more than one node;
* each action of an `instantActions` message becomes one actionStates entry, FINISHED;
* the state goes out every --period seconds and at once after each order or instant action;
* --garbage: first publishes a state that is not JSON and one whose `driving` is a string;
* after --seconds: publishes `connection` OFFLINE (retained), disconnects, exits 0.

It prints one line per message received (`order o-1 update 0: 2 nodes`, `instantActions a-1`).
"""

from __future__ import annotations

import argparse
import datetime
import json
import sys
import threading
import time

import paho.mqtt.client as mqtt


def now() -> str:
    return datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="milliseconds")


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--broker", required=True, help="host:port")
    ap.add_argument("--manufacturer", default="acme")
    ap.add_argument("--serial", default="tango")
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--period", type=float, default=0.5)
    ap.add_argument("--garbage", action="store_true")
    a = ap.parse_args()
    host, port = a.broker.rsplit(":", 1)
    base = f"uagv/v2/{a.manufacturer}/{a.serial}"
    lock = threading.Lock()
    headers = {"n": 0}

    def header() -> dict:
        headers["n"] += 1
        return {
            "headerId": headers["n"],
            "timestamp": now(),
            "version": "2.0.0",
            "manufacturer": a.manufacturer,
            "serialNumber": a.serial,
        }

    state = {
        "orderId": "",
        "orderUpdateId": 0,
        "lastNodeId": "",
        "driving": False,
        "actionStates": [],
        "batteryState": {"batteryCharge": 87.5, "charging": False},
        "errors": [],
        "operatingMode": "AUTOMATIC",
        "agvPosition": {"x": 0.0, "y": 0.0, "theta": 0.0, "mapId": "floor-1", "positionInitialized": True},
    }

    def connection(status: str) -> str:
        return json.dumps({**header(), "connectionState": status})

    client = mqtt.Client(
        mqtt.CallbackAPIVersion.VERSION2,
        client_id=f"agv-{a.manufacturer}-{a.serial}",
        protocol=mqtt.MQTTv5,
    )
    client.will_set(f"{base}/connection", connection("CONNECTIONBROKEN"), qos=1, retain=True)
    ready = threading.Event()

    def publish_state() -> None:
        with lock:
            body = json.dumps({**header(), **state})
        client.publish(f"{base}/state", body, qos=1)

    def on_connect(c, _userdata, _flags, reason, _props):
        if reason.is_failure:
            print(f"connect refused: {reason}", file=sys.stderr)
            return
        c.subscribe([(f"{base}/order", 1), (f"{base}/instantActions", 1)])

    def on_subscribe(c, _userdata, _mid, _codes, _props):
        c.publish(f"{base}/connection", connection("ONLINE"), qos=1, retain=True)
        ready.set()

    def on_message(_c, _userdata, msg):
        try:
            m = json.loads(msg.payload)
        except ValueError:
            print(f"not JSON on {msg.topic}", flush=True)
            return
        if msg.topic.endswith("/order"):
            nodes = m.get("nodes", [])
            with lock:
                state["orderId"] = m.get("orderId", "")
                state["orderUpdateId"] = m.get("orderUpdateId", 0)
                state["lastNodeId"] = nodes[0].get("nodeId", "") if nodes else ""
                state["driving"] = len(nodes) > 1
            print(f"order {state['orderId']} update {state['orderUpdateId']}: {len(nodes)} nodes", flush=True)
        elif msg.topic.endswith("/instantActions"):
            with lock:
                for action in m.get("actions", []):
                    state["actionStates"].append(
                        {
                            "actionId": action.get("actionId", ""),
                            "actionType": action.get("actionType", ""),
                            "actionStatus": "FINISHED",
                        }
                    )
                    print(f"instantActions {action.get('actionId', '')}", flush=True)
        publish_state()

    client.on_connect = on_connect
    client.on_subscribe = on_subscribe
    client.on_message = on_message
    client.connect(host, int(port), keepalive=10)
    client.loop_start()
    if not ready.wait(10):
        print("not connected within 10 s", file=sys.stderr)
        return 1
    print("online", flush=True)
    if a.garbage:
        client.publish(f"{base}/state", b"\xffnot json", qos=1)
        with lock:
            bad = {**header(), **state, "driving": "yes"}
        client.publish(f"{base}/state", json.dumps(bad), qos=1)
    end = time.monotonic() + a.seconds
    while time.monotonic() < end:
        publish_state()
        time.sleep(min(a.period, max(0.0, end - time.monotonic())))
    client.publish(f"{base}/connection", connection("OFFLINE"), qos=1, retain=True).wait_for_publish(5)
    client.disconnect()
    client.loop_stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
