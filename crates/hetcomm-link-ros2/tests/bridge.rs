//! The `ros2_bridge` kind against a foreign ROS 2 node: examples/ros2/tango_rover.py, a rover
//! written with Cyclone DDS's Python package (no ROS 2, no hetcomm). Alpha (hetcomm) drives
//! Tango with Twist commands and sees it move through its Odometry; a String goes there and
//! back; garbage and a publisher of the wrong type on a mapped topic are counted and reported.
//!
//! The Python interpreter with `cyclonedds` is `$HETCOMM_ROS2_PYTHON` (scripts/ros2-test.sh
//! sets it up); the fleet-file tests need no Python.

use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use hetcomm::Comm;

#[path = "../../hetcomm-rosmsg/tests/support/rover.rs"]
mod tango;
use tango::{drive_and_talk, mappings_and_table, Odom};

fn fleet_text(prefix: &str, domain: u16, extra: &str) -> String {
    format!(
        r#"[systems]
Alpha = 0
Tango = 4
[modules]
Drive = 1
World = 2
[transports.tango_ros]
kind = "ros2_bridge"
robot = "Tango"
domain_id = {domain}
delivery = "unacknowledged"
security = "none"
{extra}
{}"#,
        mappings_and_table(prefix, "")
    )
}

#[test]
fn mappings_parse_and_their_mistakes_are_located() {
    let ok = hetcomm::parse_fleet(&fleet_text("/t", 0, ""), "b.toml", None).expect("valid");
    let hetcomm::config::TransportSettings::Registered(s) = &ok.transports[0].settings else {
        panic!("registered settings expected");
    };
    let b: &hetcomm_link_ros2::bridge::BridgeSettings = s.downcast_ref().unwrap();
    assert_eq!(b.robot, "Tango");
    assert_eq!(b.publish.len(), 3);
    assert_eq!(b.subscribe[0].ros_type(), "nav_msgs/Odometry");
    assert_eq!(b.subscribe[0].message, 41);

    let errors = |text: String| {
        hetcomm::parse_fleet(&text, "b.toml", None)
            .unwrap_err()
            .to_string()
    };
    let t = fleet_text("/t", 0, "").replace("nav_msgs/Odometry", "nav_msgs/Path");
    let e = errors(t);
    assert!(
        e.starts_with("b.toml:19:13: mapping of `/t/odom`: this build does not know the ROS type `nav_msgs/Path`"),
        "{e}"
    );
    assert!(
        e.contains("known types: std_msgs/String, std_msgs/Float64"),
        "{e}"
    );
    let e = errors(
        fleet_text("/t", 0, "")
            .replace("\"Drive 42 std_msgs/String\"", "\"Drive std_msgs/String\""),
    );
    assert!(
        e.contains("b.toml:16:12: mapping of `/t/say` must have three parts"),
        "{e}"
    );
    let e = errors(fleet_text("/t", 0, "").replace("delivery = \"unacknowledged\"\n", ""));
    assert!(
        e.contains("carries plain ROS messages, which nobody acknowledges")
            && e.contains("add `delivery = \"unacknowledged\"`"),
        "{e}"
    );
    let e = errors(fleet_text("/t", 0, "").replace("security = \"none\"\n", ""));
    assert!(
        e.contains("a ROS node cannot open hetcomm's secured sessions"),
        "{e}"
    );
    let e = errors(fleet_text("t", 0, ""));
    assert!(
        e.contains("`t/cmd_vel` is not a ROS 2 topic name: it must start with `/`"),
        "{e}"
    );
}

#[test]
fn opening_names_an_unknown_module() {
    let text = fleet_text("/t", 0, "").replace("\"World 41", "\"Wrold 41");
    let fleet = hetcomm::parse_fleet(&text, "b.toml", None).expect("valid");
    let e = Comm::open_fleet(&fleet, "Alpha")
        .err()
        .expect("open fails")
        .to_string();
    assert!(
        e.contains("the mapping of /t/odom names module `Wrold`, which is not in [modules]"),
        "{e}"
    );
}

#[test]
fn declared_types_that_do_not_fit_refuse_to_open() {
    let fleet = hetcomm::parse_fleet(&fleet_text("/t", 0, ""), "b.toml", None).expect("valid");
    tango::declared_types_are_checked_when_the_bridge_opens(&fleet);
}

/// The rover process, killed when dropped.
struct Rover(Child);

