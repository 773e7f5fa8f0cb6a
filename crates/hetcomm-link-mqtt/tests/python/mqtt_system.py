"""A fleet system written in Python with paho-mqtt (MQTT 5), from docs/mqtt.md and
docs/wire-format.md only (frames from docport.py, the standard-library port of the wire
format). It speaks for system NAME (id ID) of a fleet on an unsecured `mqtt` transport:

  python mqtt_system.py --broker 127.0.0.1:1883 --prefix hetcomm --fleet F --name Py --id 2 \
      --names Alpha=0,Py=2 [--send-to Alpha --to-id 0 --module 0 --type 1 --text hello]
      [--receive N] [--timeout S]

* connects with a last will (retained `lost` on PREFIX/FLEET/@presence/NAME), subscribes to
  PREFIX/FLEET/NAME, PREFIX/FLEET/@all and PREFIX/FLEET/@presence/+, then announces itself:
  retained `online` on its presence topic (hetcomm systems refuse to send to a system that
  has not), and `offline` when it is done;
* --receive N: waits for N data frames for it, prints each as one JSON line
  ({"from": .., "module": .., "type": .., "payload_hex": ..}) and answers each that asks for an
  acknowledgement with a `delivered` ACK on the sender's topic;
* --send-to: waits for the destination's `online`, publishes one data frame (MessagePack
  string payload --text, acknowledgement requested) on PREFIX/FLEET/DEST, publishes it again
  every 200 ms until its ACK comes back, and prints `ack <status>`.

Exits 0 when everything asked for happened, 1 on a timeout."""

from __future__ import annotations

import argparse
import json
import os
import queue
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "..", "..", "hetcomm-py", "tests"))
import docport  # noqa: E402
import paho.mqtt.client as mqtt  # noqa: E402
from paho.mqtt.subscribeoptions import SubscribeOptions  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--broker", required=True, help="host:port")
    ap.add_argument("--prefix", default="hetcomm")
    ap.add_argument("--fleet", required=True)
    ap.add_argument("--name", required=True)
    ap.add_argument("--id", type=int, required=True)
    ap.add_argument("--send-to")
    ap.add_argument("--to-id", type=int, default=0)
    ap.add_argument("--module", type=int, default=0)
    ap.add_argument("--type", type=int, default=1)
    ap.add_argument("--text", default="hello from python")
    ap.add_argument("--receive", type=int, default=0)
    ap.add_argument("--timeout", type=float, default=20.0)
    ap.add_argument("--names", default="", help="the fleet's systems, e.g. Alpha=0,Py=2")
    a = ap.parse_args()

    base = f"{a.prefix}/{a.fleet}"
    me = f"{base}/{a.name}"
    my_presence = f"{base}/@presence/{a.name}"
    names = {int(i): n for n, i in (p.split("=") for p in a.names.split(",") if p)}
    inbox: "queue.Queue[bytes]" = queue.Queue()
    online = set()
    subscribed = queue.Queue()

    client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=f"py-{a.fleet}-{a.name}",
                         protocol=mqtt.MQTTv5)
    client.will_set(my_presence, b"lost", qos=1, retain=True)

    def on_connect(c, _userdata, _flags, reason, _props):
        if reason.is_failure:
            print(f"refused: {reason}", file=sys.stderr)
            return
        # No local: this system's own broadcasts do not come back to it.
        c.subscribe([(me, SubscribeOptions(qos=1, noLocal=True)),
                     (f"{base}/@all", SubscribeOptions(qos=1, noLocal=True)),
                     (f"{base}/@presence/+", SubscribeOptions(qos=1))])

    def on_subscribe(c, _userdata, _mid, _reasons, _props):
        c.publish(my_presence, b"online", qos=1, retain=True)
        subscribed.put(True)

    def on_message(_c, _userdata, msg):
        if msg.topic.startswith(f"{base}/@presence/"):
            who = msg.topic.rsplit("/", 1)[-1]
            (online.add if msg.payload == b"online" else online.discard)(who)
        elif not msg.retain and msg.payload:
            inbox.put(bytes(msg.payload))  # a retained frame is stale: never taken

    client.on_connect = on_connect
    client.on_subscribe = on_subscribe
    client.on_message = on_message
    host, port = a.broker.rsplit(":", 1)
    client.connect(host, int(port), keepalive=10)
    client.loop_start()
    deadline = time.monotonic() + a.timeout
    try:
        subscribed.get(timeout=a.timeout)
    except queue.Empty:
        print("no subscription", file=sys.stderr)
        return 1
    print("ready", flush=True)
    incarnation = int(time.time()) & 0xFFFFFFFF

    def answer(frame: bytes) -> None:
        h, payload = docport.decode_frame(frame)
        print(json.dumps({"from": h["source"]["system"], "module": h["destination"]["module"],
                          "type": h["message_type"], "payload_hex": payload.hex()}), flush=True)
        if h["flags"] & docport.FLAG_ACK_REQUESTED:
            client.publish(f"{base}/{names.get(h['source']['system'], '')}",
                           docport.ack_for(h, 0, me=a.id), qos=1)

    received = 0
    if a.send_to:
        while a.send_to not in online:
            if time.monotonic() > deadline:
                print(f"{a.send_to} never came online", file=sys.stderr)
                return 1
            time.sleep(0.02)
        h = {"kind": docport.KIND_DATA, "flags": docport.FLAG_ACK_REQUESTED, "priority": 100,
             "transport": ord("M"), "source": {"system": a.id, "module": a.module},
             "destination": {"system": a.to_id, "module": a.module}, "incarnation": incarnation,
             "seq": 1, "message_type": a.type, "timestamp": int(time.time() * 1e6)}
        frame = docport.encode_frame(h, docport.msgpack_str(a.text))
        acked = None
        while acked is None:
            if time.monotonic() > deadline:
                print("no acknowledgement", file=sys.stderr)
                return 1
            client.publish(f"{base}/{a.send_to}", frame, qos=1)
            until = time.monotonic() + 0.2
            while acked is None and time.monotonic() < until:
                try:
                    got = inbox.get(timeout=0.05)
                except queue.Empty:
                    continue
                gh, gp = docport.decode_frame(got)
                if gh["kind"] == docport.KIND_ACK and gh["seq"] == 1:
                    acked = docport.ACK_STATUS[gp[0]]
                elif gh["kind"] == docport.KIND_DATA:
                    answer(got)
                    received += 1
        print(f"ack {acked}", flush=True)
    while received < a.receive:
        try:
            got = inbox.get(timeout=max(0.0, deadline - time.monotonic()))
        except queue.Empty:
            print(f"received {received} of {a.receive}", file=sys.stderr)
            return 1
        h, _ = docport.decode_frame(got)
        if h["kind"] == docport.KIND_DATA:
            answer(got)
            received += 1
    # The last acknowledgement out, then the goodbye (retained), then a clean disconnect.
    time.sleep(0.2)
    client.publish(my_presence, b"offline", qos=1, retain=True).wait_for_publish(5)
    client.disconnect()
    client.loop_stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
