"""Checks what hetcomm serves to Foxglove and writes for it, with clients written from the
protocols' descriptions: the Foxglove WebSocket protocol (subprotocol foxglove.sdk.v1, Python
`websockets`) and MCAP (the `mcap` package); protobuf messages are decoded with the
descriptors their channels carry (the `protobuf` package), never with hetcomm's code.

    python foxglove-client.py monitor PORT   # `hetcomm monitor --foxglove` while a fleet runs
    python foxglove-client.py demo PORT      # `hetcomm demo --realtime --foxglove` while it runs
    python foxglove-client.py listen PORT    # `hetcomm listen --as Charlie --foxglove`, secured
    python foxglove-client.py replay PORT    # `hetcomm replay --foxglove` of a demo recording
    python foxglove-client.py mcap FILE      # a recording of `hetcomm demo --record`

Called by scripts/foxglove-test.sh. The WebSocket modes connect, expect `serverInfo`, read
`advertise` ops (channels arrive as pairs and topics appear), subscribe to the topics they
check, decode binary message frames (opcode 1, subscription id u32 LE, log time u64 LE,
payload) and assert on their fields. Exits non-zero on any failed check or after a deadline
without every check passing.
"""

import asyncio
import base64
import json
import math
import pathlib
import struct
import sys
import time

import websockets
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

DEADLINE_S = 40
ROVERS = {"Alpha", "Charlie", "Tango"}
EPOCH_2020_NS = 1_577_836_800 * 10**9


def message_class(schema_name: str, descriptor_set: bytes):
    """The protobuf class of `schema_name` from a serialized FileDescriptorSet (dependencies
    first, as MCAP's protobuf profile and the Foxglove protocol require them included)."""
    files = list(descriptor_pb2.FileDescriptorSet.FromString(descriptor_set).file)
    pool = descriptor_pool.DescriptorPool()
    added = set()
    while files:
        ready = [f for f in files if all(d in added for d in f.dependency)]
        assert ready, f"unresolvable dependencies in {[f.name for f in files]}"
        for f in ready:
            pool.Add(f)
            added.add(f.name)
            files.remove(f)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(schema_name))


def stamp_ns(ts) -> int:
    return ts.seconds * 10**9 + ts.nanos


# --- docs/foxglove-layout.json -------------------------------------------------------------

LAYOUT = pathlib.Path(__file__).resolve().parent.parent / "docs/foxglove-layout.json"


def layout_topics() -> set:
    """Every topic the layout's panels show (3D topics, plot paths' topics, raw messages)."""
    config = json.loads(LAYOUT.read_text())["configById"]
    topics = set()
    for panel_id, panel in config.items():
        kind = panel_id.split("!")[0]
        if kind == "3D":
            topics |= set(panel["topics"])
        elif kind == "Plot":
            topics |= {p["value"].split(".")[0] for p in panel["paths"]}
        elif kind == "RawMessages":
            topics.add(panel["topicPath"])
    return topics


def recorded_only(topic: str) -> bool:
    """Topics of recordings (hetcomm-record's events), not served live."""
    return topic.split("/")[1] in ("send", "receipt", "outcome")


# --- the Foxglove WebSocket protocol -------------------------------------------------------

