//! Large messages through the `ros2_bridge` at 30 Hz, both ways, with a Cyclone DDS Python
//! node (tests/py/large_node.py, no ROS 2 install): `sensor_msgs/msg/Image` (640×480 rgb8)
//! and `sensor_msgs/msg/PointCloud2` (100,000 points), reliable, so that every sample is
//! fragmented by RTPS (about 15 and 26 fragments of 64 KiB). Every byte of every message is
//! checked at the reading end; the rate and latency are printed (`--nocapture`), and are what
//! `benchmarks/ros-large.sh` reports in a release build with `HETCOMM_LARGE_COUNT`.
//!
//! The Python interpreter with `cyclonedds` is `$HETCOMM_ROS2_PYTHON` (scripts/ros2-test.sh).

#[path = "../../hetcomm-rosmsg/tests/support/large.rs"]
mod large;

use std::path::PathBuf;
use std::process::Command;
use std::time::Duration;

use hetcomm::Comm;
use large::{Kind, Node};
use serde::{Deserialize, Serialize};

/// `builtin_interfaces/Time`.
#[derive(Serialize, Deserialize, Debug, Clone, PartialEq, Default)]
struct Time {
    sec: i32,
    nanosec: u32,
}

impl Time {
    fn now() -> Time {
        let d = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .unwrap_or_default();
        Time {
            sec: d.as_secs() as i32,
            nanosec: d.subsec_nanos(),
        }
    }

    fn secs(&self) -> f64 {
        self.sec as f64 + self.nanosec as f64 * 1e-9
    }
}

/// ROS 2's `std_msgs/Header` (no `seq`).
#[derive(Serialize, Deserialize, Debug, Clone, PartialEq, Default)]
struct Header {
    stamp: Time,
    frame_id: String,
}

impl large::Stamp for Header {
    fn for_message(k: usize) -> Header {
        Header {
            stamp: Time::now(),
            frame_id: k.to_string(),
        }
    }

    fn frame_id(&self) -> &str {
        &self.frame_id
    }

    fn secs(&self) -> f64 {
        self.stamp.secs()
    }
}

fn fleet_text(prefix: &str, domain: u16) -> String {
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
[transports.tango_ros.publish]
"{prefix}/image_out" = "Drive 60 sensor_msgs/Image"
"{prefix}/cloud_out" = "Drive 61 sensor_msgs/PointCloud2"
[transports.tango_ros.subscribe]
"{prefix}/image_in" = "World 60 sensor_msgs/Image"
"{prefix}/cloud_in" = "World 61 sensor_msgs/PointCloud2"
[table]
columns = ["Alpha", "Tango"]
Alpha = ["X", "tango_ros"]
Tango = ["tango_ros", "X"]
"#
    )
}

/// `large_node.py ARGS --domain DOMAIN`.
fn node(domain: u16, args: &[String]) -> Node {
    let python = std::env::var("HETCOMM_ROS2_PYTHON").expect(
        "set HETCOMM_ROS2_PYTHON to a Python with the `cyclonedds` package \
         (scripts/ros2-test.sh does: target/py-venv/bin/python)",
    );
    let mut cmd = Command::new(python);
    cmd.arg(PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/py/large_node.py"))
        .args(args)
        .args(["--domain", &domain.to_string()]);
    Node::start(cmd)
}

/// A domain of the test's own (parallel runs of the crate's tests do not meet).
fn domain(kind: Kind, out: bool) -> u16 {
    40 + 2 * (kind == Kind::Cloud) as u16 + out as u16
}

fn to_python(kind: Kind) {
    let _one = large::ONE_AT_A_TIME.lock();
    let domain = domain(kind, true);
    let prefix = format!("/hc_{}_large_out_{}", std::process::id(), kind.arg());
    let fleet = hetcomm::parse_fleet(&fleet_text(&prefix, domain), "large.toml", None)
        .expect("a valid fleet");
    let alpha = Comm::open_fleet(&fleet, "Alpha").expect("open Alpha");
    let count = large::count();
    let topic = format!("{prefix}/{}_out", kind.arg());
    let node = node(domain, &large::node_args("read", &topic, kind, count));
    assert_eq!(
        node.lines_until("ready", Duration::from_secs(30)),
        ["ready"]
    );
    let drive = alpha.module("Drive").unwrap();
    large::send_kind::<Header>(&drive, kind, count);
    let lines = node.lines_until("done", Duration::from_secs(30));
    large::check_read(
        &lines,
        count,
        &format!("hetcomm → cyclonedds Python, {}", kind.arg()),
    );
}

fn from_python(kind: Kind) {
    let _one = large::ONE_AT_A_TIME.lock();
    let domain = domain(kind, false);
    let prefix = format!("/hc_{}_large_in_{}", std::process::id(), kind.arg());
    let fleet = hetcomm::parse_fleet(&fleet_text(&prefix, domain), "large.toml", None)
        .expect("a valid fleet");
    let alpha = Comm::open_fleet(&fleet, "Alpha").expect("open Alpha");
    let world = alpha.module("World").unwrap();
    let count = large::count();
    let topic = format!("{prefix}/{}_in", kind.arg());
    let node = node(domain, &large::node_args("publish", &topic, kind, count));
    let arrivals = large::receive_in_order::<Header>(&world, kind, count, "the Python node");
    large::check_received(
        &arrivals,
        count,
        &format!("cyclonedds Python → hetcomm, {}", kind.arg()),
        &node,
        &alpha,
    );
}

#[test]
fn images_at_30_hz_reach_a_cyclone_dds_reader_intact() {
    to_python(Kind::Image);
}

/// A 1.6 MB cloud leaves rustdds as one burst of about 6,250 fragments: the reader keeps up
/// only with a socket buffer larger than the kernel's default (the node asks Cyclone DDS for
/// 4 MB; docs/ros-bridges.md), else fragments overflow it and whole samples are resent.
#[test]
fn point_clouds_at_30_hz_reach_a_cyclone_dds_reader_intact() {
    to_python(Kind::Cloud);
}

#[test]
fn images_at_30_hz_from_a_cyclone_dds_writer_arrive_intact() {
    from_python(Kind::Image);
}

#[test]
fn point_clouds_at_30_hz_from_a_cyclone_dds_writer_arrive_intact() {
    from_python(Kind::Cloud);
}
