//! Section `failover`: how long a pair's traffic is dark when its preferred transport is lost
//! (issue 36: "time from a path's loss to the first delivery on the next path (p50, p99 over
//! repeated cuts) — at most twice that path's retransmission timeout — and no message lost
//! in acknowledged mode").
//!
//! Two systems of this process, A and B, over real loopback sockets: `wifi` (UDP) first,
//! `wired` (TCP) second, both acknowledged. A's `wifi` datagrams to B pass through a
//! forwarding proxy (a UDP socket and a thread) that the bench cuts: while cut, it reads and
//! drops every datagram, as a radio out of range would (the socket still takes them, so only
//! the missing acknowledgements tell). A sends a 64 B acknowledged message every 200 µs for the
//! whole run. Each cut: the proxy stops forwarding at `t0`; the figure is the time from `t0`
//! to the first message B receives on `wired` (B's observer sees the link each receipt came
//! by, on the monotonic clock). Then the proxy forwards again, the pair returns to `wifi`
//! (after the hold time), and it waits longer than twice the hold before the next cut, so
//! every cut meets the same hysteresis.
//!
//! The path's retransmission timeout is the router's for that path just before the cut
//! (`Comm::paths`' `rto`): on loopback the smoothed RTT is far below the router's floor, so it
//! is that floor (`Timing::min_rto`, 2 ms); the row prints both. Security is off
//! (`security = "none"`): the figure is the router's reaction, not a handshake's. The row also
//! gives the time from the cut to A's router judging the path down (its path change), which
//! comes after the first delivery on the next path: a send whose acknowledgement timed out
//! goes on the other path at once (`docs/failover.md`).
//!
//! Every send is accounted for at the end: each ends delivered (the row counts those that
//! ended unconfirmed or failed), B's inbox has each message exactly once.

use parking_lot::Mutex;
use std::collections::BTreeSet;
use std::net::UdpSocket;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::thread;
use std::time::{Duration, Instant};

use hetcomm::observe::{PathChangeRecord, ReceiptRecord, Via};
use hetcomm::{Comm, MessageType, Observer, Outcome, SendError};

use crate::report::{Row, Target};

/// The row's name.
pub const PATH: &str = "udp→tcp, loopback, cut by a proxy";
const TY: MessageType = MessageType(36);
/// Between two sends of A.
const PACE: Duration = Duration::from_micros(200);

fn free_port(udp: bool) -> Result<u16, String> {
    let port = match udp {
        true => UdpSocket::bind("127.0.0.1:0").and_then(|s| s.local_addr()),
        false => std::net::TcpListener::bind("127.0.0.1:0").and_then(|s| s.local_addr()),
    };
    port.map(|a| a.port()).map_err(|e| e.to_string())
}

/// The fleet as `system` sees it: A's file names the proxy as B's `wifi` endpoint.
fn fleet(b_wifi: u16, ports: [u16; 3]) -> String {
    let [a_wifi, a_tcp, b_tcp] = ports;
    format!(
        r#"
[systems]
A = 0
B = 1
[modules]
M = 0
[transports.wifi]
kind = "udp"
security = "none"
endpoints = {{ A = "127.0.0.1:{a_wifi}", B = "127.0.0.1:{b_wifi}" }}
[transports.wired]
kind = "tcp"
security = "none"
endpoints = {{ A = "127.0.0.1:{a_tcp}", B = "127.0.0.1:{b_tcp}" }}
[table]
columns = ["A", "B"]
A = ["X", "wifi,wired"]
B = ["wifi,wired", "X"]
"#
    )
}

/// B's receipts on `wired` after a cut: the first one's time.
struct FirstOnWired {
    wired: usize,
    armed: AtomicBool,
    first: Mutex<Option<Instant>>,
}

impl Observer for FirstOnWired {
    fn on_receipt(&self, r: &ReceiptRecord<'_>) {
        if r.via == Via::Link(self.wired) && self.armed.swap(false, Ordering::AcqRel) {
            *self.first.lock() = Some(Instant::now());
        }
    }
}

/// A's path changes after a cut: the first one's time.
struct FirstSwitch {
    armed: AtomicBool,
    first: Mutex<Option<Instant>>,
    /// Every change: when, from, to (printed on stderr at the end, to see what each cut did).
    all: Mutex<Vec<(Instant, String, String)>>,
}

impl Observer for FirstSwitch {
    fn on_path_change(&self, r: &PathChangeRecord<'_>) {
        let mut all = self.all.lock();
        all.push((Instant::now(), r.from.to_string(), r.now.to_string()));
        drop(all);
        if self.armed.swap(false, Ordering::AcqRel) {
            *self.first.lock() = Some(Instant::now());
        }
    }
}

