//! # hetcomm-link-ros2 — the `ros2` transport kind
//!
//! Carries hetcomm frames between hetcomm systems over DDS, named as ROS 2 names things, with
//! [rustdds](https://docs.rs/rustdds) (a native Rust DDS/RTPS implementation that
//! interoperates with Cyclone DDS and Fast DDS; no ROS 2 installation is needed). The `ros1`
//! transport's layout, on ROS 2:
//!
//! * every system reads **one topic named after it**, under the transport's namespace:
//!   `namespace = "/hetcomm"` (the default) gives `/hetcomm/Bravo`, DDS topic
//!   `rt/hetcomm/Bravo` ([`names`]); a link writes on each other system's topic, with one DDS
//!   writer per destination, all created when the link opens;
//! * the message type is **`std_msgs/msg/UInt8MultiArray`** (DDS type
//!   `std_msgs::msg::dds_::UInt8MultiArray_`, CDR): `layout` empty, `data` exactly one hetcomm
//!   frame ([`msg::FrameMessage`]). Any ROS 2 program can read and write it; samples that do
//!   not deserialize, or carry no data, are counted as dropped and never delivered;
//! * settings ([`Ros2Settings`]): `domain_id`, `namespace`, `reliability`, `history_depth`,
//!   `interface`, `same_host`, `connect_timeout_ms` (docs/ros2.md).
//!
//! ## What the link guarantees
//!
//! [`hetcomm_link::LinkCaps`]: `reliable = false`, `ordered = true`. With reliable QoS, RTPS
//! resends a sample until every *matched* reader acknowledged it, in order; but a DDS writer
//! does not keep samples for readers that match later (volatile durability), and a KeepLast
//! history overwrites samples a slow reader has not acknowledged yet. So a send to a system
//! whose reader is not matched yet **waits for the match** (at most `connect_timeout_ms`) and
//! fails with `Unreachable` if none comes; once matched, sends do not wait. The router's
//! acknowledgements make delivery reliable end to end on top.
//!
//! ## Bridges
//!
//! The crate also has the `ros2_bridge` kind ([`bridge`]): an external ROS 2 robot in the
//! fleet through typed topics (docs/ros-bridges.md), any type read from its `.msg` definition
//! (`hetcomm_rosmsg::registry`), CDR conversion in [`rostypes`] and Rust types for common ones
//! in [`msgs`]; and the `dds` kind ([`bridge::dds`]): the same bridge to a robot that runs
//! plain DDS, with its own topic and type names.
//!
//! ## Discovery
//!
//! DDS discovery (SPDP/SEDP): multicast on the LAN, plus, with `same_host = true` (the
//! default), unicast announcements to the well-known ports of the first participants on
//! `127.0.0.1`, so that participants of one host find each other without multicast on
//! loopback (which Linux's `lo` lacks by default).

pub mod bridge;
#[cfg(feature = "cyclone")]
pub mod cyclone;
pub mod factory;
pub mod frame_cdr;
pub mod link;
pub mod msg;
pub mod msgs;
pub mod names;
pub mod raw;
pub mod rostypes;
pub mod settings;

pub use factory::Ros2Factory;
pub use link::{Ros2Link, Ros2OpenError, MAX_FRAME};
pub use settings::{Backend, Reliability, Ros2Settings};

/// Registers the `ros2` transport kind, the `ros2_bridge` and the plain-DDS bridge `dds`
/// (called by `hetcomm`'s registry with the `ros2` feature).
pub fn register_transports(registry: &mut hetcomm_link::registry::Registry) {
    registry.register(Ros2Factory);
    registry.register(bridge::Ros2BridgeFactory::default());
    registry.register(bridge::dds::DdsFactory::default());
}
