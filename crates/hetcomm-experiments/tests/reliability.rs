//! The reliability experiment (thesis §5.2): acknowledged delivery recovers every loss exactly
//! once, thesis mode shows the thesis's kind of losses, runs are repeatable for a seed.
//!
//! Seeded tests put their seed in every assertion message; `HETCOMM_SEED=n cargo test -p
//! hetcomm-experiments` reruns them with seed `n`.

use hetcomm_experiments::reliability::{
    self, default_fleet, LossModel, Mode, ModeReport, ReliabilityConfig, ReliabilityReport,
    DEFAULT_ATTEMPTS,
};
use hetcomm_experiments::report;
use hetcomm_experiments::sweep::{self, SweepConfig};

/// The seed for a test: `HETCOMM_SEED` if set (to reproduce a failure), else `default`.
fn seed(default: u64) -> u64 {
    std::env::var("HETCOMM_SEED")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(default)
}

fn run(config: &ReliabilityConfig) -> ReliabilityReport {
    let fleet = default_fleet().expect("the default fleet loads");
    reliability::run(&fleet, config).expect("the experiment runs")
}

fn column<'a>(
    m: &'a ModeReport,
    letter: &str,
) -> impl Iterator<Item = &'a reliability::TransportCounts> + 'a {
    let letter = letter.to_string();
    m.systems
        .iter()
        .flat_map(|r| r.per_transport.iter())
        .filter(move |c| c.transport == letter)
}

/// Every message delivered exactly once, and the send-side accounting balances.
fn assert_exactly_once(m: &ModeReport, seed: u64, what: &str) {
    let ctx = format!("{what}, seed {seed} (rerun with HETCOMM_SEED={seed})");
    assert_eq!(m.messages, 420, "{ctx}: messages sent");
    assert_eq!(
        m.received, 420,
        "{ctx}: every message received; report: {m:#?}"
    );
    assert_eq!(m.duplicates_delivered, 0, "{ctx}: duplicates delivered");
    assert_eq!(
        m.out_of_order, 0,
        "{ctx}: messages out of order (ordering is on)"
    );
    assert_eq!(
        m.accounting.failed, 0,
        "{ctx}: failed sends {:?}",
        m.failure_reasons
    );
    let a = &m.accounting;
    assert_eq!(a.accepted, 420, "{ctx}: accepted");
    assert_eq!(
        a.accepted,
        a.delivered + a.sent + a.unconfirmed + a.failed + a.in_flight,
        "{ctx}: accepted = delivered + sent + unconfirmed + failed + in flight: {a:?}"
    );
    assert_eq!(a.delivered, 420, "{ctx}: every send acknowledged: {a:?}");
    assert_eq!(a.in_flight, 0, "{ctx}: nothing left in flight: {a:?}");
    assert!(a.balanced, "{ctx}: accounting balanced: {a:?}");
    for r in &m.systems {
        for c in &r.per_transport {
            assert_eq!(
                c.transmit_successes, c.transmit_attempts,
                "{ctx}: {} over {}: every send succeeded",
                r.system, c.transport
            );
        }
    }
    let receivals: u64 = m
        .systems
        .iter()
        .flat_map(|r| &r.per_transport)
        .map(|c| c.receivals)
        .sum();
    assert_eq!(receivals, 420, "{ctx}: receivals over both transports");
    assert!(
        m.max_attempts <= DEFAULT_ATTEMPTS,
        "{ctx}: attempts within the budget"
    );
}