/// What one run measured.
struct Measured {
    failovers: Vec<Duration>,
    /// Per cut: from the cut to A judging the path down.
    switched: Vec<Duration>,
    rto: Duration,
    srtt: Option<Duration>,
    sends: u64,
    delivered: u64,
    unconfirmed: u64,
    not_delivered: u64,
    received: usize,
    duplicates: usize,
    switches: u64,
}

fn wait_until(timeout: Duration, mut f: impl FnMut() -> bool) -> bool {
    let end = Instant::now() + timeout;
    while Instant::now() < end {
        if f() {
            return true;
        }
        thread::sleep(Duration::from_millis(1));
    }
    false
}

fn active(a: &Comm) -> Option<String> {
    a.paths("B")
        .into_iter()
        .find(|p| p.active)
        .map(|p| p.transport)
}

fn run(cuts: usize) -> Result<Measured, String> {
    let (a_wifi, b_wifi, proxy_port) = (free_port(true)?, free_port(true)?, free_port(true)?);
    let (a_tcp, b_tcp) = (free_port(false)?, free_port(false)?);
    let parse = |text: String| {
        hetcomm::config::parse_str(&text, "failover-bench.toml", None).map_err(|e| e.to_string())
    };
    let fleet_a = parse(fleet(proxy_port, [a_wifi, a_tcp, b_tcp]))?;
    let fleet_b = parse(fleet(b_wifi, [a_wifi, a_tcp, b_tcp]))?;
    let proxy = UdpSocket::bind(("127.0.0.1", proxy_port)).map_err(|e| e.to_string())?;
    proxy
        .set_read_timeout(Some(Duration::from_millis(20)))
        .map_err(|e| e.to_string())?;
    let b = Comm::open_fleet(&fleet_b, "B").map_err(|e| e.to_string())?;
    let a = Comm::open_fleet(&fleet_a, "A").map_err(|e| e.to_string())?;
    let wired = b
        .endpoints()
        .iter()
        .position(|(n, _)| n == "wired")
        .ok_or("B has no wired link")?;
    let watch = Arc::new(FirstOnWired {
        wired,
        armed: AtomicBool::new(false),
        first: Mutex::new(None),
    });
    let _observing = b.observe(watch.clone());
    let switch = Arc::new(FirstSwitch {
        armed: AtomicBool::new(false),
        first: Mutex::new(None),
        all: Mutex::new(Vec::new()),
    });
    let started = Instant::now();
    let mut cut_at = Vec::with_capacity(cuts);
    let _observing_a = a.observe(switch.clone());
    let stop = Arc::new(AtomicBool::new(false));
    let cut = Arc::new(AtomicBool::new(false));
    let proxy_thread = {
        let (stop, cut) = (stop.clone(), cut.clone());
        thread::spawn(move || {
            let mut buf = vec![0u8; 65536];
            while !stop.load(Ordering::Relaxed) {
                if let Ok((n, _)) = proxy.recv_from(&mut buf) {
                    if !cut.load(Ordering::Relaxed) {
                        let _ = proxy.send_to(&buf[..n], ("127.0.0.1", b_wifi));
                    }
                }
            }
        })
    };
    let b_m = b.module("M").map_err(|e| e.to_string())?;
    let receiver = {
        let stop = stop.clone();
        thread::spawn(move || {
            let mut got = Vec::new();
            loop {
                match b_m.recv_raw_timeout(Some(Duration::from_millis(200))) {
                    Ok(m) if m.payload.len() >= 8 => got.push(u64::from_le_bytes(
                        m.payload[..8].try_into().unwrap_or([0; 8]),
                    )),
                    Ok(_) => {}
                    Err(_) if stop.load(Ordering::Relaxed) => return got,
                    Err(_) => {}
                }
            }
        })
    };
    let a_m = a.module("M").map_err(|e| e.to_string())?;
    let sending = Arc::new(AtomicBool::new(true));
    let sent = Arc::new(AtomicU64::new(0));
    let sender = {
        let (sending, sent) = (sending.clone(), sent.clone());
        thread::spawn(move || {
            let mut tickets = Vec::new();
            let mut payload = [0u8; 64];
            let mut next = Instant::now();
            let mut seq = 0u64;
            while sending.load(Ordering::Relaxed) {
                payload[..8].copy_from_slice(&seq.to_le_bytes());
                match a_m.send_raw("B", "M", TY, &payload, Default::default()) {
                    Ok(t) => {
                        tickets.push(t);
                        seq += 1;
                        sent.store(seq, Ordering::Relaxed);
                    }
                    // A full window: this one was not sent; it goes again next time.
                    Err(SendError::Backpressure { .. }) => {}
                    Err(e) => return Err(e.to_string()),
                }
                next += PACE;
                if let Some(d) = next.checked_duration_since(Instant::now()) {
                    thread::sleep(d);
                }
            }
            Ok(tickets)
        })
    };
    let mut failovers = Vec::with_capacity(cuts);
    let mut switched = Vec::with_capacity(cuts);
    let mut rto = Duration::ZERO;
    let mut srtt = None;
    let mut error = None;
    for i in 0..cuts {
        if !wait_until(Duration::from_secs(20), || {
            active(&a).as_deref() == Some("wifi")
        }) {
            error = Some(format!("cut {i}: the pair is not back on wifi within 20 s"));
            break;
        }
        // Longer than twice the hold since the return (and than twice a hold doubled once by
        // a flap): every cut meets the same hysteresis.
        thread::sleep(Duration::from_millis(2_500));
        // A stall of this shared machine may have moved the pair meanwhile: cut only the
        // path sends take.
        if !wait_until(Duration::from_secs(20), || {
            active(&a).as_deref() == Some("wifi")
        }) {
            error = Some(format!("cut {i}: the pair is not back on wifi within 20 s"));
            break;
        }
        let wifi = a.paths("B").into_iter().find(|p| p.transport == "wifi");
        srtt = wifi.as_ref().and_then(|p| p.srtt);
        rto = wifi.map_or(Duration::ZERO, |p| p.rto);
        *watch.first.lock() = None;
        *switch.first.lock() = None;
        watch.armed.store(true, Ordering::Release);
        switch.armed.store(true, Ordering::Release);
        let t0 = Instant::now();
        cut_at.push(t0);
        cut.store(true, Ordering::Release);
        let seen = wait_until(Duration::from_secs(5), || watch.first.lock().is_some());
        let first = *watch.first.lock();
        // Give the wired path a moment of traffic, then bring wifi back.
        thread::sleep(Duration::from_millis(100));
        cut.store(false, Ordering::Release);
        switch.armed.store(false, Ordering::Release);
        if let Some(t) = *switch.first.lock() {
            switched.push(t.saturating_duration_since(t0));
        }
        match (seen, first) {
            (true, Some(t)) => failovers.push(t.saturating_duration_since(t0)),
            _ => {
                error = Some(format!("cut {i}: nothing arrived on wired within 5 s"));
                break;
            }
        }
    }
    sending.store(false, Ordering::Relaxed);
    let tickets = sender
        .join()
        .map_err(|_| "the sender panicked".to_string())??;
    let (mut delivered, mut unconfirmed) = (0u64, 0u64);
    for t in &tickets {
        match t.wait_timeout(Duration::from_secs(30)) {
            Some(Outcome::Delivered { .. }) => delivered += 1,
            Some(Outcome::Unconfirmed { .. }) => unconfirmed += 1,
            _ => {}
        }
    }
    // The last deliveries reach the inbox before their acknowledgements leave.
    thread::sleep(Duration::from_millis(300));
    stop.store(true, Ordering::Relaxed);
    let got = receiver.join().map_err(|_| "the receiver panicked")?;
    let _ = proxy_thread.join();
    if let Some(e) = error {
        return Err(e);
    }
    let cut_list: Vec<String> = cut_at
        .iter()
        .map(|t| format!("{:.3}", t.duration_since(started).as_secs_f64()))
        .collect();
    eprintln!("failover: cuts at {} s", cut_list.join(", "));
    for (t, from, now) in switch.all.lock().iter() {
        let at = t.duration_since(started).as_secs_f64();
        eprintln!("failover: +{at:.3} s A's traffic to B moved from {from} to {now}");
    }
    eprintln!("failover: A's router {:?}", a.stats().router);
    let distinct: BTreeSet<u64> = got.iter().copied().collect();
    let sends = sent.load(Ordering::Relaxed);
    Ok(Measured {
        failovers,
        switched,
        rto,
        srtt,
        sends,
        delivered,
        unconfirmed,
        not_delivered: sends - delivered,
        received: distinct.len(),
        duplicates: got.len() - distinct.len(),
        switches: a.stats().router.path_changes,
    })
}