impl Drop for Rover {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn rover(prefix: &str, domain: u16, extra: &[&str]) -> Rover {
    let python = std::env::var("HETCOMM_ROS2_PYTHON").expect(
        "set HETCOMM_ROS2_PYTHON to a Python with the `cyclonedds` package \
         (bash scripts/ros2-test.sh does)",
    );
    let script =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../examples/ros2/tango_rover.py");
    let child = Command::new(python)
        .arg(script)
        .args([
            "--domain",
            &domain.to_string(),
            "--prefix",
            prefix,
            "--seconds",
            "60",
        ])
        .args(extra)
        .stdout(Stdio::null())
        .spawn()
        .expect("start the Python rover");
    Rover(child)
}

fn prefix(tag: &str) -> String {
    format!("/hc_{}_{tag}", std::process::id())
}

#[test]
fn a_cyclone_dds_rover_follows_twist_commands_and_reports_odometry() {
    let (p, domain) = (prefix("drive"), 71);
    let fleet = hetcomm::parse_fleet(&fleet_text(&p, domain, ""), "b.toml", None).expect("valid");
    let alpha = Comm::open_fleet(&fleet, "Alpha").expect("open Alpha");
    let (drive, world) = (
        alpha.module("Drive").unwrap(),
        alpha.module("World").unwrap(),
    );
    let _rover = rover(&p, domain, &[]);

    // Odometry arrives as a typed message from Tango (the rover is at rest at first).
    let first = world
        .recv_timeout::<Odom>(Duration::from_secs(20))
        .expect("odometry from the rover");
    assert_eq!(first.message.child_frame_id, "base_link");
    assert_eq!(first.envelope.source().system, hetcomm::SystemId(4));

    // Twist commands drive it (outcome Sent), a String goes there and back, a command that
    // does not fit Twist fails naming both types and the field.
    drive_and_talk(&drive, &world);
}

#[test]
fn garbage_and_wrong_types_on_a_mapped_topic_are_counted_not_delivered() {
    let (p, domain) = (prefix("bad"), 72);
    let fleet = hetcomm::parse_fleet(&fleet_text(&p, domain, ""), "b.toml", None).expect("valid");
    let alpha = Comm::open_fleet(&fleet, "Alpha").expect("open Alpha");
    let world = alpha.module("World").unwrap();
    let _rover = rover(&p, domain, &["--garbage", "20", "--wrong-type"]);
    // Good odometry keeps arriving, nothing else reaches the module, and both the garbage
    // samples and the String publisher are counted as dropped.
    let deadline = Instant::now() + Duration::from_secs(20);
    let mut good = 0;
    loop {
        let dropped = alpha.stats().links[0].1.frames_dropped;
        if good >= 20 && dropped >= 2 {
            break;
        }
        assert!(
            Instant::now() < deadline,
            "good = {good}, dropped = {dropped}: {:?}",
            alpha.stats()
        );
        if let Ok(r) = world.recv_timeout::<Odom>(Duration::from_millis(100)) {
            assert_eq!(r.message.child_frame_id, "base_link");
            good += 1;
        }
    }
    assert!(world
        .try_recv_raw()
        .is_none_or(|m| m.envelope.message_type().0 == 41));
}

#[test]
fn a_system_that_does_not_host_a_subscribed_module_does_not_read_its_topic() {
    let (p, domain) = (prefix("hosts"), 73);
    let text = tango::with_bravo_watching(&fleet_text(&p, domain, ""));
    let fleet = hetcomm::parse_fleet(&text, "b.toml", None).expect("valid");
    let alpha = Comm::open_fleet(&fleet, "Alpha").expect("open Alpha");
    let bravo = Comm::open_fleet(&fleet, "Bravo").expect("open Bravo");
    let _rover = rover(&p, domain, &[]);
    tango::only_the_hosting_system_reads_the_topic(&alpha, &bravo, Duration::from_secs(20));
}

#[test]
fn the_registry_names_the_bridged_robot() {
    let fleet = hetcomm::parse_fleet(&fleet_text("/t", 0, ""), "b.toml", None).expect("valid");
    assert_eq!(hetcomm::registry().bridged_robots(&fleet), ["Tango"]);
    // A `ros2` transport links hetcomm systems: nobody is bridged.
    let plain = fleet_text("/t", 0, "")
        .replace("kind = \"ros2_bridge\"\nrobot = \"Tango\"", "kind = \"ros2\"")
        .split("[transports.tango_ros.publish]")
        .next()
        .unwrap()
        .to_string()
        + "[table]\ncolumns = [\"Alpha\", \"Tango\"]\nAlpha = [\"X\", \"tango_ros\"]\nTango = [\"tango_ros\", \"X\"]\n";
    let fleet = hetcomm::parse_fleet(&plain, "p.toml", None).expect("valid");
    assert!(hetcomm::registry().bridged_robots(&fleet).is_empty());
}

/// A Cyclone DDS (Python) reader of `topic`'s `geometry_msgs/Twist` on `domain`, with ROS 2's
/// default QoS (the rover's types and QoS), printing each sample's `linear.x` (not the
/// invalid samples that say a writer went away); running (its
/// reader created) when this returns. Its stdout lines come out of the receiver.
fn twist_reader(topic: &str, domain: u16) -> (Rover, std::sync::mpsc::Receiver<String>) {
    use std::io::BufRead;
    let python = std::env::var("HETCOMM_ROS2_PYTHON").expect(
        "set HETCOMM_ROS2_PYTHON to a Python with the `cyclonedds` package \
         (bash scripts/ros2-test.sh does)",
    );
    let examples = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../examples/ros2");
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
                     print(s.linear.x, flush=True)\n    \
             time.sleep(0.005)\n"
    );
    let mut child = Command::new(python)
        .args(["-c", &script])
        .stdout(Stdio::piped())
        .spawn()
        .expect("start the Python reader");
    let stdout = child.stdout.take().expect("piped");
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        for line in std::io::BufReader::new(stdout)
            .lines()
            .map_while(Result::ok)
        {
            let _ = tx.send(line);
        }
    });
    let reader = Rover(child);
    let first = rx.recv_timeout(Duration::from_secs(30));
    assert_eq!(
        first.as_deref(),
        Ok("ready"),
        "the Python reader did not start"
    );
    (reader, rx)
}

