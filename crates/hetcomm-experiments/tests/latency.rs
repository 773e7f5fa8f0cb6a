//! `latency`: the delay analysis. Seeded virtual-time runs are repeatable and exact on a link
//! of fixed latency; a real-UDP run on 127.0.0.1 measures every pair; bad settings are clear
//! errors.

use std::time::Duration;

use hetcomm_experiments::latency::{self, Clock, Direction, LatencyConfig};

fn seed() -> u64 {
    std::env::var("HETCOMM_SEED")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(2019)
}

/// A, B and C on emulated links: A ⇄ B over `fixed` (latency L = 5 ms, nothing else), A → C
/// over `radio` (jittery and lossy, acknowledged) with no way back (C → A is X), B ⇄ C over
/// `radio`.
const EMULATED: &str = r#"
name = "emulated-three"
[systems]
A = 0
B = 1
C = 2
[modules]
M = 0
[transports.fixed]
kind = "emulated"
latency_ms = 5
[transports.radio]
kind = "emulated"
delivery = "acknowledged"
attempts = 16
latency_ms = 2
jitter_ms = 1
loss_percent = 10
[table]
columns = ["A", "B", "C"]
A = ["X", "fixed", "radio"]
B = ["fixed", "X", "radio"]
C = ["X", "radio", "X"]
"#;

fn emulated() -> hetcomm::config::Fleet {
    hetcomm::parse_fleet(EMULATED, "emulated-three.toml", None).expect("fleet parses")
}

fn config(seed: u64) -> LatencyConfig {
    LatencyConfig {
        messages: 300,
        warmup: 5,
        rate_hz: 100.0,
        size_bytes: 64,
        seed,
        ..LatencyConfig::default()
    }
}

#[test]
fn a_fixed_latency_link_gives_exactly_its_latency_one_way_and_twice_round_trip() {
    let seed = seed();
    let report = latency::run(&emulated(), &config(seed), None).expect("runs");
    for (from, to) in [("A", "B"), ("B", "A")] {
        let p = report.pair(from, to).expect("pair measured");
        assert_eq!(p.clock, Clock::Virtual, "seed {seed}");
        assert_eq!(
            (p.sent, p.lost_one_way, p.refused),
            (300, 0, 0),
            "seed {seed}"
        );
        let d = &p.one_way;
        assert_eq!(d.count, 300, "seed {seed}");
        // The simulator's resolution is 1 µs; an emulated link without bandwidth adds no
        // serialization time, so every one-way delay is L exactly.
        for x in [
            d.min_us, d.p50_us, d.p90_us, d.p99_us, d.p999_us, d.max_us, d.mean_us,
        ] {
            assert_eq!(x, 5000.0, "seed {seed}: {from} → {to} one-way {d:?}");
        }
        let rt = p.round_trip.as_ref().expect("a way back");
        assert_eq!(p.lost_round_trip, Some(0), "seed {seed}");
        for x in [rt.min_us, rt.p50_us, rt.p99_us, rt.max_us] {
            assert_eq!(x, 10_000.0, "seed {seed}: {from} → {to} round trip {rt:?}");
        }
        assert!(
            (p.achieved_rate_hz - 100.0).abs() < 0.5,
            "{}",
            p.achieved_rate_hz
        );
    }
    // No way back: one-way only, said so.
    let ac = report.pair("A", "C").expect("A → C measured");
    assert_eq!(ac.return_transport, None);
    assert_eq!((ac.round_trip.as_ref(), ac.lost_round_trip), (None, None));
    assert!(report.pair("C", "A").is_none(), "C → A is X");
    // The lossy, jittery link: acknowledged, so every probe arrives, within its bounds
    // (latency ± jitter, plus retransmissions for the lost ones).
    for (from, to) in [("A", "C"), ("B", "C"), ("C", "B")] {
        let p = report.pair(from, to).unwrap();
        assert_eq!(p.lost_one_way, 0, "seed {seed}: {from} → {to}");
        assert_eq!(p.one_way.count, 300, "seed {seed}");
        assert!(p.one_way.min_us >= 1000.0, "seed {seed}: {:?}", p.one_way);
        assert!(p.one_way.p50_us <= 3000.0, "seed {seed}: {:?}", p.one_way);
        assert!(
            p.one_way.max_us > 3000.0,
            "seed {seed}: 10% loss makes some probes wait for a retransmission: {:?}",
            p.one_way
        );
        assert_eq!(p.duplicates, 0);
    }
    // Every sample is in the report: one-way for 5 pairs, round trips for the 4 with a way
    // back.
    let count = |d: Direction| report.samples.iter().filter(|s| s.direction == d).count();
    assert_eq!(count(Direction::OneWay), 5 * 300);
    assert_eq!(count(Direction::RoundTrip), 4 * 300);
    assert_eq!(
        report.clock_methods.keys().collect::<Vec<_>>(),
        ["virtual"],
        "only the simulator ran"
    );
    assert!(report.clock_methods["virtual"].contains("no clock offset"));
}

