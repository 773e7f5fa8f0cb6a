//! Targets against the peers measured in the same run (issue 22: the `zenoh` transport beside
//! raw Zenoh; issue 23: the `ros2` transport beside Cyclone DDS's `ddsperf`; issue 37: the
//! `mqtt` transport beside a raw rumqttc client) and the
//! recorder's (issue 24: recording the demo, replaying a 1 GB recording).

use super::targets::verdict;
use super::*;

const WHY_ZENOH: &str = "the `zenoh` transport is our frame (header, router, acknowledgements when asked for) inside a Zenoh put on the destination's key; raw Zenoh (benchmarks/zenoh-peer) puts the bare payload. Both use the same Zenoh session settings (TCP to a router on 127.0.0.1); figures on this 2-vCPU VM move by about ±15% between runs, so compare rows of the same run.";
const WHY_ROS2: &str = "the default DDS stack, rustdds, hands every write to its event-loop thread and wakes the reader through another thread, and with reliable QoS answers every DATA's heartbeat with an ACKNACK: rustdds alone takes about 6× ddsperf's round trip (docs/ros2.md, \"Speed\"). The `cyclone` backend (`dds = \"cyclone\"`, cargo feature `ros2-cyclone`) runs Cyclone DDS itself, as ddsperf does. ddsperf's ping and pong answer inside Cyclone's listeners, on its receive thread; a module waiting in `recv` adds a thread wake-up per direction (about 2× ddsperf when wake-ups are cheap on this VM). With `deliver_on_receive_thread = true` and `Module::set_inline_callbacks`, hetcomm answers on that thread too (docs/ros2.md, \"Delivering on the receive thread\"): that row has ddsperf's structure. ddsperf and the Cyclone rows run interleaved, median of the rounds; the verdict is on the fastest row, and every row is shown.";
const WHY_RECORD: &str = "the recorder writes every send, receipt and outcome as JSON (with a JSON Schema per channel) into MCAP from an observer on the sending and receiving systems; the demo in virtual time takes a few tens of milliseconds, so its overhead is a ratio of two small, noisy wall times (median of interleaved runs).";

fn g(rows: &[Row], section: &str, path: &str, size: usize, k: &str) -> Option<f64> {
    find(rows, section, path, size).and_then(|r| r.get(k))
}

fn unmeasured(name: &'static str, why: &'static str) -> Target {
    Target {
        name,
        status: "not measured",
        figure: "-".into(),
        why,
    }
}

/// `ours / theirs` against a bound: at most `bound` (`at_most`) or at least `bound`.
fn ratio(
    name: &'static str,
    ours: Option<f64>,
    theirs: Option<f64>,
    bound: f64,
    at_most: bool,
    what: &str,
    why: &'static str,
) -> Target {
    match (ours, theirs) {
        (Some(o), Some(t)) if t > 0.0 => {
            let x = o / t;
            let ok = if at_most { x <= bound } else { x >= bound };
            Target {
                name,
                status: verdict(ok),
                figure: format!("{what}: {o:.4} vs {t:.4} = {x:.2}× (bound {bound}×)"),
                why,
            }
        }
        _ => unmeasured(name, why),
    }
}

/// Issue 22's speed targets: our `zenoh` transport (unacknowledged, as raw Zenoh is) against
/// raw Zenoh put/subscribe (`zenoh-tcp`) in the same run.
pub fn zenoh(rows: &[Row]) -> Vec<Target> {
    let ours = "hetcomm-zenoh-unack";
    let raw = "zenoh-tcp";
    vec![
        ratio(
            "zenoh transport 64 B round trip p50: ≤ 1.2× raw Zenoh",
            g(rows, "rtt", ours, 64, "p50_us"),
            g(rows, "rtt", raw, 64, "p50_us"),
            1.2,
            true,
            "p50 µs, ours vs raw Zenoh",
            WHY_ZENOH,
        ),
        ratio(
            "zenoh transport one-way 64 B: ≥ 90% of raw Zenoh's msg/s",
            g(rows, "oneway", ours, 64, "msgs_per_s"),
            g(rows, "oneway", raw, 64, "msgs_per_s"),
            0.9,
            false,
            "msg/s, ours vs raw Zenoh",
            WHY_ZENOH,
        ),
        ratio(
            "zenoh transport one-way 64 KiB: ≥ 90% of raw Zenoh's bytes/s",
            g(rows, "oneway", ours, 64 * 1024, "bytes_per_s"),
            g(rows, "oneway", raw, 64 * 1024, "bytes_per_s"),
            0.9,
            false,
            "B/s, ours vs raw Zenoh",
            WHY_ZENOH,
        ),
    ]
}

const WHY_MQTT: &str = "both paths go through the same mosquitto (started by the benchmark on a free port, `set_tcp_nodelay true`) at QoS 0, both ends in the benchmark's process: ours is systems A and B on an unsecured, unacknowledged `mqtt` transport, B's module echoing from a thread waiting in `recv` (the link's event-loop thread puts the frame in the inbox and wakes it, and the echo's publish wakes the event loop again) or from an inline callback on the link's event-loop thread (`Module::set_inline_callbacks`); each is compared with raw rumqttc clients of the same structure: B echoing from a thread its event loop hands each publish (`raw-mqtt-rumqttc-thread`), or from its event loop (`raw-mqtt-rumqttc`). Met when both are within the bound. Each publish carries our 48-byte header too. Figures on this shared 2-vCPU VM are noisy: compare rows of one run.";

