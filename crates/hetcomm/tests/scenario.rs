//! Scenario files applied to a fleet: a partition changes outcomes exactly as scheduled (in
//! virtual time, seeded and repeatable), a silent system neither sends nor receives,
//! injections are real sends at their time, degraded links lose and delay frames, and the
//! same scenario acts in real time.

use std::time::Duration;

use hetcomm::config::scenario::parse_scenario;
use hetcomm::sim::{SimFleet, SimOptions};
use hetcomm::{LocalFleet, Message, Outcome, Ticket, Time};
use serde::{Deserialize, Serialize};

#[derive(Serialize, Deserialize, Message, Debug, Clone, PartialEq)]
#[message(id = 60)]
struct Ping {
    n: u32,
}

const FLEET: &str = r#"
[systems]
A = 0
B = 1
C = 2
[modules]
Plan = 0
Act = 1
[transports.net]
kind = "inproc"
[transports.radio]
kind = "emulated"
profile = "wired"
[table]
columns = ["A", "B", "C"]
A = ["X", "net", "radio"]
B = ["net", "X", "X"]
C = ["radio", "X", "X"]
"#;

/// One run: A pings B every 100 ms for 4 s under `scenario`; returns, per ping, its outcome
/// (delivered or not) and when B got it (ms), plus the harness's frame drops at A.
fn run(scenario: &str, seed: u64) -> (Vec<(u32, bool, Option<u64>)>, u64) {
    let fleet = hetcomm::parse_fleet(FLEET, "fleet.toml", None).unwrap();
    let sc = parse_scenario(scenario, "scenario.toml", &fleet).unwrap();
    let sim = SimFleet::open(
        fleet,
        SimOptions {
            seed,
            ..SimOptions::default()
        },
    )
    .unwrap();
    let _run = sim.apply_scenario(&sc, seed).unwrap();
    let a = sim.system("A").unwrap().module("Plan").unwrap();
    let b = sim.system("B").unwrap().module("Act").unwrap();
    let mut tickets: Vec<(u32, Ticket)> = Vec::new();
    let mut arrived = std::collections::BTreeMap::new();
    for k in 0..40u32 {
        sim.run_until(Time::ZERO + Duration::from_millis(100 * u64::from(k)));
        while let Some(m) = b.try_recv::<Ping>().unwrap() {
            arrived.insert(m.message.n, sim.now().as_micros() / 1000);
        }
        tickets.push((k, a.send("B", "Act", &Ping { n: k }).unwrap()));
        // Arrivals at the send's own instant come after it, as separate events.
        sim.run_until(sim.now() + Duration::from_millis(1));
        while let Some(m) = b.try_recv::<Ping>().unwrap() {
            arrived.insert(m.message.n, sim.now().as_micros() / 1000);
        }
    }
    sim.run_idle(Time::ZERO + Duration::from_secs(120));
    while let Some(m) = b.try_recv::<Ping>().unwrap() {
        arrived.insert(m.message.n, sim.now().as_micros() / 1000);
    }
    let drops = sim.system("A").unwrap().harness_stats().fault_dropped;
    let out = tickets
        .into_iter()
        .map(|(k, t)| {
            let delivered = matches!(t.try_outcome(), Some(Outcome::Delivered { .. }));
            (k, delivered, arrived.get(&k).copied())
        })
        .collect();
    (out, drops)
}

const CUT: &str = r#"
[[partition]]
between = ["A", "B"]
start = 1.0
end = 2.5
"#;