#[test]
fn the_same_seed_gives_the_same_figures_and_another_seed_other_ones() {
    let seed = seed();
    let a = latency::run(&emulated(), &config(seed), None).unwrap();
    let b = latency::run(&emulated(), &config(seed), None).unwrap();
    assert_eq!(a, b, "seed {seed}: every figure and every sample");
    assert_eq!(latency::csv_samples(&a), latency::csv_samples(&b));
    assert_eq!(latency::text(&a), latency::text(&b));
    // One pair alone: the same figures as among all the others (its link is its own).
    let only = latency::run(
        &emulated(),
        &LatencyConfig {
            pairs: vec![("A".into(), "B".into())],
            ..config(seed)
        },
        None,
    )
    .unwrap();
    assert_eq!(only.pairs.len(), 1);
    assert_eq!(
        only.pair("A", "B").unwrap().one_way,
        a.pair("A", "B").unwrap().one_way
    );
    let c = latency::run(&emulated(), &config(seed + 1), None).unwrap();
    assert_eq!(
        a.pair("A", "B"),
        c.pair("A", "B"),
        "the fixed link does not depend on the seed"
    );
    assert_ne!(
        a.pair("B", "C").unwrap().one_way,
        c.pair("B", "C").unwrap().one_way,
        "seeds {seed} and {}: the jittery link does",
        seed + 1
    );
}

/// Two ports nobody listens on now, for a fleet of systems that must know each other's.
const UDP: &str = r#"
name = "udp-three"
[systems]
A = 0
B = 1
C = 2
[modules]
M = 0
[transports.lan]
kind = "udp"
delivery = "acknowledged"
security = "none"
endpoints = { A = "127.0.0.1:0", B = "127.0.0.1:0", C = "127.0.0.1:0" }
[table]
columns = ["A", "B", "C"]
A = ["X", "lan", "lan"]
B = ["lan", "X", "lan"]
C = ["lan", "lan", "X"]
"#;

