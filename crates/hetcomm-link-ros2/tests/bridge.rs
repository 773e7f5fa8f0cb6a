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

/// The bridge of `fleet_text(prefix, domain)` opened on Alpha by itself, with a sink that
/// keeps what it receives.
fn open_bridge(
    prefix: &str,
    domain: u16,
) -> (
    hetcomm_link_ros2::bridge::Ros2Bridge,
    std::sync::Arc<hetcomm_link::conformance::CollectSink>,
) {
    let fleet = hetcomm::parse_fleet(&fleet_text(prefix, domain, ""), "b.toml", None).unwrap();
    let hetcomm::config::TransportSettings::Registered(s) = &fleet.transports[0].settings else {
        panic!("registered settings expected");
    };
    let settings: &hetcomm_link_ros2::bridge::BridgeSettings = s.downcast_ref().unwrap();
    let sink = hetcomm_link::conformance::CollectSink::new();
    let bridge = hetcomm_link_ros2::bridge::Ros2Bridge::open(
        &fleet,
        hetcomm::SystemId(0),
        settings,
        sink.clone(),
    )
    .expect("open the bridge");
    (bridge, sink)
}

/// What ROS 2 Jazzy offers for nav_msgs/msg/Odometry and geometry_msgs/msg/Twist.
const ODOMETRY_HASH: &str =
    "RIHS01_3cc97dc7fb7502f8714462c526d369e35b603cfc34d946e3f2eda2766dfec6e0";
const TWIST_HASH: &str = "RIHS01_9c45bf16fe0983d80e3cfe750d6835843d265a9a6c46bd2e609fcddde6fb8d2a";

#[test]
fn peers_that_offer_the_definitions_type_hashes_are_received_without_a_word() {
    let (p, domain) = (prefix("hash_ok"), 74);
    let (bridge, sink) = open_bridge(&p, domain);
    let _rover = rover(
        &p,
        domain,
        &["--odom-hash", ODOMETRY_HASH, "--cmd-vel-hash", TWIST_HASH],
    );
    assert!(
        sink.wait_for(10, Duration::from_secs(20)) >= 10,
        "odometry from a rover that offers its type hash: {:?}",
        bridge.problems()
    );
    // A second of the subscriber check having run (every 500 ms) on the matched cmd_vel.
    std::thread::sleep(Duration::from_secs(1));
    assert_eq!(bridge.problems(), Vec::<String>::new());
    use hetcomm_link::Link;
    assert_eq!(bridge.stats().frames_dropped, 0);
}

#[test]
fn peers_that_offer_another_type_hash_are_reported_and_what_they_publish_is_dropped() {
    let (p, domain) = (prefix("hash_bad"), 75);
    let (bridge, sink) = open_bridge(&p, domain);
    let wrong = format!("RIHS01_{}", "0".repeat(64));
    let _rover = rover(
        &p,
        domain,
        &["--odom-hash", &wrong, "--cmd-vel-hash", &wrong],
    );
    use hetcomm_link::Link;
    let deadline = Instant::now() + Duration::from_secs(20);
    let expected = [
        format!(
            "a publisher on {p}/odom offers type hash {wrong} for nav_msgs/msg/Odometry, but \
             the definition the bridge read hashes to {ODOMETRY_HASH}: the two definitions \
             differ, so its messages are dropped"
        ),
        format!(
            "a subscriber of {p}/cmd_vel expects type hash {wrong} for geometry_msgs/msg/Twist, \
             but the definition the bridge read hashes to {TWIST_HASH}: the two definitions \
             differ, so it may misread what the bridge publishes"
        ),
    ];
    while bridge.stats().frames_dropped < 10 || bridge.problems().len() < 2 {
        assert!(
            Instant::now() < deadline,
            "dropped {}, problems {:?}",
            bridge.stats().frames_dropped,
            bridge.problems()
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    let mut problems = bridge.problems();
    problems.sort();
    assert_eq!(problems, expected);
    assert!(
        sink.is_empty(),
        "nothing of the mismatched publisher is received"
    );
}
