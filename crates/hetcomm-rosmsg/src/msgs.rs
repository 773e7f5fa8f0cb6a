//! Seven common ROS messages (any type with a definition maps: these save writing the Rust
//! side of the most used ones), as Rust types whose serde field names are the
//! ROS field names: wrap one in a hetcomm message and it maps to its ROS type with nothing
//! to write by hand. The header differs between ROS 1 and ROS 2: take the stamped types from
//! [`ros1`] or [`ros2`].
//!
//! ```
//! use hetcomm_rosmsg::msgs::Twist;
//! # use serde::{Deserialize, Serialize};
//! // A hetcomm message that is a geometry_msgs/Twist (a newtype is encoded as its content).
//! #[derive(Serialize, Deserialize)]
//! struct Command(Twist);
//! ```

use serde::{Deserialize, Serialize};

/// `std_msgs/String`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct StringMsg {
    /// The text.
    pub data: String,
}

/// `std_msgs/Float64`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Float64 {
    /// The value.
    pub data: f64,
}

/// `geometry_msgs/Vector3` (also the shape of `geometry_msgs/Point`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Vector3 {
    /// x.
    pub x: f64,
    /// y.
    pub y: f64,
    /// z.
    pub z: f64,
}

/// `geometry_msgs/Point`.
pub type Point = Vector3;

/// `geometry_msgs/Quaternion`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
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

impl Default for Quaternion {
    /// The identity rotation.
    fn default() -> Self {
        Quaternion {
            x: 0.0,
            y: 0.0,
            z: 0.0,
            w: 1.0,
        }
    }
}

/// `geometry_msgs/Twist`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Twist {
    /// Linear velocity (m/s).
    pub linear: Vector3,
    /// Angular velocity (rad/s).
    pub angular: Vector3,
}

/// `geometry_msgs/Pose`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Pose {
    /// Position.
    pub position: Point,
    /// Orientation.
    pub orientation: Quaternion,
}

/// `geometry_msgs/PoseStamped`, with the header of [`ros1`] or [`ros2`].
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PoseStamped<H> {
    /// Header.
    pub header: H,
    /// Pose.
    pub pose: Pose,
}

/// `geometry_msgs/PoseWithCovariance`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PoseWithCovariance {
    /// Pose.
    pub pose: Pose,
    /// Row-major 6×6 covariance (36 values).
    pub covariance: Vec<f64>,
}

/// `geometry_msgs/TwistWithCovariance`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TwistWithCovariance {
    /// Twist.
    pub twist: Twist,
    /// Row-major 6×6 covariance (36 values).
    pub covariance: Vec<f64>,
}

/// `nav_msgs/Odometry`, with the header of [`ros1`] or [`ros2`].
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Odometry<H> {
    /// Header.
    pub header: H,
    /// The child frame.
    pub child_frame_id: String,
    /// Pose.
    pub pose: PoseWithCovariance,
    /// Twist.
    pub twist: TwistWithCovariance,
}

/// `sensor_msgs/NavSatStatus`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct NavSatStatus {
    /// Fix status (-1 no fix, 0 fix, 1 SBAS, 2 GBAS).
    pub status: i8,
    /// Which GNSS services were used (bit mask).
    pub service: u16,
}

/// `sensor_msgs/NavSatFix`, with the header of [`ros1`] or [`ros2`].
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct NavSatFix<H> {
    /// Header.
    pub header: H,
    /// Status.
    pub status: NavSatStatus,
    /// Degrees.
    pub latitude: f64,
    /// Degrees.
    pub longitude: f64,
    /// Metres above the WGS 84 ellipsoid.
    pub altitude: f64,
    /// Row-major 3×3 covariance (9 values, m²).
    pub position_covariance: Vec<f64>,
    /// How the covariance is known (0 unknown … 3 known).
    pub position_covariance_type: u8,
}

/// ROS 1's header (`seq`, `stamp` as `secs`/`nsecs`) and the stamped types with it.
pub mod ros1 {
    use serde::{Deserialize, Serialize};

    /// ROS 1's `time`.
    #[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
    pub struct Time {
        /// Seconds.
        pub secs: u32,
        /// Nanoseconds.
        pub nsecs: u32,
    }

    /// `std_msgs/Header` of ROS 1.
    #[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
    pub struct Header {
        /// Sequence number (publishers usually fill it in).
        pub seq: u32,
        /// When.
        pub stamp: Time,
        /// In which frame.
        pub frame_id: String,
    }

    /// `geometry_msgs/PoseStamped` of ROS 1.
    pub type PoseStamped = super::PoseStamped<Header>;
    /// `nav_msgs/Odometry` of ROS 1.
    pub type Odometry = super::Odometry<Header>;
    /// `sensor_msgs/NavSatFix` of ROS 1.
    pub type NavSatFix = super::NavSatFix<Header>;
}

