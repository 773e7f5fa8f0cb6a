//! Range on an emulated link under the simulator: two systems drive apart past `range_m` and
//! back. Acknowledged sends fail (no acknowledgement) while out of range and are delivered
//! again once back in range.

use std::time::Duration;

use hetcomm::sim::{LossVisibility, SimFleet, SimOptions};
use hetcomm::{FailReason, Message, Outcome, Ticket, Time};
use serde::{Deserialize, Serialize};

#[derive(Serialize, Deserialize, Message, Debug, Clone, PartialEq)]
#[message(id = 3)]
struct Beacon {
    n: u32,
}

const RANGE_M: f64 = 50.0;
/// Rover speed, m/s.
const SPEED: f64 = 10.0;
/// Out to 120 m and back: 12 s each way.
const TURN_S: f64 = 12.0;

/// Distance of the rover from the base at virtual time `t` (seconds).
fn distance(t: f64) -> f64 {
    if t <= TURN_S {
        SPEED * t
    } else {
        (SPEED * (2.0 * TURN_S - t)).max(0.0)
    }
}

#[test]
fn sends_fail_out_of_range_and_deliver_again_after() {
    // Budget 3, first RTO 20 ms doubling: a send is decided within 20 + 40 + 80 = 140 ms, in
    // which the rover moves 1.4 m; sends made within 5 m of the range edge are not judged.
    let fleet = hetcomm::config::parse_str(
        &format!(
            r#"
            [systems]
            Base = 0
            Rover = 1
            [modules]
            Plan = 0
            [transports.radio]
            kind = "emulated"
            latency_ms = 2
            range_m = {RANGE_M}
            attempts = 3
            [table]
            columns = ["Base", "Rover"]
            Base = ["X", "radio"]
            Rover = ["radio", "X"]
            "#
        ),
        "range.toml",
        None,
    )
    .expect("fleet parses");
    let timing = hetcomm_router_timing();
    let sim = SimFleet::open(
        fleet,
        SimOptions {
            seed: 1,
            losses: LossVisibility::Silent,
            timing: Some(timing),
        },
    )
    .expect("sim opens");
    let base = sim.system("Base").unwrap().module("Plan").unwrap();
    let rover = sim.system("Rover").unwrap().module("Plan").unwrap();
    let base_id = sim.system("Base").unwrap().id();
    let rover_id = sim.system("Rover").unwrap().id();
    sim.positions().set(base_id, 0.0, 0.0);

    let step = Duration::from_millis(10);
    let mut sends: Vec<(f64, Ticket)> = Vec::new();
    let mut received = Vec::new();
    let mut t = Time::ZERO;
    let end = Time::from_secs_f64(2.0 * TURN_S + 1.0);
    let mut n = 0;
    let mut next_beacon = Time::ZERO;
    while t < end {
        let secs = t.as_secs_f64();
        sim.positions().set(rover_id, distance(secs), 0.0);
        // One beacon every 250 ms.
        if t >= next_beacon {
            next_beacon = next_beacon + Duration::from_millis(250);
            sends.push((
                distance(secs),
                base.send("Rover", "Plan", &Beacon { n }).unwrap(),
            ));
            n += 1;
        }
        t = t + step;
        sim.run_until(t);
        while let Some(r) = rover.try_recv::<Beacon>().unwrap() {
            received.push((r.message.n, distance(r.envelope.received_at.as_secs_f64())));
        }
    }
    sim.run_idle(end + Duration::from_secs(5));

    let (mut in_range_ok, mut out_of_range_unconfirmed, mut after_return_ok) = (0, 0, 0);
    for (i, (d, ticket)) in sends.iter().enumerate() {
        let outcome = ticket.try_outcome().expect("every send ended");
        let sent_at = i as f64 * 0.25;
        if *d < RANGE_M - 5.0 {
            assert!(
                matches!(outcome, Outcome::Delivered { attempts: 1, .. }),
                "beacon {i} sent at {d:.1} m (t = {sent_at} s): {outcome:?}"
            );
            in_range_ok += 1;
            if sent_at > TURN_S {
                after_return_ok += 1;
            }
        } else if *d > RANGE_M + 5.0 {
            // Out of range the frames are lost in the air: the sender saw them leave and no
            // acknowledgement come back, so it cannot claim they failed.
            assert_eq!(
                outcome,
                Outcome::Unconfirmed {
                    reason: FailReason::NoAcknowledgement,
                    attempts: 3
                },
                "beacon {i} sent at {d:.1} m (t = {sent_at} s)"
            );
            out_of_range_unconfirmed += 1;
        }
    }
    // 0–45 m out and back: 2 × 4.5 s of beacons; 55–120–55 m: 2 × 6.5 s.
    assert!(in_range_ok >= 30, "in range and delivered: {in_range_ok}");
    assert!(
        out_of_range_unconfirmed >= 45,
        "out of range and unconfirmed: {out_of_range_unconfirmed}"
    );
    assert!(
        after_return_ok >= 15,
        "delivered again after the return: {after_return_ok}"
    );
    // Nothing arrived while the rover was out of range (plus the latency margin).
    for (n, d) in &received {
        assert!(*d <= RANGE_M + 1.0, "beacon {n} received at {d:.1} m");
    }
    let drops = sim.net_stats().dropped;
    assert!(
        drops.get("OutOfRange").copied().unwrap_or(0) >= 3 * 45,
        "frames dropped as out of range: {drops:?}"
    );
}

/// First RTO 20 ms, floor 10 ms, ceiling 160 ms, backoff 2: the experiment's timing.
fn hetcomm_router_timing() -> hetcomm_experiments::reliability::Timing {
    hetcomm_experiments::reliability::default_timing()
}