#[test]
fn a_partition_changes_outcomes_exactly_as_scheduled() {
    let seed = 11;
    let (pings, drops) = run(CUT, seed);
    let (clear, _) = run("", seed);
    assert!(
        clear.iter().all(|(_, d, at)| *d && at.is_some()),
        "seed {seed}: {clear:?}"
    );
    assert!(drops > 0, "seed {seed}");
    for (k, delivered, at) in &pings {
        let sent_ms = u64::from(*k) * 100;
        if sent_ms < 1000 {
            // Before the cut: as without it (arrival within the millisecond after sending).
            assert_eq!(at.map(|t| t - sent_ms), Some(1), "seed {seed}, ping {k}");
        } else if sent_ms >= 2500 {
            assert!(
                *delivered && at.is_some(),
                "seed {seed}, ping {k} after the cut"
            );
        }
        // Nothing crosses during the cut; what was sent in it arrives after it or fails.
        if let Some(t) = at {
            assert!(
                !(1000..2500).contains(t),
                "seed {seed}: ping {k} arrived at {t} ms"
            );
        }
        if (1000..2500).contains(&sent_ms) && *delivered {
            assert!(
                at.is_some_and(|t| t >= 2500),
                "seed {seed}: ping {k} {at:?}"
            );
        }
    }
    // The cut is visible in outcomes: some ping sent in it did not arrive on time.
    assert!(
        pings
            .iter()
            .any(|(k, d, at)| (10..25).contains(k) && (!d || at.is_some_and(|t| t >= 2500))),
        "seed {seed}: {pings:?}"
    );
    // Seeded: the same seed gives the same run.
    assert_eq!(run(CUT, seed), (pings, drops), "seed {seed}");
}

#[test]
fn degraded_links_lose_and_delay_repeatably_for_a_seed() {
    let sc = r#"
[[link]]
between = ["A", "B"]
loss = 0.3
latency_ms = 40.0
jitter_ms = 20.0
start = 0.0
end = 4.0
"#;
    for seed in [1, 2] {
        let (pings, drops) = run(sc, seed);
        assert!(drops > 0, "seed {seed}");
        for (k, _, at) in &pings {
            let sent = u64::from(*k) * 100;
            if let Some(t) = at {
                assert!(
                    *t >= sent + 40,
                    "seed {seed}: ping {k} at {t} ms, sent {sent} ms"
                );
            }
        }
        assert_eq!(run(sc, seed), (pings, drops), "seed {seed}");
    }
}

#[test]
fn injections_are_sends_at_their_time_and_silence_cuts_both_ways() {
    let fleet = hetcomm::parse_fleet(FLEET, "fleet.toml", None).unwrap();
    let sc = parse_scenario(
        r#"
[[inject]]
at = 0.5
from = "A.Plan"
to = "B.Act"
type = 60
payload = { n = 7 }

[[inject]]
at = 1.5
from = "B.Plan"
to = "A.Act"
type = 60
payload = { n = 8 }

[[silence]]
system = "B"
start = 1.0
end = 30.0
"#,
        "scenario.toml",
        &fleet,
    )
    .unwrap();
    let sim = SimFleet::open(fleet, SimOptions::default()).unwrap();
    let run = sim.apply_scenario(&sc, 3).unwrap();
    let b = sim.system("B").unwrap().module("Act").unwrap();
    let a = sim.system("A").unwrap().module("Act").unwrap();
    sim.run_until(Time::ZERO + Duration::from_millis(499));
    assert!(b.try_recv::<Ping>().unwrap().is_none());
    sim.run_until(Time::ZERO + Duration::from_millis(501));
    assert_eq!(
        b.try_recv::<Ping>().unwrap().unwrap().message,
        Ping { n: 7 }
    );
    sim.run_until(Time::ZERO + Duration::from_secs(60));
    assert!(a.try_recv::<Ping>().unwrap().is_none(), "B is silent");
    let report = run.injection_report();
    assert!(report[0].contains("delivered"), "{report:?}");
    assert!(
        report[1].contains("Failed") || report[1].contains("Unconfirmed"),
        "{report:?}"
    );
}

