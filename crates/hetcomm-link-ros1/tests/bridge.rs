//! The `ros1_bridge` kind against real ROS 1 software on a real master: `rosmsg` (MD5 sums),
//! `rostopic pub` and `rostopic echo`, rospy (examples/ros1/tango_rover.py, a rover driven by
//! a hetcomm system that gets its odometry back), and bad input (a message that does not
//! deserialize, a publisher of another type on a mapped topic), counted and reported.

mod common;

use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use common::Master;
use hetcomm::{Comm, Outcome};
use hetcomm_link::{FrameSink, Peer};
use hetcomm_link_ros1::bridge::{description, BridgeSettings, Ros1Bridge};
use hetcomm_rosmsg::schema::Flavour;
use serde::{Deserialize, Serialize};

#[path = "../../hetcomm-rosmsg/tests/support/rover.rs"]
mod tango;
use tango::{drive_and_talk, mappings_and_table, Drive, Odom, Vector3};

/// `nav_msgs/Odometry`'s ROS 1 header, as the rover's rospy fills it in (read from the raw
/// payload: one system knows one Rust type per message type id, `Odom` here).
#[derive(Deserialize, Debug)]
struct Stamped {
    header: Header,
}

#[derive(Serialize, Deserialize, Debug, Clone, PartialEq)]
struct Header {
    seq: u32,
    stamp: Stamp,
    frame_id: String,
}

#[derive(Serialize, Deserialize, Debug, Clone, PartialEq)]
struct Stamp {
    secs: u32,
    nsecs: u32,
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
{}"#,
        mappings_and_table(
            prefix,
            &format!("\"{prefix}/cmd_in\" = \"World 40 geometry_msgs/Twist\"\n")
        )
    )
}

fn settings(fleet: &hetcomm::config::Fleet) -> &BridgeSettings {
    let hetcomm::config::TransportSettings::Registered(s) = &fleet.transports[0].settings else {
        panic!("registered settings expected");
    };
    s.downcast_ref().expect("ros1_bridge settings")
}

#[test]
fn the_md5_sums_are_those_rosmsg_computes() {
    common::require_ros();
    for ty in Flavour::Ros1.known() {
        let out = Command::new("rosmsg")
            .args(["md5", ty.name])
            .output()
            .expect("running rosmsg");
        let theirs = String::from_utf8_lossy(&out.stdout).trim().to_string();
        let d = description(ty);
        assert_eq!(d.md5sum, theirs, "{}", ty.name);
        assert_eq!(d.ros_type_name, ty.name);
    }
}

#[test]
fn mappings_parse_and_their_mistakes_are_located() {
    let ok = hetcomm::parse_fleet(&fleet_text("/t", "http://127.0.0.1:1"), "b.toml", None)
        .expect("valid");
    let b = settings(&ok);
    assert_eq!(b.robot, "Tango");
    assert_eq!(b.master_uri, "http://127.0.0.1:1");
    assert_eq!(b.publish.len(), 3);
    assert_eq!(b.subscribe[0].ros_type(), "nav_msgs/Odometry");
    assert_eq!(b.subscribe[0].message, 41);

    let errors = |text: String| {
        hetcomm::parse_fleet(&text, "b.toml", None)
            .unwrap_err()
            .to_string()
    };
    let good = fleet_text("/t", "http://127.0.0.1:1");
    let e = errors(good.replace("nav_msgs/Odometry", "my_robot_msgs/Status"));
    assert!(
        e.starts_with("b.toml:18:13: mapping of `/t/odom`: the ROS type `my_robot_msgs/Status` was not found: looked in "),
        "{e}"
    );
    assert!(
        e.contains("the definitions shipped with hetcomm (actionlib_msgs, diagnostic_msgs, "),
        "{e}"
    );
    assert!(e.contains("to `msg_paths`"), "{e}");
    let e = errors(good.replace("delivery = \"unacknowledged\"\n", ""));
    assert!(
        e.contains("(kind ros1_bridge) carries plain ROS messages, which nobody acknowledges"),
        "{e}"
    );
    let e = errors(good.replace("security = \"none\"\n", ""));
    assert!(
        e.contains("a ROS node cannot open hetcomm's secured sessions"),
        "{e}"
    );
    let e = errors(good.replace("\"/t/say\"", "\"/t/2say\""));
    assert!(
        e.contains(
            "b.toml:15:13: `/t/2say` is not a ROS 1 topic name: `2say` is not a name segment"
        ),
        "{e}"
    );
    let e = errors(good.replace("http://127.0.0.1:1", "127.0.0.1:1"));
    assert!(e.contains("`master_uri` must be an http:// URI"), "{e}");
}

