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

use hetcomm::{Comm, Message};
use large::{Figures, Kind, Node, Pattern};
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
fn node(domain: u16, args: &[&str]) -> Node {
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
    let _one = large::ONE_AT_A_TIME
        .lock()
        .unwrap_or_else(|e| e.into_inner());
    let domain = domain(kind, true);
    let prefix = format!("/hc_{}_large_out_{}", std::process::id(), kind.arg());
    let fleet = hetcomm::parse_fleet(&fleet_text(&prefix, domain), "large.toml", None)
        .expect("a valid fleet");
    let alpha = Comm::open_fleet(&fleet, "Alpha").expect("open Alpha");
    let count = large::count();
    let topic = format!("{prefix}/{}_out", kind.arg());
    let n = count.to_string();
    let node = node(
        domain,
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
    large::check_read(
        &lines,
        count,
        &format!("hetcomm → cyclonedds Python, {}", kind.arg()),
    );
}

fn from_python(kind: Kind) {
    let _one = large::ONE_AT_A_TIME
        .lock()
        .unwrap_or_else(|e| e.into_inner());
    let domain = domain(kind, false);
    let prefix = format!("/hc_{}_large_in_{}", std::process::id(), kind.arg());
    let fleet = hetcomm::parse_fleet(&fleet_text(&prefix, domain), "large.toml", None)
        .expect("a valid fleet");
    let alpha = Comm::open_fleet(&fleet, "Alpha").expect("open Alpha");
    let world = alpha.module("World").unwrap();
    let count = large::count();
    let topic = format!("{prefix}/{}_in", kind.arg());
    let n = count.to_string();
    let node = node(
        domain,
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
                    .expect("an Image from the Python node");
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
                    .expect("a PointCloud2 from the Python node");
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
        figures.line(&format!("cyclonedds Python → hetcomm, {}", kind.arg()))
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