class Session:
    """One connection: advertised channels, subscriptions, and what arrived per topic."""

    def __init__(self, ws, wanted):
        self.ws = ws
        self.wanted = wanted  # topic -> predicate on the topic name
        self.channels = {}  # topic -> advertised channel
        self.subs = {}  # subscription id -> topic
        self.decoders = {}  # topic -> payload decoder
        self.got = {}  # topic -> [(log time, decoded payload)]

    async def run(self, done, server_name):
        info = json.loads(await self.ws.recv())
        assert info["op"] == "serverInfo", info
        assert info["name"] == server_name, info
        deadline = time.monotonic() + DEADLINE_S
        while not done(self.got):
            left = deadline - time.monotonic()
            if left <= 0:
                raise SystemExit(f"deadline: advertised {sorted(self.channels)}, got "
                                 f"{ {t: len(v) for t, v in self.got.items()} }")
            msg = await asyncio.wait_for(self.ws.recv(), left)
            if isinstance(msg, str):
                await self.on_op(json.loads(msg))
                continue
            assert msg[0] == 1, f"binary opcode {msg[0]}"  # 1 = message data
            sid, log_time = struct.unpack_from("<IQ", msg, 1)
            topic = self.subs[sid]
            self.got.setdefault(topic, []).append((log_time, self.decoders[topic](msg[13:])))

    async def on_op(self, op):
        # The SDK's server sends an advertisement before it records the channel as
        # advertised: a subscription made the instant it arrives can be refused as an unknown
        # channel. Ask again.
        if op["op"] == "status" and op["message"].startswith("Unknown channel ID: "):
            channel = int(op["message"].rsplit(" ", 1)[1])
            for sid, topic in self.subs.items():
                if self.channels[topic]["id"] == channel:
                    await asyncio.sleep(0.02)
                    await self.ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                        {"id": sid, "channelId": channel}]}))
            return
        if op["op"] != "advertise":
            return
        new = []
        for ch in op["channels"]:
            self.channels[ch["topic"]] = ch
            if ch["encoding"] == "json":
                assert ch["schemaEncoding"] == "jsonschema", ch
                json.loads(ch["schema"])  # the schema is JSON itself
                decoder = json.loads
            else:
                assert (ch["encoding"], ch["schemaEncoding"]) == ("protobuf", "protobuf"), ch
                cls = message_class(ch["schemaName"], base64.b64decode(ch["schema"]))
                decoder = cls.FromString
            if any(w(ch["topic"]) for w in self.wanted) and ch["topic"] not in self.subs.values():
                sid = len(self.subs) + 1
                self.subs[sid] = ch["topic"]
                self.decoders[ch["topic"]] = decoder
                new.append({"id": sid, "channelId": ch["id"]})
        if new:
            await self.ws.send(json.dumps({"op": "subscribe", "subscriptions": new}))


async def connect(port):
    ws = await websockets.connect(f"ws://127.0.0.1:{port}", subprotocols=["foxglove.sdk.v1"],
                                  max_size=None)
    assert ws.subprotocol == "foxglove.sdk.v1", ws.subprotocol
    return ws


# --- `hetcomm monitor --foxglove`: the statistics of a multi-process fleet -------------------

PAIR_TOPIC = "/hetcomm/pair/Alpha/VirtualEnv/wired"


async def monitor(port: int) -> None:
    wanted = ["/hetcomm/pairs", PAIR_TOPIC, "/hetcomm/systems"]
    ws = await connect(port)
    async with ws:
        s = Session(ws, [lambda t, w=w: t == w for w in wanted])
        await s.run(monitor_done, "hetcomm monitor")
        check_monitor(s.got, s.channels)
        pair = s.got[PAIR_TOPIC]
        print(f"foxglove client (monitor): {sum(map(len, s.got.values()))} messages on "
              f"{len(wanted)} topics; {PAIR_TOPIC} sends {pair[0][1]['sends']} -> "
              f"{pair[-1][1]['sends']}")


def monitor_done(got) -> bool:
    """Two pair messages with growing counters, and a pairs table with Charlie→Tango received."""
    pair = got.get(PAIR_TOPIC, [])
    if len(pair) < 2 or pair[-1][1]["sends"] <= pair[0][1]["sends"]:
        return False
    if not got.get("/hetcomm/systems"):
        return False
    return any(radio_received(p) for _, p in got.get("/hetcomm/pairs", []))


def radio_received(table) -> bool:
    return any(r["source"] == "Charlie" and r["destination"] == "Tango"
               and r["transport"] == "radio" and r["received"] > 0 for r in table["pairs"])


def check_monitor(got, channels) -> None:
    first, last = got[PAIR_TOPIC][0][1], got[PAIR_TOPIC][-1][1]
    assert (last["source"], last["destination"], last["transport"]) == \
        ("Alpha", "VirtualEnv", "wired"), last
    assert last["delivered"] > first["delivered"], (first, last)
    assert last["failed"] == 0, last
    assert last["rate"] > 0, last
    times = [t for t, _ in got[PAIR_TOPIC]]
    assert times == sorted(times) and times[0] > EPOCH_2020_NS, times  # ns since epoch
    systems = {s["system"]: s for _, m in got["/hetcomm/systems"] for s in m["systems"]}
    assert "Act" in [i["module"] for i in systems["Alpha"]["inboxes"]], systems
    # Every advertised per-pair topic is a row of the latest table (rows never disappear).
    rows = {f"/hetcomm/pair/{r['source']}/{r['destination']}/{r['transport']}"
            for r in got["/hetcomm/pairs"][-1][1]["pairs"]}
    pair_topics = {t for t in channels if t.startswith("/hetcomm/pair/")}
    assert PAIR_TOPIC in pair_topics and pair_topics <= rows, (sorted(pair_topics), sorted(rows))


# --- `hetcomm demo --realtime --foxglove`: messages, outcomes, poses ------------------------