/// Issue 37's speed target: the `mqtt` transport's 64 B round trip against raw rumqttc
/// clients through the same broker in the same run, each of our two echo structures (a module
/// waiting in `recv`; an inline callback on the link's thread) against the raw clients' of the
/// same structure (an echo thread handed each publish; the event loop itself).
pub fn mqtt(rows: &[Row]) -> Vec<Target> {
    const NAME: &str = "mqtt transport 64 B round trip p50: ≤ 1.2× a raw rumqttc client";
    let pairs = [
        (
            "echo waiting in recv",
            "hetcomm-mqtt-unack",
            "raw-mqtt-rumqttc-thread",
        ),
        (
            "echo from an inline callback",
            "hetcomm-mqtt-unack-inline",
            "raw-mqtt-rumqttc",
        ),
    ];
    let measured: Vec<(&str, f64, f64)> = pairs
        .iter()
        .filter_map(|(name, ours, raw)| {
            let raw = g(rows, "rtt", raw, 64, "p50_us").filter(|&r| r > 0.0)?;
            Some((*name, g(rows, "rtt", ours, 64, "p50_us")?, raw))
        })
        .collect();
    if measured.is_empty() {
        return vec![unmeasured(NAME, WHY_MQTT)];
    }
    let each: Vec<String> = measured
        .iter()
        .map(|(name, p, r)| format!("{name} {p:.1} µs vs raw {r:.1} µs = {:.2}×", p / r))
        .collect();
    vec![Target {
        name: NAME,
        status: verdict(measured.iter().all(|(_, p, r)| p / r <= 1.2)),
        figure: each.join("; "),
        why: WHY_MQTT,
    }]
}

/// Issue 23's speed target: the `ros2` transport's 64 B round trip within 1.5× of ddsperf's,
/// judged on the fastest DDS backend measured (rustdds, Cyclone DDS), both shown.
pub fn ros2(rows: &[Row]) -> Vec<Target> {
    const NAME: &str = "ros2 transport 64 B round trip p50: ≤ 1.5× Cyclone DDS's ddsperf";
    let dds = g(rows, "rtt", "cyclone-ddsperf", 64, "p50_us");
    // ddsperf answers inside Cyclone's listeners; the inline row has the same structure
    // (callbacks on Cyclone's receive thread), the others a module thread waiting in `recv`.
    let backends = [
        ("rustdds, recv", "hetcomm-ros2-unack"),
        ("cyclone, recv", "hetcomm-ros2cyclone-unack"),
        (
            "cyclone, inline callbacks on the receive thread",
            "hetcomm-ros2cyclone-unack-inline",
        ),
    ];
    let measured: Vec<(&str, f64)> = backends
        .iter()
        .filter_map(|(name, path)| Some((*name, g(rows, "rtt", path, 64, "p50_us")?)))
        .collect();
    let best = measured.iter().copied().min_by(|a, b| a.1.total_cmp(&b.1));
    match (best, dds) {
        (Some((_, fastest)), Some(d)) if d > 0.0 => {
            let x = fastest / d;
            let each: Vec<String> = measured
                .iter()
                .map(|(name, p)| format!("{name} {p:.1} µs = {:.2}×", p / d))
                .collect();
            vec![Target {
                name: NAME,
                status: verdict(x <= 1.5),
                figure: format!("ddsperf {d:.1} µs; {}", each.join("; ")),
                why: WHY_ROS2,
            }]
        }
        _ => vec![unmeasured(NAME, WHY_ROS2)],
    }
}

