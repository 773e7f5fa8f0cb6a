//! # hetcomm-rosmsg — what the ROS 1 and ROS 2 bridges share
//!
//! The `ros1_bridge` (crate `hetcomm-link-ros1`) and `ros2_bridge` (crate
//! `hetcomm-link-ros2`) transport kinds put an external ROS robot in a fleet through typed
//! topics (docs/ros-bridges.md). Everything about them that does not depend on the ROS
//! transport is here, once:
//!
//! * [`msgfile`]: reading a `.msg` file (ROS 1 or ROS 2), with errors at `file:line`;
//! * [`idlfile`]: reading a ROS 2 message from an `.idl` file, for packages that ship only
//!   that;
//! * [`registry`]: where definitions are found (`msg_paths`, an installed ROS, the shipped
//!   common_interfaces) and how a type resolves into a schema, with ROS 1's MD5 sum;
//! * [`schema`]: a ROS type's schema, for ROS 1 or ROS 2 (they differ in `std_msgs/Header`);
//! * [`codec`]: conversion between a hetcomm payload and a ROS message body, by serde field
//!   name, in ROS 1's serialization or ROS 2's CDR;
//! * [`msgs`]: Rust types of those messages whose serde names are the ROS names;
//! * [`check`]: whether a declared message type's shape converts to or from a ROS type,
//!   checked when the bridge opens;
//! * [`typehash`]: ROS 2's type hash (RIHS01) of a definition, and the one a DDS endpoint
//!   offers;
//! * [`bridge`]: reading a bridge's fleet-file table, and the receive and report helpers.

pub mod bridge;
pub mod check;
pub mod codec;
pub mod idlfile;
pub mod msgfile;
pub mod msgs;
pub mod registry;
pub mod schema;
pub mod typehash;
