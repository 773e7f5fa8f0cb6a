//! A stepped wall clock moves no timer (issue 34): two systems over UDP on 127.0.0.1 in one
//! process, with a clock whose wall time the test steps by an hour forward and back while a
//! stream of acknowledged, ordered sends runs. Every delivery is held back 20 ms by a delay
//! tap (the acknowledgement is not), so that at each step some twenty messages await the
//! harness's timer, beside the sends awaiting their acknowledgement. Were timers on the wall
//! clock, the step forward would fire every retransmission timer at once, and the step back
//! would leave the held messages (and any retransmission) waiting for the hour: with the
//! clock's `now` made the stepped wall time, as the runtime had it before, about twenty
//! messages never arrive at each step back.

use std::sync::atomic::{AtomicI64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use hetcomm_core::{MessageType, Time};

use crate::comm::{LocalFleet, OpenEnv};
use crate::harness::{TapAction, TapPath};
use crate::transports::Hubs;
use crate::{Clock, Outcome, SendOptions};

/// The real clock with a wall clock the test steps.
#[derive(Default)]
struct SteppedClock {
    /// Added to the wall clock, microseconds.
    offset_us: AtomicI64,
}

impl Clock for SteppedClock {
    fn now(&self) -> Time {
        Time::now_mono()
    }
    fn wall(&self, now: Time) -> Time {
        let wall = Time::wall_at(now).as_micros();
        Time(wall.saturating_add_signed(self.offset_us.load(Ordering::Relaxed)))
    }
}

fn free_udp_port() -> u16 {
    let s = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    s.local_addr().unwrap().port()
}

const HOUR_US: i64 = 3_600_000_000;
/// One send every this long; the wall clock steps at `STEPS`' times.
const EVERY: Duration = Duration::from_millis(1);
const RUN: Duration = Duration::from_millis(1_600);
const STEPS: [(u64, i64); 3] = [(400, HOUR_US), (800, 0), (1_200, -HOUR_US)];

#[test]
fn stepping_the_wall_clock_fires_no_retransmission_and_stalls_no_send() {
    let (pa, pb) = (free_udp_port(), free_udp_port());
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
ordered = true
security = "none"
endpoints = {{ A = "127.0.0.1:{pa}", B = "127.0.0.1:{pb}" }}
[table]
columns = ["A", "B"]
A = ["X", "u"]
B = ["u", "X"]
"#
    );
    let fleet = crate::parse_fleet(&text, "stepped.toml", None).unwrap();
    let clock = Arc::new(SteppedClock::default());
    let env = OpenEnv {
        clock: clock.clone(),
        // A retransmission timeout well above the tap's delay: on this loopback nothing is
        // retransmitted unless a timer fires early.
        timing: Some(hetcomm_router::Timing {
            initial_rto: Duration::from_millis(500),
            min_rto: Duration::from_millis(500),
            ..Default::default()
        }),
        ..OpenEnv::real(Hubs::default())
    };
    let fleet = LocalFleet::open_in(Arc::new(fleet), env).unwrap();
    let (a, b) = (fleet.system("A").unwrap(), fleet.system("B").unwrap());
    let _tap = b
        .tap(
            &TapPath::messages("B").from("A").module("Act"),
            TapAction::Delay(Duration::from_millis(20)),
        )
        .unwrap();
    let (plan, act) = (a.module("Plan").unwrap(), b.module("Act").unwrap());

    let receiver = std::thread::spawn(move || {
        // (sequence number, arrival) of every message, until none comes for a second.
        let mut got = Vec::new();
        while let Ok(m) = act.recv_raw_timeout(Some(Duration::from_secs(1))) {
            got.push((m.envelope.header.seq, Instant::now()));
        }
        got
    });

    let start = Instant::now();
    let mut tickets = Vec::new();
    let mut steps = STEPS.iter().peekable();
    let mut stamps = Vec::new();
    while start.elapsed() < RUN {
        if let Some(&&(at, offset)) = steps.peek() {
            if start.elapsed() >= Duration::from_millis(at) {
                clock.offset_us.store(offset, Ordering::Relaxed);
                steps.next();
            }
        }
        let n = tickets.len() as u64;
        let payload = n.to_le_bytes();
        let ticket = plan
            .send_raw("B", "Act", MessageType(9), &payload, SendOptions::default())
            .unwrap();
        tickets.push(ticket);
        let due = EVERY * tickets.len() as u32;
        if let Some(wait) = due.checked_sub(start.elapsed()) {
            std::thread::sleep(wait);
        }
        stamps.push(clock.wall(clock.now()));
    }
    let sent = tickets.len() as u64;
    let mut slowest = Duration::ZERO;
    for (i, t) in tickets.iter().enumerate() {
        match t.wait_timeout(Duration::from_secs(3)) {
            Some(Outcome::Delivered { latency, .. }) => slowest = slowest.max(latency),
            other => panic!("send {i} of {sent} ended {other:?}"),
        }
    }
    let got = receiver.join().unwrap();
    let retransmissions = a.stats().router.retransmissions;
    let seqs: Vec<u64> = got.iter().map(|(s, _)| *s).collect();
    let largest_gap = got
        .windows(2)
        .map(|w| w[1].1 - w[0].1)
        .max()
        .unwrap_or_default();
    eprintln!(
        "{sent} sent, {} received, {retransmissions} retransmissions, slowest {slowest:?}, largest gap {largest_gap:?}",
        got.len()
    );
    let missing: Vec<u64> = (1..=sent).filter(|s| !seqs.contains(s)).collect();
    assert!(
        missing.is_empty(),
        "{} never arrived: {missing:?}",
        missing.len()
    );
    assert!(
        seqs.windows(2).all(|w| w[0] < w[1]),
        "exactly once, in order"
    );
    assert_eq!(seqs.len() as u64, sent);
    assert_eq!(retransmissions, 0, "no timer fired early");
    // A send's latency is on the monotonic clock: about the tap's delay, never the step.
    assert!(slowest < Duration::from_millis(400), "slowest {slowest:?}");
    assert!(
        largest_gap < Duration::from_millis(200),
        "largest gap {largest_gap:?}"
    );
    // The stamps did follow the steps (within the 100 ms a thread keeps the offset).
    let first = stamps[0].as_micros() as i64;
    let at = |ms: u64| stamps[(ms / EVERY.as_millis() as u64) as usize].as_micros() as i64;
    for (step_ms, offset) in STEPS {
        let after = at(step_ms + 150) - first - (step_ms + 150) as i64 * 1_000;
        assert!(
            after.abs_diff(offset) < 100_000,
            "{step_ms} ms: stamps {after} µs off, step {offset}"
        );
    }
}
