//! Acceptance tests of the `ros2` transport and the `ros2_bridge` with one `hetcomm send`
//! process per message (issue 40): every send is the first message of a fresh DDS participant,
//! which discovery must have matched before it goes.
//!
//! * 50 fresh `hetcomm send` processes over `ros2` to a running `hetcomm listen`, each
//!   delivered on its first attempt (its acknowledgement is read at once, not after a
//!   retransmission), none received twice;
//! * 20 fresh `hetcomm send` processes through a `ros2_bridge` to a running Cyclone DDS reader
//!   (Cyclone DDS's Python package, `$HETCOMM_ROS2_PYTHON`), every one read;
//! * a bridge send that no reader matches fails, saying so, and one that does not convert
//!   fails at once with its own reason.
//!
//! Compiled only with the `ros2` feature: `cargo test -p hetcomm-cli --features ros2 --test
//! ros2_send` (scripts/ros2-test.sh).
#![cfg(feature = "ros2")]

mod support;

use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use support::*;

/// Fresh `hetcomm send` processes over `ros2`.
const SENDS: usize = 50;
/// Fresh `hetcomm send` processes through the bridge.
const BRIDGE_SENDS: usize = 20;

fn python() -> String {
    std::env::var("HETCOMM_ROS2_PYTHON").expect(
        "set HETCOMM_ROS2_PYTHON to a Python with the `cyclonedds` package \
         (scripts/ros2-test.sh does: target/py-venv/bin/python)",
    )
}

/// A domain id of its own for each test of this process.
fn domain(offset: u16) -> u16 {
    100 + (std::process::id() % 50) as u16 * 2 + offset
}

#[test]
fn fifty_fresh_acknowledged_sends_over_ros2_are_each_delivered_on_the_first_attempt() {
    let deadline = Deadline::after(400);
    let dir = TempDir::new("ros2-send");
    let ns = format!("/cli_{}", std::process::id());
    let fleet = dir.write(
        "fleet.toml",
        &format!(
            r#"
[systems]
Alpha = 1
Bravo = 2

[modules]
Plan = 1
Act = 2

[transports.dds]
kind = "ros2"
domain_id = {}
namespace = "{ns}"
delivery = "acknowledged"

[table]
columns = ["Alpha", "Bravo"]
Alpha   = ["X",     "dds"]
Bravo   = ["dds",   "X"]
"#,
            domain(0)
        ),
    );
    let count = SENDS.to_string();
    let mut bravo = listen(&fleet, "Bravo", &["--count", &count], deadline);
    let mut outputs = Vec::new();
    for i in 0..SENDS {
        let json = format!(r#"{{"code":{i},"text":"hello"}}"#);
        let sent = send(&fleet, "Alpha", "Bravo", &json, deadline);
        assert_eq!(sent.status.code(), Some(0), "send {i}: {sent:?}");
        assert!(
            !sent.stderr.iter().any(|l| l.contains("panicked")),
            "send {i}: {sent:?}"
        );
        assert_eq!(sent.stdout.len(), 1, "send {i}: {sent:?}");
        outputs.push(sent.stdout[0].clone());
    }
    let status = bravo.wait_exit(deadline.within(Duration::from_secs(30)));
    assert_eq!(status.code(), Some(0), "{:?}", bravo.stderr_lines());
    for o in &outputs {
        assert!(
            o.starts_with("Bravo: delivered to the inbox (attempts: 1, "),
            "not delivered on the first attempt: {o} (all: {outputs:#?})"
        );
    }
    let counters = counters_line(&bravo);
    let expected = format!("received {SENDS} messages; router: {SENDS} received, 0 duplicates, ");
    assert!(counters.starts_with(&expected), "{counters}");
}
/// Alpha and the ROS 2 robot Tango through a `ros2_bridge` publishing Twist on `topic`.
fn bridge_fleet(dir: &TempDir, domain_id: u16, topic: &str, extra: &str) -> PathBuf {
    let link = format!("domain_id = {domain_id}");
    twist_bridge_fleet(dir, "ros2_bridge", &link, topic, extra)
}

/// tests/py/typed_reader.py of the ros2 crate, its lines on a channel; killed when dropped.
struct Reader {
    child: Child,
    lines: mpsc::Receiver<String>,
}

impl Reader {
    fn start(domain_id: u16, dds_topic: &str) -> Reader {
        let script = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
            .join("../hetcomm-link-ros2/tests/py/typed_reader.py");
        let mut child = Command::new(python())
            .arg(script)
            .args(["--domain", &domain_id.to_string(), "--topic", dds_topic])
            .args(["--type", "twist", "--seconds", "300"])
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .spawn()
            .expect("the Cyclone DDS reader");
        let (tx, lines) = mpsc::channel();
        let out = child.stdout.take().unwrap();
        std::thread::spawn(move || {
            for line in BufReader::new(out).lines().map_while(Result::ok) {
                if tx.send(line).is_err() {
                    break;
                }
            }
        });
        let reader = Reader { child, lines };
        let ready = reader.lines.recv_timeout(Duration::from_secs(30));
        assert_eq!(ready.as_deref(), Ok("ready"), "the reader did not start");
        reader
    }
}

impl Drop for Reader {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

#[test]
fn twenty_one_shot_bridge_sends_reach_a_running_cyclone_dds_reader() {
    let deadline = Deadline::after(300);
    let dir = TempDir::new("ros2-bridge-send");
    let topic = format!("/hc_cli_{}/cmd_vel", std::process::id());
    let d = domain(1);
    let fleet = bridge_fleet(&dir, d, &topic, "");
    let reader = Reader::start(d, &format!("rt{topic}"));
    for i in 0..BRIDGE_SENDS {
        let sent = send_twist(&fleet, &twist(i), deadline);
        assert_eq!(
            sent.stdout,
            ["Tango: sent without confirmation (attempts: 1)"],
            "send {i}: {sent:?}"
        );
        assert_eq!(sent.status.code(), Some(0), "send {i}: {sent:?}");
    }
    let mut xs: Vec<usize> = Vec::new();
    let until = Instant::now() + Duration::from_secs(10);
    while xs.len() < BRIDGE_SENDS {
        let left = until.saturating_duration_since(Instant::now());
        let Ok(line) = reader.lines.recv_timeout(left) else {
            break;
        };
        xs.push(line.parse().expect("a number"));
    }
    assert_eq!(
        xs,
        (0..BRIDGE_SENDS).collect::<Vec<_>>(),
        "what the reader read"
    );
}

#[test]
fn a_bridge_send_no_reader_matches_and_one_that_does_not_convert_fail_with_their_reason() {
    let deadline = Deadline::after(120);
    let dir = TempDir::new("ros2-bridge-nobody");
    let topic = format!("/hc_cli_{}/nobody", std::process::id());
    let fleet = bridge_fleet(&dir, domain(1), &topic, "connect_timeout_ms = 150");
    let started = Instant::now();
    let sent = send_twist(&fleet, &twist(1), deadline);
    let took = started.elapsed();
    assert_eq!(
        sent.stdout,
        [format!(
            "Tango: failed: peer unreachable: no subscriber of {topic} matched within 150 ms \
             (nothing was published) (attempts: 3)"
        )],
        "{sent:?}"
    );
    assert_eq!(sent.status.code(), Some(1), "{sent:?}");
    assert!(took >= Duration::from_millis(3 * 150), "took {took:?}");

    assert_a_non_twist_is_refused_at_once(&fleet, deadline);
}