/// Acknowledged mode at 30% i.i.d. loss on B (both directions: data and acknowledgements).
/// Budget: the default, 64 attempts (a message fails with probability 0.51⁶⁴); timeout: the
/// default timing, first RTO 20 ms, floor 10 ms, ceiling 160 ms, backoff 2.
#[test]
fn acknowledged_mode_delivers_everything_once_at_30_percent_iid_loss() {
    let seed = seed(2019);
    let config = ReliabilityConfig {
        seed,
        modes: vec![Mode::Acknowledged],
        loss: LossModel::Iid { percent: 30.0 },
        ..ReliabilityConfig::default()
    };
    assert_eq!(config.attempts, 64, "the budget this test documents");
    let report = run(&config);
    let m = report.mode(Mode::Acknowledged).expect("mode ran");
    assert_exactly_once(m, seed, "acknowledged, 30% i.i.d.");
    // The loss really happened, and lost acknowledgements made the senders retransmit
    // messages that had arrived: the receivers suppressed those copies.
    let lost = m.network_drops.get("Loss").copied().unwrap_or(0);
    assert!(lost > 50, "seed {seed}: frames lost on B: {lost}");
    assert!(
        m.duplicates_suppressed > 0,
        "seed {seed}: some acknowledgements were lost, so some copies were suppressed"
    );
    assert!(
        column(m, "B").map(|c| c.additional_attempts).sum::<u64>() > 50,
        "seed {seed}: B needed retransmissions"
    );
    assert_eq!(
        column(m, "R").map(|c| c.additional_attempts).sum::<u64>(),
        0,
        "seed {seed}: the wired link loses nothing"
    );
}

/// Acknowledged mode at 30% bursty loss (Gilbert–Elliott, mean burst 3 frames) on B: the same
/// mean as above, harder on retransmissions. Same budget (64) and timing.
#[test]
fn acknowledged_mode_delivers_everything_once_at_30_percent_bursty_loss() {
    let seed = seed(2019);
    let config = ReliabilityConfig {
        seed,
        modes: vec![Mode::Acknowledged],
        loss: LossModel::Bursty {
            percent: 30.0,
            burst_length: 3.0,
        },
        ..ReliabilityConfig::default()
    };
    assert_eq!(config.attempts, 64, "the budget this test documents");
    let report = run(&config);
    let m = report.mode(Mode::Acknowledged).expect("mode ran");
    assert_exactly_once(m, seed, "acknowledged, 30% bursty (L = 3)");
    let lost = m.network_drops.get("BurstLoss").copied().unwrap_or(0);
    assert!(lost > 50, "seed {seed}: frames lost in bursts on B: {lost}");
    assert_eq!(
        m.network_drops.get("Loss").copied().unwrap_or(0),
        0,
        "seed {seed}: the i.i.d. loss is off"
    );
}

/// Thesis mode with the default `bluetooth-classic` profile: losses of the kind the thesis
/// saw. The profile was fitted to Tables 19–20 (expected ≈ 27 additional attempts and ≈ 7
/// failed sends per 232 Bluetooth sends), so over 20 trials:
///
/// - the wired R link never needs an additional attempt and never fails (it has no loss:
///   holds for every seed);
/// - some B sends fail, each after all 3 attempts (so the most attempts any send made is 3);
/// - more additional attempts were made than the failures explain (2 each): some second or
///   third attempts succeeded — the thesis's argument from 25 not being divisible by 3;
/// - every frame the transport accepted was received (losses are reported, not silent), so
///   receivals equal successes per transport and the ratio is in [95%, 100%).
///
/// The lower bounds (≥ 1 failure, more retries than failures explain) are the only
/// seed-dependent ones; with the default seed 2019 the run has 3 failures and 20 additional
/// attempts (the thesis: 7 and 25), and seeds 1–40 all pass.
#[test]
fn thesis_mode_shows_the_thesis_kind_of_losses() {
    let seed = seed(2019);
    let config = ReliabilityConfig {
        seed,
        modes: vec![Mode::Thesis],
        ..ReliabilityConfig::default()
    };
    let report = run(&config);
    let m = report.mode(Mode::Thesis).expect("mode ran");
    let ctx = format!("thesis mode, seed {seed} (rerun with HETCOMM_SEED={seed})");
    assert_eq!(m.messages, 420, "{ctx}");
    for c in column(m, "R") {
        assert_eq!(c.additional_attempts, 0, "{ctx}: R never retries: {c:?}");
        assert_eq!(c.failed, 0, "{ctx}: R never fails: {c:?}");
        assert_eq!(c.transmit_successes, c.transmit_attempts, "{ctx}: {c:?}");
    }
    let b_failed: u64 = column(m, "B").map(|c| c.failed).sum();
    let b_additional: u64 = column(m, "B").map(|c| c.additional_attempts).sum();
    assert!(b_failed >= 1, "{ctx}: some B sends failed after 3 attempts");
    assert_eq!(
        m.max_attempts, 3,
        "{ctx}: failures used the whole budget of 3"
    );
    assert_eq!(
        m.failure_reasons.get("unreachable").copied(),
        Some(b_failed),
        "{ctx}: every failure is the transport's reported loss: {:?}",
        m.failure_reasons
    );
    assert!(
        b_additional > 2 * b_failed,
        "{ctx}: {b_additional} additional attempts, {b_failed} failures: some retries succeeded"
    );
    for letter in ["R", "B"] {
        let successes: u64 = column(m, letter).map(|c| c.transmit_successes).sum();
        let receivals: u64 = column(m, letter).map(|c| c.receivals).sum();
        assert_eq!(
            successes, receivals,
            "{ctx}: {letter}: accepted frames all arrive"
        );
    }
    assert!(
        (95.0..100.0).contains(&m.delivery_ratio_percent),
        "{ctx}: delivery ratio {:.2}%",
        m.delivery_ratio_percent
    );
    assert_eq!(
        m.received + b_failed,
        420,
        "{ctx}: every lost message is a failed send"
    );
    assert_eq!(m.duplicates_delivered, 0, "{ctx}");
    let a = &m.accounting;
    assert_eq!(
        a.delivered, 0,
        "{ctx}: unacknowledged: nothing is confirmed"
    );
    assert_eq!(a.sent + a.failed, 420, "{ctx}: {a:?}");
    assert!(a.balanced, "{ctx}: {a:?}");
}

