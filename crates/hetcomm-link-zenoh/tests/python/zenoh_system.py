"""A fleet system written in Python with eclipse-zenoh, from docs/zenoh.md and
docs/wire-format.md only (frames from docport.py, the standard-library port of the wire
format). It speaks for system NAME (id ID) of a fleet on a `zenoh` transport:

  python zenoh_system.py --connect tcp/127.0.0.1:7447 --prefix P --name Py --id 2 \
      --names Alpha=0,Py=2 [--send-to Alpha --to-id 0 --module 0 --type 1 --text hello]
      [--receive N] [--timeout S]

* declares its liveliness token on P/live/NAME and subscribes to P/sys/NAME and to P/all
  (native broadcasts: one frame for every system, taken from the systems of --names, for
  which this program's table row is the zenoh transport);
* --receive N: waits for N data frames for it, prints each as one JSON line
  ({"from": .., "module": .., "type": .., "payload_hex": .., "to_all": ..}, to_all: it came
  as a native broadcast's one frame) and answers each that asks
  for an acknowledgement with a `delivered` ACK;
* --send-to: waits for the destination's token, puts one data frame (MessagePack string
  payload --text, acknowledgement requested) on P/sys/DEST, retransmits every 200 ms until
  its ACK comes back on P/sys/NAME, and prints `ack <status>`.

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
import zenoh  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--connect", required=True)
    ap.add_argument("--prefix", required=True)
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

    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([a.connect]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    session = zenoh.open(conf)

    inbox: "queue.Queue[bytes]" = queue.Queue()
    me = f"{a.prefix}/sys/{a.name}"
    def frames(put: bytes) -> None:
        """A put is one frame, or a batch of them (docs/zenoh.md): queues each frame."""
        if not put.startswith(b"HB"):
            inbox.put(put)
            return
        if put[:4] != b"HB\x01\x00":
            return  # a batch version this program does not read
        rest = put[4:]
        while len(rest) >= 4:
            n = int.from_bytes(rest[:4], "little")
            if n > len(rest) - 4:
                return  # a malformed tail
            inbox.put(rest[4:4 + n])
            rest = rest[4 + n:]

    sub = session.declare_subscriber(me, lambda s: frames(bytes(s.payload.to_bytes())))
    every = session.declare_subscriber(f"{a.prefix}/all",
                                       lambda s: frames(bytes(s.payload.to_bytes())))
    token = session.liveliness().declare_token(f"{a.prefix}/live/{a.name}")
    present = set()
    live = session.liveliness().declare_subscriber(
        f"{a.prefix}/live/*",
        lambda s: (present.add if s.kind == zenoh.SampleKind.PUT else present.discard)(
            str(s.key_expr).rsplit("/", 1)[-1]),
        history=True,
    )
    deadline = time.monotonic() + a.timeout
    incarnation = int(time.time()) & 0xFFFFFFFF
    print("ready", flush=True)

    def answer(frame: bytes) -> None:
        """Prints a data frame for us and acknowledges it if asked; returns nothing."""
        h, payload = docport.decode_frame(frame)
        if h["kind"] != docport.KIND_DATA:
            return
        if h["flags"] & docport.FLAG_TO_ALL and h["source"]["system"] not in names:
            return  # a broadcast the table does not let its sender send here
        print(json.dumps({"from": h["source"]["system"], "module": h["destination"]["module"],
                          "type": h["message_type"], "payload_hex": payload.hex(),
                          "to_all": bool(h["flags"] & docport.FLAG_TO_ALL)}), flush=True)
        if h["flags"] & docport.FLAG_ACK_REQUESTED:
            session.put(f"{a.prefix}/sys/{names.get(h['source']['system'], '')}",
                        docport.ack_for(h, 0, me=a.id))

    names = {int(i): n for n, i in (p.split("=") for p in a.names.split(",") if p)}
    received = 0
    if a.send_to:
        while a.send_to not in present:
            if time.monotonic() > deadline:
                print(f"{a.send_to} never appeared", file=sys.stderr)
                return 1
            time.sleep(0.02)
        h = {"kind": docport.KIND_DATA, "flags": docport.FLAG_ACK_REQUESTED, "priority": 100,
             "transport": ord("Z"), "source": {"system": a.id, "module": a.module},
             "destination": {"system": a.to_id, "module": a.module}, "incarnation": incarnation,
             "seq": 1, "message_type": a.type, "timestamp": int(time.time() * 1e6)}
        frame = docport.encode_frame(h, docport.msgpack_str(a.text))
        acked = None
        while acked is None:
            if time.monotonic() > deadline:
                print("no acknowledgement", file=sys.stderr)
                return 1
            session.put(f"{a.prefix}/sys/{a.send_to}", frame)
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
    # Let the last acknowledgement leave before the session closes.
    time.sleep(0.2)
    live.undeclare()
    token.undeclare()
    sub.undeclare()
    every.undeclare()
    session.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
