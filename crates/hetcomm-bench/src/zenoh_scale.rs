//! The Zenoh scale benchmark (feature `hetcomm-zenoh`): N systems in this process, each its
//! own Zenoh session, all clients of one Zenoh router (also in this process), over one
//! acknowledged `zenoh` transport.
//!
//! ```text
//! hetcomm-bench zenoh-scale 50 100 200
//! ```
//!
//! For each N it measures: the time to open the N systems (one after the other), the memory
//! they add (resident set growth over the N sessions, per system), the time one broadcast
//! from S0 takes to reach the N-1 others (median of 5; one put on `<prefix>/all` that the
//! router fans out, acknowledged by every receiver: docs/zenoh.md, "Broadcasts"), and a
//! sustained point-to-point load of 1 000 messages per second across the fleet for 5 s (each
//! millisecond, the next system sends one 64-byte message to the one after it), with every
//! outcome and arrival counted. Prints one Markdown table row per N (header first).

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use hetcomm::{Comm, MessageType, Outcome, SendOptions};
use hetcomm_link_zenoh::router::ZenohRouter;

/// Resident set size of this process, bytes.
fn rss_bytes() -> u64 {
    std::fs::read_to_string("/proc/self/statm")
        .ok()
        .and_then(|s| s.split_whitespace().nth(1)?.parse::<u64>().ok())
        .map(|pages| pages * 4096)
        .unwrap_or(0)
}

fn fleet_text(n: usize, endpoint: &str, prefix: &str) -> String {
    let mut t = String::from("[systems]\n");
    for i in 0..n {
        t.push_str(&format!("S{i} = {i}\n"));
    }
    // Unsecured: this measures the Zenoh transport's scale; a secured fleet adds one handshake
    // per pair that talks (docs/security.md), not measured here.
    t.push_str("[modules]\nM = 0\n[inbox]\ncapacity = 4096\n[transports.z]\nkind = \"zenoh\"\nsecurity = \"none\"\n");
    t.push_str(&format!(
        "mode = \"client\"\nconnect = [\"{endpoint}\"]\nmulticast_scouting = false\nprefix = \"{prefix}\"\npresence_timeout_ms = 20000\n"
    ));
    t.push_str("[table]\ncolumns = [");
    t.push_str(
        &(0..n)
            .map(|i| format!("\"S{i}\""))
            .collect::<Vec<_>>()
            .join(", "),
    );
    t.push_str("]\n");
    for i in 0..n {
        let row: Vec<&str> = (0..n)
            .map(|j| if i == j { "\"X\"" } else { "\"z\"" })
            .collect();
        t.push_str(&format!("S{i} = [{}]\n", row.join(",")));
    }
    t
}

fn percentile(sorted: &[Duration], p: f64) -> Duration {
    if sorted.is_empty() {
        return Duration::ZERO;
    }
    sorted[((sorted.len() - 1) as f64 * p).round() as usize]
}