/// ROS 2's header (`stamp` as `sec`/`nanosec`, no `seq`) and the stamped types with it.
pub mod ros2 {
    use serde::{Deserialize, Serialize};

    /// `builtin_interfaces/Time`.
    #[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
    pub struct Time {
        /// Seconds.
        pub sec: i32,
        /// Nanoseconds.
        pub nanosec: u32,
    }

    /// `std_msgs/Header` of ROS 2.
    #[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
    pub struct Header {
        /// When.
        pub stamp: Time,
        /// In which frame.
        pub frame_id: String,
    }

    /// `geometry_msgs/PoseStamped` of ROS 2.
    pub type PoseStamped = super::PoseStamped<Header>;
    /// `nav_msgs/Odometry` of ROS 2.
    pub type Odometry = super::Odometry<Header>;
    /// `sensor_msgs/NavSatFix` of ROS 2.
    pub type NavSatFix = super::NavSatFix<Header>;
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::codec::{decode, encode, Wire};
    use crate::schema::Flavour;
    use serde::de::DeserializeOwned;

    /// Encodes `msg` as hetcomm does (MessagePack, structs as maps), converts it to the ROS
    /// type `ros` of `flavour` and back, and decodes it again: the Rust type and the schema
    /// agree.
    fn round_trip<T: Serialize + DeserializeOwned + PartialEq + std::fmt::Debug>(
        msg: T,
        flavour: Flavour,
        ros: &str,
    ) {
        let bytes = hetcomm_core::payload::encode_buf(&msg).unwrap();
        let value = rmpv::decode::read_value(&mut &bytes[..]).unwrap();
        let ty = flavour.lookup(ros).unwrap();
        let wire = match flavour {
            Flavour::Ros1 => Wire::Ros1,
            Flavour::Ros2 => Wire::CDR,
        };
        let body = encode(&value, ty, wire, "test").unwrap_or_else(|e| panic!("{ros}: {e}"));
        let back = decode(&body, ty, wire).unwrap();
        let mut out = Vec::new();
        rmpv::encode::write_value(&mut out, &back).unwrap();
        let decoded: T = rmp_serde::from_slice(&out).unwrap();
        assert_eq!(decoded, msg, "{ros}");
    }

    fn stamped<H>(flavour: Flavour, header: H)
    where
        H: Clone + Serialize + DeserializeOwned + PartialEq + std::fmt::Debug,
    {
        let twist = Twist {
            linear: Vector3 {
                x: 1.0,
                y: 0.0,
                z: 0.0,
            },
            angular: Vector3 {
                x: 0.0,
                y: 0.0,
                z: 0.5,
            },
        };
        let pose = Pose {
            position: Point {
                x: 1.0,
                y: 2.0,
                z: 3.0,
            },
            orientation: Quaternion::default(),
        };
        round_trip(StringMsg { data: "hi".into() }, flavour, "std_msgs/String");
        round_trip(Float64 { data: 2.5 }, flavour, "std_msgs/Float64");
        round_trip(twist, flavour, "geometry_msgs/Twist");
        round_trip(pose, flavour, "geometry_msgs/Pose");
        let ps = PoseStamped {
            header: header.clone(),
            pose,
        };
        round_trip(ps, flavour, "geometry_msgs/PoseStamped");
        let odom = Odometry {
            header: header.clone(),
            child_frame_id: "base_link".into(),
            pose: PoseWithCovariance {
                pose,
                covariance: vec![0.1; 36],
            },
            twist: TwistWithCovariance {
                twist,
                covariance: vec![0.0; 36],
            },
        };
        round_trip(odom, flavour, "nav_msgs/Odometry");
        let fix = NavSatFix {
            header,
            status: NavSatStatus {
                status: -1,
                service: 1,
            },
            latitude: 60.2,
            longitude: 24.9,
            altitude: 12.0,
            position_covariance: vec![1.0; 9],
            position_covariance_type: 2,
        };
        round_trip(fix, flavour, "sensor_msgs/NavSatFix");
    }

    #[test]
    fn every_standard_type_round_trips_through_its_ros_schemas() {
        let h2 = ros2::Header {
            stamp: ros2::Time { sec: 3, nanosec: 4 },
            frame_id: "map".into(),
        };
        stamped(Flavour::Ros2, h2);
        let h1 = ros1::Header {
            seq: 7,
            stamp: ros1::Time { secs: 3, nsecs: 4 },
            frame_id: "map".into(),
        };
        stamped(Flavour::Ros1, h1);
    }
}
