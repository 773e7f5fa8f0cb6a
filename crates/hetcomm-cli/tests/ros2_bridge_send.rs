//! Acceptance test of the `ros2_bridge` with one `hetcomm send` process per message (issue
//! 40): each process opens the bridge, publishes one Twist and exits, and a Cyclone DDS
//! (Python) reader that was running before gets every one; a message that does not convert
//! fails once with its own reason. Before the bridge waited for matched readers and for
//! acknowledgements, each send said "sent" and the reader got none.
//!
//! Compiled only with the `ros2` feature; the Python with `cyclonedds` is
//! `$HETCOMM_ROS2_PYTHON` (scripts/ros2-test.sh sets both up): `cargo test -p hetcomm-cli
//! --features ros2 --test ros2_bridge_send`.
#![cfg(feature = "ros2")]

mod support;

use support::*;

/// How many fresh `hetcomm send` processes the test runs.
const SENDS: usize = 20;

#[test]
fn one_shot_sends_through_the_ros2_bridge_reach_a_running_reader() {
    let python = std::env::var("HETCOMM_ROS2_PYTHON").expect(
        "set HETCOMM_ROS2_PYTHON to a Python with the `cyclonedds` package \
         (bash scripts/ros2-test.sh does)",
    );
    let deadline = Deadline::after(120);
    let dir = TempDir::new("ros2-bridge-send");
    let topic = format!("/cli2_{}/cmd_vel", std::process::id());
    let domain = 79;
    let fleet = dir.write(
        "fleet.toml",
        &format!(
            r#"
[systems]
Alpha = 0
Tango = 4

[modules]
Drive = 1

[transports.tango_ros]
kind = "ros2_bridge"
robot = "Tango"
domain_id = {domain}
delivery = "unacknowledged"
security = "none"

[transports.tango_ros.publish]
"{topic}" = "Drive 40 geometry_msgs/Twist"

[table]
columns = ["Alpha", "Tango"]
Alpha = ["X", "tango_ros"]
Tango = ["tango_ros", "X"]
"#
        ),
    );
    let examples = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../examples/ros2");
    // The rover's types and ROS 2's default QoS; invalid samples (a writer went away) skipped.
    let script = format!(
        "import sys, time\n\
         sys.path.insert(0, {examples:?})\n\
         from tango_rover import Twist, ros2_qos, DomainParticipant, Topic, DataReader\n\
         dp = DomainParticipant({domain})\n\
         qos = ros2_qos()\n\
         reader = DataReader(dp, Topic(dp, 'rt{topic}', Twist, qos=qos), qos=qos)\n\
         print('ready', flush=True)\n\
         while True:\n    \
             for s in reader.take(N=16):\n        \
                 if hasattr(s, 'linear'):\n            \
                     print(int(s.linear.x), flush=True)\n    \
             time.sleep(0.005)\n"
    );
    let mut reader = std::process::Command::new(python);
    reader.args(["-c", &script]);
    let reader = ChildGuard::spawn("Cyclone DDS reader", reader);
    while reader.stdout_lines().is_empty() {
        assert!(!deadline.passed(), "the reader did not start");
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
    assert_eq!(reader.stdout_lines(), ["ready"]);
    let send = |json: &str| {
        let mut cmd = std::process::Command::new(HETCOMM);
        cmd.arg("send")
            .arg(&fleet)
            .args([
                "--as", "Alpha", "--to", "Tango", "--module", "Drive", "--type", "40",
            ])
            .args(["--json", json, "--timeout", "20"]);
        run("send through the bridge", cmd, deadline)
    };
    for i in 0..SENDS {
        let json = format!(
            r#"{{"linear":{{"x":{i}.0,"y":0.0,"z":0.0}},"angular":{{"x":0.0,"y":0.0,"z":0.0}}}}"#
        );
        let sent = send(&json);
        assert_eq!(
            sent.stdout,
            ["Tango: sent without confirmation (attempts: 1)"],
            "send {i}: {sent:?}"
        );
        assert_eq!(sent.status.code(), Some(0), "send {i}: {sent:?}");
    }
    let want: Vec<String> = std::iter::once("ready".to_string())
        .chain((0..SENDS).map(|i| i.to_string()))
        .collect();
    while reader.stdout_lines().len() < want.len() && !deadline.passed() {
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
    assert_eq!(reader.stdout_lines(), want, "what the reader got");

    let bad = send(r#"{"speed":1.0}"#);
    assert_eq!(
        bad.stdout,
        [
            "Tango: failed: message type 40 for Drive does not convert to geometry_msgs/Twist: \
          field `speed` has no counterpart in geometry_msgs/Twist (attempts: 1)"
        ],
        "{bad:?}"
    );
    assert_eq!(bad.status.code(), Some(1), "{bad:?}");
}