#[test]
fn same_seed_same_results_other_seed_differs() {
    let seed = seed(7);
    let config = |seed| ReliabilityConfig {
        seed,
        ..ReliabilityConfig::default()
    };
    let a = report::json(&run(&config(seed)));
    let b = report::json(&run(&config(seed)));
    assert!(a == b, "seed {seed}: two runs differ");
    let c = report::json(&run(&config(seed + 1)));
    assert!(a != c, "seeds {seed} and {}: identical results", seed + 1);
}

#[test]
fn reports_have_the_shape_of_tables_19_and_20() {
    let seed = seed(2019);
    let r = run(&ReliabilityConfig {
        seed,
        trials: 3,
        ..ReliabilityConfig::default()
    });
    assert_eq!(r.messages_per_trial, 21);
    let text = report::text(&r);
    for needle in [
        "R transmit attempts",
        "B transmit attempts",
        "R transmit successes",
        "B transmit successes",
        "R receivals",
        "B receivals",
        "R additional attempts",
        "B additional attempts",
        "of 63 messages",
        "[thesis: 413 of 420 (98.33%)]",
        "Accounting: accepted 63 = ",
        "== mode: thesis ==",
        "== mode: acknowledged ==",
    ] {
        assert!(
            text.contains(needle),
            "seed {seed}: `{needle}` missing from:\n{text}"
        );
    }
    let rows: Vec<&str> = text
        .lines()
        .filter(|l| l.starts_with("Bravo") || l.starts_with("Charlie") || l.starts_with("Delta"))
        .collect();
    // Per mode: Table 19 and Table 20 rows; plus the published tables.
    assert_eq!(rows.len(), 3 * 2 * 3, "seed {seed}: rows: {rows:#?}");
    let tables = report::tables_csv(&r);
    // 3 systems × 2 transports × (2 modes + the published tables), plus the header.
    assert_eq!(tables.lines().count(), 1 + 3 * 2 * 3, "{tables}");
    let summary = report::summary_csv(&r);
    assert_eq!(summary.lines().count(), 1 + 2 + 1, "{summary}");
    // The published numbers are the thesis's.
    let t = &r.thesis;
    let b_attempts: u64 = t
        .systems
        .iter()
        .map(|s| s.per_transport[1].transmit_attempts)
        .sum();
    let b_additional: u64 = t
        .systems
        .iter()
        .map(|s| s.per_transport[1].additional_attempts)
        .sum();
    assert_eq!((b_attempts, b_additional, t.received), (232, 25, 413));
    // JSON round-trips (floats to within parsing precision).
    let back: ReliabilityReport = serde_json::from_str(&report::json(&r)).expect("json parses");
    assert_eq!(back.thesis, r.thesis);
    for (b, m) in back.modes.iter().zip(&r.modes) {
        assert_eq!(b.systems, m.systems);
        assert_eq!(b.accounting, m.accounting);
        assert_eq!(b.transports, m.transports);
        assert!((b.attempts_per_message - m.attempts_per_message).abs() < 1e-12);
        assert!((b.delay.mean_ms - m.delay.mean_ms).abs() < 1e-12);
    }
}

