//! A robot's own message type through the `ros1_bridge`: `hetcomm_test_msgs/Status`
//! (tests/msg: constants, a header, a nested type, fixed and unbounded arrays, `time` and
//! `duration`), found through the fleet's `msg_paths`, between hetcomm and a rospy node
//! (tests/py/status_node.py, its class generated from the same `.msg` files) on a real master,
//! both ways; and its MD5 sum equal to genmsg's.

mod common;

use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use common::Master;
use hetcomm::{Comm, Message, Outcome};
use serde::{Deserialize, Serialize};

#[derive(Serialize, Deserialize, Debug, Clone, PartialEq, Default)]
struct Time {
    secs: u32,
    nsecs: u32,
}

#[derive(Serialize, Deserialize, Debug, Clone, PartialEq, Default)]
struct Span {
    secs: i32,
    nsecs: i32,
}

#[derive(Serialize, Deserialize, Debug, Clone, PartialEq, Default)]
struct Header {
    seq: u32,
    stamp: Time,
    frame_id: String,
}

#[derive(Serialize, Deserialize, Debug, Clone, PartialEq, Default)]
struct Vector3 {
    x: f64,
    y: f64,
    z: f64,
}

#[derive(Serialize, Deserialize, Debug, Clone, PartialEq)]
struct Part {
    name: String,
    temperature: f64,
    ok: bool,
    offset: Vector3,
}

/// `hetcomm_test_msgs/Status` by field name.
#[derive(Serialize, Deserialize, Message, Debug, Clone, PartialEq)]
#[message(id = 50)]
struct Status {
    header: Header,
    level: u8,
    name: String,
    parts: Vec<Part>,
    position: [f32; 3],
    counters: Vec<i64>,
    checked: Time,
    uptime: Span,
}

fn msg_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/msg")
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
msg_paths = ["msg"]
[transports.tango_ros.publish]
"{prefix}/command" = "Drive 50 hetcomm_test_msgs/Status"
[transports.tango_ros.subscribe]
"{prefix}/status" = "World 50 hetcomm_test_msgs/Status"
[table]
columns = ["Alpha", "Tango"]
Alpha = ["X", "tango_ros"]
Tango = ["tango_ros", "X"]
"#
    )
}

/// The rospy node, killed when dropped, and its stdout's lines.
struct Node {
    child: Child,
    lines: mpsc::Receiver<String>,
}

impl Drop for Node {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Node {
    fn start(master: &Master, prefix: &str) -> Node {
        let script = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/py/status_node.py");
        let mut child = Command::new("/usr/bin/python3")
            .arg(script)
            .args(["--prefix", prefix, "--seconds", "60", "--msg-dir"])
            .arg(msg_dir())
            .envs(master.env())
            .stdout(Stdio::piped())
            .spawn()
            .expect("start the rospy node");
        let out = BufReader::new(child.stdout.take().expect("stdout"));
        let (tx, lines) = mpsc::channel();
        std::thread::spawn(move || {
            for line in out.lines().map_while(Result::ok) {
                if tx.send(line).is_err() {
                    return;
                }
            }
        });
        Node { child, lines }
    }

