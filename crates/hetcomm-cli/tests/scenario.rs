//! Scenario files on the command line: `hetcomm validate --scenario` checks them with located
//! errors, and `hetcomm demo --scenario` runs the demonstration's example scenario and reports
//! what it changed.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn hetcomm(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_hetcomm"))
        .current_dir(root())
        .args(args)
        .output()
        .expect("hetcomm runs")
}

const FLEET: &str = "examples/leader_follower/fleet.toml";
const CUT: &str = "examples/leader_follower/scenario-tango-cut.toml";

#[test]
fn validate_checks_a_scenario_against_its_fleet() {
    let ok = hetcomm(&["validate", FLEET, "--scenario", CUT]);
    assert!(
        ok.status.success(),
        "{}",
        String::from_utf8_lossy(&ok.stderr)
    );
    let stdout = String::from_utf8_lossy(&ok.stdout);
    assert!(
        stdout.contains("ok: scenario examples/leader_follower/scenario-tango-cut.toml: 1 fault(s), 0 injection(s), 0 tap(s), last event at 7.5 s"),
        "{stdout}"
    );

    let bad = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("bad-scenario.toml");
    std::fs::write(
        &bad,
        "[[partition]]\nbetween = [\"Charlie\", \"Tnago\"]\nstart = 2.0\nend = 1.0\n",
    )
    .unwrap();
    let out = hetcomm(&["validate", FLEET, "--scenario", bad.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(2));
    let stderr = String::from_utf8_lossy(&out.stderr);
    let file = bad.display().to_string();
    assert!(
        stderr.contains(&format!(
            "{file}:2:23: unknown system `Tnago` in [[partition]] at line 1"
        )),
        "{stderr}"
    );
    assert!(stderr.contains("did you mean `Tango`?"), "{stderr}");
    assert!(
        stderr.contains(&format!(
            "{file}:4:7: [[partition]] at line 1 ends at 1 s, not after its start at 2 s"
        )),
        "{stderr}"
    );
}

#[test]
fn demo_reports_what_the_example_scenario_changed() {
    let out_dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("demo-scenario");
    let _ = std::fs::remove_dir_all(&out_dir);
    let out = hetcomm(&[
        "demo",
        "--scenario",
        CUT,
        "--out",
        out_dir.to_str().unwrap(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let stdout = String::from_utf8_lossy(&out.stdout);
    for expected in [
        "4.50–  7.50 s  partition (cut): Charlie→Tango, Tango→Charlie",
        "What the scenario changed (same seed, without → with):",
        "code 0 at   5.10 s     → never arrived",
        "Tango ends at",
    ] {
        assert!(
            stdout.contains(expected),
            "missing {expected:?} in:\n{stdout}"
        );
    }
    let written = std::fs::read_to_string(out_dir.join("scenario.txt")).unwrap();
    assert!(written.contains("frames cut"), "{written}");
}
