//! The `ros2` transport (feature `ros2`): the same two-process round trip and one-way runs as
//! [`crate::hc`], over DDS with ROS 2 names (docs/ros2.md), unsecured (`security = "none"`)
//! so that the row stands beside Cyclone DDS's own `ddsperf` measured in the same run.

use std::time::{Duration, Instant};

use hetcomm::Comm;

use crate::child::{Peer, DATA, STOP};
use crate::raw::TempDir;
use crate::stats::{parse_sink_line, Latency, Throughput};

/// The row name.
pub const PATH: &str = "hetcomm-ros2-unack";

/// The 64 B variants measured beside [`PATH`]: (row, best-effort QoS, spinning waiters).
/// rustdds answers the heartbeat it sends with every reliable sample by an ACKNACK
/// datagram, so reliable QoS costs two datagrams more per round trip than best effort;
/// spinning waiters take the reply without a wake-up of the module's thread (docs/ros2.md,
/// "Speed").
pub const VARIANTS: [(&str, bool, bool); 3] = [
    ("hetcomm-ros2-unack-spin", false, true),
    ("hetcomm-ros2-be-unack", true, false),
    ("hetcomm-ros2-be-unack-spin", true, true),
];

/// Systems A and B on one unacknowledged `ros2` transport, on a domain and namespace of
/// their own (so concurrent runs do not meet); reliable QoS unless `best_effort`.
fn fleet_text(best_effort: bool) -> String {
    let domain = 100 + std::process::id() % 100;
    format!(
        r#"[systems]
A = 0
B = 1
[modules]
M = 0
[inbox]
capacity = 65536
overflow = "block"
block_timeout_ms = 1000
[transports.t]
kind = "ros2"
delivery = "unacknowledged"
security = "none"
domain_id = {domain}
namespace = "/bench_{}"
reliability = "{}"
[table]
columns = ["A", "B"]
A = ["X", "t"]
B = ["t", "X"]
"#,
        std::process::id(),
        if best_effort {
            "best_effort"
        } else {
            "reliable"
        }
    )
}

/// Writes `fleet` (systems A and B, module M) to a scratch folder, starts B as a peer process
/// in `role` (`echo`, `echo-spin`, `sink`) and opens A.
fn open(role: &str, fleet: &str) -> Result<(TempDir, Peer, Comm), String> {
    let dir = TempDir::new()?;
    let path = dir.0.join("fleet.toml");
    std::fs::write(&path, fleet).map_err(|e| format!("{}: {e}", path.display()))?;
    let peer = Peer::spawn(None, &[format!("hc-{role}"), path.display().to_string()])?;
    peer.expect("ready", Duration::from_secs(20))?;
    let comm = Comm::open(&path, "A").map_err(|e| e.to_string())?;
    Ok((dir, peer, comm))
}

/// Ping-pong round trips through a peer process that echoes; best-effort QoS with
/// `best_effort`. With `spin`, both ends' waiting modules spin [`crate::hc::WAIT_SPIN`] before
/// they sleep ([`hetcomm::Module::set_wait_spin`]), reading the DDS reader meanwhile: the
/// reply is taken without a wake-up of the module's thread (rustdds's own threads still wake).
pub fn rtt(
    size: usize,
    warmup: u64,
    iters: u64,
    best_effort: bool,
    spin: bool,
) -> Result<Latency, String> {
    rtt_on(&fleet_text(best_effort), size, warmup, iters, spin)
}

/// [`rtt`] over the `ros2` transport `fleet` describes (the Cyclone DDS rows use it too).
pub(crate) fn rtt_on(
    fleet: &str,
    size: usize,
    warmup: u64,
    iters: u64,
    spin: bool,
) -> Result<Latency, String> {
    let role = if spin { "echo-spin" } else { "echo" };
    with_echo(fleet, role, |_, m| {
        if spin {
            m.set_wait_spin(crate::hc::WAIT_SPIN);
        }
        crate::hc::round_trips(m, size, warmup, iters)
    })
}

/// [`rtt_on`] with inline callbacks at both ends ([`crate::hc::round_trips_inline`]).
#[cfg(feature = "ros2-cyclone")]
pub(crate) fn rtt_inline_on(
    fleet: &str,
    size: usize,
    warmup: u64,
    iters: u64,
) -> Result<Latency, String> {
    with_echo(fleet, "echo-inline", |comm, m| {
        crate::hc::round_trips_inline(comm, m, size, warmup, iters)
    })
}

/// Runs `measure` on A's module M against a peer process echoing in `role`, then closes both.
fn with_echo(
    fleet: &str,
    role: &str,
    measure: impl FnOnce(&Comm, &hetcomm::Module) -> Result<Latency, String>,
) -> Result<Latency, String> {
    let (_dir, peer, comm) = open(role, fleet)?;
    let m = comm.module("M").map_err(|e| e.to_string())?;
    let result = measure(&comm, &m);
    drop(m);
    drop(comm);
    peer.finish(Duration::from_secs(3));
    result
}

/// One-way: A sends as fast as `send_raw` returns for `duration`; the peer counts.
pub fn oneway(size: usize, duration: Duration) -> Result<Throughput, String> {
    oneway_on(&fleet_text(false), size, duration)
}

/// [`oneway`] over the `ros2` transport `fleet` describes (the Cyclone DDS rows use it too).
pub(crate) fn oneway_on(
    fleet: &str,
    size: usize,
    duration: Duration,
) -> Result<Throughput, String> {
    let (_dir, mut peer, comm) = open("sink", fleet)?;
    let m = comm.module("M").map_err(|e| e.to_string())?;
    let msg = vec![7u8; size];
    // The first send waits for B's reader to be matched.
    let mut sent = u64::from(m.send_raw("B", "M", DATA, &msg, Default::default()).is_ok());
    std::thread::sleep(Duration::from_millis(50));
    let end = Instant::now() + duration;
    while Instant::now() < end {
        for _ in 0..16 {
            if m.send_raw("B", "M", DATA, &msg, Default::default()).is_ok() {
                sent += 1;
            }
        }
    }
    for _ in 0..3 {
        let _ = m.send_raw("B", "M", STOP, &[0], Default::default());
        std::thread::sleep(Duration::from_millis(5));
    }
    peer.close_input();
    let line = peer.expect("result", Duration::from_secs(40))?;
    drop(m);
    drop(comm);
    peer.finish(Duration::from_secs(3));
    parse_sink_line(&line, sent).ok_or(format!("bad sink line {line:?}"))
}
