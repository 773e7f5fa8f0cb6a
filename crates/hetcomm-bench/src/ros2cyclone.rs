//! The `ros2` transport on Cyclone DDS (`dds = "cyclone"`, feature `ros2-cyclone`): the same
//! two-process round trip and one-way runs as [`crate::ros2`] (rustdds), unsecured, beside
//! `ddsperf` (Cyclone DDS's own tool) measured in the same run. Rows with unacknowledged and
//! with acknowledged delivery (the router's acknowledgement crosses DDS too).

use std::time::Duration;

use crate::stats::{Latency, Throughput};

/// The round-trip rows: (name, acknowledged delivery, spinning waiters). The `-spin` row
/// shows where the time goes: both waiting modules spin [`crate::hc::WAIT_SPIN`] before they
/// sleep ([`hetcomm::Module::set_wait_spin`]), taking the sample Cyclone DDS's receive thread
/// stored without a wake-up of the module's thread (docs/ros2.md, "Cyclone DDS backend").
pub const PATHS: [(&str, bool, bool); 3] = [
    ("hetcomm-ros2cyclone-unack", false, false),
    ("hetcomm-ros2cyclone-ack", true, false),
    ("hetcomm-ros2cyclone-unack-spin", false, true),
];

/// The round-trip row measured the way `ddsperf` measures: frames delivered on Cyclone
/// DDS's receive thread (`deliver_on_receive_thread = true`) to modules whose callbacks run
/// inline ([`hetcomm::Module::set_inline_callbacks`]), which answer there — as ddsperf's
/// ping and pong answer inside their listeners.
pub const INLINE_PATH: &str = "hetcomm-ros2cyclone-unack-inline";

/// Systems A and B on one `ros2` transport on Cyclone DDS, on a domain and namespace of
/// their own (so concurrent runs, and the rustdds rows, do not meet); with `listener`,
/// delivering on Cyclone's receive thread.
fn fleet_text(acked: bool, listener: bool) -> String {
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
deliver_on_receive_thread = {listener}
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

/// Ping-pong round trips through a peer process that echoes; both waiting modules spin with
/// `spin`.
pub fn rtt(
    acked: bool,
    spin: bool,
    size: usize,
    warmup: u64,
    iters: u64,
) -> Result<Latency, String> {
    crate::ros2::rtt_on(&fleet_text(acked, false), size, warmup, iters, spin)
}

/// Ping-pong round trips of [`INLINE_PATH`], unacknowledged.
pub fn rtt_inline(size: usize, warmup: u64, iters: u64) -> Result<Latency, String> {
    crate::ros2::rtt_inline_on(&fleet_text(false, true), size, warmup, iters)
}

/// One-way, unacknowledged: A sends as fast as `send_raw` returns for `duration`; the peer
/// counts what arrives.
pub fn oneway(size: usize, duration: Duration) -> Result<Throughput, String> {
    crate::ros2::oneway_on(&fleet_text(false, false), size, duration)
}