COMMANDS = "/hetcomm/message/Charlie/Plan/type0"  # Alpha's Commands to Charlie
FORWARDED = "/hetcomm/message/Tango/Plan/type0"  # Charlie's, forwarded over the radio
WHEELS = "/hetcomm/message/VirtualEnv/World/type1"  # Alpha's Wheels to its VE
OUTCOMES = "/hetcomm/outcome/Alpha/Charlie"
DEMO_TOPICS = [COMMANDS, FORWARDED, WHEELS, OUTCOMES, "/tf", "/hetcomm/rovers",
               "/hetcomm/foxglove", "/hetcomm/security/Alpha", "/hetcomm/paths/Charlie",
               "/hetcomm/pairs"]


async def demo(port: int) -> None:
    ws = await connect(port)
    async with ws:
        s = Session(ws, [lambda t, w=w: t == w for w in DEMO_TOPICS])
        await s.run(demo_done, "hetcomm demo")
        check_demo(s.got, s.channels)
        print(f"foxglove client (demo): {sum(map(len, s.got.values()))} messages on "
              f"{len(s.got)} topics; {len(s.got[COMMANDS])} commands to Charlie, "
              f"{len(s.got['/tf'])} transforms messages")


def moved(tf_messages) -> set:
    """The rovers whose translation changed between their first and last transform."""
    first, last = {}, {}
    for _, m in tf_messages:
        for t in m.transforms:
            first.setdefault(t.child_frame_id, (t.translation.x, t.translation.y))
            last[t.child_frame_id] = (t.translation.x, t.translation.y)
    return {r for r in first if math.dist(first[r], last[r]) > 1.0}


def demo_done(got) -> bool:
    if any(not got.get(t) for t in DEMO_TOPICS):
        return False
    # A turn was commanded (code 1 comes 2 s in), and every rover has moved.
    codes = {m["payload"]["code"] for _, m in got[COMMANDS]}
    return 1 in codes and moved(got["/tf"]) == ROVERS and len(got["/hetcomm/foxglove"]) >= 2


def check_message(m, source, destination, message_type):
    assert m["event"] == "receipt" and m["status"] == "delivered", m
    assert (m["source"]["system"], m["source"]["module"]) == source, m
    assert (m["destination"]["system"], m["destination"]["module"]) == destination, m
    assert m["message_type"] == message_type and m["size"] > 0, m
    assert m["timestamp_us"] * 1000 > EPOCH_2020_NS, m  # the sender's wall clock


def check_scene(m) -> dict:
    """A rover entity per rover, locked to its frame, and its trail in `world`; the trails'
    points by rover."""
    rovers = {e.id: e for e in m.entities if not e.id.endswith("/trail")}
    trails = {e.id.removesuffix("/trail"): e for e in m.entities if e.id.endswith("/trail")}
    assert set(rovers) == ROVERS and set(trails) == ROVERS, [e.id for e in m.entities]
    for e in rovers.values():
        assert e.frame_id == e.id and e.frame_locked, e
        assert len(e.cubes) == 1 and e.texts[0].text == e.id, e
    for e in trails.values():
        assert e.frame_id == "world" and not e.frame_locked and e.lines[0].points, e
    return {r: list(e.lines[0].points) for r, e in trails.items()}


