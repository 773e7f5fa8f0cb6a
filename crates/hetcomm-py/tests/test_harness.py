"""The Node API's topics and the harness from Python: a published object reaches subscribers
as the same object, notifications, taps with Python functions (observe, modify, drop, delay,
duplicate) on message and topic paths, replacement, and the counters."""

from __future__ import annotations

import time

import pytest

import hetcomm
from conftest import Command


def test_topics_hand_over_the_very_object(fleet):
    alpha = fleet.system("Alpha")
    plan, act = alpha.module("Plan"), alpha.module("Act")
    pub = plan.advertise("pose")
    sub = act.subscribe("pose", capacity=2)
    seen = []
    note = act.on_topic("pose", seen.append)
    value = {"x": 1.5, "y": [1, 2]}
    pub.publish(value)
    got = sub.try_recv()
    assert got is value and seen == [value] and seen[0] is value
    for i in range(3):
        pub.publish(i)
    assert (sub.pending, sub.dropped) == (2, 1)
    assert sub.latest() == 2 and sub.try_recv() is None
    with pytest.raises(TimeoutError):
        sub.recv(timeout=0.05)
    del note


def test_taps_with_python_functions_on_messages(fleet):
    plan = fleet.module("Alpha", "Plan")
    act = fleet.module("Charlie", "Act")
    charlie = fleet.system("Charlie")
    seen = []
    obs = charlie.tap("observe", to="Charlie", from_="Alpha", module="Act",
                      function=lambda m: seen.append(m["payload"]))

    def double(m):
        if m["payload"]["code"] == 13:
            return "drop"
        m["payload"] = {"code": m["payload"]["code"] * 2}
        return ("duplicate", 1)

    mod = charlie.tap("modify", to="Charlie", module="Act", function=double)
    for code in (1, 13, 4):
        assert plan.send("Charlie", "Act", Command(code=code)).wait().delivered
    got = [r.message.code for r in iter(act.try_recv, None)]
    assert got == [2, 2, 8, 8]
    assert [p["code"] for p in seen] == [1, 13, 4]
    stats = charlie.harness_stats()
    assert (stats["tapped"], stats["modified"], stats["dropped"], stats["duplicated"]) == (3, 2, 1, 2)
    obs.remove()
    mod.remove()

    delay = charlie.tap("delay", to="Charlie", delay=0.2)
    t0 = time.monotonic()
    plan.send("Charlie", "Act", Command(code=5)).wait()
    assert act.try_recv() is None
    assert act.recv(timeout=5).message.code == 5
    assert time.monotonic() - t0 >= 0.2
    delay.remove()

    fake = charlie.replace(to="Charlie", from_="Alpha", module="Act")
    plan.send("Charlie", "Act", Command(code=6)).wait()
    fake.inject(0, {"code": 600})
    r = act.try_recv()
    assert r.message.code == 600 and r.envelope.source_system == "Alpha"
    assert act.try_recv() is None
    fake.end()
    plan.send("Charlie", "Act", Command(code=7)).wait()
    assert act.try_recv().message.code == 7


def test_taps_on_topics_and_bad_paths(fleet):
    alpha = fleet.system("Alpha")
    pub = alpha.module("Plan").advertise("cmd")
    sub = alpha.module("Act").subscribe("cmd")
    t = alpha.tap("modify", system="Alpha", topic="cmd",
                  function=lambda m: m.update(value=m["value"] + 1))
    pub.publish(1)
    assert sub.try_recv() == 2
    t.remove()
    r = alpha.replace(system="Alpha", topic="cmd")
    pub.publish(3)
    r.publish(30)
    assert sub.try_recv() == 30 and sub.try_recv() is None
    r.end()
    with pytest.raises(ValueError, match="no system `Nowhere`"):
        alpha.tap("drop", to="Alpha", from_="Nowhere")
    with pytest.raises(ValueError, match="acts at system `Charlie`"):
        alpha.tap("drop", to="Charlie")
    with pytest.raises(TypeError, match="needs function="):
        alpha.tap("observe", to="Alpha")


def test_scenario_files_from_python(fleet, tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text('[[silence]]\nsystem = "Tnago"\nstart = 0\nend = 1\n')
    with pytest.raises(hetcomm.ConfigError, match="unknown system `Tnago`"):
        fleet.apply_scenario(bad)
    sc = tmp_path / "cut.toml"
    sc.write_text('[[partition]]\nbetween = ["Alpha", "Charlie"]\nstart = 0.0\nend = 30.0\n'
                  '[[inject]]\nat = 0.0\nfrom = "Charlie.Plan"\nto = "Alpha.Act"\ntype = 0\n'
                  'payload = { code = 4 }\n')
    run = fleet.apply_scenario(sc, seed=3)
    assert run.faulted_systems == 2
    plan = fleet.module("Alpha", "Plan")
    ticket = plan.send("Charlie", "Act", Command(code=1))
    assert not ticket.wait(timeout=0.3) or not ticket.try_outcome().delivered
    assert fleet.system("Alpha").harness_stats()["fault_dropped"] > 0
    time.sleep(0.2)
    assert len(run.injection_report()) == 1
