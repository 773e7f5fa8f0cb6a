//! The security issue's targets: what sealing every frame costs, secured rows against the
//! unsecured ones of the same run (`docs/security.md`).

use std::time::{Duration, Instant};

use hetcomm::SystemId;
use hetcomm_security::envelope::{inner_len, DirectionKey};

use crate::report::{find, Row, Target};

const K64: usize = 64 * 1024;

const WHY: &str = "a secured frame costs an AES-256-GCM seal on the sender and an open on the receiver (ring, with the CPU's vector AES instructions) and 36 bytes on the wire; frames the router lets wait to leave together (a fast stream of small messages) are sealed and opened once per batch (a data batch), and large frames are sealed from the caller's buffer and opened where the link received them, without copies; over TCP and UDP a streaming sender's large frames are written by the link's writer thread while the caller seals the next (write-behind), so on a machine with a spare core the seal is hidden behind the write. The session's handshake happens once, before the first frame, and is outside the measurement (a probe message waits for it). Large frames pay for the cipher's pass over every byte on both sides, which the unsecured path does not make at all (over TCP it does not even checksum payloads): run with HETCOMM_BENCH_SINK_CPU=1 to see each side's CPU time per message, which a busy machine's throughput hides. With a core per process a 64 KiB ratio is bounded by the slower side's unsecured CPU per message over the same plus its cipher pass; with both processes sharing the cores, by the total CPU per message of both sides, unsecured over secured. The cipher table gives the pass's cost on this CPU: where AES-GCM runs at about 4 GB/s (no AVX-512), sealing and opening a 64 KiB frame cost about as much CPU as the whole unsecured path, and the 85% target is out of reach of any AEAD layer (docs/security.md, \"What it costs\").";

fn unmeasured(name: &'static str) -> Target {
    Target {
        name,
        status: "not measured",
        figure: "-".into(),
        why: WHY,
    }
}

fn ratio_target(
    name: &'static str,
    secured: Option<f64>,
    plain: Option<f64>,
    at_least: f64,
    unit: &str,
) -> Target {
    ratio_target_beside(name, secured, plain, at_least, unit, None)
}

/// As [`ratio_target`], with the same ratio of the acknowledged rows (`acked`: secured and
/// unsecured) shown beside when both were measured.
fn ratio_target_beside(
    name: &'static str,
    secured: Option<f64>,
    plain: Option<f64>,
    at_least: f64,
    unit: &str,
    acked: Option<(Option<f64>, Option<f64>)>,
) -> Target {
    let beside = match acked {
        Some((Some(s), Some(p))) if p > 0.0 => {
            format!(" (acknowledged: {:.0}%)", s / p * 100.0)
        }
        _ => String::new(),
    };
    match (secured, plain) {
        (Some(s), Some(p)) if p > 0.0 => {
            let x = s / p;
            Target {
                name,
                status: if x >= at_least { "met" } else { "missed" },
                figure: format!(
                    "secured {s:.3e} {unit} vs unsecured {p:.3e} {unit} = {:.0}%{}{beside}",
                    x * 100.0,
                    if x < at_least {
                        format!("; misses by {:.0} points", (at_least - x) * 100.0)
                    } else {
                        String::new()
                    }
                ),
                why: WHY,
            }
        }
        _ => unmeasured(name),
    }
}

/// The 64 KiB one-way target of `transport` (`udp` or `tcp`), unacknowledged: the median of
/// the round-by-round ratios (the `paired` row) where measured, else the ratio of the two rows'
/// medians; the acknowledged rows' ratio beside.
fn large_target(rows: &[Row], transport: &str) -> Target {
    let name: &'static str = match transport {
        "udp" => "secured udp one-way 64 KiB: ≥ 85% of unsecured bytes/s",
        _ => "secured tcp one-way 64 KiB: ≥ 85% of unsecured bytes/s",
    };
    let rate = |path: String| find(rows, "oneway", &path, K64).and_then(|r| r.get("bytes_per_s"));
    let secured = rate(format!("hetcomm-{transport}-secured-unack"));
    let plain = rate(format!("hetcomm-{transport}-unack"));
    let acked = Some((
        rate(format!("hetcomm-{transport}-secured-ack")),
        rate(format!("hetcomm-{transport}-ack")),
    ));
    let mut target = ratio_target_beside(name, secured, plain, 0.85, "B/s", acked);
    let secured_path = format!("hetcomm-{transport}-secured-unack");
    let paired = find(rows, "paired", &secured_path, K64);
    if let (Some(p), Some(median)) = (paired, paired.and_then(|p| p.get("ratio_median"))) {
        target.status = if median >= 0.85 { "met" } else { "missed" };
        target.figure = format!(
            "median of the rounds' ratios {:.0}% ({}); medians of the rows: {}",
            median * 100.0,
            p.note,
            target.figure
        );
    }
    let cipher = find(rows, "cipher", CIPHER, K64);
    let us = |k| cipher.and_then(|c| c.get(k));
    if let (Some(seal), Some(open)) = (us("seal_us"), us("open_us")) {
        target.figure = format!(
            "{}; the cipher on this CPU: seal {seal:.1} µs, open {open:.1} µs per 64 KiB frame",
            target.figure
        );
    }
    target
}

