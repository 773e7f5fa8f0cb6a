//! The virtual-time simulator: repeatable for a seed, and acknowledged delivery recovering
//! every loss exactly once.

use std::collections::hash_map::DefaultHasher;
use std::hash::{Hash, Hasher};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use hetcomm::sim::{LossVisibility, SimFleet, SimOptions};
use hetcomm::{Message, Outcome, Ticket, Time};
use rand::{Rng, SeedableRng};
use serde::{Deserialize, Serialize};

#[derive(Serialize, Deserialize, Message, Debug, Clone, PartialEq)]
#[message(id = 1)]
struct Ping {
    from: String,
    n: u32,
}

/// The seed for a test: `HETCOMM_SEED` if set (to reproduce a failure), else `default`.
fn seed(default: u64) -> u64 {
    std::env::var("HETCOMM_SEED")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(default)
}

fn lossy_fleet(loss: f64, attempts: u32, delivery: &str) -> hetcomm::config::Fleet {
    let text = lossy_fleet_text(loss, attempts, delivery);
    hetcomm::config::parse_str(&text, "lossy.toml", None).expect("fleet parses")
}

fn lossy_fleet_text(loss: f64, attempts: u32, delivery: &str) -> String {
    format!(
        r#"
[systems]
A = 0
B = 1
C = 2
[modules]
Plan = 0
[transports.radio]
kind = "emulated"
delivery = "{delivery}"
attempts = {attempts}
latency_ms = 5.0
jitter_ms = 2.0
loss_percent = {loss}
[table]
columns = ["A", "B", "C"]
A = ["X", "radio", "radio"]
B = ["radio", "X", "radio"]
C = ["radio", "radio", "X"]
"#
    )
}

struct Run {
    trace: Vec<String>,
    outcomes: Vec<Outcome>,
    received: usize,
    duplicates: u64,
}

/// Every system sends `n` pings to random others; returns what happened.
fn run(seed: u64, loss: f64, attempts: u32, delivery: &str, n: u32) -> Run {
    run_secured(seed, loss, attempts, delivery, n, false).0
}

/// [`run`], with every simulated link sealed or not; also returns the links' security
/// counters, summed over systems.
fn run_secured(
    seed: u64,
    loss: f64,
    attempts: u32,
    delivery: &str,
    n: u32,
    secure: bool,
) -> (Run, hetcomm::SecurityStats) {
    let mut fleet = lossy_fleet(loss, attempts, delivery);
    fleet.secure_in_process = secure;
    let sim = SimFleet::open(
        fleet,
        SimOptions {
            seed,
            losses: LossVisibility::Silent,
            timing: None,
        },
    )
    .expect("open sim");
    let trace = Arc::new(Mutex::new(Vec::new()));
    for name in ["A", "B", "C"] {
        let plan = sim.system(name).unwrap().module("Plan").unwrap();
        let trace = trace.clone();
        let me = name.to_string();
        plan.on::<Ping>(move |r| {
            trace.lock().unwrap().push(format!(
                "{} {me} <- {} #{} seq {}",
                r.envelope.received_at.as_micros(),
                r.message.from,
                r.message.n,
                r.envelope.id().seq
            ));
        })
        .unwrap();
    }
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let mut tickets: Vec<Ticket> = Vec::new();
    for i in 0..n {
        for name in ["A", "B", "C"] {
            let others: Vec<&str> = ["A", "B", "C"].into_iter().filter(|o| *o != name).collect();
            let to = others[rng.gen_range(0..2)];
            let plan = sim.system(name).unwrap().module("Plan").unwrap();
            tickets.push(
                plan.send(
                    to,
                    "Plan",
                    &Ping {
                        from: name.into(),
                        n: i,
                    },
                )
                .unwrap(),
            );
        }
        sim.run_until(sim.now() + Duration::from_millis(3));
    }
    sim.run_idle(Time::from_secs_f64(3600.0));
    let outcomes: Vec<Outcome> = tickets
        .iter()
        .map(|t| t.try_outcome().expect("every send ended"))
        .collect();
    let trace = trace.lock().unwrap().clone();
    let duplicates = sim
        .systems()
        .iter()
        .map(|c| c.stats().router.duplicates)
        .sum();
    let mut security = hetcomm::SecurityStats::default();
    for c in sim.systems() {
        for (_, l) in c.stats().links {
            security.enabled |= l.security.enabled;
            security.handshakes += l.security.handshakes;
            security.rejected_auth += l.security.rejected();
        }
    }
    let run = Run {
        received: trace.len(),
        trace,
        outcomes,
        duplicates,
    };
    (run, security)
}

