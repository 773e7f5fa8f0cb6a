//! `--foxglove` where it cannot serve: refused with what to do, before anything runs (the
//! live view itself is tested by scripts/foxglove-test.sh, with the feature).

use std::path::PathBuf;
use std::process::Command;

fn hetcomm(args: &[&str]) -> (Option<i32>, String, String) {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..");
    let output = Command::new(env!("CARGO_BIN_EXE_hetcomm"))
        .current_dir(root)
        .args(args)
        .env_remove("HETCOMM_MONITOR")
        .output()
        .expect("hetcomm runs");
    (
        output.status.code(),
        String::from_utf8_lossy(&output.stdout).into_owned(),
        String::from_utf8_lossy(&output.stderr).into_owned(),
    )
}

#[test]
fn a_virtual_time_demo_is_not_served_live() {
    let (code, stdout, stderr) = hetcomm(&["demo", "--foxglove", "127.0.0.1:0"]);
    assert_eq!(code, Some(1), "{stdout}{stderr}");
    assert!(stdout.is_empty(), "no run: {stdout}");
    assert_eq!(
        stderr.trim(),
        "error: --foxglove serves a run while it happens: add --realtime (a virtual-time run is \
         over in milliseconds; to look at one in Foxglove, --record FILE and open the file)"
    );
}

#[test]
fn a_simulated_replay_is_not_served_live() {
    let (code, stdout, stderr) = hetcomm(&[
        "replay",
        "no-such.mcap",
        "--into",
        "examples/leader_follower/fleet.toml",
        "--sim",
        "--foxglove",
        "127.0.0.1:0",
    ]);
    assert_eq!(code, Some(1), "{stdout}{stderr}");
    assert_eq!(
        stderr.trim(),
        "error: --foxglove serves a live replay while it happens; a replay --sim runs in virtual \
         time, as fast as it computes: leave out --sim or --foxglove"
    );
}

/// A build without the feature refuses the flag instead of ignoring it, before the run.
#[cfg(not(feature = "foxglove"))]
#[test]
fn without_the_feature_the_flag_is_refused() {
    for args in [
        &["demo", "--realtime", "--foxglove", "127.0.0.1:0"][..],
        &[
            "listen",
            "examples/relay_chain.toml",
            "--insecure",
            "--as",
            "Charlie",
            "--foxglove",
            "127.0.0.1:0",
        ][..],
    ] {
        let (code, stdout, stderr) = hetcomm(args);
        assert_eq!(code, Some(1), "{args:?}: {stdout}{stderr}");
        assert!(
            stderr.trim_end().ends_with(
                "error: this build has no Foxglove server: rebuild this command with `cargo \
                 build --release -p hetcomm-cli --features foxglove`"
            ),
            "{args:?}: {stderr}"
        );
        assert!(!stderr.contains("listening as"), "{stderr}");
    }
}

/// With the feature, an address that is not one says so.
#[cfg(feature = "foxglove")]
#[test]
fn a_malformed_address_is_refused() {
    let (code, _, stderr) = hetcomm(&["demo", "--realtime", "--foxglove", "localhost"]);
    assert_eq!(code, Some(1), "{stderr}");
    assert!(
        stderr.contains("--foxglove localhost: expected host:port"),
        "{stderr}"
    );
}