    fn line(&self, within: Duration) -> String {
        self.lines
            .recv_timeout(within)
            .expect("a line from the rospy node")
    }
}

#[test]
fn a_custom_type_from_msg_paths_goes_both_ways_with_rospy() {
    common::require_ros();
    let master = Master::start();
    let prefix = format!("/hc_{}_custom", std::process::id());
    // msg_paths is relative to the fleet file: parse it as if it were in tests/.
    let fleet = hetcomm::parse_fleet(
        &fleet_text(&prefix, &master.uri()),
        "custom.toml",
        Some(&PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests")),
    )
    .expect("a valid fleet");
    let alpha = Comm::open_fleet(&fleet, "Alpha").expect("open Alpha");
    let node = Node::start(&master, &prefix);

    // The MD5 sum genmsg computes is the one the bridge advertises and subscribes with.
    let md5 = node.line(Duration::from_secs(20));
    let registry = hetcomm_rosmsg::registry::Registry::from_dirs(
        hetcomm_rosmsg::schema::Flavour::Ros1,
        &[msg_dir()],
    )
    .expect("the test package");
    let ours = registry
        .resolve("hetcomm_test_msgs/Status")
        .expect("Status");
    assert_eq!(md5, format!("MD5 {}", ours.md5));
    assert_eq!(ours.constants.len(), 4);
    // roslibrust advertises with the sum it computes from the full definition.
    let advertised = roslibrust::md5sum::from_message_definition(ours.name, ours.definition)
        .expect("roslibrust reads the definition");
    assert_eq!(advertised, ours.md5, "{}", ours.definition);
    assert!(!hetcomm_link_ros1::bridge::md5_checked(ours));

    // ROS → hetcomm.
    let world = alpha.module("World").unwrap();
    let got = world
        .recv_timeout::<Status>(Duration::from_secs(20))
        .expect("a Status from the rospy node")
        .message;
    assert_eq!(got.header.frame_id, "base");
    assert_eq!((got.level, got.name.as_str()), (1, "tango"));
    assert_eq!(got.parts.len(), 2);
    assert_eq!(
        got.parts[0],
        Part {
            name: "wheel".into(),
            temperature: 41.5,
            ok: true,
            offset: Vector3 {
                x: 1.0,
                y: 2.0,
                z: 3.0
            }
        }
    );
    assert_eq!(
        (got.parts[1].name.as_str(), got.parts[1].ok),
        ("arm", false)
    );
    assert_eq!(got.position, [1.5, -2.0, 0.25]);
    assert_eq!(got.counters, [1, -2, 1 << 40]);
    assert_eq!(
        got.checked,
        Time {
            secs: 12,
            nsecs: 34
        }
    );
    assert_eq!(got.uptime, Span { secs: 5, nsecs: 6 });

    // hetcomm → ROS: sent until the node has printed one (its subscription connects late).
    let drive = alpha.module("Drive").unwrap();
    let command = Status {
        header: Header {
            frame_id: "map".into(),
            ..Header::default()
        },
        level: 2,
        name: "from hetcomm".into(),
        parts: vec![Part {
            name: "gripper".into(),
            temperature: 20.0,
            ok: true,
            offset: Vector3::default(),
        }],
        position: [0.5, 0.0, -0.5],
        counters: vec![],
        checked: Time { secs: 1, nsecs: 2 },
        uptime: Span { secs: -3, nsecs: 4 },
    };
    let deadline = Instant::now() + Duration::from_secs(20);
    let line = loop {
        assert!(
            Instant::now() < deadline,
            "the rospy node printed no Status"
        );
        let outcome = drive.send("Tango", "Drive", &command).expect("send").wait();
        assert!(matches!(outcome, Outcome::Sent { .. }), "{outcome:?}");
        if let Ok(line) = node.lines.recv_timeout(Duration::from_millis(200)) {
            break line;
        }
    };
    let v: serde_json::Value = serde_json::from_str(&line).expect("a JSON line");
    assert_eq!(
        v,
        serde_json::json!({
            "frame_id": "map", "level": 2, "name": "from hetcomm",
            "parts": [["gripper", 20.0, true, [0.0, 0.0, 0.0]]],
            "position": [0.5, 0.0, -0.5], "counters": [],
            "checked": [1, 2], "uptime": [-3, 4],
        })
    );
}

#[test]
fn a_malformed_msg_file_and_a_missing_type_are_located() {
    let dir = std::env::temp_dir().join(format!("hc_bad_msgs_{}", std::process::id()));
    let pkg = dir.join("my_robot_msgs/msg");
    std::fs::create_dir_all(&pkg).unwrap();
    std::fs::write(pkg.join("Status.msg"), "uint8 level\nfloat64[x] values\n").unwrap();
    let text = fleet_text("/t", "http://127.0.0.1:1")
        .replace(
            "msg_paths = [\"msg\"]",
            &format!("msg_paths = [{:?}]", dir.display().to_string()),
        )
        .replace(
            "hetcomm_test_msgs/Status\"\n[table]",
            "my_robot_msgs/Missing\"\n[table]",
        )
        .replace("hetcomm_test_msgs/Status", "my_robot_msgs/Status");
    let e = hetcomm::parse_fleet(&text, "b.toml", None)
        .unwrap_err()
        .to_string();
    let file = pkg.join("Status.msg");
    assert!(
        e.contains(&format!(
            "b.toml:15:16: mapping of `/t/command`: {}:2: `float64[x]`: `x` is not an array size",
            file.display()
        )),
        "{e}"
    );
    assert!(
        e.contains(&format!(
            "b.toml:17:15: mapping of `/t/status`: the ROS type `my_robot_msgs/Missing` was not \
             found: looked in msg_paths entry {} (1 types); the definitions shipped with hetcomm",
            dir.display()
        )),
        "{e}"
    );
    let e = hetcomm::parse_fleet(
        &text.replace(&dir.display().to_string(), "/nonexistent/x"),
        "b.toml",
        None,
    )
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("`msg_paths`: `/nonexistent/x` is not a directory"),
        "{e}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}