/// The `cipher` row's path.
const CIPHER: &str = "aes-256-gcm";

/// The cipher's speed on this CPU, in this process: a 64 KiB frame sealed, and opened,
/// over and over for `each` (a `cipher` row). It is the part of a secured large frame's cost
/// that no layer can take away, so it is printed beside the 64 KiB targets.
pub fn cipher_row(each: Duration) -> Row {
    let key = DirectionKey::new(&[7; 32]);
    let ids = (SystemId(1), SystemId(2));
    let body = vec![5u8; K64];
    let mut sealed = Vec::new();
    let mut counter = 0;
    let seal = time_per_call(each, || {
        counter += 1;
        key.seal(&mut sealed, ids, 1, counter, &[], &body);
    });
    let mut plain = vec![0; inner_len(sealed.len())];
    let mut opened = true;
    let open = time_per_call(each, || opened &= key.open_into(&sealed, &mut plain));
    if !opened {
        return Row::failed("cipher", CIPHER, K64, "a sealed frame did not open");
    }
    let us = |d: Duration| d.as_secs_f64() * 1e6;
    let mut r = Row::new("cipher", CIPHER, K64);
    r.metrics = vec![
        ("seal_us", us(seal)),
        ("open_us", us(open)),
        ("seal_bytes_per_s", K64 as f64 / seal.as_secs_f64()),
        ("open_bytes_per_s", K64 as f64 / open.as_secs_f64()),
    ];
    r
}

/// How long one call of `f` takes, calling it for about `each`.
fn time_per_call(each: Duration, mut f: impl FnMut()) -> Duration {
    let started = Instant::now();
    let mut calls = 0u32;
    while calls == 0 || started.elapsed() < each {
        f();
        calls += 1;
    }
    started.elapsed() / calls
}

/// The `cipher` table.
pub fn tables(rows: &[Row]) -> Vec<crate::report::Table> {
    let body = rows
        .iter()
        .filter(|r| r.section == "cipher")
        .map(|r| {
            if let Some(e) = &r.error {
                return vec![r.path.clone(), format!("failed: {e}")];
            }
            let f =
                |k: &str, scale: f64| r.get(k).map_or("-".into(), |v| format!("{:.2}", v / scale));
            vec![
                r.path.clone(),
                f("seal_us", 1.0),
                f("seal_bytes_per_s", 1e9),
                f("open_us", 1.0),
                f("open_bytes_per_s", 1e9),
            ]
        })
        .collect();
    vec![(
        "The cipher on this CPU (one 64 KiB frame sealed, and opened, over and over in this process: what securing a large frame costs at least, on each side)".into(),
        vec!["cipher", "seal µs", "seal GB/s", "open µs", "open GB/s"],
        body,
    )]
}

/// Secured 64 B round trip adds ≤ 3 µs at p50; one-way 64 B ≥ 70% and 64 KiB ≥ 85% of the
/// unsecured rate (UDP, unacknowledged; TCP shown beside; the acknowledged rows' ratios beside the
/// 64 KiB ones).
pub fn targets(rows: &[Row]) -> Vec<Target> {
    let g = |section: &str, path: &str, size: usize, k: &str| {
        find(rows, section, path, size).and_then(|r| r.get(k))
    };
    let mut t = Vec::new();
    let name = "secured udp adds ≤ 3 µs (64 B round trip p50, unacknowledged)";
    t.push(
        match (
            g("rtt", "hetcomm-udp-secured-unack", 64, "p50_us"),
            g("rtt", "hetcomm-udp-unack", 64, "p50_us"),
        ) {
            (Some(s), Some(u)) => {
                let d = s - u;
                Target {
                    name,
                    status: if d <= 3.0 { "met" } else { "missed" },
                    figure: format!(
                        "secured {s:.1} µs − unsecured {u:.1} µs = {d:+.1} µs{} (acknowledged: {})",
                        if d > 3.0 {
                            format!("; misses by {:.1} µs", d - 3.0)
                        } else {
                            String::new()
                        },
                        match (
                            g("rtt", "hetcomm-udp-secured-ack", 64, "p50_us"),
                            g("rtt", "hetcomm-udp-ack", 64, "p50_us")
                        ) {
                            (Some(a), Some(b)) => format!("{:+.1} µs", a - b),
                            _ => "-".into(),
                        }
                    ),
                    why: WHY,
                }
            }
            _ => unmeasured(name),
        },
    );
    t.push(ratio_target(
        "secured udp one-way 64 B: ≥ 70% of unsecured msg/s",
        g("oneway", "hetcomm-udp-secured-unack", 64, "msgs_per_s"),
        g("oneway", "hetcomm-udp-unack", 64, "msgs_per_s"),
        0.70,
        "msg/s",
    ));
    for transport in ["udp", "tcp"] {
        t.push(large_target(rows, transport));
    }
    t
}

