//! Leader–follower with Tango as an external ROS 2 robot: Alpha (hetcomm) is the leader, moving
//! on a circle; Tango is `examples/ros2/tango_rover.py` (Cyclone DDS, no hetcomm). Alpha's
//! World module takes Tango's pose from its `nav_msgs/Odometry`; Alpha's Drive module steers
//! Tango with `geometry_msgs/Twist` commands towards a point one metre behind the leader.
//! Prints one table row per second and exits 0 if Tango ended within 1 m of its target.
//!
//! ```sh
//! target/py-venv/bin/python examples/ros2/tango_rover.py --prefix /tango --seconds 40 &
//! cargo run --manifest-path crates/hetcomm-link-ros2/Cargo.toml --example tango_follows -- \
//!     --prefix /tango --seconds 20
//! ```

use std::time::{Duration, Instant};

use hetcomm::{Comm, Message};
use serde::{Deserialize, Serialize};

#[derive(Serialize, Deserialize, Clone, Copy, Debug, Default)]
struct Vector3 {
    x: f64,
    y: f64,
    z: f64,
}

#[derive(Serialize, Deserialize, Clone, Copy, Debug, Default)]
struct Quaternion {
    x: f64,
    y: f64,
    z: f64,
    w: f64,
}

/// `geometry_msgs/Twist`.
#[derive(Serialize, Deserialize, Message, Debug)]
#[message(id = 40)]
struct Drive {
    linear: Vector3,
    angular: Vector3,
}

/// The part of `nav_msgs/Odometry` the World module needs.
#[derive(Serialize, Deserialize, Message, Debug)]
#[message(id = 41)]
struct Odom {
    pose: PoseWithCovariance,
}

#[derive(Serialize, Deserialize, Debug)]
struct PoseWithCovariance {
    pose: Pose,
}

#[derive(Serialize, Deserialize, Debug)]
struct Pose {
    position: Vector3,
    orientation: Quaternion,
}

fn fleet(prefix: &str, domain: u16) -> String {
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
history_depth = 10
delivery = "unacknowledged"
security = "none"
[transports.tango_ros.publish]
"{prefix}/cmd_vel" = "Drive 40 geometry_msgs/Twist"
[transports.tango_ros.subscribe]
"{prefix}/odom" = "World 41 nav_msgs/Odometry"
[table]
columns = ["Alpha", "Tango"]
Alpha = ["X", "tango_ros"]
Tango = ["tango_ros", "X"]
"#
    )
}

fn arg(name: &str, default: &str) -> String {
    let args: Vec<String> = std::env::args().collect();
    args.iter()
        .position(|a| a == name)
        .and_then(|i| args.get(i + 1).cloned())
        .unwrap_or_else(|| default.to_string())
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let prefix = arg("--prefix", "/tango");
    let domain: u16 = arg("--domain", "0").parse()?;
    let seconds: f64 = arg("--seconds", "20").parse()?;
    let fleet = hetcomm::parse_fleet(&fleet(&prefix, domain), "tango-ros2.toml", None)?;
    let alpha = Comm::open_fleet(&fleet, "Alpha")?;
    let (drive, world) = (alpha.module("Drive")?, alpha.module("World")?);

    // Wait for Tango's first odometry: it is on the domain.
    let first = world.recv_timeout::<Odom>(Duration::from_secs(20))?;
    let (mut tx, mut ty) = (
        first.message.pose.pose.position.x,
        first.message.pose.pose.position.y,
    );
    let mut heading = 0.0f64;
    println!("  t (s) | leader x, y     | Tango x, y      | target distance (m)");
    let start = Instant::now();
    let mut next_row = 0.0;
    let mut distance = f64::MAX;
    while start.elapsed().as_secs_f64() < seconds {
        let t = start.elapsed().as_secs_f64();
        // The leader: a circle of radius 2 m around (2, 0), 0.2 rad/s, starting at the origin.
        let a = 0.2 * t - std::f64::consts::PI;
        let (lx, ly) = (2.0 + 2.0 * a.cos(), 2.0 * a.sin());
        // Target: one metre behind the leader along its direction of travel.
        let (dx, dy) = (-a.sin(), a.cos());
        let (gx, gy) = (lx - dx, ly - dy);
        while let Ok(Some(o)) = world.try_recv::<Odom>() {
            let p = o.message.pose.pose;
            (tx, ty) = (p.position.x, p.position.y);
            heading = 2.0 * p.orientation.z.atan2(p.orientation.w);
        }
        distance = ((gx - tx).powi(2) + (gy - ty).powi(2)).sqrt();
        let bearing = (gy - ty).atan2(gx - tx);
        let turn = (bearing - heading).sin().atan2((bearing - heading).cos());
        let speed = (distance * 0.8).min(1.0) * turn.cos().max(0.0);
        let cmd = Drive {
            linear: Vector3 {
                x: speed,
                ..Default::default()
            },
            angular: Vector3 {
                z: (2.0 * turn).clamp(-1.5, 1.5),
                ..Default::default()
            },
        };
        drive.send("Tango", "Drive", &cmd)?;
        if t >= next_row {
            next_row += 1.0;
            println!("{t:7.1} | {lx:6.2}, {ly:6.2} | {tx:6.2}, {ty:6.2} | {distance:6.2}");
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    let stop = Drive {
        linear: Vector3::default(),
        angular: Vector3::default(),
    };
    drive.send("Tango", "Drive", &stop)?;
    let link = &alpha.stats().links[0].1;
    println!(
        "commands sent: {}, odometry received: {}, dropped: {}",
        link.frames_sent, link.frames_received, link.frames_dropped
    );
    if distance > 1.0 {
        return Err(format!("Tango ended {distance:.2} m from its target").into());
    }
    println!("Tango followed the leader (final distance {distance:.2} m)");
    Ok(())
}
