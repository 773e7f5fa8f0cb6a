//! What the bridge tests of both ROS versions do with their rover (examples/ros1 and
//! examples/ros2 `tango_rover.py`, same topics and behaviour): the user's message types,
//! mapped by serde field name, and the drive-and-talk exchange. Included with `#[path]` by
//! `crates/hetcomm-link-ros1/tests/bridge.rs` and `crates/hetcomm-link-ros2/tests/bridge.rs`
//! (this crate's own tests do not use it: it needs the `hetcomm` facade).
#![allow(dead_code)]

use std::time::{Duration, Instant};

use hetcomm::{Comm, LocalFleet, Message, Module, OpenOptions, Outcome};
use serde::{Deserialize, Serialize};

/// `geometry_msgs/Vector3` by field name.
#[derive(Serialize, Deserialize, Debug, Clone, Copy, PartialEq, Default)]
pub struct Vector3 {
    pub x: f64,
    pub y: f64,
    pub z: f64,
}

/// A user's command, mapped to `geometry_msgs/Twist` by its serde field names.
#[derive(Serialize, Deserialize, Message, Debug, Clone, PartialEq)]
#[message(id = 40)]
pub struct Drive {
    pub linear: Vector3,
    pub angular: Vector3,
}

/// A user's view of `nav_msgs/Odometry`: only the fields it needs.
#[derive(Serialize, Deserialize, Message, Debug, Clone, PartialEq)]
#[message(id = 41)]
pub struct Odom {
    pub child_frame_id: String,
    pub pose: PoseWithCovariance,
}

#[derive(Serialize, Deserialize, Debug, Clone, PartialEq)]
pub struct PoseWithCovariance {
    pub pose: Pose,
}

#[derive(Serialize, Deserialize, Debug, Clone, PartialEq)]
pub struct Pose {
    pub position: Vector3,
    pub orientation: Quaternion,
}

/// `geometry_msgs/Quaternion` by field name.
#[derive(Serialize, Deserialize, Debug, Clone, Copy, PartialEq)]
pub struct Quaternion {
    pub x: f64,
    pub y: f64,
    pub z: f64,
    pub w: f64,
}

/// `std_msgs/String`.
#[derive(Serialize, Deserialize, Message, Debug, Clone, PartialEq)]
#[message(id = 42)]
pub struct Text {
    pub data: String,
}

/// A command that does not fit `geometry_msgs/Twist` (a `speed` field, no `linear`).
#[derive(Serialize, Deserialize, Message, Debug, Clone, PartialEq)]
#[message(id = 44)]
pub struct BadDrive {
    pub speed: f64,
    pub angular: Vector3,
}

/// A view of `nav_msgs/Odometry` whose field has the wrong type (`child_frame_id` is a
/// string there).
#[derive(Serialize, Deserialize, Message, Debug, Clone, PartialEq)]
#[message(id = 41)]
pub struct BadOdom {
    pub child_frame_id: f64,
}

/// Opening system `Alpha` of `fleet` (a bridge with [`mappings_and_table`]'s mappings under
/// `/t`) with the message types declared: the rover's types open; a declared type that does
/// not fit its mapping's ROS type (either way) refuses to open, naming both types, the topic
/// and the field, before the bridge touches the ROS network.
pub fn declared_types_are_checked_when_the_bridge_opens(fleet: &hetcomm::config::Fleet) {
    let open = |options: OpenOptions| {
        LocalFleet::open_systems_with(fleet.clone(), &["Alpha"], options).map(drop)
    };
    let fitting = || {
        OpenOptions::new()
            .message::<Drive>()
            .message::<Odom>()
            .message::<Text>()
    };
    open(fitting()).expect("the rover's own types fit their mappings");
    let e = open(fitting().message::<BadDrive>())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains(
            "message type 44 (BadDrive) does not convert to geometry_msgs/Twist for topic \
             /t/cmd_vel_bad: field `speed` has no counterpart in geometry_msgs/Twist"
        ),
        "{e}"
    );
    let e = open(fitting().message::<BadOdom>())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains(
            "nav_msgs/Odometry from topic /t/odom does not convert to message type 41 \
             (BadOdom): field `child_frame_id` is a float, the ROS field is string"
        ),
        "{e}"
    );
}

