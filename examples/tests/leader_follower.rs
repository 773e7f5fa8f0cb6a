//! The leader–follower demonstration behaves like the thesis's, repeatably.

use hetcomm_examples::leader_follower::{self, DemoOptions, DemoReport, Layout};
use hetcomm_sim::report::CommandKind;
use hetcomm_sim::PoseSample;

fn run(seed: u64, layout: Layout) -> DemoReport {
    leader_follower::run(&DemoOptions {
        seed,
        layout,
        ..DemoOptions::default()
    })
    .unwrap_or_else(|e| panic!("seed {seed}: demo failed: {e}"))
}

fn received(report: &DemoReport, rover: &str) -> Vec<(f64, i64)> {
    report
        .commands
        .iter()
        .filter(|c| c.rover == rover && c.kind == CommandKind::Received)
        .map(|c| (c.t_s, c.code))
        .collect()
}

#[test]
fn every_command_reaches_both_followers_in_order() {
    let r = run(1, Layout::ThreeVe);
    let sent: Vec<(f64, i64)> = r
        .commands
        .iter()
        .filter(|c| c.rover == "Alpha" && c.kind == CommandKind::Sent)
        .map(|c| (c.t_s, c.code))
        .collect();
    assert_eq!(
        sent.iter().map(|c| c.1).collect::<Vec<_>>(),
        vec![1, 0, 1, 0]
    );
    let charlie = received(&r, "Charlie");
    let tango = received(&r, "Tango");
    let codes = |v: &[(f64, i64)]| v.iter().map(|c| c.1).collect::<Vec<_>>();
    assert_eq!(codes(&charlie), codes(&sent), "Charlie");
    assert_eq!(codes(&tango), codes(&sent), "Tango");
    for i in 0..sent.len() {
        assert!(
            charlie[i].0 >= sent[i].0,
            "Charlie got command {i} before Alpha sent it"
        );
        assert!(
            tango[i].0 >= charlie[i].0,
            "Tango got command {i} before Charlie"
        );
    }
}

/// (Δx, Δy, Δθ) between consecutive samples of one rover, with the time of the first.
fn deltas(samples: &[PoseSample], rover: &str) -> Vec<(f64, f64, f64, f64)> {
    let mine: Vec<&PoseSample> = samples.iter().filter(|s| s.rover == rover).collect();
    mine.windows(2)
        .map(|w| {
            let dtheta =
                hetcomm_sim::kinematics::angle_diff_deg(w[0].pose.theta_deg, w[1].pose.theta_deg);
            (
                w[0].t_s,
                w[1].pose.x - w[0].pose.x,
                w[1].pose.y - w[0].pose.y,
                dtheta,
            )
        })
        .collect()
}

#[test]
fn pivots_keep_position_and_straights_keep_heading() {
    let r = run(1, Layout::ThreeVe);
    for rover in ["Alpha", "Charlie", "Tango"] {
        let d = deltas(&r.samples, rover);
        let eps = 1e-9;
        let pivots = d
            .iter()
            .filter(|(_, dx, dy, dt)| dt.abs() > eps && dx.abs() < eps && dy.abs() < eps)
            .count();
        let straights = d
            .iter()
            .filter(|(_, dx, dy, dt)| dt.abs() < eps && (dx.abs() > eps || dy.abs() > eps))
            .count();
        let mixed: Vec<_> = d
            .iter()
            .filter(|(_, dx, dy, dt)| dt.abs() > eps && (dx.abs() > eps || dy.abs() > eps))
            .collect();
        assert!(pivots > 40, "{rover}: {pivots} pivot intervals");
        assert!(straights > 80, "{rover}: {straights} straight intervals");
        // Only a sample interval in which the wheels changed may both move and turn: at most
        // one per command (4).
        assert!(
            mixed.len() <= 4,
            "{rover}: moved and turned at once in {mixed:?}"
        );
    }
}

/// The rover's manoeuvres: for each turn, the total angle turned.
fn turns(samples: &[PoseSample], rover: &str) -> Vec<f64> {
    let mut out = Vec::new();
    let mut current = 0.0;
    for (_, _, _, dt) in deltas(samples, rover) {
        if dt.abs() > 1e-9 {
            current += dt;
        } else if current != 0.0 {
            out.push(current);
            current = 0.0;
        }
    }
    if current != 0.0 {
        out.push(current);
    }
    out
}