/// Issue 40: a hetcomm system that opens, sends one message through the bridge and closes at
/// once (what `hetcomm send` does) must reach a reader that was already running. Before the
/// bridge waited for matched readers (and for acknowledgements when closing), each send said
/// Sent and the reader got none: the sample was written before discovery matched it.
#[test]
fn a_one_shot_send_through_the_bridge_reaches_a_running_cyclone_reader_20_of_20() {
    let (p, domain) = (prefix("oneshot"), 75);
    let (_reader, lines) = twist_reader(&format!("{p}/cmd_vel"), domain);
    let fleet = hetcomm::parse_fleet(&fleet_text(&p, domain, ""), "b.toml", None).expect("valid");
    const SENDS: usize = 20;
    for i in 0..SENDS {
        let alpha = Comm::open_fleet(&fleet, "Alpha").expect("open Alpha");
        let drive = alpha.module("Drive").unwrap();
        let cmd = tango::Drive {
            linear: tango::Vector3 {
                x: i as f64,
                ..Default::default()
            },
            angular: tango::Vector3::default(),
        };
        let outcome = drive.send("Tango", "Drive", &cmd).expect("send").wait();
        assert!(
            matches!(outcome, hetcomm::Outcome::Sent { attempts: 1 }),
            "send {i}: {outcome:?}"
        );
        drop(drive);
        drop(alpha);
    }
    let mut got = Vec::new();
    let deadline = Instant::now() + Duration::from_secs(10);
    while got.len() < SENDS {
        let left = deadline.saturating_duration_since(Instant::now());
        let Ok(line) = lines.recv_timeout(left) else {
            break;
        };
        got.push(line.trim().parse::<f64>().expect("a number") as usize);
    }
    assert_eq!(got, (0..SENDS).collect::<Vec<_>>(), "arrived at the reader");
}

/// A send on a topic nobody reads fails, saying so, within its bound (`connect_timeout_ms`
/// per attempt): Sent would claim what nobody could receive.
#[test]
fn a_send_with_no_subscriber_fails_saying_so_within_the_bound() {
    let (p, domain) = (prefix("nobody"), 76);
    let text = fleet_text(&p, domain, "connect_timeout_ms = 300");
    let fleet = hetcomm::parse_fleet(&text, "b.toml", None).expect("valid");
    let alpha = Comm::open_fleet(&fleet, "Alpha").expect("open Alpha");
    let drive = alpha.module("Drive").unwrap();
    let cmd = tango::Drive {
        linear: tango::Vector3::default(),
        angular: tango::Vector3::default(),
    };
    let started = Instant::now();
    let outcome = drive.send("Tango", "Drive", &cmd).expect("send").wait();
    let took = started.elapsed();
    let hetcomm::Outcome::Failed {
        reason: hetcomm::FailReason::Unreachable(why),
        attempts,
    } = &outcome
    else {
        panic!("expected failed, unreachable: {outcome:?}");
    };
    assert_eq!(why, &format!("no subscriber on {p}/cmd_vel within 300 ms"));
    let least = Duration::from_millis(300 * u64::from(*attempts));
    assert!(took >= least, "took {took:?}");
    assert!(took < least + Duration::from_secs(3), "took {took:?}");
}

/// A message that does not convert to its topic's type fails once, with the conversion as
/// its reason (not "peer unreachable", and not retried: it never converts).
#[test]
fn a_conversion_error_fails_once_with_its_own_reason() {
    let (p, domain) = (prefix("convert"), 77);
    let fleet = hetcomm::parse_fleet(&fleet_text(&p, domain, ""), "b.toml", None).expect("valid");
    let alpha = Comm::open_fleet(&fleet, "Alpha").expect("open Alpha");
    let drive = alpha.module("Drive").unwrap();
    let bad = tango::BadDrive {
        speed: 1.0,
        angular: tango::Vector3::default(),
    };
    tango::conversion_fails_once(&drive, &bad);
}
