//! Acceptance tests of the `ros1` transport with one system per process, against a real ROS
//! master (`rosmaster --core` on a free port; `bash scripts/ros1-test.sh` installs ROS and
//! runs these): `hetcomm listen` runs as one process and every `hetcomm send` is a fresh
//! process, so every send is the first message of a new ROS publisher — the case where ROS 1
//! drops what is published before the subscriber has connected (issue 20).
//!
//! Compiled only with the `ros1` feature: `cargo test -p hetcomm-cli --features ros1 --test
//! ros1_send`.
#![cfg(feature = "ros1")]

mod support;

#[path = "../../hetcomm-link-ros1/tests/common/mod.rs"]
mod ros;

use std::path::PathBuf;

use support::*;

/// How many fresh `hetcomm send` processes each test runs.
const SENDS: usize = 50;

/// A fleet of Alpha and Bravo over one `ros1` transport on `master`, in `dir` (`extra`: more
/// keys of the transport).
fn ros_fleet(dir: &TempDir, master: &ros::Master, delivery: &str, extra: &str) -> PathBuf {
    dir.write(
        "fleet.toml",
        &format!(
            r#"
[systems]
Alpha = 1
Bravo = 2

[modules]
Plan = 1
Act = 2

[transports.ros]
kind = "ros1"
master_uri = "{}"
namespace = "cli"
delivery = "{delivery}"
{extra}

[table]
columns = ["Alpha", "Bravo"]
Alpha   = ["X",     "ros"]
Bravo   = ["ros",   "X"]
"#,
            master.uri()
        ),
    )
}

/// Runs `listen --as Bravo --count 50` and 50 fresh `send --as Alpha --to Bravo` processes
/// one after the other; returns what each send printed, in order, and the listener's
/// counters line after it exited.
fn fifty_sends(delivery: &str) -> (Vec<String>, String, Vec<String>) {
    let master = ros::Master::start();
    let deadline = Deadline::after(300);
    let dir = TempDir::new(&format!("ros1-send-{delivery}"));
    let fleet = ros_fleet(&dir, &master, delivery, "");
    let count = SENDS.to_string();
    let mut bravo = listen(&fleet, "Bravo", &["--count", &count], deadline);
    let mut outputs = Vec::new();
    for i in 0..SENDS {
        let json = format!(r#"{{"code":{i},"text":"hello"}}"#);
        let sent = send(&fleet, "Alpha", "Bravo", &json, deadline);
        assert_eq!(sent.stdout.len(), 1, "send {i}: {sent:?}");
        assert_eq!(sent.status.code(), Some(0), "send {i}: {sent:?}");
        outputs.push(sent.stdout[0].clone());
    }
    let status = bravo.wait_exit(deadline.within(std::time::Duration::from_secs(20)));
    assert_eq!(status.code(), Some(0), "{:?}", bravo.stderr_lines());
    (outputs, counters_line(&bravo), bravo.stdout_lines())
}

/// The `code` field of each message Bravo printed, in order.
fn codes(lines: &[String]) -> Vec<usize> {
    lines
        .iter()
        .map(|l| message_text(l))
        .filter(|l| l.starts_with("Alpha.Plan -> Act  type=7 "))
        .map(|l| {
            let json = &l[l.find('{').expect("a JSON payload")..];
            let v: serde_json::Value = serde_json::from_str(json).expect("JSON");
            v["code"].as_u64().expect("code") as usize
        })
        .collect()
}

#[test]
fn fifty_fresh_acknowledged_sends_are_each_delivered_on_the_first_attempt() {
    let (outputs, counters, received) = fifty_sends("acknowledged");
    let latencies: Vec<&str> = outputs
        .iter()
        .map(|o| {
            assert!(
                o.starts_with("Bravo: delivered to the inbox (attempts: 1, ")
                    && o.ends_with(" µs)"),
                "not delivered on the first attempt: {o} (all: {outputs:#?})"
            );
            &o["Bravo: delivered to the inbox (attempts: 1, ".len()..o.len() - " µs)".len()]
        })
        .collect();
    eprintln!("acknowledged: {SENDS} sends, attempts 1 each; latencies µs: {latencies:?}");
    assert_eq!(codes(&received), (0..SENDS).collect::<Vec<_>>());
    // No duplicates: no send was transmitted twice.
    // Then the security layer's counters (one handshake per fresh sender).
    let expected = format!(
        "received {SENDS} messages; router: {SENDS} received, 0 duplicates, 0 too old, 0 malformed, \
         0 unknown origin, 0 misrouted, 0 unknown module; inboxes dropped 0; links dropped 0; \
         security: rejected_auth 0, rejected_replay 0, rejected_table 0, \
         rejected_unknown_sender 0, "
    );
    assert!(counters.starts_with(&expected), "{counters}");
}

#[test]
fn fifty_fresh_unacknowledged_sends_each_arrive_from_the_first_attempt() {
    let (outputs, counters, received) = fifty_sends("unacknowledged");
    for o in &outputs {
        assert_eq!(
            o, "Bravo: sent without confirmation (attempts: 1)",
            "(all: {outputs:#?})"
        );
    }
    // "sent" was true every time: Bravo got every one of them.
    assert_eq!(codes(&received), (0..SENDS).collect::<Vec<_>>());
    // Then the security layer's counters (one handshake per fresh sender).
    let expected = format!(
        "received {SENDS} messages; router: {SENDS} received, 0 duplicates, 0 too old, 0 malformed, \
         0 unknown origin, 0 misrouted, 0 unknown module; inboxes dropped 0; links dropped 0; \
         security: rejected_auth 0, rejected_replay 0, rejected_table 0, \
         rejected_unknown_sender 0, "
    );
    assert!(counters.starts_with(&expected), "{counters}");
}

#[test]
fn a_send_to_a_system_that_is_not_running_says_so() {
    let master = ros::Master::start();
    let deadline = Deadline::after(60);
    let dir = TempDir::new("ros1-send-nobody");
    // The default wait, and one set in the fleet file.
    for (delivery, extra, ms) in [
        ("acknowledged", "", 500),
        ("unacknowledged", "", 500),
        ("acknowledged", "connect_timeout_ms = 150", 150),
    ] {
        let fleet = ros_fleet(&dir, &master, delivery, extra);
        let started = std::time::Instant::now();
        let sent = send(&fleet, "Alpha", "Bravo", r#"{"code":1}"#, deadline);
        let took = started.elapsed();
        assert_eq!(
            sent.stdout,
            [format!(
                "Bravo: failed: peer unreachable: the subscriber of \
                 /cli/Bravo did not connect within {ms} ms (no node subscribes to /cli/Bravo) \
                 (attempts: 3)"
            )],
            "{delivery} {extra}: {sent:?}"
        );
        assert_eq!(sent.status.code(), Some(1), "{delivery}: {sent:?}");
        // Three attempts of `ms` each, plus starting the process.
        let least = std::time::Duration::from_millis(3 * ms);
        assert!(took >= least, "{delivery} {extra}: took {took:?}");
    }
}