#[test]
fn the_three_rovers_make_the_same_manoeuvres() {
    let r = run(1, Layout::ThreeVe);
    let alpha = turns(&r.samples, "Alpha");
    assert_eq!(alpha.len(), 2, "Alpha turned {alpha:?}");
    for rover in ["Charlie", "Tango"] {
        let t = turns(&r.samples, rover);
        assert_eq!(
            t.len(),
            alpha.len(),
            "{rover} turned {t:?}, Alpha {alpha:?}"
        );
        for (a, b) in alpha.iter().zip(&t) {
            // A follower turns for as long as Alpha did, give or take one 10 ms VE step of
            // radio latency: 57.3°/s × 0.01 s.
            assert!(
                (a - b).abs() < 1.0,
                "{rover} turned {b:.3}° where Alpha turned {a:.3}°"
            );
            assert!(*b > 90.0, "{rover}: a left turn of {b:.3}°");
        }
    }
}

#[test]
fn a_fixed_seed_gives_identical_output_and_matches_the_snapshot() {
    let a = leader_follower::tables(&run(1, Layout::ThreeVe));
    let b = leader_follower::tables(&run(1, Layout::ThreeVe));
    assert_eq!(a, b, "two runs with seed 1 differ");
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/snapshots/demo_seed1.txt"
    );
    if std::env::var_os("UPDATE_SNAPSHOTS").is_some() {
        std::fs::write(path, &a).unwrap();
    }
    let expected =
        std::fs::read_to_string(path).expect("snapshot missing: run with UPDATE_SNAPSHOTS=1");
    assert_eq!(
        a, expected,
        "tables differ from {path} (UPDATE_SNAPSHOTS=1 to accept)"
    );
}

#[test]
fn single_ve_with_callbacks_gives_the_same_trajectories() {
    let three = run(1, Layout::ThreeVe);
    let single = run(1, Layout::SingleVe);
    assert_eq!(three.samples.len(), single.samples.len());
    for (a, b) in three.samples.iter().zip(&single.samples) {
        assert_eq!(a.rover, b.rover);
        assert_eq!(a.t_s, b.t_s);
        assert_eq!(a.pose, b.pose, "{} at {} s", a.rover, a.t_s);
    }
    assert_eq!(received(&three, "Tango"), received(&single, "Tango"));
}

#[test]
fn plots_and_tables_are_written() {
    let r = run(1, Layout::ThreeVe);
    let dir = std::env::temp_dir().join(format!("hetcomm-demo-test-{}", std::process::id()));
    let files = leader_follower::write_outputs(&r, &dir).unwrap();
    let names: Vec<String> = files
        .iter()
        .map(|f| f.file_name().unwrap().to_string_lossy().into_owned())
        .collect();
    for expected in [
        "commands.txt",
        "locations.txt",
        "commands.csv",
        "poses.csv",
        "x.png",
        "y.png",
        "theta.png",
        "trajectory.png",
    ] {
        assert!(
            names.iter().any(|n| n == expected),
            "{expected} not written: {names:?}"
        );
    }
    for f in files
        .iter()
        .filter(|f| f.extension().is_some_and(|e| e == "png"))
    {
        let bytes = std::fs::read(f).unwrap();
        assert!(
            bytes.starts_with(b"\x89PNG\r\n\x1a\n"),
            "{} is not a PNG",
            f.display()
        );
        assert!(
            bytes.len() > 10_000,
            "{} is only {} bytes",
            f.display(),
            bytes.len()
        );
        let width = u32::from_be_bytes([bytes[16], bytes[17], bytes[18], bytes[19]]);
        let height = u32::from_be_bytes([bytes[20], bytes[21], bytes[22], bytes[23]]);
        assert!(
            width >= 800 && height >= 600,
            "{}: {width}×{height}",
            f.display()
        );
    }
    let poses = std::fs::read_to_string(dir.join("poses.csv")).unwrap();
    assert!(
        poses.lines().count() > 400,
        "poses.csv has {} lines",
        poses.lines().count()
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn the_thesis_files_load_to_the_embedded_fleet() {
    let dir = concat!(env!("CARGO_MANIFEST_DIR"), "/leader_follower");
    let from_files =
        hetcomm::config::load(std::path::Path::new(&format!("{dir}/fleet.toml"))).unwrap();
    let embedded =
        hetcomm::config::parse_str(leader_follower::EMBEDDED_FLEET, "embedded", None).unwrap();
    assert_eq!(from_files.systems, embedded.systems);
    assert_eq!(from_files.modules, embedded.modules);
    assert_eq!(from_files.table, embedded.table);
    assert_eq!(from_files.transports, embedded.transports);
    let single =
        hetcomm::config::load(std::path::Path::new(&format!("{dir}/fleet-single-ve.toml")))
            .unwrap();
    assert_eq!(single.systems.len(), 4);
}