#[test]
fn real_udp_on_loopback_measures_every_pair_and_writes_every_sample() {
    let fleet = hetcomm::parse_fleet(UDP, "udp-three.toml", None).unwrap();
    let config = LatencyConfig {
        messages: 60,
        warmup: 5,
        rate_hz: 200.0,
        size_bytes: 100,
        drain: Duration::from_secs(5),
        ..LatencyConfig::default()
    };
    let report = latency::run(&fleet, &config, None).expect("runs");
    let names: Vec<(&str, &str)> = report
        .pairs
        .iter()
        .map(|p| (p.from.as_str(), p.to.as_str()))
        .collect();
    assert_eq!(
        names,
        [
            ("A", "B"),
            ("A", "C"),
            ("B", "A"),
            ("B", "C"),
            ("C", "A"),
            ("C", "B")
        ]
    );
    for p in &report.pairs {
        assert_eq!(p.clock, Clock::Real, "{p:?}");
        assert_eq!(p.kind, "udp");
        // Acknowledged on loopback: every probe and echo arrives.
        assert_eq!((p.sent, p.refused, p.lost_one_way), (60, 0, 0), "{p:?}");
        assert_eq!(p.lost_round_trip, Some(0), "{p:?}");
        let (ow, rt) = (&p.one_way, p.round_trip.as_ref().unwrap());
        assert_eq!((ow.count, rt.count), (60, 60));
        assert!(ow.min_us > 0.0 && ow.p50_us <= ow.p99_us && ow.p99_us <= ow.max_us);
        assert!(
            rt.p50_us > ow.p50_us,
            "a round trip is longer than one way: {p:?}"
        );
        assert!(ow.max_us < 5e6, "within the drain time: {p:?}");
    }
    assert_eq!(
        report.notes.len(),
        3,
        "three port-0 endpoints: {:?}",
        report.notes
    );
    assert!(report.clock_methods["real"].contains("monotonic"));

    let dir = tempfile::tempdir().unwrap();
    let paths = latency::write_files(&report, dir.path()).unwrap();
    let csv = std::fs::read_to_string(dir.path().join("samples.csv")).unwrap();
    let mut lines = csv.lines();
    assert_eq!(
        lines.next(),
        Some("from,to,transport,clock,delay,seq,sent_us,delay_us")
    );
    let rows: Vec<&str> = lines.collect();
    assert_eq!(rows.len(), 6 * 60 * 2, "one-way and round trip per probe");
    for pair in ["A,B", "A,C", "B,A", "B,C", "C,A", "C,B"] {
        for delay in ["one-way", "round-trip"] {
            let n = rows
                .iter()
                .filter(|r| r.starts_with(&format!("{pair},lan,real,{delay},")))
                .count();
            assert_eq!(n, 60, "{pair} {delay}");
        }
    }
    let summary = std::fs::read_to_string(dir.path().join("summary.csv")).unwrap();
    assert_eq!(summary.lines().count(), 1 + 6 * 2);
    for f in ["latency.json", "plots/A-B.png", "plots/C-B.png"] {
        assert!(dir.path().join(f).is_file(), "{f}");
    }
    assert_eq!(paths.len(), 3 + 6);
}

#[test]
fn closed_loop_keeps_one_probe_in_flight_per_pair() {
    let fleet = hetcomm::parse_fleet(UDP, "udp-three.toml", None).unwrap();
    let config = LatencyConfig {
        messages: 200,
        warmup: 5,
        // Only a cap: the next probe goes as soon as the echo is back.
        rate_hz: 1e6,
        closed_loop: true,
        pairs: vec![("A".into(), "B".into())],
        ..LatencyConfig::default()
    };
    let report = latency::run(&fleet, &config, None).expect("runs");
    assert!(report.closed_loop);
    assert_eq!(report.pairs.len(), 1, "--pair A:B only");
    let p = report.pair("A", "B").unwrap();
    assert_eq!(
        (p.sent, p.lost_one_way, p.lost_round_trip),
        (200, 0, Some(0))
    );
    // Each probe left after the previous echo: the sends are at least a round trip apart.
    let sent: Vec<f64> = report
        .samples
        .iter()
        .filter(|s| s.direction == Direction::RoundTrip)
        .map(|s| s.sent_us)
        .collect();
    let rtts: Vec<f64> = report
        .samples
        .iter()
        .filter(|s| s.direction == Direction::RoundTrip)
        .map(|s| s.delay_us)
        .collect();
    for i in 1..sent.len() {
        assert!(
            sent[i] >= sent[i - 1] + rtts[i - 1],
            "probe {i} left at {} µs, before the echo of {} (sent {} + {} µs)",
            sent[i],
            i - 1,
            sent[i - 1],
            rtts[i - 1]
        );
    }
    assert!(latency::text(&report).contains("closed loop"));
}

