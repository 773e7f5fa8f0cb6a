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
    let t = fleet_text("/t", 0, "").replace("nav_msgs/Odometry", "my_robot_msgs/Status");
    let e = errors(t);
    assert!(
        e.starts_with("b.toml:19:13: mapping of `/t/odom`: the ROS type `my_robot_msgs/Status` was not found: looked in "),
        "{e}"
    );
    assert!(
        e.contains("the definitions shipped with hetcomm (builtin_interfaces, diagnostic_msgs, "),
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
