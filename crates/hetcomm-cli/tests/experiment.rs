//! `hetcomm experiment reliability`: the JSON it prints and the files it writes.

use std::path::PathBuf;
use std::process::Command;

fn out_dir(name: &str) -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(name);
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

#[test]
fn reliability_prints_json_and_writes_files() {
    let out = out_dir("experiment-reliability-json");
    let output = Command::new(env!("CARGO_BIN_EXE_hetcomm"))
        .args([
            "experiment",
            "reliability",
            "--trials",
            "2",
            "--format",
            "json",
        ])
        .arg("--out")
        .arg(&out)
        .output()
        .expect("hetcomm runs");
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(
        output.status.success(),
        "exit {:?}: {stderr}",
        output.status
    );
    let stdout = String::from_utf8_lossy(&output.stdout);
    let v: serde_json::Value =
        serde_json::from_str(&stdout).unwrap_or_else(|e| panic!("{e}: stdout:\n{stdout}"));

    assert_eq!(v["experiment"], "reliability");
    assert_eq!(v["trials"], 2);
    assert_eq!(v["seed"], 2019);
    assert_eq!(v["messages_per_trial"], 21);
    assert_eq!(v["acknowledged_attempts"], 64);
    assert_eq!(v["lossy_transport"], "B");
    assert_eq!(v["loss"]["model"], "profile");
    assert_eq!(v["thesis"]["received"], 413);
    assert_eq!(v["thesis"]["total"], 420);
    assert_eq!(v["thesis"]["delivery_ratio_percent"], 98.33);
    assert!(v["wall_time_s"].as_f64().is_some_and(|w| w >= 0.0), "{v}");

    let modes = v["modes"].as_array().expect("modes");
    let names: Vec<&str> = modes.iter().map(|m| m["mode"].as_str().unwrap()).collect();
    assert_eq!(names, ["thesis", "acknowledged"]);
    for m in modes {
        let mode = m["mode"].as_str().unwrap();
        assert_eq!(m["messages"], 42, "{mode}");
        assert_eq!(m["duplicates_delivered"], 0, "{mode}");
        let a = &m["accounting"];
        let n = |k: &str| {
            a[k].as_u64()
                .unwrap_or_else(|| panic!("{mode}: {k} in {a}"))
        };
        assert_eq!(n("accepted"), 42, "{mode}");
        assert_eq!(
            n("accepted"),
            n("delivered") + n("sent") + n("failed") + n("in_flight"),
            "{mode}: {a}"
        );
        assert_eq!(a["balanced"], true, "{mode}");
        let received = m["received"].as_u64().unwrap();
        let ratio = m["delivery_ratio_percent"].as_f64().unwrap();
        assert!(
            (ratio - 100.0 * received as f64 / 42.0).abs() < 1e-9,
            "{mode}"
        );
        // Tables 19–20: three rows, each with R then B.
        let systems = m["systems"].as_array().unwrap();
        let rows: Vec<&str> = systems
            .iter()
            .map(|s| s["system"].as_str().unwrap())
            .collect();
        assert_eq!(rows, ["Bravo", "Charlie", "Delta"], "{mode}");
        let mut sent = 0;
        let mut receivals = 0;
        for s in systems {
            let t = s["per_transport"].as_array().unwrap();
            let letters: Vec<&str> = t.iter().map(|c| c["transport"].as_str().unwrap()).collect();
            assert_eq!(letters, ["R", "B"], "{mode}");
            for c in t {
                for k in [
                    "transmit_attempts",
                    "transmit_successes",
                    "receivals",
                    "additional_attempts",
                    "failed",
                ] {
                    assert!(c[k].is_u64(), "{mode}: {k} in {c}");
                }
                sent += c["transmit_attempts"].as_u64().unwrap();
                receivals += c["receivals"].as_u64().unwrap();
            }
            // Each system sends 2 broadcast copies and 5 point-to-point messages per trial.
            let own: u64 = t
                .iter()
                .map(|c| c["transmit_attempts"].as_u64().unwrap())
                .sum();
            assert_eq!(own, 14, "{mode}");
        }
        assert_eq!(sent, 42, "{mode}");
        assert_eq!(receivals, received, "{mode}");
    }
    let ack = &modes[1];
    assert_eq!(ack["received"], 42, "acknowledged mode delivers everything");
    assert_eq!(ack["accounting"]["failed"], 0);

    for f in [
        "reliability.json",
        "summary.csv",
        "tables.csv",
        "fleet/fleet.toml",
    ] {
        assert!(out.join(f).is_file(), "{f} written");
    }
    let files: Vec<&str> = v["files"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| f.as_str().unwrap())
        .collect();
    assert_eq!(files.len(), 4, "{files:?}");
    // The file holds the same report (without the run's wall time).
    let file: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("reliability.json")).unwrap())
            .unwrap();
    assert_eq!(file["modes"], v["modes"]);
}

#[test]
fn bad_flags_are_clear_errors() {
    let out = out_dir("experiment-reliability-bad");
    let run = |args: &[&str]| {
        let o = Command::new(env!("CARGO_BIN_EXE_hetcomm"))
            .args(["experiment", "reliability", "--out"])
            .arg(&out)
            .args(args)
            .output()
            .expect("hetcomm runs");
        assert!(!o.status.success(), "{args:?} must fail");
        String::from_utf8_lossy(&o.stderr).into_owned()
    };
    let e = run(&["--mode", "fast"]);
    assert!(e.contains("fast") && e.contains("thesis"), "{e}");
    let e = run(&["--loss", "120"]);
    assert!(e.contains("--loss must be a percentage"), "{e}");
    let e = run(&["--burst-loss", "10"]);
    assert!(e.contains("--burst-length"), "{e}");
    let e = run(&["--burst-loss", "90", "--burst-length", "2"]);
    assert!(e.contains("at most"), "{e}");
    let e = run(&["--trials", "0"]);
    assert!(e.contains("--trials"), "{e}");
    let e = run(&["--fleet", "/nonexistent/fleet.toml"]);
    assert!(e.contains("fleet file") && e.contains("nonexistent"), "{e}");
}

/// `--secure` seals every simulated link (keys and sessions from the seed): Tables 19 and 20
/// (the CSV of counts) are the same as without. Delays may differ by the time links with a
/// bandwidth take for the 36 bytes a sealed frame adds.
#[test]
fn reliability_secured_gives_the_same_tables() {
    let tables = |secure: bool| {
        let out = out_dir(if secure {
            "experiment-reliability-secure"
        } else {
            "experiment-reliability-plain"
        });
        let mut cmd = Command::new(env!("CARGO_BIN_EXE_hetcomm"));
        cmd.args(["experiment", "reliability", "--trials", "2", "--out"])
            .arg(&out);
        if secure {
            cmd.arg("--secure");
        }
        let output = cmd.output().expect("hetcomm runs");
        assert!(
            output.status.success(),
            "{}",
            String::from_utf8_lossy(&output.stderr)
        );
        let csv = std::fs::read_dir(&out)
            .unwrap()
            .map(|e| e.unwrap().path())
            .find(|p| p.to_string_lossy().ends_with("tables.csv"))
            .unwrap_or_else(|| panic!("no tables CSV in {}", out.display()));
        std::fs::read_to_string(csv).unwrap()
    };
    let plain = tables(false);
    assert!(plain.lines().count() > 3, "{plain}");
    assert_eq!(plain, tables(true));
}
