//! Followers that run ROS or plain MQTT, not hetcomm: robots a fleet file declares behind a
//! bridge transport (`ros1_bridge`, `ros2_bridge`, `mqtt_bridge`, or any kind whose factory
//! names a robot, `hetcomm::link::registry::TransportFactory::bridged_robot`).
//!
//! Such a robot has no Plan or Act code of ours: it drives on velocity commands and reports
//! odometry, as a ROS base does. So, for it,
//!
//! * the rover that forwards commands to it sends a [`Twist`] (type 40) to (robot, Plan)
//!   instead of a [`super::Command`]: the command's wheel speeds turned into forward speed
//!   and turn rate by the scenario's drive model, repeated at the control rate as ROS bases
//!   expect of `cmd_vel` (many stop when it goes quiet);
//! * its virtual environment takes its pose from the [`Odometry`] (type 41) arriving in World
//!   from it, instead of integrating Wheels ([`Odometer`]).
//!
//! The fleet file maps the two types to the robot's topics, e.g.
//! `"/tango/cmd_vel" = "Plan 40 geometry_msgs/Twist"` and
//! `"/tango/odom" = "World 41 nav_msgs/Odometry"` (or, for `mqtt_bridge`, JSON topics with
//! the same members). Nothing here depends on which bridge: the types carry the ROS field
//! names, which the bridges convert by name.

use hetcomm::Message;
use hetcomm_sim::report::{CommandKind, CommandRecord};
use hetcomm_sim::{DiffDrive, Pose};
use serde::{Deserialize, Serialize};

use super::wheels_for;

/// `geometry_msgs/Vector3` (and `Point`, whose fields are the same).
#[derive(Serialize, Deserialize, Debug, Clone, Copy, Default, PartialEq)]
pub struct Vector3 {
    /// x.
    pub x: f64,
    /// y.
    pub y: f64,
    /// z.
    pub z: f64,
}

/// `geometry_msgs/Quaternion`.
#[derive(Serialize, Deserialize, Debug, Clone, Copy, PartialEq)]
pub struct Quaternion {
    /// x.
    pub x: f64,
    /// y.
    pub y: f64,
    /// z.
    pub z: f64,
    /// w.
    pub w: f64,
}

/// A velocity command, `geometry_msgs/Twist`: `linear.x` forward speed (world units, i.e.
/// metres, per second), `angular.z` turn rate (rad/s, counter-clockwise).
#[derive(Serialize, Deserialize, Message, Debug, Clone, Copy, Default, PartialEq)]
#[message(id = 40)]
pub struct Twist {
    /// Linear velocity.
    pub linear: Vector3,
    /// Angular velocity.
    pub angular: Vector3,
}

/// The part of `nav_msgs/Odometry` the virtual environment reads (serde ignores the rest).
#[derive(Serialize, Deserialize, Message, Debug, Clone, Copy, PartialEq)]
#[message(id = 41)]
pub struct Odometry {
    /// Where the robot is, in its odometry frame.
    pub pose: PoseWithCovariance,
    /// How it moves (what it is executing).
    pub twist: TwistWithCovariance,
}

/// `geometry_msgs/PoseWithCovariance`, without the covariance.
#[derive(Serialize, Deserialize, Debug, Clone, Copy, PartialEq)]
pub struct PoseWithCovariance {
    /// The pose.
    pub pose: RosPose,
}

/// `geometry_msgs/Pose`.
#[derive(Serialize, Deserialize, Debug, Clone, Copy, PartialEq)]
pub struct RosPose {
    /// `geometry_msgs/Point`.
    pub position: Vector3,
    /// Heading as a quaternion.
    pub orientation: Quaternion,
}

/// `geometry_msgs/TwistWithCovariance`, without the covariance.
#[derive(Serialize, Deserialize, Debug, Clone, Copy, PartialEq)]
pub struct TwistWithCovariance {
    /// The velocity.
    pub twist: Twist,
}

/// The velocity command for a command code: the wheel speeds of Fig. 26 through `drive`.
pub fn twist_for(drive: &DiffDrive, code: u8) -> Twist {
    let w = wheels_for(code);
    Twist {
        linear: Vector3 {
            x: drive.linear_speed(w.left, w.right),
            ..Vector3::default()
        },
        angular: Vector3 {
            z: drive.angular_speed(w.left, w.right),
            ..Vector3::default()
        },
    }
}

/// Where a forwarding rover's commands go: another rover of ours (a Command), or a bridged
/// robot (a Twist at the control rate).
pub(super) struct Relay {
    /// The next rover's name.
    pub name: String,
    /// For a bridged robot: the drive model and the code it is executing.
    pub bridged: Option<(DiffDrive, u8)>,
}

/// A bridged rover's pose in the virtual environment's frame, from its odometry: the first
/// odometry the environment sees is taken as the scenario's starting pose (the robot's
/// odometry frame is its own), and each later one moves the rover by as much.
#[derive(Debug)]
pub struct Odometer {
    /// The rover's name.
    pub name: String,
    drive: DiffDrive,
    start: Pose,
    /// The first odometry pose: (x, y, yaw).
    reference: Option<(f64, f64, f64)>,
    /// The pose now.
    pub pose: Pose,
    /// The command code its odometry shows it executing, once it showed the initial one.
    executing: Option<u8>,
    initial: u8,
}

