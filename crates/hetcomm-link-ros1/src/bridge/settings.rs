//! The `ros1_bridge` transport's settings: the robot, its master, and its topic mappings (read
//! as every bridge's are, by `hetcomm_rosmsg::bridge::parse_common`).

use hetcomm_config::SettingsReader;
use hetcomm_rosmsg::bridge::{parse_common, COMMON_KEYS};
use hetcomm_rosmsg::schema::Flavour;

pub use hetcomm_rosmsg::bridge::Mapping;

use crate::valid_segment;

/// Settings of a `ros1_bridge` transport.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct BridgeSettings {
    /// The external system (it runs ROS 1, not hetcomm): `robot = "Tango"`.
    pub robot: String,
    /// The ROS master's XML-RPC URI (`master_uri`; default `$ROS_MASTER_URI`, else
    /// `http://localhost:11311`).
    pub master_uri: String,
    /// `[transports.x.publish]`: sends to (robot, module) of a message type become ROS
    /// messages on a topic.
    pub publish: Vec<Mapping>,
    /// `[transports.x.subscribe]`: ROS messages on a topic become messages of a type from the
    /// robot, to this system's module.
    pub subscribe: Vec<Mapping>,
    /// `msg_paths`: directories searched for message definitions first.
    pub msg_paths: Vec<std::path::PathBuf>,
    /// `connect_timeout_ms` (0–60000, default 500, as the `ros1` transport's): how long a
    /// send waits for the subscribers of its topic to connect, and a closing bridge for them
    /// to read what it published.
    pub connect_timeout_ms: u64,
}

/// The default of `connect_timeout_ms`.
pub const DEFAULT_CONNECT_TIMEOUT_MS: u64 = 500;

/// The keys of a `ros1_bridge` table, besides the shared ones.
pub const KEYS: [&str; 6] = [
    COMMON_KEYS[0],
    "master_uri",
    "connect_timeout_ms",
    COMMON_KEYS[1],
    COMMON_KEYS[2],
    COMMON_KEYS[3],
];

/// Why `topic` is not a global ROS 1 topic name (`/seg/seg`, segments of letters, digits and
/// `_` starting with a letter).
pub fn check_topic(topic: &str) -> Result<(), String> {
    let Some(rest) = topic.strip_prefix('/') else {
        return Err("it must start with `/`".into());
    };
    match rest.split('/').find(|seg| !valid_segment(seg)) {
        Some(seg) => Err(format!(
            "`{seg}` is not a name segment (letters, digits and `_`, starting with a letter)"
        )),
        None => Ok(()),
    }
}

/// Reads a `ros1_bridge` table.
pub fn parse(s: &mut SettingsReader<'_, '_>) -> Option<BridgeSettings> {
    let help = "write the master's XML-RPC URI, e.g. \"http://127.0.0.1:11311\"";
    let master_uri = match s.has("master_uri") {
        true => {
            let uri = s.string("master_uri", help)?;
            if !(uri.starts_with("http://") || uri.starts_with("https://")) {
                s.error(
                    "master_uri",
                    format!("`master_uri` must be an http:// URI, found `{uri}`"),
                    help,
                );
                return None;
            }
            uri
        }
        false => crate::default_master_uri(),
    };
    let mut connect_timeout_ms = DEFAULT_CONNECT_TIMEOUT_MS;
    let mut ok = true;
    if s.has("connect_timeout_ms") {
        match s.int_in("connect_timeout_ms", 0, 60_000, "milliseconds, e.g. 500") {
            Some(ms) => connect_timeout_ms = ms as u64,
            None => ok = false,
        }
    }
    let common = parse_common(s, Flavour::Ros1, "ros1_bridge", check_topic);
    let common = common.filter(|_| ok)?;
    Some(BridgeSettings {
        connect_timeout_ms,
        robot: common.robot,
        master_uri,
        publish: common.publish,
        subscribe: common.subscribe,
        msg_paths: common.msg_paths,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ros_1_topic_names_are_checked_segment_by_segment() {
        assert!(check_topic("/tango/cmd_vel").is_ok());
        assert!(check_topic("tango/cmd_vel").is_err());
        assert!(check_topic("/tango//odom").is_err());
        assert!(check_topic("/tango/2odom").is_err());
    }
}
