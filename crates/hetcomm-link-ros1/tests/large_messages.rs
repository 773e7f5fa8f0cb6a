//! Large messages through the `ros1_bridge` at 30 Hz, both ways, with a rospy node on a real
//! master (tests/py/large_node.py): `sensor_msgs/Image` (640×480 rgb8) and
//! `sensor_msgs/PointCloud2` (100,000 points). Every byte of every message is checked at the
//! reading end; the rate and latency are printed (`--nocapture`), and are what
//! `benchmarks/ros-large.sh` reports in a release build with `HETCOMM_LARGE_COUNT`.

mod common;

#[path = "../../hetcomm-rosmsg/tests/support/large.rs"]
mod large;

use std::path::PathBuf;
use std::process::Command;
use std::time::Duration;

use common::Master;
use hetcomm::Comm;
use large::{Kind, Node};
use serde::{Deserialize, Serialize};

#[derive(Serialize, Deserialize, Debug, Clone, PartialEq, Default)]
struct Time {
    secs: u32,
    nsecs: u32,
}

impl Time {
    fn now() -> Time {
        let d = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .unwrap_or_default();
        Time {
            secs: d.as_secs() as u32,
            nsecs: d.subsec_nanos(),
        }
    }

    fn secs(&self) -> f64 {
        self.secs as f64 + self.nsecs as f64 * 1e-9
    }
}

/// ROS 1's `std_msgs/Header`.
#[derive(Serialize, Deserialize, Debug, Clone, PartialEq, Default)]
struct Header {
    seq: u32,
    stamp: Time,
    frame_id: String,
}

impl large::Stamp for Header {
    fn for_message(k: usize) -> Header {
        Header {
            stamp: Time::now(),
            frame_id: k.to_string(),
            ..Default::default()
        }
    }

    fn frame_id(&self) -> &str {
        &self.frame_id
    }

    fn secs(&self) -> f64 {
        self.stamp.secs()
    }
}

fn fleet_text(prefix: &str, master: &str) -> String {
    format!(
        r#"[systems]
Alpha = 0
Tango = 4
[modules]
Drive = 1
World = 2
[transports.tango_ros]
kind = "ros1_bridge"
robot = "Tango"
master_uri = "{master}"
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

/// `large_node.py ARGS` as a node of `master`.
fn node(master: &Master, args: &[String]) -> Node {
    let mut cmd = Command::new("/usr/bin/python3");
    cmd.arg(PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/py/large_node.py"))
        .args(args)
        .envs(master.env());
    Node::start(cmd)
}

fn to_rospy(kind: Kind) {
    let _one = large::ONE_AT_A_TIME.lock();
    common::require_ros();
    let master = Master::start();
    let prefix = format!("/hc_{}_large_out_{}", std::process::id(), kind.arg());
    let fleet = hetcomm::parse_fleet(&fleet_text(&prefix, &master.uri()), "large.toml", None)
        .expect("a valid fleet");
    let alpha = Comm::open_fleet(&fleet, "Alpha").expect("open Alpha");
    let count = large::count();
    let topic = format!("{prefix}/{}_out", kind.arg());
    let node = node(&master, &large::node_args("read", &topic, kind, count));
    assert_eq!(
        node.lines_until("ready", Duration::from_secs(30)),
        ["ready"]
    );
    let drive = alpha.module("Drive").unwrap();
    large::send_kind::<Header>(&drive, kind, count);
    let lines = node.lines_until("done", Duration::from_secs(30));
    large::check_read(&lines, count, &format!("hetcomm → rospy, {}", kind.arg()));
}

fn from_rospy(kind: Kind) {
    let _one = large::ONE_AT_A_TIME.lock();
    common::require_ros();
    let master = Master::start();
    let prefix = format!("/hc_{}_large_in_{}", std::process::id(), kind.arg());
    let fleet = hetcomm::parse_fleet(&fleet_text(&prefix, &master.uri()), "large.toml", None)
        .expect("a valid fleet");
    let alpha = Comm::open_fleet(&fleet, "Alpha").expect("open Alpha");
    let world = alpha.module("World").unwrap();
    let count = large::count();
    let topic = format!("{prefix}/{}_in", kind.arg());
    let node = node(&master, &large::node_args("publish", &topic, kind, count));
    let arrivals = large::receive_in_order::<Header>(&world, kind, count, "the rospy node");
    large::check_received(
        &arrivals,
        count,
        &format!("rospy → hetcomm, {}", kind.arg()),
        &node,
        &alpha,
    );
}

#[test]
fn images_at_30_hz_reach_rospy_intact() {
    to_rospy(Kind::Image);
}

#[test]
fn point_clouds_at_30_hz_reach_rospy_intact() {
    to_rospy(Kind::Cloud);
}

#[test]
fn images_at_30_hz_from_rospy_arrive_intact() {
    from_rospy(Kind::Image);
}

#[test]
fn point_clouds_at_30_hz_from_rospy_arrive_intact() {
    from_rospy(Kind::Cloud);
}
