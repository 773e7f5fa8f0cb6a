//! A live sender's wall clock stepped an hour forward and back mid-stream (issue 34), over
//! real UDP and TCP on 127.0.0.1, secured with keys from `hetcomm keygen`.
//!
//! The sender is this test binary run again as a child process under libfaketime
//! (`LD_PRELOAD`, `FAKETIME_DONT_FAKE_MONOTONIC=1`: only the wall clock moves, read from a
//! timestamp file the test rewrites, uncached so a step is seen at once). It streams
//! acknowledged sends, 2000 a second (at most 32 awaiting their acknowledgement), and reports its
//! counters every 100 ms. The receiver is a system opened in this process, on the real
//! clock. Timers on the monotonic clock mean: no burst of retransmissions at a step (on
//! loopback there is next to nothing to retransmit), no stall (the stream keeps its rate),
//! no send timed across a step (its latency an hour: how timers on the wall clock showed
//! here), every send delivered and every message received exactly once. The stamps, on the
//! wall clock, do follow the steps.
//!
//! `harness = false`: `main` is both the test and, when `HETCOMM_CLOCK_STEP_SENDER` names a
//! fleet file, the sender. Without libfaketime the test fails and says to run
//! scripts/install.sh.

mod support;

use std::collections::VecDeque;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use hetcomm::{Comm, MessageType, Outcome, SendOptions, Time};
use support::*;

const SENDER_ENV: &str = "HETCOMM_CLOCK_STEP_SENDER";
const HOUR_US: i64 = 3_600_000_000;
/// The stream's length, and when the sender's wall clock is set to which offset.
const RUN_MS: u64 = 4_000;
const STEPS: [(u64, i64); 3] = [(1_000, HOUR_US), (2_000, 0), (3_000, -HOUR_US)];
/// Sends awaiting their acknowledgement at once, at most.
const WINDOW: usize = 32;
/// One send every this long.
const EVERY: Duration = Duration::from_micros(500);

fn main() {
    if let Ok(fleet) = std::env::var(SENDER_ENV) {
        sender(Path::new(&fleet));
        return;
    }
    let lib = faketime_library();
    for kind in ["udp", "tcp"] {
        stepped_stream(kind, &lib);
    }
    println!("clock_step: udp and tcp passed");
}

/// Where libfaketime is, or a failure telling how to get it.
fn faketime_library() -> PathBuf {
    let listed = Command::new("dpkg")
        .args(["-L", "libfaketime"])
        .output()
        .map(|o| String::from_utf8_lossy(&o.stdout).into_owned())
        .unwrap_or_default();
    listed
        .lines()
        .map(PathBuf::from)
        .find(|p| p.file_name().is_some_and(|n| n == "libfaketime.so.1") && p.exists())
        .unwrap_or_else(|| {
            panic!(
                "libfaketime is not installed (no libfaketime.so.1 in `dpkg -L libfaketime`): \
                 run scripts/install.sh, which installs the `faketime` package"
            )
        })
}

/// The child: opens Alpha, streams to Bravo.Act for `RUN_MS`, printing
/// `tick <ms> <sent> <delivered> <retransmissions> <wall µs>` every 100 ms and
/// `done <sent> <delivered> <retransmissions> <slowest µs>` at the end.
fn sender(fleet: &Path) {
    let comm = Comm::open(fleet, "Alpha").expect("open Alpha");
    let plan = comm.module("Plan").expect("module Plan");
    let start = Instant::now();
    let mut pending = VecDeque::new();
    let (mut sent, mut delivered, mut slowest) = (0u64, 0u64, Duration::ZERO);
    let mut next_tick = Duration::ZERO;
    let settle =
        |(n, t): (u64, hetcomm::Ticket), delivered: &mut u64, slowest: &mut Duration| match t
            .wait_timeout(Duration::from_secs(5))
        {
            Some(Outcome::Delivered { latency, .. }) => {
                *delivered += 1;
                *slowest = (*slowest).max(latency);
            }
            other => panic!(
                "send {n} ended {other:?} ({:?} into the stream; {:?})",
                start.elapsed(),
                comm.stats()
            ),
        };
    println!("start");
    while start.elapsed() < Duration::from_millis(RUN_MS) {
        if start.elapsed() >= next_tick {
            let r = comm.stats().router;
            println!(
                "tick {} {sent} {delivered} {} {}",
                start.elapsed().as_millis(),
                r.retransmissions,
                Time::now_wall().as_micros()
            );
            next_tick += Duration::from_millis(100);
        }
        let ticket = plan
            .send_raw(
                "Bravo",
                "Act",
                MessageType(9),
                &sent.to_le_bytes(),
                SendOptions::default(),
            )
            .expect("send");
        pending.push_back((sent, ticket));
        sent += 1;
        if pending.len() >= WINDOW {
            let oldest = pending.pop_front().unwrap();
            settle(oldest, &mut delivered, &mut slowest);
        }
        // Paced: a busy two-core machine (crypto in a debug build, on both ends) keeps up.
        let due = EVERY * sent as u32;
        std::thread::sleep(due.saturating_sub(start.elapsed()));
    }
    for t in pending {
        settle(t, &mut delivered, &mut slowest);
    }
    let r = comm.stats().router;
    println!(
        "done {sent} {delivered} {} {}",
        r.retransmissions,
        slowest.as_micros()
    );
}