fn quantile(sorted: &[Duration], q: f64) -> Duration {
    if sorted.is_empty() {
        return Duration::ZERO;
    }
    let rank = ((q * sorted.len() as f64).ceil() as usize).clamp(1, sorted.len());
    sorted[rank - 1]
}

/// The `failover` row: `cuts` cuts of the preferred path.
pub fn measure(cuts: usize) -> Row {
    let m = match run(cuts) {
        Ok(m) => m,
        Err(e) => return Row::failed("failover", PATH, 64, &e),
    };
    let mut f = m.failovers.clone();
    f.sort();
    let ms = |d: Duration| d.as_secs_f64() * 1e3;
    let (p50, p99) = (quantile(&f, 0.50), quantile(&f, 0.99));
    let mut sw = m.switched.clone();
    sw.sort();
    let mut r = Row::new("failover", PATH, 64);
    r.metrics = vec![
        ("p50_ms", ms(p50)),
        ("p99_ms", ms(p99)),
        ("max_ms", ms(f.last().copied().unwrap_or_default())),
        ("cuts", f.len() as f64),
        ("switch_p50_ms", ms(quantile(&sw, 0.50))),
        ("switch_p99_ms", ms(quantile(&sw, 0.99))),
        ("rto_ms", ms(m.rto)),
        (
            "srtt_us",
            m.srtt.map_or(f64::NAN, |s| s.as_secs_f64() * 1e6),
        ),
        ("p99_per_rto", p99.as_secs_f64() / m.rto.as_secs_f64()),
        ("sends", m.sends as f64),
        ("delivered", m.delivered as f64),
        ("unconfirmed", m.unconfirmed as f64),
        ("not_delivered", m.not_delivered as f64),
        ("lost", (m.sends as f64) - (m.received as f64)),
        ("duplicates", m.duplicates as f64),
        ("switches", m.switches as f64),
    ];
    r.note = format!(
        "A sends 64 B acknowledged every {} µs; each cut drops A's wifi datagrams at a proxy",
        PACE.as_micros()
    );
    r
}

