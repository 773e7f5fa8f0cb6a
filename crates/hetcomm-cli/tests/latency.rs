//! `hetcomm experiment latency`: the exact text and CSV it prints for a fleet in virtual time,
//! the files it writes, `--against-thesis`, and its errors.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn out_dir(name: &str) -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(name);
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

/// A → B, B → A and A → C over an emulated link of 5 ms and nothing else; C → A is X.
const FIXED: &str = r#"name = "fixed-pair"
[systems]
A = 0
B = 1
C = 2
[modules]
M = 0
[transports.fixed]
kind = "emulated"
latency_ms = 5
[table]
columns = ["A", "B", "C"]
A = ["X", "fixed", "fixed"]
B = ["fixed", "X", "X"]
C = ["X", "X", "X"]
"#;

fn fixed_fleet(dir: &Path) -> PathBuf {
    std::fs::create_dir_all(dir).unwrap();
    let path = dir.join("fixed.toml");
    std::fs::write(&path, FIXED).unwrap();
    path
}

fn latency(args: &[&str], out: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_hetcomm"))
        .args(["experiment", "latency"])
        .args(args)
        .arg("--out")
        .arg(out)
        .output()
        .expect("hetcomm runs")
}

const SETTINGS: [&str; 8] = [
    "--messages",
    "20",
    "--warmup",
    "2",
    "--rate",
    "50",
    "--size",
    "32",
];

#[test]
fn text_output_of_a_simulated_fleet_is_exact_and_the_same_every_run() {
    let dir = out_dir("latency-text");
    let fleet = fixed_fleet(&dir.join("in"));
    let out = dir.join("out");
    let mut args = vec!["--fleet", fleet.to_str().unwrap()];
    args.extend(SETTINGS);
    let first = latency(&args, &out);
    assert!(
        first.status.success(),
        "{}",
        String::from_utf8_lossy(&first.stderr)
    );
    let stdout = String::from_utf8(first.stdout).unwrap();
    let o = out.display();
    let expected = format!(
        "\
Delay analysis of fixed-pair: 20 probes per ordered pair (after 2 warm-up), 50 msg/s per pair, 32 B payload, seed 2019
Clocks:
  virtual: virtual time of the simulator (1 µs resolution): both ends read the one virtual clock, so no clock offset arises or is estimated

pair                     transport            clock   delay           n  lost     p50 µs     p90 µs     p99 µs   p99.9 µs     max µs
A → B                    fixed                virtual one-way        20     0     5000.0     5000.0     5000.0     5000.0     5000.0
                         back: fixed                  round-trip     20     0    10000.0    10000.0    10000.0    10000.0    10000.0
A → C                    fixed                virtual one-way        20     0     5000.0     5000.0     5000.0     5000.0     5000.0
                                                      round-trip no way back: the table has no pair C → A
B → A                    fixed                virtual one-way        20     0     5000.0     5000.0     5000.0     5000.0     5000.0
                         back: fixed                  round-trip     20     0    10000.0    10000.0    10000.0    10000.0    10000.0

wrote {o}/latency.json
wrote {o}/summary.csv
wrote {o}/samples.csv
wrote {o}/plots/A-B.png
wrote {o}/plots/A-C.png
wrote {o}/plots/B-A.png
"
    );
    assert_eq!(stdout, expected);
    let samples = std::fs::read_to_string(out.join("samples.csv")).unwrap();
    // 3 pairs one way, 2 with a way back: 5 × 20 samples and the header.
    assert_eq!(samples.lines().count(), 1 + 5 * 20, "{samples}");
    assert_eq!(
        samples.lines().take(3).collect::<Vec<_>>(),
        [
            "from,to,transport,clock,delay,seq,sent_us,delay_us",
            "A,B,fixed,virtual,one-way,0,0.000,5000.000",
            "A,B,fixed,virtual,round-trip,0,0.000,10000.000",
        ]
    );
    // The probes of a pair go every 1/rate = 20 ms.
    assert!(
        samples.contains("\nA,B,fixed,virtual,one-way,1,20000.000,5000.000\n"),
        "{samples}"
    );

    let second = latency(&args, &out);
    assert!(second.status.success());
    assert_eq!(String::from_utf8(second.stdout).unwrap(), expected);
    assert_eq!(
        std::fs::read_to_string(out.join("samples.csv")).unwrap(),
        samples
    );
}