#[test]
fn opening_names_an_unknown_module_and_an_absent_master() {
    let text = fleet_text("/t", "http://127.0.0.1:1").replace("\"World 41", "\"Wrold 41");
    let fleet = hetcomm::parse_fleet(&text, "b.toml", None).expect("valid");
    let e = Comm::open_fleet(&fleet, "Alpha")
        .err()
        .expect("open fails")
        .to_string();
    assert!(
        e.contains("the mapping of /t/odom names module `Wrold`, which is not in [modules]"),
        "{e}"
    );
    common::ros_env();
    let port = common::free_port();
    let text = fleet_text("/t", &format!("http://127.0.0.1:{port}"));
    let fleet = hetcomm::parse_fleet(&text, "b.toml", None).expect("valid");
    let e = Comm::open_fleet(&fleet, "Alpha")
        .err()
        .expect("open fails")
        .to_string();
    assert!(
        e.contains(&format!("the ROS master at http://127.0.0.1:{port}")),
        "{e}"
    );
}

#[test]
fn declared_types_that_do_not_fit_refuse_to_open() {
    let master = Master::start();
    let fleet =
        hetcomm::parse_fleet(&fleet_text("/t", &master.uri()), "b.toml", None).expect("valid");
    tango::declared_types_are_checked_when_the_bridge_opens(&fleet);
}

/// A child process, killed when dropped.
struct Proc(Child);

impl Drop for Proc {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn rover(master: &Master, prefix: &str, extra: &[&str]) -> Proc {
    let script =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../examples/ros1/tango_rover.py");
    let child = Command::new("/usr/bin/python3")
        .arg(script)
        .args(["--prefix", prefix, "--seconds", "60"])
        .args(extra)
        .envs(master.env())
        .stdout(Stdio::null())
        .spawn()
        .expect("start the rospy rover");
    Proc(child)
}

/// `rostopic pub -r 10 TOPIC TYPE VALUE`. Its stderr is dropped: it logs every connection it
/// refuses (with the whole definition), as a publisher of the wrong type does.
fn rostopic_pub(master: &Master, topic: &str, ty: &str, value: &str) -> Proc {
    let child = Command::new("rostopic")
        .args(["pub", "-r", "10", topic, ty, value])
        .envs(master.env())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("rostopic pub");
    Proc(child)
}

fn prefix(tag: &str) -> String {
    format!("/hc_{}_{tag}", std::process::id())
}

fn open(master: &Master, prefix: &str) -> Comm {
    let text = fleet_text(prefix, &master.uri());
    let fleet = hetcomm::parse_fleet(&text, "b.toml", None).expect("valid");
    Comm::open_fleet(&fleet, "Alpha").expect("open Alpha")
}

/// A master, Alpha with its bridge, and the rospy rover on topics `/hc_<pid>_<tag>/…`
/// (dropped in this order: the rover first, the master last).
struct Scene {
    _rover: Proc,
    drive: hetcomm::Module,
    world: hetcomm::Module,
    _alpha: Comm,
    _master: Master,
}

impl Scene {
    fn start(tag: &str) -> Scene {
        let master = Master::start();
        let p = prefix(tag);
        let alpha = open(&master, &p);
        Scene {
            _rover: rover(&master, &p, &[]),
            drive: alpha.module("Drive").unwrap(),
            world: alpha.module("World").unwrap(),
            _alpha: alpha,
            _master: master,
        }
    }
}

#[test]
fn rostopic_pub_reaches_a_module_as_a_typed_message() {
    let master = Master::start();
    let p = prefix("pub");
    let alpha = open(&master, &p);
    let world = alpha.module("World").unwrap();
    let twist = "{linear: {x: 0.5, y: 0.0, z: 0.0}, angular: {x: 0.0, y: 0.0, z: 0.25}}";
    let _pub = rostopic_pub(
        &master,
        &format!("{p}/cmd_in"),
        "geometry_msgs/Twist",
        twist,
    );
    let got = world
        .recv_timeout::<Drive>(Duration::from_secs(20))
        .expect("a Twist from rostopic pub");
    assert_eq!(got.message.linear.x, 0.5);
    assert_eq!(got.message.angular.z, 0.25);
    assert_eq!(got.envelope.source().system, hetcomm::SystemId(4));
}

#[test]
fn rostopic_echo_prints_what_hetcomm_publishes() {
    let master = Master::start();
    let p = prefix("echo");
    let alpha = open(&master, &p);
    let drive = alpha.module("Drive").unwrap();
    let echo = Command::new("rostopic")
        .args(["echo", "-n", "1", &format!("{p}/cmd_vel")])
        .envs(master.env())
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("rostopic echo");
    let echo = Arc::new(Mutex::new(Some(echo)));
    let cmd = Drive {
        linear: Vector3 {
            x: 1.25,
            ..Default::default()
        },
        angular: Vector3 {
            z: -0.5,
            ..Default::default()
        },
    };
    // rostopic echo subscribes some time after it starts: publish until it has printed. A
    // send before it subscribed publishes nothing and says so.
    let deadline = Instant::now() + Duration::from_secs(20);
    let out = loop {
        assert!(Instant::now() < deadline, "rostopic echo printed nothing");
        let outcome = drive.send("Tango", "Drive", &cmd).expect("send").wait();
        let nobody = matches!(&outcome, Outcome::Failed { reason, .. }
            if reason.to_string().contains(&format!("no node subscribes to {p}/cmd_vel")));
        assert!(
            matches!(outcome, Outcome::Sent { .. }) || nobody,
            "{outcome:?}"
        );
        std::thread::sleep(Duration::from_millis(200));
        let mut guard = echo.lock().unwrap();
        if let Ok(Some(_)) = guard.as_mut().unwrap().try_wait() {
            break guard
                .take()
                .unwrap()
                .wait_with_output()
                .expect("echo output");
        }
    };
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        text.contains("linear: \n  x: 1.25\n  y: 0.0\n  z: 0.0")
            && text.contains("angular: \n  x: 0.0\n  y: 0.0\n  z: -0.5"),
        "{text}"
    );
}