#[test]
fn bad_settings_and_fleets_are_clear_errors() {
    let fleet = emulated();
    let err = |c: LatencyConfig| {
        latency::run(&fleet, &c, None)
            .expect_err("must fail")
            .to_string()
    };
    let base = config(1);
    let e = err(LatencyConfig {
        messages: 0,
        ..base.clone()
    });
    assert_eq!(e, "--messages must be at least 1");
    for rate in [0.0, -3.0, f64::NAN, f64::INFINITY] {
        let e = err(LatencyConfig {
            rate_hz: rate,
            ..base.clone()
        });
        assert!(
            e.starts_with("--rate must be a number of messages per second in (0, 1000000], got"),
            "{e}"
        );
    }
    let e = err(LatencyConfig {
        size_bytes: 3,
        ..base.clone()
    });
    assert_eq!(
        e,
        "--size must be at least 4 bytes (the probe's sequence number), got 3"
    );
    let e = err(LatencyConfig {
        size_bytes: 17 * 1024 * 1024,
        ..base.clone()
    });
    assert_eq!(
        e,
        "--size must be at most 16777216 bytes (the largest payload), got 17825792"
    );
    let e = err(LatencyConfig {
        pairs: vec![("A".into(), "Zulu".into())],
        ..base.clone()
    });
    assert_eq!(e, "--pair A:Zulu: the fleet has no system `Zulu`");
    let e = err(LatencyConfig {
        pairs: vec![("C".into(), "A".into())],
        ..base.clone()
    });
    assert_eq!(e, "--pair C:A: the table has no traffic from C to A (X)");
    let e = err(LatencyConfig {
        closed_loop: true,
        ..base.clone()
    });
    assert_eq!(
        e,
        "--closed-loop runs in real time only: A → B is on emulated links (add --realtime to \
         emulate them in real time)"
    );
    let e = err(LatencyConfig {
        closed_loop: true,
        realtime: true,
        pairs: vec![("A".into(), "C".into())],
        ..base.clone()
    });
    assert_eq!(
        e,
        "--closed-loop waits for each probe's echo, but A → C has no way back (the table has no \
         pair C → A); leave it out with --pair"
    );
    let silent = hetcomm::parse_fleet(
        "[systems]\nA = 0\nB = 1\n[modules]\nM = 0\n",
        "silent.toml",
        None,
    )
    .unwrap();
    let e = latency::run(&silent, &base, None).unwrap_err().to_string();
    assert_eq!(e, "the fleet's table has no traffic: no pair to measure");
}

#[test]
fn against_the_thesis_every_pair_says_what_the_thesis_publishes() {
    let dir = tempfile::tempdir().unwrap();
    let fleet = latency::thesis::fleet(dir.path()).unwrap();
    let c = LatencyConfig {
        messages: 50,
        ..config(seed())
    };
    let report = latency::run(&fleet, &c, Some(&latency::thesis::published)).unwrap();
    assert!(report.against_thesis);
    // Table 7: 10 ordered pairs, all on emulated R and B: all in virtual time.
    assert_eq!(report.pairs.len(), 10);
    assert!(report.pairs.iter().all(|p| p.clock == Clock::Virtual));
    let ac = report.pair("Alpha", "Charlie").unwrap();
    assert_eq!(ac.transport, "ros (R)");
    assert!(ac.thesis.as_deref().unwrap().starts_with("Table 12: all 4"));
    // `wired`: 0.1 ms plus 1 Gbit/s serialization of the frame (about 1 µs).
    assert_eq!(ac.one_way.p50_us, 101.0);
    assert_eq!(ac.round_trip.as_ref().unwrap().p50_us, 202.0);
    let ct = report.pair("Charlie", "Tango").unwrap();
    assert_eq!(ct.transport, "bluetooth (B)");
    assert!(ct.thesis.as_deref().unwrap().contains("2, 0, 0 and 2 s"));
    let ve = report.pair("VirtualEnv", "Alpha").unwrap();
    assert!(ve.thesis.as_deref().unwrap().starts_with("none:"));
    assert!(latency::text(&report).contains("thesis: Table 12"));
}
