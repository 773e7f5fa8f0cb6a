//! `hetcomm validate` and `hetcomm generate-config`: exit codes, the summary line, located
//! errors, and the thesis's legacy files.

use std::path::PathBuf;
use std::process::Command;

fn hetcomm(args: &[&str]) -> (i32, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_hetcomm"))
        .args(args)
        .output()
        .expect("run hetcomm");
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

fn config_dir(rel: &str) -> String {
    let p: PathBuf = [
        env!("CARGO_MANIFEST_DIR"),
        "..",
        "hetcomm-config",
        "tests",
        rel,
    ]
    .iter()
    .collect();
    p.to_string_lossy().into_owned()
}

#[test]
fn a_valid_fleet_prints_a_summary_and_exits_0() {
    let example = config_dir("../fleet.example.toml");
    let (code, stdout, stderr) = hetcomm(&["validate", &example]);
    assert_eq!(code, 0, "{stderr}");
    assert!(stdout.starts_with("ok: "), "{stdout}");
    assert!(
        stdout.contains("systems") && stdout.contains("modules") && stdout.contains("pairs"),
        "{stdout}"
    );
}

#[test]
fn the_thesis_tables_1_2_3_validate_as_legacy_files() {
    let (code, stdout, stderr) = hetcomm(&[
        "validate",
        "--ids",
        &config_dir("fixtures/table01-ids.txt"),
        "--table",
        &config_dir("fixtures/table02-table.txt"),
        "--bluetooth",
        &config_dir("fixtures/table03-bluetooth.txt"),
    ]);
    assert_eq!(code, 0, "{stderr}");
    // Table 1: five systems; Table 2: 20 pairs over R and B.
    assert!(stdout.starts_with("ok: 5 systems"), "{stdout}");
    assert!(stdout.contains("R: ") && stdout.contains("B: "), "{stdout}");
}

#[test]
fn an_invalid_fleet_exits_2_with_located_errors() {
    let file = config_dir("cases/invalid/dup-system-id.toml");
    let (code, stdout, stderr) = hetcomm(&["validate", &file]);
    assert_eq!(code, 2, "{stdout}{stderr}");
    assert!(stdout.is_empty());
    let first = stderr.lines().next().unwrap_or_default();
    // file:line:column: message
    let parts: Vec<&str> = first.splitn(4, ':').collect();
    assert!(parts[0].ends_with("dup-system-id.toml"), "{first}");
    assert!(
        parts[1].parse::<usize>().is_ok() && parts[2].parse::<usize>().is_ok(),
        "{first}"
    );
    assert!(first.contains("duplicate"), "{first}");
}

#[test]
fn generate_config_prints_a_fleet_that_validates() {
    let (code, stdout, _) = hetcomm(&["generate-config"]);
    assert_eq!(code, 0);
    let dir = std::env::temp_dir().join(format!("hetcomm-genconf-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("fleet.toml");
    std::fs::write(&file, &stdout).unwrap();
    let (code, out, err) = hetcomm(&["validate", file.to_str().unwrap()]);
    assert_eq!(code, 0, "{err}");
    assert!(out.starts_with("ok: "));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_missing_fleet_file_is_named_without_a_made_up_position() {
    let (code, stdout, stderr) = hetcomm(&["validate", "no-such-fleet.toml"]);
    assert_eq!(code, 2, "{stdout}{stderr}");
    let first = stderr.lines().next().unwrap_or_default();
    assert!(
        first.starts_with("no-such-fleet.toml: cannot read the fleet file: "),
        "{first}"
    );
}