#[cfg(test)]
mod tests {
    use super::*;

    fn oneway(path: &str, size: usize, bytes_per_s: u64) -> Row {
        let t = crate::stats::Throughput {
            sent: 1,
            received: 1,
            bytes: bytes_per_s,
            seconds: 1.0,
            outcomes: None,
            kernel_drops: None,
        };
        Row::throughput(path, size, &t)
    }

    fn target<'a>(t: &'a [Target], name: &str) -> &'a Target {
        t.iter().find(|t| t.name.starts_with(name)).unwrap()
    }

    /// The cipher row measures a real seal and open (their speeds are plausible for AES-GCM
    /// in software or hardware), its table shows them, and the 64 KiB targets name them.
    #[test]
    fn the_cipher_row_is_measured_and_shown_beside_the_64k_targets() {
        let c = cipher_row(Duration::from_millis(5));
        assert!(c.error.is_none(), "{:?}", c.error);
        for k in ["seal_us", "open_us"] {
            let us = c.get(k).unwrap();
            assert!(us > 0.5 && us < 10_000.0, "{k} {us} µs");
        }
        let table = &tables(std::slice::from_ref(&c))[0];
        assert_eq!(table.2.len(), 1);
        assert_eq!(table.2[0][0], "aes-256-gcm");
        let rows = vec![
            oneway("hetcomm-tcp-unack", K64, 100),
            oneway("hetcomm-tcp-secured-unack", K64, 50),
            c,
        ];
        let t = targets(&rows);
        let tcp = target(&t, "secured tcp one-way 64 KiB");
        assert!(
            tcp.figure.contains("; the cipher on this CPU: seal "),
            "{}",
            tcp.figure
        );
    }

    #[test]
    fn the_64k_targets_compare_same_run_rows_and_show_the_acknowledged_ratio() {
        let k = 64 * 1024;
        let mut rows = vec![
            oneway("hetcomm-tcp-unack", k, 100),
            oneway("hetcomm-tcp-secured-unack", k, 84),
            oneway("hetcomm-udp-unack", k, 100),
            oneway("hetcomm-udp-secured-unack", k, 90),
        ];
        let t = targets(&rows);
        let tcp = target(&t, "secured tcp one-way 64 KiB");
        assert_eq!(tcp.status, "missed");
        assert!(
            tcp.figure.contains("= 84%; misses by 1 points"),
            "{}",
            tcp.figure
        );
        assert!(!tcp.figure.contains("acknowledged"), "{}", tcp.figure);
        let udp = target(&t, "secured udp one-way 64 KiB");
        assert_eq!(udp.status, "met");
        rows.push(oneway("hetcomm-tcp-ack", k, 50));
        rows.push(oneway("hetcomm-tcp-secured-ack", k, 45));
        let t = targets(&rows);
        let tcp = target(&t, "secured tcp one-way 64 KiB");
        assert!(
            tcp.figure.ends_with("(acknowledged: 90%)"),
            "{}",
            tcp.figure
        );
        // A missing unsecured row leaves the target unmeasured rather than met.
        let t = targets(&rows[1..2]);
        assert_eq!(
            target(&t, "secured tcp one-way 64 KiB").status,
            "not measured"
        );
    }

    /// With round-by-round ratios measured, the target follows their median, even where the
    /// ratio of the two rows' medians says otherwise, and shows both.
    #[test]
    fn the_64k_targets_follow_the_median_of_the_paired_rounds() {
        let k = 64 * 1024;
        let mut rows = vec![
            oneway("hetcomm-udp-unack", k, 100),
            oneway("hetcomm-udp-secured-unack", k, 80),
        ];
        rows.push(
            Row::paired(
                "hetcomm-udp-secured-unack",
                "hetcomm-udp-unack",
                k,
                &[0.91, 0.70, 0.88, 0.86, 0.95],
            )
            .unwrap(),
        );
        let t = targets(&rows);
        let udp = target(&t, "secured udp one-way 64 KiB");
        assert_eq!(udp.status, "met", "{}", udp.figure);
        assert!(
            udp.figure.starts_with("median of the rounds' ratios 88% (over hetcomm-udp-unack, round by round: 91%, 70%, 88%, 86%, 95%)"),
            "{}",
            udp.figure
        );
        assert!(
            udp.figure.contains("= 80%; misses by 5 points"),
            "{}",
            udp.figure
        );
        rows.pop();
        rows.push(
            Row::paired(
                "hetcomm-udp-secured-unack",
                "hetcomm-udp-unack",
                k,
                &[0.9, 0.8, 0.84],
            )
            .unwrap(),
        );
        let t = targets(&rows);
        assert_eq!(target(&t, "secured udp one-way 64 KiB").status, "missed");
        assert!(Row::paired("x", "y", k, &[]).is_none());
    }
}