#[test]
fn bad_settings_are_clear_errors() {
    let fleet = default_fleet().expect("fleet");
    let err = |config: ReliabilityConfig| {
        reliability::run(&fleet, &config)
            .expect_err("must be refused")
            .to_string()
    };
    let msg = err(ReliabilityConfig {
        trials: 0,
        ..ReliabilityConfig::default()
    });
    assert!(msg.contains("--trials"), "{msg}");
    let msg = err(ReliabilityConfig {
        loss: LossModel::Iid { percent: 150.0 },
        ..ReliabilityConfig::default()
    });
    assert!(msg.contains("--loss") && msg.contains("150"), "{msg}");
    let msg = err(ReliabilityConfig {
        loss: LossModel::Bursty {
            percent: 80.0,
            burst_length: 3.0,
        },
        ..ReliabilityConfig::default()
    });
    assert!(msg.contains("at most") && msg.contains("75.00%"), "{msg}");
    let msg = err(ReliabilityConfig {
        attempts: 0,
        ..ReliabilityConfig::default()
    });
    assert!(msg.contains("--attempts"), "{msg}");

    // A fleet whose B is not emulated: the loss options cannot apply.
    let data = concat!(env!("CARGO_MANIFEST_DIR"), "/data");
    let inproc = hetcomm::config::parse_str(
        r#"
        [legacy]
        ids = "table16-ids.txt"
        table = "table17-table.txt"
        [transports.wire]
        kind = "inproc"
        [transports.radio]
        kind = "inproc"
        [letters]
        R = "wire"
        B = "radio"
        "#,
        "inproc.toml",
        Some(std::path::Path::new(data)),
    )
    .expect("fleet parses");
    let msg = reliability::run(
        &inproc,
        &ReliabilityConfig {
            loss: LossModel::Iid { percent: 10.0 },
            ..ReliabilityConfig::default()
        },
    )
    .expect_err("B is not emulated")
    .to_string();
    assert!(msg.contains("not an emulated one"), "{msg}");
    // Without loss options the same fleet runs: ideal links, everything delivered.
    let r = reliability::run(&inproc, &ReliabilityConfig::default()).expect("runs");
    for m in &r.modes {
        assert_eq!(m.received, 420, "{}", m.mode);
    }
}