#[test]
fn csv_output_is_the_summary() {
    let dir = out_dir("latency-csv");
    let fleet = fixed_fleet(&dir.join("in"));
    let out = dir.join("out");
    let mut args = vec!["--fleet", fleet.to_str().unwrap(), "--format", "csv"];
    args.extend(SETTINGS);
    let o = latency(&args, &out);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let stdout = String::from_utf8(o.stdout).unwrap();
    assert_eq!(
        stdout,
        "\
from,to,transport,return_transport,clock,delay,sent,refused,count,lost,min_us,mean_us,p50_us,p90_us,p99_us,p999_us,max_us,achieved_rate_hz
A,B,fixed,fixed,virtual,one-way,20,0,20,0,5000.000,5000.000,5000.000,5000.000,5000.000,5000.000,5000.000,50.000
A,B,fixed,fixed,virtual,round-trip,20,0,20,0,10000.000,10000.000,10000.000,10000.000,10000.000,10000.000,10000.000,50.000
A,C,fixed,,virtual,one-way,20,0,20,0,5000.000,5000.000,5000.000,5000.000,5000.000,5000.000,5000.000,50.000
B,A,fixed,fixed,virtual,one-way,20,0,20,0,5000.000,5000.000,5000.000,5000.000,5000.000,5000.000,5000.000,50.000
B,A,fixed,fixed,virtual,round-trip,20,0,20,0,10000.000,10000.000,10000.000,10000.000,10000.000,10000.000,10000.000,50.000
"
    );
    assert_eq!(
        std::fs::read_to_string(out.join("summary.csv")).unwrap(),
        stdout
    );
    // The paths go to stderr with the wall time, so stdout is the CSV alone.
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(
        stderr.contains("wrote ") && stderr.contains("wall time: "),
        "{stderr}"
    );
}

#[test]
fn against_the_thesis_prints_its_figures_beside_ours() {
    let out = out_dir("latency-thesis");
    let o = latency(
        &["--against-thesis", "--messages", "30", "--format", "json"],
        &out,
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["experiment"], "latency");
    assert_eq!(v["fleet"], "thesis-5.1-leader-follower");
    assert_eq!(v["against_thesis"], true);
    let pairs = v["pairs"].as_array().unwrap();
    assert_eq!(pairs.len(), 10, "Table 7's ordered pairs");
    let pair = |from: &str, to: &str| {
        pairs
            .iter()
            .find(|p| p["from"] == from && p["to"] == to)
            .unwrap_or_else(|| panic!("{from} → {to}"))
    };
    assert!(pair("Alpha", "Charlie")["thesis"]
        .as_str()
        .unwrap()
        .starts_with("Table 12"));
    assert!(pair("Charlie", "Tango")["thesis"]
        .as_str()
        .unwrap()
        .contains("0–2 s"));
    assert!(pair("Tango", "VirtualEnv3")["thesis"]
        .as_str()
        .unwrap()
        .starts_with("none"));
    assert_eq!(pair("Alpha", "Charlie")["one_way"]["p50_us"], 101.0);
    assert!(v["clock_methods"]["virtual"].is_string());
    assert!(out.join("fleet/fleet.toml").is_file());
    assert!(out.join("fleet/table7-table.txt").is_file());
}

#[test]
fn bad_arguments_are_clear_errors() {
    let dir = out_dir("latency-bad");
    let fleet = fixed_fleet(&dir.join("in"));
    let f = fleet.to_str().unwrap();
    let fail = |args: &[&str]| {
        let o = latency(args, &dir.join("out"));
        assert!(!o.status.success(), "{args:?} must fail");
        String::from_utf8(o.stderr).unwrap()
    };
    assert_eq!(
        fail(&[]),
        "error: say what to measure: --fleet FILE (e.g. examples/leader_follower/fleet.toml) or \
         --against-thesis (the thesis's §5.1 fleet)\n"
    );
    assert_eq!(
        fail(&["--fleet", f, "--size", "2"]),
        "error: --size must be at least 4 bytes (the probe's sequence number), got 2\n"
    );
    assert_eq!(
        fail(&["--fleet", f, "--messages", "0"]),
        "error: --messages must be at least 1\n"
    );
    assert_eq!(
        fail(&["--fleet", f, "--rate", "0"]),
        "error: --rate must be a number of messages per second in (0, 1000000], got 0\n"
    );
    let e = fail(&["--fleet", f, "--rate", "fast"]);
    assert!(e.contains("invalid value 'fast' for '--rate"), "{e}");
    let e = fail(&["--fleet", f, "--pair", "A-B"]);
    assert!(
        e.contains("expected FROM:TO (two system names), got `A-B`"),
        "{e}"
    );
    assert_eq!(
        fail(&["--fleet", f, "--pair", "C:A"]),
        "error: --pair C:A: the table has no traffic from C to A (X)\n"
    );
    let e = fail(&["--fleet", f, "--against-thesis"]);
    assert!(e.contains("cannot be used with"), "{e}");
    let e = fail(&["--fleet", "/nonexistent/fleet.toml"]);
    assert!(
        e.contains("/nonexistent/fleet.toml") && e.contains("cannot read the fleet file"),
        "{e}"
    );
}