/// What the receiver saw of one message.
struct Arrival {
    n: u64,
    stamp: Time,
    wall: Time,
    at: Instant,
}

fn stepped_stream(kind: &str, lib: &Path) {
    let deadline = Deadline::after(60);
    let dir = TempDir::new("clock-step");
    let ports = [free_port(kind), free_port(kind)];
    let text = fleet_text(
        kind,
        &[
            ("Alpha", 0, format!("127.0.0.1:{}", ports[0])),
            ("Bravo", 1, format!("127.0.0.1:{}", ports[1])),
        ],
    );
    // Many attempts: a receiver descheduled for tens of milliseconds on a busy machine
    // (retransmission timeouts start at 2 ms on loopback) must not end a send unconfirmed.
    let text = text.replace(
        &format!("kind = \"{kind}\"\n"),
        &format!("kind = \"{kind}\"\nattempts = 20\n"),
    );
    let fleet = dir.write_plain("fleet.toml", &text);
    let keys = dir.path().join("keys");
    let keygen = Command::new(HETCOMM)
        .args(["keygen", "--fleet", fleet.to_str().unwrap(), "--out"])
        .arg(&keys)
        .output()
        .expect("run hetcomm keygen");
    assert!(keygen.status.success(), "keygen: {keygen:?}");
    std::fs::write(&fleet, format!("{text}\n[security]\nkeys = \"keys\"\n")).unwrap();

    let bravo = Comm::open(&fleet, "Bravo").expect("open Bravo");
    let act = bravo.module("Act").unwrap();
    let arrivals = Arc::new(Mutex::new(Vec::new()));
    let receiver = {
        let arrivals = arrivals.clone();
        std::thread::spawn(move || {
            // Until the sender has been quiet for two seconds.
            while let Ok(m) = act.recv_raw_timeout(Some(Duration::from_secs(2))) {
                let n = u64::from_le_bytes(m.payload[..8].try_into().unwrap());
                arrivals.lock().unwrap().push(Arrival {
                    n,
                    stamp: m.envelope.header.timestamp,
                    wall: m.envelope.received_at,
                    at: Instant::now(),
                });
            }
        })
    };

    let stamp_file = dir.path().join("faketime");
    std::fs::write(&stamp_file, "+0\n").unwrap();
    let mut cmd = Command::new(std::env::current_exe().unwrap());
    cmd.env(SENDER_ENV, &fleet)
        .env("LD_PRELOAD", lib)
        .env("FAKETIME_DONT_FAKE_MONOTONIC", "1")
        .env("FAKETIME_TIMESTAMP_FILE", &stamp_file)
        .env("FAKETIME_NO_CACHE", "1")
        .env("FAKETIME_CACHE_DURATION", "0");
    let mut alpha = ChildGuard::spawn("sender", cmd);
    alpha.wait_stdout("start", deadline);
    let start = Instant::now();
    for (at, offset) in STEPS {
        std::thread::sleep(Duration::from_millis(at).saturating_sub(start.elapsed()));
        std::fs::write(&stamp_file, format!("{:+}\n", offset / 1_000_000)).unwrap();
    }
    let done = alpha.wait_stdout("done ", deadline);
    let status = alpha.wait_exit(deadline);
    assert!(
        status.success(),
        "sender: {status:?}\n{:?}",
        alpha.stderr_lines()
    );
    receiver.join().unwrap();
    let arrivals = std::mem::take(&mut *arrivals.lock().unwrap());

    let nums = |l: &str| -> Vec<i64> { l.split(' ').skip(1).map(|x| x.parse().unwrap()).collect() };
    let ticks: Vec<Vec<i64>> = alpha
        .stdout_lines()
        .iter()
        .filter(|l| l.starts_with("tick "))
        .map(|l| nums(l))
        .collect();
    let d = nums(&done);
    let (sent, delivered, retransmissions, slowest_us) = (d[0] as u64, d[1] as u64, d[2], d[3]);

    // The steps reached the sender: its wall clock, against its own elapsed time, moved by
    // each offset (libfaketime works on this process, the test is not vacuous).
    let wall_offset = |ms: u64| {
        let t = ticks.iter().find(|t| t[0] as u64 >= ms).expect("a tick");
        let first = &ticks[0];
        (t[4] - first[4]) - (t[0] - first[0]) * 1_000
    };
    for (at, offset) in STEPS {
        let seen = wall_offset(at + 200);
        assert!(
            seen.abs_diff(offset) < 150_000,
            "{kind}: the sender's wall clock moved {seen} µs at {at} ms, not {offset}: is libfaketime working?"
        );
    }
    // So did the stamps its messages carry (within the 100 ms a thread keeps the offset).
    let stamp_offset = |ms: u64| {
        let a = arrivals
            .iter()
            .find(|a| a.at.saturating_duration_since(start) >= Duration::from_millis(ms))
            .expect("an arrival");
        a.stamp.as_micros() as i64 - a.wall.as_micros() as i64
    };

    // Rates in the 500 ms before and after each step (after the first 100 ms).
    let rate = |from_ms: u64, to_ms: u64| {
        let n = arrivals
            .iter()
            .filter(|a| {
                let t = a.at.saturating_duration_since(start);
                t >= Duration::from_millis(from_ms) && t < Duration::from_millis(to_ms)
            })
            .count();
        n as f64 * 1_000.0 / (to_ms - from_ms) as f64
    };
    let retx_at = |ms: u64| {
        let t = ticks
            .iter()
            .rev()
            .find(|t| t[0] as u64 <= ms)
            .expect("a tick");
        t[3]
    };
    let largest_gap = arrivals
        .windows(2)
        .map(|w| w[1].at - w[0].at)
        .max()
        .unwrap_or_default();
    println!(
        "{kind}: {sent} sent, {delivered} delivered, {} received, {retransmissions} retransmissions, slowest send {slowest_us} µs, largest gap {largest_gap:?}",
        arrivals.len()
    );
    for (at, offset) in STEPS {
        let (before, after) = (rate(at - 500, at), rate(at + 100, at + 600));
        println!(
            "{kind}: step to {:+} s at {at} ms: {before:.0}/s before, {after:.0}/s after; retransmissions {} before, {} after; stamps {:+.3} s off the receiver's clock after",
            offset / 1_000_000,
            retx_at(at),
            retx_at(at + 600),
            stamp_offset(at + 300) as f64 / 1e6
        );
        // Loopback loses nothing: a retransmission is a timer that fired before the
        // acknowledgement came. Some do on a busy machine (a descheduled receiver), spread
        // over the run; a step must not add a burst to them.
        let at_step = retx_at(at + 600) - retx_at(at.saturating_sub(100));
        let usual = retransmissions as f64 * 700.0 / RUN_MS as f64;
        assert!(
            at_step as f64 <= 20.0 + 3.0 * usual,
            "{kind}: {at_step} retransmissions around the step to {offset} µs ({retransmissions} in the whole run)"
        );
        assert!(
            after >= before * 0.5 && after > 100.0,
            "{kind}: the stream stalled at the step to {offset} µs: {before:.0}/s, then {after:.0}/s"
        );
        assert!(
            stamp_offset(at + 300).abs_diff(offset) < 1_000_000,
            "{kind}: stamps after the step to {offset} µs are {} µs off",
            stamp_offset(at + 300)
        );
    }
    assert_eq!(delivered, sent, "{kind}: every send delivered");
    let mut seen: Vec<u64> = arrivals.iter().map(|a| a.n).collect();
    seen.sort_unstable();
    assert_eq!(
        seen.len() as u64,
        sent,
        "{kind}: received exactly the sends"
    );
    assert!(
        seen.iter().enumerate().all(|(i, &n)| i as u64 == n),
        "{kind}: received exactly the sends, each once"
    );
    assert!(
        slowest_us < 1_000_000,
        "{kind}: a send took {slowest_us} µs"
    );
    assert!(
        largest_gap < Duration::from_millis(300),
        "{kind}: the stream stopped for {largest_gap:?}"
    );
}