fn hash(run: &Run) -> u64 {
    let mut h = DefaultHasher::new();
    run.trace.hash(&mut h);
    format!("{:?}", run.outcomes).hash(&mut h);
    h.finish()
}

#[test]
fn same_seed_same_trace_different_seed_different_trace() {
    let s = seed(7);
    let a = run(s, 20.0, 8, "acknowledged", 30);
    let b = run(s, 20.0, 8, "acknowledged", 30);
    assert_eq!(hash(&a), hash(&b), "seed {s}: two runs differ");
    assert_eq!(a.trace, b.trace, "seed {s}");
    let c = run(s + 1, 20.0, 8, "acknowledged", 30);
    assert_ne!(
        hash(&a),
        hash(&c),
        "seeds {s} and {} gave the same trace",
        s + 1
    );
}

/// A secured simulation (every link sealed, keys and sessions from the seed) gives the same
/// trace as the unsecured one: security adds no frame to the simulated network and draws
/// nothing from its random streams.
#[test]
fn a_secured_simulation_repeats_the_unsecured_trace() {
    let s = seed(7);
    let (plain, off) = run_secured(s, 20.0, 8, "acknowledged", 30, false);
    let (sealed, on) = run_secured(s, 20.0, 8, "acknowledged", 30, true);
    assert!(!off.enabled && on.enabled, "seed {s}: {off:?} / {on:?}");
    // Three systems, each with a session to each of the two others.
    assert_eq!(on.handshakes, 6, "seed {s}: {on:?}");
    assert_eq!(on.rejected_auth, 0, "seed {s}: nothing refused: {on:?}");
    assert_eq!(plain.trace, sealed.trace, "seed {s}");
    assert_eq!(hash(&plain), hash(&sealed), "seed {s}");
}

#[test]
fn acknowledged_delivery_recovers_30_percent_loss_exactly_once() {
    let s = seed(11);
    let r = run(s, 30.0, 15, "acknowledged", 100);
    let failed: Vec<_> = r.outcomes.iter().filter(|o| !o.is_success()).collect();
    assert!(
        failed.is_empty(),
        "seed {s}: {} failed: {failed:?}",
        failed.len()
    );
    assert_eq!(r.received, 300, "seed {s}: delivered {} of 300", r.received);
    // Exactly once: no (receiver, sender, n) twice.
    let mut keys: Vec<String> = r
        .trace
        .iter()
        .map(|l| l.split_once(' ').unwrap().1.to_string())
        .collect();
    keys.sort();
    keys.dedup();
    assert_eq!(keys.len(), 300, "seed {s}: a message was delivered twice");
    let retried = r.outcomes.iter().filter(|o| o.attempts() > 1).count();
    assert!(
        retried > 50,
        "seed {s}: only {retried} sends needed retries at 30% loss"
    );
    assert!(
        r.duplicates > 0,
        "seed {s}: lost acks must cause suppressed duplicates"
    );
}

#[test]
fn unacknowledged_delivery_loses_silently_but_reports_sent() {
    let s = seed(3);
    let r = run(s, 30.0, 3, "unacknowledged", 100);
    assert!(
        r.outcomes
            .iter()
            .all(|o| matches!(o, Outcome::Sent { attempts: 1 })),
        "seed {s}"
    );
    assert!(
        (150..=250).contains(&r.received),
        "seed {s}: {} of 300 arrived at 30% loss",
        r.received
    );
}