fn yaw(q: &Quaternion) -> f64 {
    (2.0 * (q.w * q.z + q.x * q.y)).atan2(1.0 - 2.0 * (q.y * q.y + q.z * q.z))
}

impl Odometer {
    /// A rover starting at `start`, expected to start by executing command `initial`.
    pub fn new(name: &str, start: Pose, drive: DiffDrive, initial: u8) -> Odometer {
        Odometer {
            name: name.to_string(),
            drive,
            start,
            reference: None,
            pose: start,
            executing: None,
            initial,
        }
    }

    /// Applies one odometry message that arrived `t_s` into the scenario. Returns a record of
    /// a command the robot was seen to start executing (its reported velocity became another
    /// command's), for the tables: the robot runs no code of ours that could log its receipt.
    pub fn update(&mut self, odom: &Odometry, t_s: f64) -> Option<CommandRecord> {
        let p = &odom.pose.pose;
        let (x, y, th) = (p.position.x, p.position.y, yaw(&p.orientation));
        if !(x.is_finite() && y.is_finite() && th.is_finite()) {
            return None;
        }
        let (x0, y0, th0) = *self.reference.get_or_insert((x, y, th));
        // The displacement since the reference, turned from the odometry frame into the
        // environment's.
        let a = self.start.theta_rad() - th0;
        let (dx, dy) = (x - x0, y - y0);
        self.pose = Pose::new(
            self.start.x + a.cos() * dx - a.sin() * dy,
            self.start.y + a.sin() * dx + a.cos() * dy,
            self.start.theta_deg + (th - th0).to_degrees(),
        );
        let v = odom.twist.twist;
        let code = (0..=2u8).find(|&c| {
            let t = twist_for(&self.drive, c);
            (t.linear.x - v.linear.x).abs() < 1e-6 && (t.angular.z - v.angular.z).abs() < 1e-6
        })?;
        match self.executing {
            // Before the robot shows the initial command, it is standing still from before
            // the run: that is not a command it received.
            None if code == self.initial => {
                self.executing = Some(code);
                None
            }
            Some(old) if old != code => {
                self.executing = Some(code);
                Some(CommandRecord::new(
                    &self.name,
                    t_s,
                    code.into(),
                    CommandKind::Received,
                ))
            }
            _ => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn odom(x: f64, y: f64, yaw: f64, twist: Twist) -> Odometry {
        Odometry {
            pose: PoseWithCovariance {
                pose: RosPose {
                    position: Vector3 { x, y, z: 0.0 },
                    orientation: Quaternion {
                        x: 0.0,
                        y: 0.0,
                        z: (yaw / 2.0).sin(),
                        w: (yaw / 2.0).cos(),
                    },
                },
            },
            twist: TwistWithCovariance { twist },
        }
    }

    #[test]
    fn odometry_moves_the_rover_from_its_starting_pose() {
        let drive = DiffDrive::default();
        let straight = twist_for(&drive, 0);
        assert_eq!((straight.linear.x, straight.angular.z), (10.0, 0.0));
        let left = twist_for(&drive, 1);
        assert_eq!((left.linear.x, left.angular.z), (0.0, 1.0));
        // Tango starts at (191.495, 60) facing -x; its odometry starts wherever it was.
        let mut o = Odometer::new("Tango", Pose::new(191.495, 60.0, 180.0), drive, 0);
        let stopped = twist_for(&drive, 2);
        assert_eq!(o.update(&odom(5.0, 1.0, 0.5, stopped), 0.0), None);
        assert!((o.pose.x - 191.495).abs() < 1e-9 && (o.pose.y - 60.0).abs() < 1e-9);
        // 10 m ahead in its own frame is 10 m along -x in the environment.
        let ahead = odom(
            5.0 + 10.0 * 0.5f64.cos(),
            1.0 + 10.0 * 0.5f64.sin(),
            0.5,
            straight,
        );
        assert_eq!(
            o.update(&ahead, 1.0),
            None,
            "the initial command is not a receipt"
        );
        assert!((o.pose.x - 181.495).abs() < 1e-9, "{:?}", o.pose);
        assert!((o.pose.y - 60.0).abs() < 1e-9, "{:?}", o.pose);
        // A quarter turn left, seen in the odometry's twist: a received Turn Left.
        let turned = odom(
            ahead.pose.pose.position.x,
            ahead.pose.pose.position.y,
            0.5 + std::f64::consts::FRAC_PI_2,
            left,
        );
        let rec = o.update(&turned, 2.5).expect("a receipt");
        assert_eq!((rec.rover.as_str(), rec.code, rec.t_s), ("Tango", 1, 2.5));
        assert!((o.pose.theta_deg - 270.0).abs() < 1e-6, "{:?}", o.pose);
        assert_eq!(o.update(&turned, 2.6), None, "still turning");
    }
}
