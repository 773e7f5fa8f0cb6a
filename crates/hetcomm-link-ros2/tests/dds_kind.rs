//! The `dds` kind (issue 40): a robot that runs plain DDS, here a Cyclone DDS Python
//! participant with an IDL type of its own (`fleet::Command`, tests/py/typed_reader.py), in
//! the fleet through typed topics named as it names them: no `rt/` prefix, no ROS type
//! mangling, the DDS type name set per topic. Its fleet keys and their located errors too.
//!
//! The Python interpreter with `cyclonedds` is `$HETCOMM_ROS2_PYTHON` (scripts/ros2-test.sh).

use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Command as Process, Stdio};
use std::sync::mpsc;
use std::time::Duration;

use hetcomm::{Comm, Message, Outcome};
use serde::{Deserialize, Serialize};

#[derive(Serialize, Deserialize, Message, Debug, Clone, PartialEq)]
#[message(id = 40)]
struct Command {
    speed: f64,
    turn: f64,
    note: String,
}

#[derive(Serialize, Deserialize, Message, Debug, Clone, PartialEq)]
#[message(id = 41)]
struct Answer {
    speed: f64,
    turn: f64,
    note: String,
}

fn fleet_text(domain: u16, tag: &str, types: &str) -> String {
    format!(
        r#"[systems]
Alpha = 0
Tango = 4
[modules]
Drive = 1
World = 2
[transports.plain]
kind = "dds"
robot = "Tango"
domain_id = {domain}
delivery = "unacknowledged"
security = "none"
msg_paths = ["msg"]
[transports.plain.publish]
"fleet_command_{tag}" = "Drive 40 fleet_msgs/Command"
[transports.plain.subscribe]
"fleet_answer_{tag}" = "World 41 fleet_msgs/Command"
[transports.plain.dds_types]
{types}
[table]
columns = ["Alpha", "Tango"]
Alpha = ["X", "plain"]
Tango = ["plain", "X"]
"#
    )
}

fn tests_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests")
}

fn parse(text: &str) -> Result<hetcomm::config::Fleet, String> {
    hetcomm::parse_fleet(text, "d.toml", Some(&tests_dir())).map_err(|e| e.to_string())
}

#[test]
fn the_keys_parse_and_a_mistake_in_dds_types_is_located() {
    let types = "\"fleet_command_k\" = \"fleet::Command\"";
    let fleet = parse(&fleet_text(3, "k", types)).expect("valid");
    let hetcomm::config::TransportSettings::Registered(s) = &fleet.transports[0].settings else {
        panic!("registered settings expected");
    };
    let d: &hetcomm_link_ros2::bridge::dds::DdsSettings = s.downcast_ref().expect("dds settings");
    assert_eq!(d.bridge.robot, "Tango");
    assert_eq!(d.bridge.publish[0].topic, "fleet_command_k");
    assert_eq!(d.types["fleet_command_k"], "fleet::Command");

    let e = parse(&fleet_text(3, "k", "\"nowhere\" = \"fleet::Command\"")).unwrap_err();
    assert!(
        e.starts_with("d.toml:19:13: `dds_types` names topic `nowhere`, which no `publish` or `subscribe` entry maps"),
        "{e}"
    );
    let e = parse(&fleet_text(
        3,
        "k",
        "\"fleet_command_k\" = \"fleet:Command\"",
    ))
    .unwrap_err();
    assert!(e.contains("`fleet:Command` is not a DDS type name"), "{e}");
    let e =
        parse(&fleet_text(3, "k", "").replace("\"fleet_command_k\"", "\"/fleet\"")).unwrap_err();
    assert!(e.contains("`/fleet` is not a ROS 2 topic name"), "{e}");
}

#[test]
fn a_plain_dds_participant_with_its_own_idl_type_reads_and_answers() {
    let python = std::env::var("HETCOMM_ROS2_PYTHON").expect(
        "set HETCOMM_ROS2_PYTHON to a Python with the `cyclonedds` package \
         (scripts/ros2-test.sh does: target/py-venv/bin/python)",
    );
    let domain = 60 + (std::process::id() % 30) as u16;
    let tag = format!("p{}", std::process::id());
    let types = format!(
        "\"fleet_command_{tag}\" = \"fleet::Command\"\n\"fleet_answer_{tag}\" = \"fleet::Command\""
    );
    let fleet = parse(&fleet_text(domain, &tag, &types)).expect("valid");
    let mut robot = Process::new(python)
        .arg(tests_dir().join("py/typed_reader.py"))
        .args(["--domain", &domain.to_string(), "--type", "command"])
        .args(["--topic", &format!("fleet_command_{tag}")])
        .args([
            "--answer",
            &format!("fleet_answer_{tag}"),
            "--seconds",
            "60",
        ])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .expect("the Cyclone DDS participant");
    let (tx, lines) = mpsc::channel();
    let out = robot.stdout.take().unwrap();
    std::thread::spawn(move || {
        for line in BufReader::new(out).lines().map_while(Result::ok) {
            let _ = tx.send(line);
        }
    });
    assert_eq!(
        lines.recv_timeout(Duration::from_secs(30)).as_deref(),
        Ok("ready")
    );
    let alpha = Comm::open_fleet(&fleet, "Alpha").expect("open Alpha");
    let (drive, world) = (
        alpha.module("Drive").unwrap(),
        alpha.module("World").unwrap(),
    );
    let cmd = Command {
        speed: 1.5,
        turn: -0.25,
        note: "go".into(),
    };
    // The first send waits for the robot's reader: it arrives.
    let outcome = drive.send("Tango", "Drive", &cmd).expect("send").wait();
    assert_eq!(outcome, Outcome::Sent { attempts: 1 });
    assert_eq!(
        lines.recv_timeout(Duration::from_secs(20)).as_deref(),
        Ok("1.5 go"),
        "what the robot read"
    );
    let answer = world
        .recv_timeout::<Answer>(Duration::from_secs(20))
        .expect("the robot's answer");
    assert_eq!(
        answer.message,
        Answer {
            speed: 3.0,
            turn: -0.25,
            note: "answer".into()
        }
    );
    assert_eq!(answer.envelope.source().system, hetcomm::SystemId(4));
    drop(robot.stdin.take());
    let _ = robot.wait();
}