fn run(n: usize) -> Result<String, String> {
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map_err(|e| e.to_string())?
        .port();
    let endpoint = format!("tcp/127.0.0.1:{port}");
    let router = ZenohRouter::start(std::slice::from_ref(&endpoint), false)
        .map_err(|e| format!("router: {e}"))?;
    let text = fleet_text(n, &endpoint, &format!("scale/{}/{n}", std::process::id()));
    let fleet = hetcomm::parse_fleet(&text, "scale.toml", None).map_err(|e| e.to_string())?;

    let rss0 = rss_bytes();
    let t0 = Instant::now();
    let mut comms = Vec::with_capacity(n);
    for i in 0..n {
        comms.push(Comm::open_fleet(&fleet, &format!("S{i}")).map_err(|e| e.to_string())?);
    }
    let open_time = t0.elapsed();
    let modules: Vec<_> = comms
        .iter()
        .map(|c| c.module("M").map_err(|e| e.to_string()))
        .collect::<Result<_, _>>()?;
    // Arrivals: a count per message kind and, for broadcasts, the latest arrival time.
    let received = Arc::new(AtomicU64::new(0));
    let broadcast_seen = Arc::new(AtomicU64::new(0));
    let last_arrival = Arc::new(Mutex::new(Instant::now()));
    for m in &modules {
        let (received, broadcast_seen, last_arrival) = (
            received.clone(),
            broadcast_seen.clone(),
            last_arrival.clone(),
        );
        m.on_any(move |msg| {
            if msg.envelope.header.is_broadcast() {
                broadcast_seen.fetch_add(1, Ordering::Relaxed);
                *last_arrival.lock().unwrap() = Instant::now();
            } else {
                received.fetch_add(1, Ordering::Relaxed);
            }
        });
    }
    // Everyone sees everyone before measuring (presence), bounded.
    std::thread::sleep(Duration::from_millis(500));
    let rss1 = rss_bytes();

    // One broadcast from S0, five times.
    let mut bcast = Vec::new();
    for round in 0..5u64 {
        broadcast_seen.store(0, Ordering::Relaxed);
        let start = Instant::now();
        let ticket = modules[0]
            .broadcast_raw("M", MessageType(2), &[0xcc], SendOptions::default())
            .map_err(|e| e.to_string())?;
        let deadline = start + Duration::from_secs(30);
        while broadcast_seen.load(Ordering::Relaxed) < (n - 1) as u64 {
            if Instant::now() > deadline {
                return Err(format!(
                    "broadcast {round}: {} of {} arrived",
                    broadcast_seen.load(Ordering::Relaxed),
                    n - 1
                ));
            }
            std::thread::sleep(Duration::from_micros(200));
        }
        let reached = *last_arrival.lock().unwrap() - start;
        let outcomes = ticket.wait();
        let delivered = outcomes
            .iter()
            .filter(|(_, o)| matches!(o, Outcome::Delivered { .. }))
            .count();
        if delivered != n - 1 {
            return Err(format!(
                "broadcast {round}: {delivered} of {} delivered",
                n - 1
            ));
        }
        bcast.push(reached);
    }
    bcast.sort();

    // 1 000 messages a second for 5 s, round-robin over the systems.
    let seconds = 5u64;
    let total = 1000 * seconds;
    let before = received.load(Ordering::Relaxed);
    let start = Instant::now();
    let mut tickets = Vec::with_capacity(total as usize);
    for k in 0..total {
        let due = start + Duration::from_micros(k * 1000);
        while Instant::now() < due {
            std::thread::sleep(Duration::from_micros(100));
        }
        let from = (k as usize) % n;
        let to = format!("S{}", (from + 1) % n);
        tickets.push(
            modules[from]
                .send_raw(
                    &to,
                    "M",
                    MessageType(1),
                    &[0x11; 64],
                    SendOptions::default(),
                )
                .map_err(|e| e.to_string())?,
        );
    }
    let send_time = start.elapsed();
    let mut latencies = Vec::with_capacity(tickets.len());
    let mut not_delivered = 0;
    let mut why = std::collections::BTreeMap::<String, u32>::new();
    for t in &tickets {
        match t.wait() {
            Outcome::Delivered { latency, .. } => latencies.push(latency),
            other => {
                not_delivered += 1;
                *why.entry(other.to_string()).or_default() += 1;
            }
        }
    }
    for (w, c) in &why {
        eprintln!("{n} systems: {c} × {w}");
    }
    latencies.sort();
    let deadline = Instant::now() + Duration::from_secs(10);
    while received.load(Ordering::Relaxed) - before < total && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(1));
    }
    let arrived = received.load(Ordering::Relaxed) - before;
    let rate = total as f64 / send_time.as_secs_f64();
    drop(modules);
    drop(comms);
    router.close();
    Ok(format!(
        "| {n} | {:.2} s ({:.1} ms each) | {:.1} MiB | {:.1} ms / {:.1} ms | {rate:.0} msg/s for {seconds} s: {} delivered, {not_delivered} not, {arrived} arrived; ack latency p50 {:.2} ms, p99 {:.2} ms |",
        open_time.as_secs_f64(),
        open_time.as_secs_f64() * 1000.0 / n as f64,
        (rss1.saturating_sub(rss0)) as f64 / n as f64 / (1024.0 * 1024.0),
        percentile(&bcast, 0.5).as_secs_f64() * 1000.0,
        percentile(&bcast, 1.0).as_secs_f64() * 1000.0,
        latencies.len(),
        percentile(&latencies, 0.5).as_secs_f64() * 1000.0,
        percentile(&latencies, 0.99).as_secs_f64() * 1000.0,
    ))
}

/// `hetcomm-bench zenoh-scale N…`: prints the table; exits 1 if a size failed.
pub fn main(args: &[String]) {
    let sizes: Vec<usize> = args.iter().filter_map(|a| a.parse().ok()).collect();
    let sizes = if sizes.is_empty() {
        vec![50, 100, 200]
    } else {
        sizes
    };
    println!("| systems | open (one after the other) | memory per system | one broadcast reaches all: median / max of 5 | sustained point to point |");
    println!("|---|---|---|---|---|");
    let mut failed = false;
    for n in sizes {
        match run(n) {
            Ok(row) => println!("{row}"),
            Err(e) => {
                failed = true;
                println!("| {n} | failed: {e} | | | |");
            }
        }
    }
    if failed {
        std::process::exit(1);
    }
}