def check_demo(got, channels) -> None:
    # Messages: each on its (destination, module, type) topic, decoded payloads.
    for _, m in got[COMMANDS]:
        check_message(m, ("Alpha", "Plan"), ("Charlie", "Plan"), 0)
        assert m["payload"]["code"] in (0, 1, 2), m
    for _, m in got[FORWARDED]:
        check_message(m, ("Charlie", "Plan"), ("Tango", "Plan"), 0)
        assert m["transport_name"] == "radio", m
    for _, m in got[WHEELS]:
        check_message(m, ("Alpha", "Act"), ("VirtualEnv", "World"), 1)
        assert set(m["payload"]) == {"left", "right"}, m
    seqs = [m["seq"] for _, m in got[COMMANDS]]
    assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs), seqs
    schema = json.loads(channels[COMMANDS]["schema"])
    assert channels[COMMANDS]["schemaName"] == "hetcomm.Message.type0", channels[COMMANDS]
    assert schema["properties"]["payload"]["properties"]["code"]["type"] == "integer", schema
    # Outcomes of Alpha's sends to Charlie: delivered, with a latency.
    for _, o in got[OUTCOMES]:
        assert o["event"] == "outcome", o
        assert (o["source_system"], o["destination_system"]) == ("Alpha", "Charlie"), o
        assert o["outcome"] == "delivered" and o["attempts"] >= 1 and o["latency_us"] >= 0, o
    # Poses: world -> rover frames, stamped as logged (the wall clock).
    for log_time, m in got["/tf"]:
        assert {t.child_frame_id for t in m.transforms} == ROVERS, m
        for t in m.transforms:
            assert t.parent_frame_id == "world", t
            assert abs(stamp_ns(t.timestamp) - log_time) < 10**6, (t.timestamp, log_time)
            assert log_time > EPOCH_2020_NS
            q = t.rotation
            assert abs(q.x**2 + q.y**2 + q.z**2 + q.w**2 - 1) < 1e-9, q
    assert channels["/tf"]["schemaName"] == "foxglove.FrameTransforms", channels["/tf"]
    assert channels["/hetcomm/rovers"]["schemaName"] == "foxglove.SceneUpdate"
    for _, m in got["/hetcomm/rovers"]:
        check_scene(m)
    # What the server itself counted: everything observed was published, nothing dropped.
    server = got["/hetcomm/foxglove"][-1][1]
    assert server["dropped"] == 0 and server["unpublishable"] == 0, server
    assert server["published"] > 0 and server["observed"] >= server["published"], server
    security = got["/hetcomm/security/Alpha"][-1][1]
    assert security["system"] == "Alpha" and security["rejected"] == 0, security
    assert "rejected_auth" in security and "handshakes" in security, security
    paths = got["/hetcomm/paths/Charlie"][-1][1]
    assert paths["system"] == "Charlie" and paths["path_changes"] == 0, paths
    # The layout's live panels show topics the demo serves.
    live = {t for t in layout_topics() if not recorded_only(t)}
    assert live <= set(channels), sorted(live - set(channels))
    table = got["/hetcomm/pairs"][-1][1]["pairs"]
    assert any(r["source"] == "Alpha" and r["destination"] == "Charlie" and r["delivered"] > 0
               for r in table), table


# --- `hetcomm listen --foxglove` on a secured fleet: messages and security rejections -------

LISTENED = "/hetcomm/message/Charlie/Plan/type5"
LISTEN_SECURITY = "/hetcomm/security/Charlie"


async def listen(port: int) -> None:
    ws = await connect(port)
    async with ws:
        s = Session(ws, [lambda t: t in (LISTENED, LISTEN_SECURITY, "/hetcomm/pairs")])
        await s.run(listen_done, "hetcomm listen")
        for _, m in s.got[LISTENED]:
            check_message(m, ("Alpha", "Plan"), ("Charlie", "Plan"), 5)
            assert m["payload"] == {"n": 1} and m["transport_name"] == "radio", m
        last = s.got[LISTEN_SECURITY][-1][1]
        assert last["enabled"] and last["handshakes"] >= 1, last
        # The rejections counted once a second, and what moved since the last message.
        assert sum(m["rejected_since_last"] for _, m in s.got[LISTEN_SECURITY]) <= last["rejected"]
        print(f"foxglove client (listen): {len(s.got[LISTENED])} messages from Alpha; security: "
              f"{last['rejected']} rejected ({', '.join(f'{k} {v}' for k, v in last.items() if k.startswith('rejected_') and k != 'rejected_since_last' and v)}), "
              f"{last['handshakes']} handshakes")


def listen_done(got) -> bool:
    security = got.get(LISTEN_SECURITY, [])
    return bool(got.get(LISTENED)) and any(m["rejected"] > 0 for _, m in security)


# --- `hetcomm replay --foxglove`: a recording's sends, served as they are made again --------

async def replay(port: int) -> None:
    ws = await connect(port)
    async with ws:
        s = Session(ws, [lambda t: t.startswith("/hetcomm/message/") or
                         t.startswith("/hetcomm/outcome/")])
        await s.run(replay_done, "hetcomm replay")
        messages = [m for t, v in s.got.items() if t.startswith("/hetcomm/message/") for _, m in v]
        outcomes = [m for t, v in s.got.items() if t.startswith("/hetcomm/outcome/") for _, m in v]
        for m in messages:
            topic = f"/hetcomm/message/{m['destination']['system']}/{m['destination']['module']}/type{m['message_type']}"
            assert topic in s.got, (topic, m)
            # A message to a system this process opened is shown as received, else as it left
            # (its first attempt).
            if m["event"] == "receipt":
                assert m["status"] == "delivered", m
            else:
                assert m["event"] == "send" and m["attempt"] == 1, m
        for o in outcomes:
            assert o["outcome"] in ("delivered", "sent", "unconfirmed", "failed"), o
        print(f"foxglove client (replay): {len(messages)} messages on "
              f"{sum(t.startswith('/hetcomm/message/') for t in s.got)} topics, "
              f"{len(outcomes)} outcomes ({sorted({o['outcome'] for o in outcomes})})")