#[test]
fn a_rospy_rover_follows_twist_commands_and_reports_odometry() {
    let scene = Scene::start("drive");
    let (drive, world) = (&scene.drive, &scene.world);

    // Odometry arrives as a typed message from Tango, ROS 1 header included.
    let first = world
        .recv_raw_timeout(Some(Duration::from_secs(30)))
        .expect("odometry from the rover");
    assert_eq!(first.envelope.message_type().0, 41);
    assert_eq!(first.envelope.source().system, hetcomm::SystemId(4));
    let stamped: Stamped = rmp_serde::from_slice(&first.payload).expect("a header");
    assert_eq!(stamped.header.frame_id, "odom");
    assert!(stamped.header.stamp.secs > 1_600_000_000);
    let odom: Odom = rmp_serde::from_slice(&first.payload).expect("an Odom");
    assert_eq!(odom.child_frame_id, "base_link");

    // Twist commands drive it (outcome Sent), a String goes there and back through rospy, a
    // command that does not fit Twist fails naming both types and the field.
    drive_and_talk(drive, world);
}

#[test]
fn tango_follows_a_hetcomm_leader_through_the_bridge() {
    let scene = Scene::start("follow");
    let (drive, world) = (&scene.drive, &scene.world);
    world
        .recv_timeout::<Odom>(Duration::from_secs(30))
        .expect("odometry from the rover");
    // The leader (virtual, in Alpha) starts 1 m from Tango and drives at 0.3 m/s along the
    // 45° diagonal; Tango is steered, from its odometry alone, to a point 1 m behind it.
    let dir = std::f64::consts::FRAC_1_SQRT_2;
    let (mut tx, mut ty, mut heading) = (0.0, 0.0, 0.0f64);
    let start = Instant::now();
    let mut distance = f64::MAX;
    while start.elapsed() < Duration::from_secs(15) {
        let along = 0.3 * start.elapsed().as_secs_f64();
        let (gx, gy) = (along * dir, along * dir);
        while let Ok(Some(o)) = world.try_recv::<Odom>() {
            let pose = o.message.pose.pose;
            (tx, ty) = (pose.position.x, pose.position.y);
            heading = 2.0 * pose.orientation.z.atan2(pose.orientation.w);
        }
        distance = (gx - tx).hypot(gy - ty);
        let error = (gy - ty).atan2(gx - tx) - heading;
        let turn = error.sin().atan2(error.cos());
        let cmd = Drive {
            linear: Vector3 {
                x: (distance * 1.5).min(0.8) * turn.cos().max(0.0),
                ..Default::default()
            },
            angular: Vector3 {
                z: (2.0 * turn).clamp(-1.5, 1.5),
                ..Default::default()
            },
        };
        let outcome = drive.send("Tango", "Drive", &cmd).expect("send").wait();
        assert!(matches!(outcome, Outcome::Sent { .. }), "{outcome:?}");
        std::thread::sleep(Duration::from_millis(50));
    }
    assert!(
        tx > 2.0 && ty > 2.0,
        "Tango did not follow: at ({tx:.2}, {ty:.2})"
    );
    assert!(distance < 0.4, "Tango is {distance:.2} m from its target");
}

