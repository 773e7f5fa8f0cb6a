"""A Foxglove WebSocket client written from the protocol's description (subprotocol
foxglove.sdk.v1), checking what `hetcomm monitor --foxglove` serves while a fleet runs.

    python foxglove-client.py PORT

Called by scripts/foxglove-test.sh. Connects, expects `serverInfo`, reads `advertise` ops
(channels arrive as pairs appear), subscribes to the pairs table, one per-pair topic and the
systems topic, decodes binary message frames (opcode 1, subscription id u32 LE, log time u64
LE, JSON payload) and asserts on their content. Exits non-zero on any failed check or after
a deadline without every check passing.
"""

import asyncio
import json
import struct
import sys
import time

import websockets

PAIR_TOPIC = "/hetcomm/pair/Alpha/VirtualEnv/wired"
WANTED = ["/hetcomm/pairs", PAIR_TOPIC, "/hetcomm/systems"]
DEADLINE_S = 40


async def main(port: int) -> None:
    url = f"ws://127.0.0.1:{port}"
    async with websockets.connect(url, subprotocols=["foxglove.sdk.v1"], max_size=None) as ws:
        assert ws.subprotocol == "foxglove.sdk.v1", ws.subprotocol
        info = json.loads(await ws.recv())
        assert info["op"] == "serverInfo", info
        assert info["name"] == "hetcomm monitor", info
        channels = {}  # topic -> advertised channel
        subs = {}  # subscription id -> topic
        got = {t: [] for t in WANTED}  # topic -> [(log time, payload)]
        deadline = time.monotonic() + DEADLINE_S
        while not done(got):
            left = deadline - time.monotonic()
            if left <= 0:
                raise SystemExit(f"deadline: advertised {sorted(channels)}, got "
                                 f"{ {t: len(v) for t, v in got.items()} }")
            msg = await asyncio.wait_for(ws.recv(), left)
            if isinstance(msg, str):
                op = json.loads(msg)
                if op["op"] == "advertise":
                    new = []
                    for ch in op["channels"]:
                        assert ch["encoding"] == "json", ch
                        assert ch["schemaEncoding"] == "jsonschema", ch
                        json.loads(ch["schema"])  # the schema is JSON itself
                        channels[ch["topic"]] = ch
                        if ch["topic"] in WANTED and ch["topic"] not in subs.values():
                            sid = len(subs) + 1
                            subs[sid] = ch["topic"]
                            new.append({"id": sid, "channelId": ch["id"]})
                    if new:
                        await ws.send(json.dumps({"op": "subscribe", "subscriptions": new}))
                continue
            assert msg[0] == 1, f"binary opcode {msg[0]}"  # 1 = message data
            sid, log_time = struct.unpack_from("<IQ", msg, 1)
            payload = json.loads(msg[13:])
            got[subs[sid]].append((log_time, payload))
        check(got, channels)
        print(f"foxglove client: {sum(map(len, got.values()))} messages on {len(WANTED)} topics; "
              f"{PAIR_TOPIC} sends {got[PAIR_TOPIC][0][1]['sends']} -> "
              f"{got[PAIR_TOPIC][-1][1]['sends']}")


def done(got) -> bool:
    """Two pair messages with growing counters, and a pairs table with Charlie→Tango received."""
    pair = got[PAIR_TOPIC]
    if len(pair) < 2 or pair[-1][1]["sends"] <= pair[0][1]["sends"]:
        return False
    if not got["/hetcomm/systems"]:
        return False
    return any(radio_received(p) for _, p in got["/hetcomm/pairs"])


def radio_received(table) -> bool:
    return any(r["source"] == "Charlie" and r["destination"] == "Tango"
               and r["transport"] == "radio" and r["received"] > 0 for r in table["pairs"])


def check(got, channels) -> None:
    first, last = got[PAIR_TOPIC][0][1], got[PAIR_TOPIC][-1][1]
    assert (last["source"], last["destination"], last["transport"]) == \
        ("Alpha", "VirtualEnv", "wired"), last
    assert last["delivered"] > first["delivered"], (first, last)
    assert last["failed"] == 0, last
    assert last["rate"] > 0, last
    times = [t for t, _ in got[PAIR_TOPIC]]
    assert times == sorted(times) and times[0] > 1_500_000_000 * 10**9, times  # ns since epoch
    systems = {s["system"]: s for _, m in got["/hetcomm/systems"] for s in m["systems"]}
    assert "Act" in [i["module"] for i in systems["Alpha"]["inboxes"]], systems
    # Every advertised per-pair topic is a row of the latest table (rows never disappear).
    rows = {f"/hetcomm/pair/{r['source']}/{r['destination']}/{r['transport']}"
            for r in got["/hetcomm/pairs"][-1][1]["pairs"]}
    pair_topics = {t for t in channels if t.startswith("/hetcomm/pair/")}
    assert PAIR_TOPIC in pair_topics and pair_topics <= rows, (sorted(pair_topics), sorted(rows))

if __name__ == "__main__":
    asyncio.run(main(int(sys.argv[1])))
