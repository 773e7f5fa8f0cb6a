//! The standard ROS 2 messages a bridge knows, as Rust types whose serde field names are the
//! ROS field names: wrap one in a hetcomm message and it maps to its ROS type with nothing
//! to write by hand. (Shared with the ROS 1 bridge in `hetcomm_rosmsg::msgs`; here with ROS
//! 2's header.)
//!
//! ```
//! use hetcomm_link_ros2::msgs::Twist;
//! # use serde::{Deserialize, Serialize};
//! // A hetcomm message that is a geometry_msgs/Twist (a newtype is encoded as its content).
//! #[derive(Serialize, Deserialize)]
//! struct Command(Twist);
//! ```

pub use hetcomm_rosmsg::msgs::ros2::{Header, NavSatFix, Odometry, PoseStamped, Time};
pub use hetcomm_rosmsg::msgs::{
    Float64, NavSatStatus, Point, Pose, PoseWithCovariance, Quaternion, StringMsg, Twist,
    TwistWithCovariance, Vector3,
};