/// Issue 24's recording targets: recording the demo adds under 10% wall time; a 1 GB
/// recording replays into the simulator at least 10× faster than real time.
pub fn record(rows: &[Row]) -> Vec<Target> {
    const OVERHEAD: &str = "recording the demo adds < 10% wall time";
    const REPLAY: &str = "a 1 GB recording replays into the simulator ≥ 10× faster than real time";
    let mut t = Vec::new();
    let demo = |k| g(rows, "record", "demo recording overhead", 0, k);
    t.push(
        match (demo("overhead_pct"), demo("plain_s"), demo("recorded_s")) {
            (Some(pct), Some(plain), Some(rec)) => Target {
                name: OVERHEAD,
                status: verdict(pct < 10.0),
                figure: format!("{plain:.3} s → {rec:.3} s = {pct:+.1}%"),
                why: WHY_RECORD,
            },
            _ => unmeasured(OVERHEAD, WHY_RECORD),
        },
    );
    let dense = |k| {
        g(
            rows,
            "record",
            "dense recording replayed into the simulator",
            0,
            k,
        )
    };
    t.push(
        match (dense("speed_x"), dense("file_bytes"), dense("wall_s")) {
            (Some(x), Some(bytes), Some(wall)) => {
                let gb = bytes / 1e9;
                Target {
                    name: REPLAY,
                    status: verdict(x >= 10.0 && gb >= 1.0),
                    figure: format!(
                        "{gb:.2} GB replayed in {wall:.1} s = {x:.1}× real time{}",
                        if gb < 1.0 {
                            " (a smaller file than asked: quick run)"
                        } else {
                            ""
                        }
                    ),
                    why: WHY_RECORD,
                }
            }
            _ => unmeasured(REPLAY, WHY_RECORD),
        },
    );
    t
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(section: &'static str, path: &str, size: usize, metrics: &[(&'static str, f64)]) -> Row {
        let mut r = Row::new(section, path, size);
        r.metrics = metrics.to_vec();
        r
    }

    #[test]
    fn zenoh_targets_compare_with_raw_zenoh_of_the_same_run() {
        let rows = [
            row("rtt", "hetcomm-zenoh-unack", 64, &[("p50_us", 60.0)]),
            row("rtt", "zenoh-tcp", 64, &[("p50_us", 55.0)]),
            row("oneway", "hetcomm-zenoh-unack", 64, &[("msgs_per_s", 80.0)]),
            row("oneway", "zenoh-tcp", 64, &[("msgs_per_s", 100.0)]),
        ];
        let t = zenoh(&rows);
        assert_eq!(t[0].status, "met", "{}", t[0].figure); // 1.09× ≤ 1.2×
        assert_eq!(t[1].status, "missed", "{}", t[1].figure); // 80% < 90%
        assert_eq!(t[2].status, "not measured");
    }

    #[test]
    fn the_mqtt_target_compares_each_structure_with_the_raw_clients_of_the_same_run() {
        let rows = [
            row("rtt", "hetcomm-mqtt-unack", 64, &[("p50_us", 130.0)]),
            row("rtt", "raw-mqtt-rumqttc-thread", 64, &[("p50_us", 100.0)]),
        ];
        let t = mqtt(&rows);
        assert_eq!(t[0].status, "missed", "{}", t[0].figure); // 1.3× > 1.2×
        assert_eq!(mqtt(&rows[..1])[0].status, "not measured");
        let mut both = rows.to_vec();
        both[1] = row("rtt", "raw-mqtt-rumqttc-thread", 64, &[("p50_us", 120.0)]);
        both.push(row(
            "rtt",
            "hetcomm-mqtt-unack-inline",
            64,
            &[("p50_us", 110.0)],
        ));
        both.push(row("rtt", "raw-mqtt-rumqttc", 64, &[("p50_us", 100.0)]));
        let t = mqtt(&both);
        assert_eq!(t[0].status, "met", "{}", t[0].figure); // 1.08× and 1.10×
        assert!(
            t[0].figure
                .contains("echo waiting in recv 130.0 µs vs raw 120.0 µs = 1.08×"),
            "{}",
            t[0].figure
        );
        // One structure over the bound misses the target.
        both[2] = row("rtt", "hetcomm-mqtt-unack-inline", 64, &[("p50_us", 125.0)]);
        assert_eq!(mqtt(&both)[0].status, "missed");
    }

    #[test]
    fn the_ros2_target_is_judged_on_the_fastest_row_and_shows_every_row() {
        let dds = row("rtt", "cyclone-ddsperf", 64, &[("p50_us", 14.0)]);
        let rustdds = row("rtt", "hetcomm-ros2-unack", 64, &[("p50_us", 95.0)]);
        let cyclone = row("rtt", "hetcomm-ros2cyclone-unack", 64, &[("p50_us", 33.0)]);
        let inline = row(
            "rtt",
            "hetcomm-ros2cyclone-unack-inline",
            64,
            &[("p50_us", 17.5)],
        );
        let t = &ros2(&[dds.clone(), rustdds.clone(), cyclone.clone(), inline])[0];
        assert_eq!(t.status, "met");
        assert!(
            t.figure.contains("rustdds, recv 95.0 µs = 6.79×"),
            "{}",
            t.figure
        );
        assert!(
            t.figure.contains("cyclone, recv 33.0 µs = 2.36×"),
            "{}",
            t.figure
        );
        assert!(
            t.figure
                .contains("cyclone, inline callbacks on the receive thread 17.5 µs = 1.25×"),
            "{}",
            t.figure
        );
        assert_eq!(ros2(&[dds, rustdds, cyclone])[0].status, "missed");
    }

    #[test]
    fn replay_speed_counts_only_for_a_file_of_a_gigabyte() {
        let replay = |bytes: f64| {
            row(
                "record",
                "dense recording replayed into the simulator",
                0,
                &[("speed_x", 30.0), ("file_bytes", bytes), ("wall_s", 9.0)],
            )
        };
        assert_eq!(record(&[replay(1.08e9)])[1].status, "met");
        assert_eq!(record(&[replay(0.2e9)])[1].status, "missed");
        assert_eq!(record(&[replay(1.08e9)])[0].status, "not measured");
    }
}
