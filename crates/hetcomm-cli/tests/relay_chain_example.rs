//! The three-process relay chain example (`examples/relay_chain.rs`): Tango, Charlie and
//! Alpha as three OS processes on a copy of `examples/relay_chain.toml` whose fixed ports are
//! replaced by free ones; Tango must print the five commands in order. The same with
//! `examples/relay_chain_shm.toml` (Charlie ↔ Tango in shared memory): that one builds the
//! example with the `shm` feature (iceoryx2), which `cargo test --workspace` never compiles,
//! so it is ignored here and run by `scripts/shm-test.sh`.
//!
//! The example binary belongs to another package (`hetcomm-examples`), which `cargo test -p
//! hetcomm-cli` does not build, so the test builds it with the cargo that runs the tests
//! (`$CARGO`; cargo does not hold its build lock while tests run) and takes the executable's
//! path from cargo's JSON messages. A test binary run without cargo uses the cargo that built
//! it (cargo sets `CARGO` at compile time too), so the test runs wherever it is run.

mod support;

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use support::*;

/// Builds the example with `features` and returns its executable's path.
fn build_example(features: &str, deadline: Deadline) -> PathBuf {
    let cargo = std::env::var_os("CARGO").unwrap_or_else(|| env!("CARGO").into());
    let manifest = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../examples/Cargo.toml");
    let mut cmd = Command::new(cargo);
    cmd.args(["build", "--example", "relay_chain", "--message-format=json"])
        .arg("--manifest-path")
        .arg(&manifest)
        .stdin(Stdio::null());
    if !features.is_empty() {
        cmd.args(["--features", features]);
    }
    let built = run("cargo build --example relay_chain", cmd, deadline);
    assert!(
        built.status.success(),
        "building the example failed: {built:?}"
    );
    built
        .stdout
        .iter()
        .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
        .filter(|m| m["reason"] == "compiler-artifact" && m["target"]["name"] == "relay_chain")
        .find_map(|m| m["executable"].as_str().map(PathBuf::from))
        .unwrap_or_else(|| panic!("cargo did not name the example's executable: {built:?}"))
}

#[test]
fn relay_chain_example_in_three_processes() {
    run_chain(
        "relay_chain.toml",
        "",
        &[
            (47310, "udp"),
            (47311, "udp"),
            (47320, "tcp"),
            (47321, "tcp"),
        ],
    );
}

#[test]
#[ignore = "builds iceoryx2 (the `shm` feature): run by scripts/shm-test.sh"]
fn relay_chain_example_with_an_shm_hop() {
    run_chain(
        "relay_chain_shm.toml",
        "shm",
        &[(47310, "udp"), (47311, "udp")],
    );
}

/// Runs the example's three systems on a copy of `examples/<fleet_file>` with its fixed
/// `ports` replaced by free ones (and a fleet name of its own, so that shared-memory services
/// of concurrent runs never meet), and checks what each printed.
fn run_chain(fleet_file: &str, features: &str, ports: &[(u16, &str)]) {
    // Building the example may take a while on a cold cache; the chain itself ~5 s.
    let deadline = Deadline::after(240);
    let exe = build_example(features, deadline);
    let deadline = Deadline::after(40);

    let original = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../examples")
            .join(fleet_file),
    )
    .unwrap();
    let mut text = original.clone();
    for &(fixed, kind) in ports {
        let from = format!("127.0.0.1:{fixed}");
        assert!(
            text.contains(&from),
            "the example fleet no longer uses {from}"
        );
        text = text.replace(&from, &format!("127.0.0.1:{}", free_port(kind)));
    }
    let name = text
        .lines()
        .find(|l| l.starts_with("name = "))
        .expect("the example fleet has a name")
        .to_string();
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.subsec_nanos())
        .unwrap_or(0);
    text = text.replace(
        &name,
        &format!("name = \"relay-{}-{nanos}\"", std::process::id()),
    );
    let dir = TempDir::new("relay");
    let fleet = dir.write("relay_chain.toml", &text);

    let start = |system: &str| {
        let mut cmd = Command::new(&exe);
        cmd.arg(system).arg(&fleet);
        let mut child = ChildGuard::spawn(system, cmd);
        child.wait_stdout(&format!("{system} ready on "), deadline);
        child
    };
    let mut tango = start("Tango");
    let mut charlie = start("Charlie");
    let mut alpha = start("Alpha");

    for child in [&mut alpha, &mut charlie, &mut tango] {
        let status = child.wait_exit(deadline);
        assert!(status.success(), "{} exited with {status}", child.name);
    }
    let got: Vec<String> = tango
        .stdout_lines()
        .into_iter()
        .filter(|l| l.starts_with("Tango: command "))
        .collect();
    assert_eq!(
        got,
        [
            r#"Tango: command 1/5 "advance 2 m" (via Charlie.Plan)"#,
            r#"Tango: command 2/5 "turn left" (via Charlie.Plan)"#,
            r#"Tango: command 3/5 "advance 1 m" (via Charlie.Plan)"#,
            r#"Tango: command 4/5 "turn right" (via Charlie.Plan)"#,
            r#"Tango: command 5/5 "stop" (via Charlie.Plan)"#,
        ]
    );
    let charlie_got = charlie
        .stdout_lines()
        .iter()
        .filter(|l| {
            l.starts_with("Charlie: got command ")
                && l.ends_with("from Alpha.Plan; forwarding to Tango")
        })
        .count();
    assert_eq!(charlie_got, 5, "{:?}", charlie.stdout_lines());
    let alpha_sent = alpha
        .stdout_lines()
        .iter()
        .filter(|l| {
            l.starts_with("Alpha: sent command ")
                && l.contains(": delivered to the inbox (attempts: ")
        })
        .count();
    assert_eq!(alpha_sent, 5, "{:?}", alpha.stdout_lines());
}