#[test]
fn a_partition_acts_in_real_time_too() {
    let fleet = hetcomm::parse_fleet(FLEET, "fleet.toml", None).unwrap();
    let sc = parse_scenario(
        "[[partition]]\nbetween = [\"A\", \"B\"]\nstart = 0.0\nend = 0.3\n",
        "scenario.toml",
        &fleet,
    )
    .unwrap();
    let local = LocalFleet::open(fleet).unwrap();
    let _run = local.apply_scenario(&sc, 1).unwrap();
    let a = local.system("A").unwrap().module("Plan").unwrap();
    let b = local.system("B").unwrap().module("Act").unwrap();
    let t0 = std::time::Instant::now();
    let ticket = a.send("B", "Act", &Ping { n: 1 }).unwrap();
    let got = b.recv_timeout::<Ping>(Duration::from_secs(10)).unwrap();
    // Cut for 0.3 s: the first attempts were lost, a retransmission after the cut got through.
    assert!(
        t0.elapsed() >= Duration::from_millis(300),
        "{:?}",
        t0.elapsed()
    );
    assert_eq!(got.message, Ping { n: 1 });
    assert!(matches!(ticket.wait(), Outcome::Delivered { attempts, .. } if attempts > 1));
    assert!(local.system("A").unwrap().harness_stats().fault_dropped > 0);
}

/// One system per `Comm` over real UDP sockets, as one process per system would run them:
/// each applies the scenario to itself, and a partition written for both directions acts at
/// both ends.
#[test]
fn each_system_applies_its_part_of_a_scenario() {
    let port = || {
        std::net::UdpSocket::bind("127.0.0.1:0")
            .and_then(|s| s.local_addr())
            .map(|a| a.port())
            .unwrap()
    };
    let text = format!(
        r#"
[systems]
A = 0
B = 1
[modules]
Plan = 0
Act = 1
[transports.u]
kind = "udp"
security = "none"
attempts = 12
endpoints = {{ A = "127.0.0.1:{}", B = "127.0.0.1:{}" }}
[table]
columns = ["A", "B"]
A = ["X", "u"]
B = ["u", "X"]
"#,
        port(),
        port()
    );
    let fleet = hetcomm::parse_fleet(&text, "udp.toml", None).unwrap();
    let sc = parse_scenario(
        "[[partition]]\nbetween = [\"A\", \"B\"]\nstart = 0.0\nend = 0.4\n",
        "scenario.toml",
        &fleet,
    )
    .unwrap();
    let a = hetcomm::Comm::open_fleet(&fleet, "A").unwrap();
    let b = hetcomm::Comm::open_fleet(&fleet, "B").unwrap();
    let (_ra, _rb) = (
        a.apply_scenario(&sc, 5).unwrap(),
        b.apply_scenario(&sc, 5).unwrap(),
    );
    let t0 = std::time::Instant::now();
    let ticket = a
        .module("Plan")
        .unwrap()
        .send("B", "Act", &Ping { n: 3 })
        .unwrap();
    let got = b
        .module("Act")
        .unwrap()
        .recv_timeout::<Ping>(Duration::from_secs(10));
    let got = got.unwrap_or_else(|e| {
        panic!(
            "{e}: outcome {:?}, A {:?}, B {:?}",
            ticket.try_outcome(),
            a.harness_stats(),
            b.harness_stats()
        )
    });
    assert_eq!(got.message, Ping { n: 3 });
    assert!(
        t0.elapsed() >= Duration::from_millis(400),
        "{:?}",
        t0.elapsed()
    );
    assert!(matches!(ticket.wait(), Outcome::Delivered { attempts, .. } if attempts > 1));
    // Both ends cut: A's data frames, and (once B has heard nothing) nothing of B's.
    assert!(a.harness_stats().fault_dropped > 0);
}