/// A sink that keeps the frames a bridge hands it.
#[derive(Default)]
struct Frames(Mutex<Vec<Vec<u8>>>);

impl FrameSink for Frames {
    fn on_frame(&self, frame: &[u8], _from: Peer) {
        self.0.lock().unwrap().push(frame.to_vec());
    }
}

#[test]
fn malformed_messages_and_wrong_types_on_a_mapped_topic_are_counted_not_delivered() {
    let master = Master::start();
    let p = prefix("bad");
    let text = fleet_text(&p, &master.uri());
    let fleet = hetcomm::parse_fleet(&text, "b.toml", None).expect("valid");
    let sink = Arc::new(Frames::default());
    let bridge = Ros1Bridge::open(&fleet, hetcomm::SystemId(0), settings(&fleet), sink.clone())
        .expect("open the bridge");
    let _rover = rover(&master, &p, &["--garbage", "20"]);
    let topic = format!("{p}/odom");
    let _wrong = rostopic_pub(&master, &topic, "std_msgs/String", "data: not an odometry");
    // Good odometry keeps arriving; the garbage and the String publisher are counted (the
    // rover's first few garbage messages may go out before the bridge's connection is up).
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        let good = sink.0.lock().unwrap().len();
        let dropped = hetcomm_link::Link::stats(&bridge).frames_dropped;
        if good >= 20 && dropped >= 6 && bridge.problems().len() == 2 {
            break;
        }
        assert!(
            Instant::now() < deadline,
            "good = {good}, dropped = {dropped}: {:?}",
            bridge.problems()
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    for frame in sink.0.lock().unwrap().iter() {
        let f = hetcomm_core::wire::decode(frame).expect("a frame");
        assert_eq!(f.header.message_type.0, 41);
        let odom: Odom = rmp_serde::from_slice(f.payload).expect("an Odom");
        assert_eq!(odom.child_frame_id, "base_link");
    }
    let problems = bridge.problems().join("\n");
    assert!(
        problems.contains(&format!("a message on {p}/odom is not a nav_msgs/Odometry")),
        "{problems}"
    );
    assert!(
        problems.contains(&format!("a publisher on {p}/odom (/rostopic_"))
            && problems.contains(
                "has type std_msgs/String, but the topic is mapped as nav_msgs/Odometry: ROS 1 \
                 refuses its connection (MD5 sum mismatch)"
            ),
        "{problems}"
    );
}

#[test]
fn a_system_that_does_not_host_a_subscribed_module_does_not_read_its_topic() {
    let master = Master::start();
    let p = prefix("hosts");
    let text = tango::with_bravo_watching(&fleet_text(&p, &master.uri()));
    let fleet = hetcomm::parse_fleet(&text, "b.toml", None).expect("valid");
    let alpha = Comm::open_fleet(&fleet, "Alpha").expect("open Alpha");
    let bravo = Comm::open_fleet(&fleet, "Bravo").expect("open Bravo");
    let _rover = rover(&master, &p, &[]);
    tango::only_the_hosting_system_reads_the_topic(&alpha, &bravo, Duration::from_secs(30));
}

#[test]
fn the_registry_names_the_bridged_robot() {
    let text = fleet_text("/t", "http://127.0.0.1:11311");
    let fleet = hetcomm::parse_fleet(&text, "b.toml", None).expect("valid");
    assert_eq!(hetcomm::registry().bridged_robots(&fleet), ["Tango"]);
    // A `ros1` transport links hetcomm systems: nobody is bridged.
    let plain = text
        .replace("kind = \"ros1_bridge\"\nrobot = \"Tango\"", "kind = \"ros1\"")
        .split("[transports.tango_ros.publish]")
        .next()
        .unwrap()
        .to_string()
        + "[table]\ncolumns = [\"Alpha\", \"Tango\"]\nAlpha = [\"X\", \"tango_ros\"]\nTango = [\"tango_ros\", \"X\"]\n";
    let fleet = hetcomm::parse_fleet(&plain, "p.toml", None).expect("valid");
    assert!(hetcomm::registry().bridged_robots(&fleet).is_empty());
}