#[test]
fn ordered_transport_delivers_in_send_order_despite_jitter_and_loss() {
    let s = seed(21);
    let text = r#"
[systems]
A = 0
B = 1
[modules]
Plan = 0
[transports.radio]
kind = "emulated"
attempts = 20
ordered = true
latency_ms = 5.0
jitter_ms = 4.0
loss_percent = 20.0
[table]
columns = ["A", "B"]
A = ["X", "radio"]
B = ["radio", "X"]
"#;
    let fleet = hetcomm::config::parse_str(text, "ordered.toml", None).unwrap();
    let sim = SimFleet::open(
        fleet,
        SimOptions {
            seed: s,
            ..SimOptions::default()
        },
    )
    .unwrap();
    let got = Arc::new(Mutex::new(Vec::new()));
    let g = got.clone();
    sim.system("B")
        .unwrap()
        .module("Plan")
        .unwrap()
        .on::<Ping>(move |r| g.lock().unwrap().push(r.message.n))
        .unwrap();
    let plan = sim.system("A").unwrap().module("Plan").unwrap();
    let tickets: Vec<Ticket> = (0..200)
        .map(|n| {
            let t = plan
                .send(
                    "B",
                    "Plan",
                    &Ping {
                        from: "A".into(),
                        n,
                    },
                )
                .unwrap();
            sim.run_until(sim.now() + Duration::from_millis(1));
            t
        })
        .collect();
    sim.run_idle(Time::from_secs_f64(3600.0));
    assert!(
        tickets
            .iter()
            .all(|t| matches!(t.try_outcome(), Some(Outcome::Delivered { .. }))),
        "seed {s}"
    );
    let got = got.lock().unwrap().clone();
    assert_eq!(
        got,
        (0..200).collect::<Vec<_>>(),
        "seed {s}: out of order or missing"
    );
    let stats = sim.system("B").unwrap().stats().router;
    assert!(
        stats.held > 0,
        "seed {s}: jitter should have made some arrive early"
    );
    assert_eq!(stats.gaps_skipped, 0, "seed {s}");
}

#[test]
fn a_burst_through_a_small_window_under_loss_is_delivered_exactly_once() {
    // A sends 200 pings to B as fast as it may over a radio losing 30% of frames, with at
    // most 4 awaiting their acknowledgement: a refused send waits a simulated millisecond
    // and tries again, as a program would. Nothing is lost and the window is never exceeded.
    let s = seed(5);
    let fleet = hetcomm::config::parse_str(
        &lossy_fleet_text(30.0, 15, "acknowledged")
            .replace("attempts = 15", "attempts = 15\nmax_in_flight = 4"),
        "window.toml",
        None,
    )
    .expect("fleet parses");
    let sim = SimFleet::open(
        fleet,
        SimOptions {
            seed: s,
            losses: LossVisibility::Silent,
            timing: None,
        },
    )
    .expect("open sim");
    let a = sim.system("A").unwrap();
    let plan = a.module("Plan").unwrap();
    let got = Arc::new(Mutex::new(Vec::new()));
    let seen = got.clone();
    sim.system("B")
        .unwrap()
        .module("Plan")
        .unwrap()
        .on::<Ping>(move |r| seen.lock().unwrap().push(r.message.n))
        .unwrap();
    let mut tickets = Vec::new();
    let mut refused = 0u64;
    for n in 0..200 {
        let ping = Ping {
            from: "A".into(),
            n,
        };
        loop {
            match plan.send("B", "Plan", &ping) {
                Ok(t) => break tickets.push(t),
                Err(hetcomm::SendError::Backpressure { limit: 4, .. }) => {
                    refused += 1;
                    sim.run_until(sim.now() + Duration::from_millis(1));
                }
                Err(e) => panic!("seed {s}: {e}"),
            }
            assert!(a.stats().router.in_flight() <= 4, "seed {s}");
        }
        assert!(a.stats().router.in_flight() <= 4, "seed {s}");
    }
    sim.run_idle(Time::from_secs_f64(3600.0));
    assert!(
        tickets
            .iter()
            .all(|t| matches!(t.try_outcome(), Some(Outcome::Delivered { .. }))),
        "seed {s}: every accepted send is delivered"
    );
    let mut got = got.lock().unwrap().clone();
    got.sort_unstable();
    assert_eq!(
        got,
        (0..200).collect::<Vec<u32>>(),
        "seed {s}: exactly once"
    );
    assert!(refused > 0, "seed {s}: the window never filled");
    assert_eq!(a.stats().router.backpressured, refused, "seed {s}");
}
