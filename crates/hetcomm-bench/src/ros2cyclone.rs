//! The `ros2` transport on Cyclone DDS (`dds = "cyclone"`, feature `ros2-cyclone`): the same
//! two-process round trip and one-way runs as [`crate::ros2`] (rustdds), unsecured, beside
//! `ddsperf` (Cyclone DDS's own tool) measured in the same run. Rows with unacknowledged and
//! with acknowledged delivery (the router's acknowledgement crosses DDS too).

use std::time::{Duration, Instant};

use hetcomm::Comm;

use crate::child::{Peer, DATA, STOP};
use crate::raw::TempDir;
use crate::stats::{parse_sink_line, Latency, Throughput};

/// The round-trip rows: (name, acknowledged delivery, spinning waiters). The `-spin` row
/// shows where the time goes: both waiting modules spin [`crate::hc::WAIT_SPIN`] before they
/// sleep ([`hetcomm::Module::set_wait_spin`]), taking the sample Cyclone DDS's receive thread
/// stored without a wake-up of the module's thread (docs/ros2.md, "Cyclone DDS backend").
pub const PATHS: [(&str, bool, bool); 3] = [
    ("hetcomm-ros2cyclone-unack", false, false),
    ("hetcomm-ros2cyclone-ack", true, false),
    ("hetcomm-ros2cyclone-unack-spin", false, true),
];

/// Systems A and B on one `ros2` transport on Cyclone DDS, on a domain and namespace of
/// their own (so concurrent runs, and the rustdds rows, do not meet).
fn fleet_text(acked: bool) -> String {
    let domain = 100 + (std::process::id() + 50) % 100;
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
dds = "cyclone"
delivery = "{}"
security = "none"
domain_id = {domain}
namespace = "/bench_cyclone_{}"
[table]
columns = ["A", "B"]
A = ["X", "t"]
B = ["t", "X"]
"#,
        if acked {
            "acknowledged"
        } else {
            "unacknowledged"
        },
        std::process::id()
    )
}

fn open(role: &str, acked: bool) -> Result<(TempDir, Peer, Comm), String> {
    let dir = TempDir::new()?;
    let path = dir.0.join("fleet.toml");
    std::fs::write(&path, fleet_text(acked)).map_err(|e| format!("{}: {e}", path.display()))?;
    let peer = Peer::spawn(None, &[format!("hc-{role}"), path.display().to_string()])?;
    peer.expect("ready", Duration::from_secs(20))?;
    let comm = Comm::open(&path, "A").map_err(|e| e.to_string())?;
    Ok((dir, peer, comm))
}

/// Ping-pong round trips through a peer process that echoes; both waiting modules spin with
/// `spin`.
pub fn rtt(
    acked: bool,
    spin: bool,
    size: usize,
    warmup: u64,
    iters: u64,
) -> Result<Latency, String> {
    let (_dir, peer, comm) = open(if spin { "echo-spin" } else { "echo" }, acked)?;
    let m = comm.module("M").map_err(|e| e.to_string())?;
    if spin {
        m.set_wait_spin(crate::hc::WAIT_SPIN);
    }
    let result = crate::hc::round_trips(&m, size, warmup, iters);
    drop(m);
    drop(comm);
    peer.finish(Duration::from_secs(3));
    result
}

/// One-way, unacknowledged: A sends as fast as `send_raw` returns for `duration`; the peer
/// counts what arrives.
pub fn oneway(size: usize, duration: Duration) -> Result<Throughput, String> {
    let (_dir, mut peer, comm) = open("sink", false)?;
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
