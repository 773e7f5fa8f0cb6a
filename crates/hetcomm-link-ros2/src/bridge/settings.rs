//! The `ros2_bridge` transport's settings: the robot, its DDS settings, and its topic mappings
//! (read as every bridge's are, by `hetcomm_rosmsg::bridge::parse_common`).

use hetcomm_config::SettingsReader;
use hetcomm_rosmsg::bridge::{parse_common, COMMON_KEYS};
use hetcomm_rosmsg::schema::Flavour;

pub use hetcomm_rosmsg::bridge::Mapping;

use crate::names;
use crate::settings::{self as ros2, Ros2Settings};

/// Settings of a `ros2_bridge` transport.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct BridgeSettings {
    /// The external system (it runs ROS 2, not hetcomm): `robot = "Tango"`.
    pub robot: String,
    /// DDS settings (`domain_id`, `reliability`, `history_depth`, `interface`, `same_host`,
    /// `connect_timeout_ms`: how long a send waits for its topic's readers to be matched, and
    /// a closing bridge for their acknowledgements); `namespace` is not used by a bridge.
    pub dds: Ros2Settings,
    /// `[transports.x.publish]`: sends to (robot, module) of a message type become ROS
    /// messages on a topic.
    pub publish: Vec<Mapping>,
    /// `[transports.x.subscribe]`: ROS messages on a topic become messages of a type from the
    /// robot, to this system's module.
    pub subscribe: Vec<Mapping>,
    /// `msg_paths`: directories searched for message definitions first.
    pub msg_paths: Vec<std::path::PathBuf>,
}

/// The keys of a `ros2_bridge` table, besides the shared ones.
pub const KEYS: [&str; 10] = [
    COMMON_KEYS[0],
    "domain_id",
    "reliability",
    "history_depth",
    "interface",
    "same_host",
    "connect_timeout_ms",
    COMMON_KEYS[1],
    COMMON_KEYS[2],
    COMMON_KEYS[3],
];

/// Reads a `ros2_bridge` table.
pub fn parse(s: &mut SettingsReader<'_, '_>) -> Option<BridgeSettings> {
    // The DDS keys read exactly as a `ros2` transport's.
    let dds = ros2::parse(s).and_then(|r| r.downcast_ref::<Ros2Settings>().cloned());
    let common = parse_common(s, Flavour::Ros2, "ros2_bridge", |t| {
        names::check_topic(t).map_err(|e| e.to_string())
    });
    let common = common?;
    Some(BridgeSettings {
        robot: common.robot,
        dds: dds?,
        publish: common.publish,
        subscribe: common.subscribe,
        msg_paths: common.msg_paths,
    })
}
