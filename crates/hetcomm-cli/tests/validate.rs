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

/// A fresh directory under the system's temporary directory.
fn temp_dir(tag: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("hetcomm-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

#[test]
fn a_valid_fleet_prints_a_summary_and_a_line_per_transport() {
    let file = config_dir("cases/valid/all-kinds.toml");
    let (code, stdout, stderr) = hetcomm(&["validate", &file]);
    assert_eq!(code, 0, "{stderr}");
    assert!(stdout.starts_with("ok: "), "{stdout}");
    assert!(
        stdout.contains("systems") && stdout.contains("modules") && stdout.contains("pairs"),
        "{stdout}"
    );
    // One line per transport, indented, after the summary.
    let lines: Vec<&str> = stdout.lines().skip(1).collect();
    assert!(!lines.is_empty(), "{stdout}");
    assert!(
        lines.iter().all(|l| l.starts_with("  transport `")),
        "{stdout}"
    );
}

#[test]
fn validate_with_keys_reports_secured_transports() {
    let dir = temp_dir("validate-keys");
    let fleet = dir.join("fleet.toml");
    std::fs::write(
        &fleet,
        "[systems]\nAlpha = 0\nBravo = 1\n\n\
         [transports.lan]\nkind = \"udp\"\nendpoints = { Alpha = \"127.0.0.1:0\", Bravo = \"127.0.0.1:0\" }\n\n\
         [transports.open]\nkind = \"tcp\"\nsecurity = \"none\"\nendpoints = { Alpha = \"127.0.0.1:0\", Bravo = \"127.0.0.1:0\" }\n\n\
         [table]\ncolumns = [\"Alpha\", \"Bravo\"]\nAlpha = [\"X\", \"lan\"]\nBravo = [\"open\", \"X\"]\n",
    )
    .unwrap();
    let fleet = fleet.to_str().unwrap();
    let (code, stdout, stderr) = hetcomm(&["validate", fleet]);
    assert_eq!(code, 0, "{stderr}");
    assert_eq!(
        stdout.lines().skip(1).collect::<Vec<_>>(),
        [
            "  transport `lan` (udp): secured; 2 of the 2 systems it carries have no public key: Alpha, Bravo",
            "  transport `open` (tcp): NOT SECURED (security = \"none\"): anyone who can reach it can pose as any system",
        ]
    );
    let keys = dir.join("keys");
    let keys = keys.to_str().unwrap();
    let (code, _, stderr) = hetcomm(&["keygen", "--fleet", fleet, "--out", keys]);
    assert_eq!(code, 0, "{stderr}");
    let (code, stdout, stderr) = hetcomm(&["validate", fleet, "--keys", keys]);
    assert_eq!(code, 0, "{stderr}");
    assert_eq!(
        stdout.lines().nth(1),
        Some("  transport `lan` (udp): secured; all 2 systems it carries have a public key")
    );
    let (code, _, stderr) = hetcomm(&["validate", fleet, "--keys", "no-such-keys"]);
    assert_eq!(code, 2);
    assert!(
        stderr.starts_with("no-such-keys: the keys directory `no-such-keys` does not exist"),
        "{stderr}"
    );
    let _ = std::fs::remove_dir_all(&dir);
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
fn generate_config_prints_a_secured_fleet_that_validates_once_keygen_ran() {
    let (code, stdout, _) = hetcomm(&["generate-config"]);
    assert_eq!(code, 0);
    assert!(stdout.contains("[security]\nkeys = \"keys\"\n"), "{stdout}");
    assert!(stdout.contains("# security = \"none\""), "{stdout}");
    let dir = temp_dir("genconf");
    let file = dir.join("fleet.toml");
    std::fs::write(&file, &stdout).unwrap();
    let file = file.to_str().unwrap();
    let keys = dir.join("keys");
    let keys = keys.to_str().unwrap();
    // A new user's first `validate` says what to run.
    let (code, out, err) = hetcomm(&["validate", file]);
    assert_eq!(code, 2, "{out}");
    assert!(
        err.contains(&format!(
            "the keys directory `{keys}` does not exist\n  help: run `hetcomm keygen --fleet {file} --out {keys}`"
        )),
        "{err}"
    );
    let (code, out, err) = hetcomm(&["keygen", "--fleet", file, "--out", keys]);
    assert_eq!(code, 0, "{err}");
    assert!(
        out.contains("already reads its keys from this directory"),
        "{out}"
    );
    let (code, out, err) = hetcomm(&["validate", file]);
    assert_eq!(code, 0, "{err}");
    assert!(out.starts_with("ok: "), "{out}");
    assert!(
        out.contains(
            "  transport `lan` (udp): secured; all 2 systems it carries have a public key\n"
        ),
        "{out}"
    );
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

#[test]
fn a_fleet_file_tap_on_a_path_that_does_not_exist_is_a_located_error() {
    let dir = temp_dir("validate-taps");
    let fleet = "[systems]\nA = 0\nB = 1\nC = 2\n[modules]\nPlan = 0\n[transports.net]\nkind = \"inproc\"\n[table]\ncolumns = [\"A\", \"B\", \"C\"]\nA = [\"X\", \"net\", \"X\"]\nB = [\"net\", \"X\", \"net\"]\nC = [\"X\", \"net\", \"X\"]\n\n[[tap]]\nto = \"B\"\nfrom = \"A\"\naction = \"observe\"\n";
    let good = dir.join("good.toml");
    std::fs::write(&good, fleet).unwrap();
    let (code, stdout, stderr) = hetcomm(&["validate", good.to_str().unwrap()]);
    assert_eq!(code, 0, "{stdout}{stderr}");
    assert!(
        stdout.contains("1 tap(s) placed for the whole run"),
        "{stdout}"
    );
    let bad = dir.join("bad.toml");
    std::fs::write(&bad, fleet.replace("to = \"B\"", "to = \"C\"")).unwrap();
    let (code, stdout, stderr) = hetcomm(&["validate", bad.to_str().unwrap()]);
    assert_eq!(code, 2, "{stdout}{stderr}");
    assert_eq!(
        stderr.lines().next().unwrap_or_default(),
        format!(
            "{}:17:8: [[tap]] at line 15 is on a path that does not exist: the communication table has `X` from A to C",
            bad.display()
        ),
        "{stderr}"
    );
    assert!(
        stderr.contains("help: tap a pair the table connects"),
        "{stderr}"
    );
}

#[test]
fn a_system_the_table_connects_to_nobody_is_warned_of() {
    let dir = temp_dir("isolated");
    let file = dir.join("fleet.toml");
    std::fs::write(
        &file,
        "[systems]\nAlpha = 0\nBravo = 1\nEcho = 2\n[modules]\nPlan = 0\n\
         [transports.R]\nkind = \"inproc\"\n\
         [table]\ncolumns = [\"Alpha\", \"Bravo\"]\nAlpha = [\"X\", \"R\"]\nBravo = [\"R\", \"X\"]\n",
    )
    .unwrap();
    let (code, stdout, stderr) = hetcomm(&["validate", file.to_str().unwrap()]);
    assert_eq!(code, 0, "valid all the same: {stderr}");
    let warnings: Vec<&str> = stdout.lines().filter(|l| l.contains("warning")).collect();
    assert_eq!(
        warnings,
        [
            "  warning: `Echo` is in [systems] but every pair with it is X: it can talk to nobody \
          (add it to the table's columns and rows)"
        ],
        "{stdout}"
    );
}
