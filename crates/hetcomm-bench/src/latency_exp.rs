//! Row `latency-experiment-udp` of the `rtt` section: the round trip that
//! `hetcomm experiment latency` measures on a two-system UDP fleet (both systems in this
//! process, on 127.0.0.1, port 0, unacknowledged, security off), run in the same rounds as
//! `hetcomm-udp-unack` (two processes, ping–pong), so that the experiment's real-time figures
//! can be checked against the benchmark's in the same run: its target asks the two p50s to
//! agree within 20%.

use std::time::Duration;

use hetcomm_experiments::latency::{self, LatencyConfig};

use crate::hc::{fleet_text, Kind};
use crate::report::{find, Row, Target};
use crate::stats::Latency;

/// The row's name.
pub const PATH: &str = "latency-experiment-udp";

/// The benchmark row it is compared with.
pub const TWIN: &str = "hetcomm-udp-unack";

/// Probes per second per pair: spaced well beyond a round trip (about 0.1 ms here), so that
/// each probe finds the path idle, as a ping–pong's ping does.
pub const RATE_HZ: f64 = 1000.0;

/// Runs the experiment on the two-system UDP fleet and gives A → B's round trips.
pub fn rtt(size: usize, warmup: u64, iters: u64) -> Result<Latency, String> {
    let text = fleet_text(Kind::Udp, false, Some((0, 0)));
    let fleet = hetcomm::parse_fleet(&text, "latency-experiment-udp.toml", None)
        .map_err(|e| e.to_string())?;
    let config = LatencyConfig {
        messages: u32::try_from(iters).map_err(|e| e.to_string())?,
        warmup: u32::try_from(warmup).map_err(|e| e.to_string())?,
        rate_hz: RATE_HZ,
        size_bytes: size,
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

const WHY: &str = "the experiment keeps both systems in one process and paces its probes \
     (1000 per second per pair, both directions at once), where the benchmark's ping–pong runs \
     two processes back to back; each round trip still crosses two UDP sockets and two \
     wake-ups, so the two measure the same path.";

/// The target: the experiment's 64 B UDP round trip p50 within 20% of `hetcomm-udp-unack`'s,
/// measured in the same rounds.
pub fn targets(rows: &[Row]) -> Vec<Target> {
    let name = "latency experiment: real-UDP round trip 64 B p50 within 20% of hetcomm-udp-unack";
    let g = |path: &str| find(rows, "rtt", path, 64).and_then(|r| r.get("p50_us"));
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
                figure: format!("{e:.1} µs vs {TWIN} {b:.1} µs = {x:.2}× (target 0.80–1.20×)"),
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
