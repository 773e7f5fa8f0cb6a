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
use hetcomm::{Comm, Message};
use large::{Figures, Kind, Node, Pattern};
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

/// `sensor_msgs/Image` by field name; the pixels as bytes (one copy each way).
#[derive(Serialize, Deserialize, Message, Debug, Clone, PartialEq)]
#[message(id = 60)]
struct Image {
    header: Header,
    height: u32,
    width: u32,
    encoding: String,
    is_bigendian: u8,
    step: u32,
    #[serde(with = "serde_bytes")]
    data: Vec<u8>,
}

/// `sensor_msgs/PointCloud2` by field name.
#[derive(Serialize, Deserialize, Message, Debug, Clone, PartialEq)]
#[message(id = 61)]
struct PointCloud2 {
    header: Header,
    height: u32,
    width: u32,
    fields: Vec<large::PointField>,
    is_bigendian: bool,
    point_step: u32,
    row_step: u32,
    #[serde(with = "serde_bytes")]
    data: Vec<u8>,
    is_dense: bool,
}

fn header(k: usize) -> Header {
    Header {
        seq: k as u32,
        stamp: Time::now(),
        frame_id: k.to_string(),
    }
}

fn image(k: usize, pattern: &Pattern) -> Image {
    Image {
        header: header(k),
        height: large::HEIGHT,
        width: large::WIDTH,
        encoding: "rgb8".into(),
        is_bigendian: 0,
        step: large::WIDTH * 3,
        data: pattern.of(k).to_vec(),
    }
}

fn cloud(k: usize, pattern: &Pattern) -> PointCloud2 {
    PointCloud2 {
        header: header(k),
        height: 1,
        width: large::POINTS,
        fields: large::point_fields(),
        is_bigendian: false,
        point_step: large::POINT_STEP,
        row_step: large::POINT_STEP * large::POINTS,
        data: pattern.of(k).to_vec(),
        is_dense: true,
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
fn node(master: &Master, args: &[&str]) -> Node {
    let mut cmd = Command::new("/usr/bin/python3");
    cmd.arg(PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/py/large_node.py"))
        .args(args)
        .envs(master.env());
    Node::start(cmd)
}

fn to_rospy(kind: Kind) {
    let _one = large::ONE_AT_A_TIME
        .lock()
        .unwrap_or_else(|e| e.into_inner());
    common::require_ros();
    let master = Master::start();
    let prefix = format!("/hc_{}_large_out_{}", std::process::id(), kind.arg());
    let fleet = hetcomm::parse_fleet(&fleet_text(&prefix, &master.uri()), "large.toml", None)
        .expect("a valid fleet");
    let alpha = Comm::open_fleet(&fleet, "Alpha").expect("open Alpha");
    let count = large::count();
    let topic = format!("{prefix}/{}_out", kind.arg());
    let n = count.to_string();
    let node = node(
        &master,
        &[
            "read",
            "--topic",
            &topic,
            "--type",
            kind.arg(),
            "--count",
            &n,
        ],
    );
    assert_eq!(
        node.lines_until("ready", Duration::from_secs(30)),
        ["ready"]
    );
    let drive = alpha.module("Drive").unwrap();
    let pattern = Pattern::new(kind);
    match kind {
        Kind::Image => large::send_at_30_hz(&drive, count, |k| image(k, &pattern)),
        Kind::Cloud => large::send_at_30_hz(&drive, count, |k| cloud(k, &pattern)),
    }
    let lines = node.lines_until("done", Duration::from_secs(30));
    large::check_read(&lines, count, &format!("hetcomm → rospy, {}", kind.arg()));
}

fn from_rospy(kind: Kind) {
    let _one = large::ONE_AT_A_TIME
        .lock()
        .unwrap_or_else(|e| e.into_inner());
    common::require_ros();
    let master = Master::start();
    let prefix = format!("/hc_{}_large_in_{}", std::process::id(), kind.arg());
    let fleet = hetcomm::parse_fleet(&fleet_text(&prefix, &master.uri()), "large.toml", None)
        .expect("a valid fleet");
    let alpha = Comm::open_fleet(&fleet, "Alpha").expect("open Alpha");
    let world = alpha.module("World").unwrap();
    let count = large::count();
    let topic = format!("{prefix}/{}_in", kind.arg());
    let n = count.to_string();
    let node = node(
        &master,
        &[
            "publish",
            "--topic",
            &topic,
            "--type",
            kind.arg(),
            "--count",
            &n,
        ],
    );
    let pattern = Pattern::new(kind);
    let mut arrivals = Vec::new();
    for _ in 0..count {
        let (k, stamp, intact, at) = match kind {
            Kind::Image => {
                let got = world
                    .recv_timeout::<Image>(Duration::from_secs(30))
                    .expect("an Image from the rospy node");
                let k: usize = got.message.header.frame_id.parse().expect("K");
                let m = &got.message;
                let intact = m.data == pattern.of(k)
                    && (m.width, m.height, m.step, m.encoding.as_str())
                        == (large::WIDTH, large::HEIGHT, large::WIDTH * 3, "rgb8");
                (k, m.header.stamp.secs(), intact, got.envelope.received_at)
            }
            Kind::Cloud => {
                let got = world
                    .recv_timeout::<PointCloud2>(Duration::from_secs(30))
                    .expect("a PointCloud2 from the rospy node");
                let m = &got.message;
                let k: usize = m.header.frame_id.parse().expect("K");
                let intact = m.data == pattern.of(k)
                    && m.fields == large::point_fields()
                    && (m.width, m.point_step, m.is_dense)
                        == (large::POINTS, large::POINT_STEP, true);
                (k, m.header.stamp.secs(), intact, got.envelope.received_at)
            }
        };
        assert_eq!(k, arrivals.len(), "messages arrive in order, none lost");
        let at = at.as_micros() as f64 / 1e6;
        arrivals.push((intact, Duration::from_secs_f64((at - stamp).max(0.0)), at));
    }
    let figures = Figures::of(&arrivals);
    println!(
        "{}",
        figures.line(&format!("rospy → hetcomm, {}", kind.arg()))
    );
    assert_eq!(figures.intact, count, "every byte of every message");
    let sent = node.lines_until("", Duration::from_secs(10));
    let prefix = format!("sent {count} ");
    assert!(
        sent.first().is_some_and(|l| l.starts_with(&prefix)),
        "{sent:?}"
    );
    large::assert_rate(&figures);
    let stats = alpha.stats();
    let dropped: u64 = stats.links.iter().map(|(_, l)| l.frames_dropped).sum();
    assert_eq!(dropped, 0, "{stats:?}");
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