#[test]
fn sweep_writes_csv_json_and_png() {
    let seed = seed(2019);
    let fleet = default_fleet().expect("fleet");
    let config = SweepConfig {
        base: ReliabilityConfig {
            seed,
            trials: 4,
            ..ReliabilityConfig::default()
        },
        rates: vec![0.0, 30.0],
        ..SweepConfig::default()
    };
    let report = sweep::run(&fleet, &config).expect("sweep runs");
    // 2 loss models × 2 rates × 2 modes.
    assert_eq!(report.points.len(), 8);
    for p in &report.points {
        let ctx = format!("seed {seed}: {p:?}");
        assert_eq!(p.duplicates_delivered, 0, "{ctx}");
        assert!(p.balanced, "{ctx}");
        if p.mode == Mode::Acknowledged || p.loss_percent == 0.0 {
            assert_eq!(p.received, p.messages, "{ctx}");
        }
        if p.loss_percent == 0.0 {
            assert_eq!(p.attempts_per_message, 1.0, "{ctx}");
        } else {
            assert!(p.attempts_per_message > 1.0, "{ctx}");
        }
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let paths = sweep::write_files(&report, dir.path()).expect("files written");
    let names: Vec<String> = paths
        .iter()
        .map(|p| p.file_name().unwrap().to_string_lossy().into_owned())
        .collect();
    assert_eq!(names, ["sweep.csv", "sweep.json", "sweep.png"]);
    let csv = std::fs::read_to_string(&paths[0]).expect("csv");
    assert_eq!(csv.lines().count(), 1 + 8, "{csv}");
    assert!(csv.starts_with("mode,loss_model,loss_percent,"), "{csv}");
    let png = std::fs::read(&paths[2]).expect("png");
    assert!(png.starts_with(b"\x89PNG\r\n\x1a\n"), "a PNG file");
    let pixels = hetcomm_experiments::plot::render_sweep(&report).expect("renders");
    let colours: std::collections::HashSet<&[u8]> = pixels.chunks_exact(3).collect();
    assert!(
        colours.len() > 20,
        "the plot has lines and text, not a blank image"
    );
}

/// A budget too small for the loss: sends whose frames left but whose acknowledgements never
/// came back end unconfirmed, never failed, and some of them did arrive (the case that used to
/// be reported as a failure). The totals add up with the new column.
#[test]
fn a_small_budget_under_loss_reports_unconfirmed_not_failed() {
    let seed = seed(20);
    let config = ReliabilityConfig {
        seed,
        attempts: 2,
        modes: vec![Mode::Acknowledged],
        loss: LossModel::Iid { percent: 30.0 },
        ..ReliabilityConfig::default()
    };
    let ctx = format!("30% loss, 2 attempts, seed {seed} (rerun with HETCOMM_SEED={seed})");
    let report = run(&config);
    let m = report.mode(Mode::Acknowledged).expect("mode ran");
    let a = &m.accounting;
    assert_eq!(a.failed, 0, "{ctx}: nothing certainly failed: {a:?}");
    assert!(a.unconfirmed > 0, "{ctx}: some sends unconfirmed: {a:?}");
    assert!(a.balanced, "{ctx}: accounting balanced: {a:?}");
    assert_eq!(
        a.accepted,
        a.delivered + a.unconfirmed + a.in_flight,
        "{ctx}: {a:?}"
    );
    // Every delivered send arrived; of the unconfirmed ones, some arrived too.
    assert!(
        m.received > a.delivered && m.received <= a.delivered + a.unconfirmed,
        "{ctx}: received {} of delivered {} + unconfirmed {}",
        m.received,
        a.delivered,
        a.unconfirmed
    );
    let cells: u64 = m
        .systems
        .iter()
        .flat_map(|r| &r.per_transport)
        .map(|c| c.unconfirmed)
        .sum();
    assert_eq!(cells, a.unconfirmed, "{ctx}: the table's column adds up");
    let text = report::text(&report);
    assert!(
        text.contains("unconfirmed sends") && text.contains("+ unconfirmed"),
        "{ctx}: the tables show the column:\n{text}"
    );
}

/// The experiment secured (`[security] in_process = true`: every simulated link sealed, keys
/// from the seed, sessions made in memory) gives exactly the tables (19 and 20: attempts,
/// successes, receivals, unconfirmed, failed, per system and transport) of the unsecured run
/// with the same seed: security adds no frame to the simulated network and draws nothing from
/// its random streams. Delays are not identical, and should not be: a sealed frame is 36
/// bytes longer, and links with a bandwidth (the Bluetooth profile) take longer to send it.
/// (That the links really are sealed in a simulation is checked in `hetcomm`'s
/// `tests/sim.rs`.)
#[test]
fn a_secured_run_gives_the_same_tables_as_an_unsecured_one() {
    let seed = seed(11);
    let config = ReliabilityConfig {
        seed,
        trials: 3,
        ..ReliabilityConfig::default()
    };
    let fleet = default_fleet().expect("the default fleet loads");
    let mut secured = fleet.clone();
    secured.secure_in_process = true;
    let plain = reliability::run(&fleet, &config).expect("runs");
    let sealed = reliability::run(&secured, &config).expect("runs secured");
    assert_eq!(
        report::tables_csv(&plain),
        report::tables_csv(&sealed),
        "seed {seed} (rerun with HETCOMM_SEED={seed}): secured and unsecured tables differ"
    );
    for (p, s) in plain.modes.iter().zip(&sealed.modes) {
        assert_eq!(
            (
                p.received,
                p.transmissions,
                &p.network_drops,
                &p.failure_reasons
            ),
            (
                s.received,
                s.transmissions,
                &s.network_drops,
                &s.failure_reasons
            ),
            "seed {seed}: mode {}",
            p.mode.name()
        );
    }
}
