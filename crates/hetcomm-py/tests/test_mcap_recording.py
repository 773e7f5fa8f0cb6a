"""A recording of the demonstration, read back by the `mcap` Python package (PyPI) without
hetcomm: every send, receipt and outcome is there, with the envelope, a JSON Schema per
message type, and the payload's fields by name (docs/record-replay.md)."""

from __future__ import annotations

import json
import re
import subprocess

from mcap.reader import make_reader

from conftest import CLI


def test_every_message_and_outcome_of_the_demo_is_in_the_recording(tmp_path):
    path = tmp_path / "run.mcap"
    done = subprocess.run(
        [CLI, "demo", "--out", str(tmp_path / "out"), "--record", str(path)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr
    counts = re.search(
        r"recorded .*: (\d+) send attempts, (\d+) receipts, (\d+) outcomes", done.stderr
    )
    assert counts, done.stderr
    attempts, receipts, outcomes = (int(x) for x in counts.groups())

    events = {"send": [], "receipt": [], "outcome": []}
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary.statistics.message_count == attempts + receipts + outcomes
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
        assert meta["hetcomm"]["encoding"] == "json"
        assert meta["hetcomm"]["fleet"] == "leader-follower"
        for schema, channel, message in reader.iter_messages():
            assert channel.message_encoding == "json"
            assert schema.encoding == "jsonschema"
            json.loads(schema.data)  # a JSON Schema document
            event = json.loads(message.data)
            assert message.log_time == event["time_us"] * 1000
            events[event["event"]].append((channel.topic, schema.name, event))

    sends = [e for _, _, e in events["send"] if e["attempt"] == 1]
    assert len(events["send"]) == attempts and len(sends) > 400
    assert len(events["receipt"]) == receipts
    assert len(events["outcome"]) == outcomes == len(sends)

    key = lambda e: (e["source"]["system"], e["destination"]["system"], e["seq"])
    received = {key(e): e for _, _, e in events["receipt"]}
    ended = {
        (e["source_system"], e["destination_system"], e["seq"]): e
        for _, _, e in events["outcome"]
    }
    for e in sends:
        # Every send reached its destination's inbox with the same payload, and ended.
        assert received[key(e)]["payload"] == e["payload"]
        assert received[key(e)]["status"] == "delivered"
        assert ended[key(e)]["outcome"] == "delivered"

    # The leader's commands to Charlie, by field name, on their own topic and schema.
    commands = [
        (schema, e["payload"])
        for topic, schema, e in events["send"]
        if topic == "/send/Alpha/Plan/Charlie/Plan"
    ]
    assert [p["code"] for _, p in commands] == [1, 0, 1, 0]
    assert {s for s, _ in commands} == {"hetcomm.Send.type0"}
    wheels = [e for t, _, e in events["send"] if t == "/send/Alpha/Act/VirtualEnv/World"]
    assert set(wheels[0]["payload"]) == {"left", "right"}