#[test]
fn a_scenario_replaces_a_topic_source_and_delays_a_path_for_an_interval() {
    let fleet = hetcomm::parse_fleet(FLEET, "fleet.toml", None).unwrap();
    let sc = parse_scenario(
        r#"
[[tap]]
system = "B"
topic = "cmd"
action = "replace"
start = 1.0
end = 2.0
script = [{ at = 1.5, payload = { n = 99 } }]

[[tap]]
to = "B"
from = "A"
action = "delay"
delay_ms = 250.0
start = 3.0
end = 4.0
"#,
        "scenario.toml",
        &fleet,
    )
    .unwrap();
    let sim = SimFleet::open(fleet, SimOptions::default()).unwrap();
    let b = sim.system("B").unwrap();
    let publisher = b.node("Plan").unwrap().advertise::<Ping>("cmd").unwrap();
    let sub = b.node("Act").unwrap().subscribe::<Ping>("cmd").unwrap();
    let run = sim.apply_scenario(&sc, 1).unwrap();
    assert_eq!(run.taps(), 2);
    let at = |s: f64| Time::ZERO + Duration::from_secs_f64(s);
    let mut got = Vec::new();
    for (t, n) in [(0.5, 1), (1.2, 2), (1.8, 3), (2.5, 4)] {
        sim.run_until(at(t));
        publisher.publish(Ping { n }).unwrap();
        while let Some(p) = sub.try_recv() {
            got.push((sim.now().as_micros() / 1000, p.n));
        }
        sim.run_until(at(t + 0.001));
        while let Some(p) = sub.try_recv() {
            got.push((sim.now().as_micros() / 1000, p.n));
        }
    }
    // The real values of 1.2 s and 1.8 s are replaced; the script's value arrives at 1.5 s
    // (taken at the next look, 1.8 s).
    assert_eq!(got, [(500, 1), (1800, 99), (2500, 4)]);
    assert_eq!(b.harness_stats().replaced, 2);

    let a = sim.system("A").unwrap().module("Plan").unwrap();
    let act = b.module("Act").unwrap();
    for (t, n) in [(2.9, 10), (3.5, 11)] {
        sim.run_until(at(t));
        a.send("B", "Act", &Ping { n }).unwrap();
        sim.run_until(at(t + 0.01));
        let now = act.try_recv::<Ping>().unwrap().map(|m| m.message.n);
        sim.run_until(at(t + 0.3));
        let later = act.try_recv::<Ping>().unwrap().map(|m| m.message.n);
        match n {
            10 => assert_eq!((now, later), (Some(10), None)),
            _ => assert_eq!(
                (now, later),
                (None, Some(11)),
                "held 250 ms inside the window"
            ),
        }
    }
}

/// An unacknowledged send leaves by the unqueued path, not the router's loop: the scheduled
/// faults act there too (one interception point), in real time, and the send says only what
/// it knows: *sent*, the frame having left, not *delivered*.
#[test]
fn a_partition_takes_unacknowledged_frames_on_the_unqueued_path_too() {
    let fleet = FLEET.replace(
        "[transports.net]\nkind = \"inproc\"\n",
        "[transports.net]\nkind = \"inproc\"\ndelivery = \"unacknowledged\"\n",
    );
    let fleet = hetcomm::parse_fleet(&fleet, "fleet.toml", None).unwrap();
    let sc = parse_scenario(
        "[[partition]]\nbetween = [\"A\", \"B\"]\nstart = 0.0\nend = 30.0\n",
        "scenario.toml",
        &fleet,
    )
    .unwrap();
    let local = LocalFleet::open(fleet).unwrap();
    let _run = local.apply_scenario(&sc, 1).unwrap();
    let a = local.system("A").unwrap().module("Plan").unwrap();
    let b = local.system("B").unwrap().module("Act").unwrap();
    for n in 0..5 {
        let ticket = a.send("B", "Act", &Ping { n }).unwrap();
        assert!(
            matches!(ticket.wait(), Outcome::Sent { attempts: 1 }),
            "ping {n}"
        );
    }
    assert!(matches!(
        b.recv_timeout::<Ping>(Duration::from_millis(300)),
        Err(hetcomm::RecvError::Timeout(_))
    ));
    let stats = local.system("A").unwrap().harness_stats();
    assert_eq!(stats.fault_dropped, 5, "{stats:?}");
}