def replay_done(got) -> bool:
    wheels = [m for t, v in got.items() if t.endswith("/World/type1") for _, m in v]
    outcomes = sum(len(v) for t, v in got.items() if t.startswith("/hetcomm/outcome/"))
    return len(wheels) >= 5 and outcomes >= 5 and all("left" in m["payload"] for m in wheels)


# --- a recording of `hetcomm demo --record` -------------------------------------------------

def recording(path: str) -> None:
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        schemas = {s.id: s for s in summary.schemas.values()}
        by_topic = {c.topic: (c, schemas.get(c.schema_id)) for c in summary.channels.values()}
        # The layout's panels for recordings show topics the recording holds.
        wanted = {t for t in layout_topics() if recorded_only(t)} | {"/hetcomm/rovers"}
        assert wanted <= set(by_topic), sorted(wanted - set(by_topic))
        for topic, name in [("/tf", "foxglove.FrameTransforms"),
                            ("/hetcomm/rovers", "foxglove.SceneUpdate")]:
            channel, schema = by_topic[topic]
            assert schema.name == name and schema.encoding == "protobuf", schema
            assert channel.message_encoding == "protobuf", channel
        classes = {topic: message_class(by_topic[topic][1].name, by_topic[topic][1].data)
                   for topic in ("/tf", "/hetcomm/rovers")}
        tracks = {}  # rover -> [(log time, x, y)]
        scenes = 0
        receipts = 0
        first_trails = last_trails = None
        for schema, channel, message in reader.iter_messages(log_time_order=True):
            if channel.topic == "/tf":
                m = classes["/tf"].FromString(message.data)
                assert {t.child_frame_id for t in m.transforms} == ROVERS, m
                for t in m.transforms:
                    assert t.parent_frame_id == "world", t
                    assert stamp_ns(t.timestamp) == message.log_time, (t, message.log_time)
                    tracks.setdefault(t.child_frame_id, []).append(
                        (message.log_time, t.translation.x, t.translation.y))
            elif channel.topic == "/hetcomm/rovers":
                trails = check_scene(classes["/hetcomm/rovers"].FromString(message.data))
                first_trails = first_trails or trails
                last_trails = trails
                scenes += 1
            elif channel.topic.startswith("/receipt/"):
                receipts += 1
    assert receipts > 0, "the recording's own events are there too"
    for rover, track in tracks.items():
        times = [t for t, _, _ in track]
        assert times == sorted(times) and len(set(times)) == len(times), rover
        # 10 Hz over the run's 14 s, and the rover drove.
        assert len(track) >= 100, (rover, len(track))
        travelled = sum(math.dist(a[1:], b[1:]) for a, b in zip(track, track[1:]))
        assert travelled > 50, (rover, travelled)
        assert math.dist(track[0][1:], track[-1][1:]) > 10, (rover, track[0], track[-1])
    # Each trail grew as its rover drove, and ends where the rover is.
    for rover in ROVERS:
        assert len(last_trails[rover]) > len(first_trails[rover]) >= 1, rover
        end = last_trails[rover][-1]
        assert math.dist((end.x, end.y), tracks[rover][-1][1:]) <= 1.0, (rover, end)
    # The demo's start poses (hetcomm-sim's thesis scenario).
    assert abs(tracks["Alpha"][0][1] - -190.494) < 1 and abs(tracks["Alpha"][0][2] - -200) < 1
    print(f"foxglove client (mcap): {path}: {sum(map(len, tracks.values()))} transforms of "
          f"{sorted(tracks)}, {scenes} scene updates, {receipts} receipts; Alpha from "
          f"{tracks['Alpha'][0][1:]} to {tuple(round(v, 1) for v in tracks['Alpha'][-1][1:])}")


if __name__ == "__main__":
    mode, arg = sys.argv[1], sys.argv[2]
    if mode == "monitor":
        asyncio.run(monitor(int(arg)))
    elif mode == "demo":
        asyncio.run(demo(int(arg)))
    elif mode == "listen":
        asyncio.run(listen(int(arg)))
    elif mode == "replay":
        asyncio.run(replay(int(arg)))
    elif mode == "mcap":
        recording(arg)
    else:
        raise SystemExit(f"unknown mode {mode}: monitor, demo, listen, replay or mcap")