const WHY: &str = "a send whose acknowledgement timed out goes on the other healthy path at once (SCTP's rule, RFC 4960 s6.4), so the first delivery on the next path comes one RTO after the cut plus the timer's and the scheduler's delay; the path itself is judged down after `down_after` rounds of timeouts (`switch_p50_ms`)";

/// The issue's target for the row.
pub fn targets(rows: &[Row]) -> Vec<Target> {
    let name = "failover: loss to first delivery on the next path p99 ≤ 2× the path's RTO, nothing lost (acknowledged)";
    let g = |k: &str| crate::report::find(rows, "failover", PATH, 64)?.get(k);
    match (
        g("p99_ms"),
        g("p50_ms"),
        g("rto_ms"),
        g("lost"),
        g("not_delivered"),
        g("duplicates"),
    ) {
        (Some(p99), Some(p50), Some(rto), Some(lost), Some(nd), Some(dup)) => {
            let x = p99 / rto;
            let ok = x <= 2.0 && lost == 0.0 && nd == 0.0 && dup == 0.0;
            vec![Target {
                name,
                status: if ok { "met" } else { "missed" },
                figure: format!(
                    "p50 {p50:.2} ms, p99 {p99:.2} ms = {x:.2}× RTO {rto:.2} ms (target 2×); lost {lost}, not delivered {nd}, duplicates {dup}{}",
                    if x > 2.0 {
                        format!("; misses by {:.0}%", (x / 2.0 - 1.0) * 100.0)
                    } else {
                        String::new()
                    }
                ),
                why: WHY,
            }]
        }
        _ => vec![Target {
            name,
            status: "not measured",
            figure: "-".into(),
            why: "the run failed (see the row)",
        }],
    }
}

/// The row as a table of the report.
pub fn tables(rows: &[Row]) -> Vec<crate::report::Table> {
    let f = crate::report::num;
    let body: Vec<Vec<String>> = rows
        .iter()
        .filter(|r| r.section == "failover")
        .map(|r| {
            if let Some(e) = &r.error {
                return vec![r.path.clone(), format!("failed: {e}")];
            }
            vec![
                r.path.clone(),
                f(r.get("cuts"), 0),
                f(r.get("p50_ms"), 2),
                f(r.get("p99_ms"), 2),
                f(r.get("max_ms"), 2),
                format!(
                    "{} (srtt {} µs)",
                    f(r.get("rto_ms"), 2),
                    f(r.get("srtt_us"), 0)
                ),
                f(r.get("p99_per_rto"), 2),
                f(r.get("switch_p50_ms"), 2),
                format!(
                    "{} / {} / {} / {} / {}",
                    f(r.get("sends"), 0),
                    f(r.get("delivered"), 0),
                    f(r.get("unconfirmed"), 0),
                    f(r.get("lost"), 0),
                    f(r.get("duplicates"), 0)
                ),
            ]
        })
        .collect();
    vec![(
        "Failover: a pair's preferred path cut, time from the cut to the first delivery on the next path"
            .into(),
        vec![
            "pair",
            "cuts",
            "p50 ms",
            "p99 ms",
            "max ms",
            "path RTO ms",
            "p99 ÷ RTO",
            "judged down p50 ms",
            "sends / delivered / unconfirmed / lost / duplicates",
        ],
        body,
    )]
}