/// The end of a fleet file for the rover under `prefix` (after the bridge transport
/// `tango_ros`'s own keys): its `publish` and `subscribe` sections, `more_subscribe` lines
/// added to the latter, and the table of Alpha and Tango.
pub fn mappings_and_table(prefix: &str, more_subscribe: &str) -> String {
    format!(
        r#"[transports.tango_ros.publish]
"{prefix}/cmd_vel" = "Drive 40 geometry_msgs/Twist"
"{prefix}/say" = "Drive 42 std_msgs/String"
"{prefix}/cmd_vel_bad" = "Drive 44 geometry_msgs/Twist"
[transports.tango_ros.subscribe]
"{prefix}/odom" = "World 41 nav_msgs/Odometry"
"{prefix}/heard" = "World 42 std_msgs/String"
{more_subscribe}[table]
columns = ["Alpha", "Tango"]
Alpha = ["X", "tango_ros"]
Tango = ["tango_ros", "X"]
"#
    )
}

/// With the rover's odometry arriving in `world` (mapped as type 41) and `drive` mapped to its
/// `cmd_vel` (type 40, Twist), `say` (type 42, String) and a Twist topic for type 44: commands
/// go out (outcome Sent) until the odometry shows the rover moved half a metre, a String goes
/// there and back (`heard: hello Tango`), and a command that does not fit Twist fails naming
/// both types and the field.
pub fn drive_and_talk(drive: &Module, world: &Module) {
    let forward = Drive {
        linear: Vector3 {
            x: 1.0,
            ..Default::default()
        },
        angular: Vector3::default(),
    };
    let deadline = Instant::now() + Duration::from_secs(20);
    let mut x = 0.0;
    while x < 0.5 {
        assert!(Instant::now() < deadline, "the rover did not move: x = {x}");
        let outcome = drive.send("Tango", "Drive", &forward).expect("send").wait();
        assert!(matches!(outcome, Outcome::Sent { .. }), "{outcome:?}");
        std::thread::sleep(Duration::from_millis(100));
        while let Ok(Some(odom)) = world.try_recv::<Odom>() {
            x = odom.message.pose.pose.position.x;
        }
    }

    let text = Text {
        data: "hello Tango".into(),
    };
    let deadline = Instant::now() + Duration::from_secs(10);
    let heard = loop {
        assert!(Instant::now() < deadline, "no answer on /heard");
        drive.send("Tango", "Drive", &text).expect("send").wait();
        if let Ok(r) = world.recv_timeout::<Text>(Duration::from_millis(300)) {
            break r.message;
        }
    };
    assert_eq!(heard.data, "heard: hello Tango");

    let bad = BadDrive {
        speed: 1.0,
        angular: Vector3::default(),
    };
    let outcome = drive.send("Tango", "Drive", &bad).expect("send").wait();
    let text = format!("{outcome:?}");
    assert!(matches!(outcome, Outcome::Failed { .. }), "{text}");
    assert!(
        text.contains("message type 44 for Drive does not convert to geometry_msgs/Twist: field `speed` has no counterpart in geometry_msgs/Twist"),
        "{text}"
    );
}

/// `text` (a fleet with [`mappings_and_table`]) with a second hetcomm system, Bravo, that hosts
/// the `World` module, while Alpha hosts only `Drive`: both use the bridge.
pub fn with_bravo_watching(text: &str) -> String {
    text.replace("Alpha = 0\n", "Alpha = { id = 0, modules = [\"Drive\"] }\nBravo = 1\n")
        .replace(
            "columns = [\"Alpha\", \"Tango\"]\nAlpha = [\"X\", \"tango_ros\"]\nTango = [\"tango_ros\", \"X\"]",
            "columns = [\"Alpha\", \"Bravo\", \"Tango\"]\nAlpha = [\"X\", \"X\", \"tango_ros\"]\n\
             Bravo = [\"X\", \"X\", \"tango_ros\"]\nTango = [\"tango_ros\", \"tango_ros\", \"X\"]",
        )
}

/// With the rover running: Bravo (hosting `World`) gets its odometry, Alpha (hosting only
/// `Drive`) reads none of it, and Alpha's commands still go out.
pub fn only_the_hosting_system_reads_the_topic(alpha: &Comm, bravo: &Comm, wait: Duration) {
    let world = bravo.module("World").unwrap();
    for _ in 0..5 {
        world
            .recv_timeout::<Odom>(wait)
            .expect("odometry reaches Bravo");
    }
    let received = |c: &Comm| c.stats().links[0].1.frames_received;
    assert!(received(bravo) >= 5);
    assert_eq!(
        received(alpha),
        0,
        "Alpha hosts no World: it must not read /odom"
    );
    // Alpha still publishes.
    let stop = Drive {
        linear: Vector3::default(),
        angular: Vector3::default(),
    };
    let outcome = alpha
        .module("Drive")
        .unwrap()
        .send("Tango", "Drive", &stop)
        .expect("send")
        .wait();
    assert!(matches!(outcome, Outcome::Sent { .. }), "{outcome:?}");
}
