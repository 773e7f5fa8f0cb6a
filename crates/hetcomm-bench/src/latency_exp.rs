//! Rows `latency-experiment-udp` and `latency-experiment-udp-paced` of the `rtt` section: the
//! round trip that `hetcomm experiment latency` measures on a two-system UDP fleet (both
//! systems in this process, on 127.0.0.1, unacknowledged, security off, pair A → B, echoed on
//! B → A), run in the same rounds as `hetcomm-udp-unack` (two processes, ping–pong).
//!
//! - `latency-experiment-udp`: `--closed-loop`, each probe as soon as the previous one's echo
//!   is back — the load of a ping–pong. Its target asks its p50 to agree with
//!   `hetcomm-udp-unack`'s within 20%: the experiment's real-time method adds nothing to what
//!   it measures.
//! - `latency-experiment-udp-paced`: the experiment's default open-loop load, probes paced
//!   at [`PACED_RATE_HZ`] per second, shown beside it without a target: on a VM a probe that
//!   finds both threads asleep waits for their wake-ups from idle, which a back-to-back
//!   ping–pong never does.

use std::time::Duration;

use hetcomm_experiments::latency::{self, LatencyConfig};

use crate::hc::{fleet_text, Kind};
use crate::report::{find, Row, Target};
use crate::stats::Latency;

/// The closed-loop row's name.
pub const PATH: &str = "latency-experiment-udp";

/// The paced row's name.
pub const PACED_PATH: &str = "latency-experiment-udp-paced";

/// The benchmark row they are compared with.
pub const TWIN: &str = "hetcomm-udp-unack";

/// Probes per second of the paced row.
pub const PACED_RATE_HZ: f64 = 1000.0;

/// Runs the experiment on the two-system UDP fleet and gives A → B's round trips; closed loop
/// (as fast as the echoes come back) or paced at [`PACED_RATE_HZ`].
pub fn rtt(size: usize, warmup: u64, iters: u64, closed_loop: bool) -> Result<Latency, String> {
    let text = fleet_text(Kind::Udp, false, Some((0, 0)));
    let fleet = hetcomm::parse_fleet(&text, "latency-experiment-udp.toml", None)
        .map_err(|e| e.to_string())?;
    let config = LatencyConfig {
        messages: u32::try_from(iters).map_err(|e| e.to_string())?,
        warmup: u32::try_from(warmup).map_err(|e| e.to_string())?,
        // Closed loop: the rate is only a cap, far above what a round trip allows.
        rate_hz: if closed_loop { 1e6 } else { PACED_RATE_HZ },
        closed_loop,
        size_bytes: size,
        pairs: vec![("A".into(), "B".into())],
        drain: Duration::from_secs(2),
        ..LatencyConfig::default()
    };
    let report = latency::run(&fleet, &config, None).map_err(|e| e.to_string())?;
    let pair = report.pair("A", "B").ok_or("no pair A → B in the report")?;
    let rt = pair.round_trip.as_ref().ok_or("no round trip A → B")?;
    Ok(Latency {
        count: rt.count,
        p50: rt.p50_us,
        p90: rt.p90_us,
        p99: rt.p99_us,
        p999: rt.p999_us,
        max: rt.max_us,
        lost: pair.lost_round_trip.unwrap_or(0),
    })
}

const WHY: &str = "both measure one probe in flight over two UDP sockets with two wake-ups \
     per round trip; the experiment keeps both systems in one process (a thread each, waiting \
     in `recv`), the benchmark runs two processes. The paced row \
     (latency-experiment-udp-paced, 1000 probes per second) is higher on this VM: each probe \
     finds both threads asleep and pays their wake-ups from idle.";

/// The target: the experiment's closed-loop 64 B UDP round trip p50 within 20% of
/// `hetcomm-udp-unack`'s, measured in the same rounds.
pub fn targets(rows: &[Row]) -> Vec<Target> {
    let name =
        "latency experiment: real-UDP round trip 64 B p50 (closed loop) within 20% of hetcomm-udp-unack";
    let g = |path: &str| find(rows, "rtt", path, 64).and_then(|r| r.get("p50_us"));
    let paced = g(PACED_PATH)
        .map(|p| format!("; paced at 1000/s: {p:.1} µs"))
        .unwrap_or_default();
    vec![match (g(PATH), g(TWIN)) {
        (Some(e), Some(b)) if b > 0.0 => {
            let x = e / b;
            Target {
                name,
                status: if (0.8..=1.2).contains(&x) {
                    "met"
                } else {
                    "missed"
                },
                figure: format!(
                    "{e:.1} µs vs {TWIN} {b:.1} µs = {x:.2}× (target 0.80–1.20×){paced}"
                ),
                why: WHY,
            }
        }
        _ => Target {
            name,
            status: "not measured",
            figure: "-".into(),
            why: "a run failed or the rows were not selected (--paths)",
        },
    }]
}
