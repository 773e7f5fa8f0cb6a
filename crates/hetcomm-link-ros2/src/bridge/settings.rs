//! The `ros2_bridge` transport's settings: the robot, its DDS settings, and its topic mappings.

use hetcomm_config::{RegisteredSettings, SettingsReader};

use crate::names;
use crate::rostypes::{self, RosType};
use crate::settings::{self as ros2, Ros2Settings};

/// One mapping between a hetcomm (module, message type) and a ROS topic of a ROS type.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Mapping {
    /// The ROS 2 topic, e.g. `/tango/cmd_vel`.
    pub topic: String,
    /// The hetcomm module: on the robot (publish) or on this system (subscribe).
    pub module: String,
    /// The hetcomm message type id.
    pub message: u32,
    /// The ROS type.
    pub ros_type: &'static str,
}

impl Mapping {
    /// The ROS type's schema.
    pub fn schema(&self) -> &'static RosType {
        rostypes::lookup(self.ros_type).expect("checked when read")
    }
}

/// Settings of a `ros2_bridge` transport.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct BridgeSettings {
    /// The external system (it runs ROS 2, not hetcomm): `robot = "Tango"`.
    pub robot: String,
    /// DDS settings (`domain_id`, `reliability`, `history_depth`, `interface`, `same_host`);
    /// `namespace` and `connect_timeout_ms` are not used by a bridge.
    pub dds: Ros2Settings,
    /// `[transports.x.publish]`: sends to (robot, module) of a message type become ROS
    /// messages on a topic.
    pub publish: Vec<Mapping>,
    /// `[transports.x.subscribe]`: ROS messages on a topic become messages of a type from the
    /// robot, to this system's module.
    pub subscribe: Vec<Mapping>,
}

/// The keys of a `ros2_bridge` table, besides the shared ones.
pub const KEYS: [&str; 8] = [
    "robot",
    "domain_id",
    "reliability",
    "history_depth",
    "interface",
    "same_host",
    "publish",
    "subscribe",
];

const MAPPING_HELP: &str =
    "write \"MODULE TYPE_ID ROS_TYPE\", e.g. \"Drive 40 geometry_msgs/Twist\"";

fn mappings(s: &mut SettingsReader<'_, '_>, key: &str, ok: &mut bool) -> Vec<Mapping> {
    let Some(entries) = s.string_table(key, MAPPING_HELP) else {
        *ok &= !s.has(key);
        return Vec::new();
    };
    let mut out = Vec::new();
    for (topic, text) in entries {
        if let Err(why) = names::check_topic(&topic) {
            s.error_entry(
                key,
                &topic,
                format!("`{topic}` is not a ROS 2 topic name: {why}"),
                "write the full name, e.g. \"/tango/cmd_vel\"",
            );
            *ok = false;
            continue;
        }
        let parts: Vec<&str> = text.split_whitespace().collect();
        let [module, id, ros_type] = parts[..] else {
            s.error_entry(
                key,
                &topic,
                format!(
                    "mapping of `{topic}` must have three parts, found {:?}",
                    text
                ),
                MAPPING_HELP,
            );
            *ok = false;
            continue;
        };
        let Ok(message) = id.parse::<u32>() else {
            s.error_entry(
                key,
                &topic,
                format!("mapping of `{topic}`: `{id}` is not a message type id"),
                "the number in the message's #[message(id = N)]",
            );
            *ok = false;
            continue;
        };
        let Some(schema) = rostypes::lookup(ros_type) else {
            s.error_entry(
                key,
                &topic,
                format!("mapping of `{topic}`: this build does not know the ROS type `{ros_type}`"),
                format!("known types: {}", rostypes::known_names()),
            );
            *ok = false;
            continue;
        };
        out.push(Mapping {
            topic,
            module: module.to_string(),
            message,
            ros_type: schema.name,
        });
    }
    out
}

/// Reads a `ros2_bridge` table.
pub fn parse(s: &mut SettingsReader<'_, '_>) -> Option<RegisteredSettings> {
    let mut ok = true;
    let robot = match s.has("robot") {
        true => s.string(
            "robot",
            "the name of the ROS robot's system in quotes, e.g. \"Tango\"",
        ),
        false => {
            s.missing(
                "robot",
                "add `robot = \"NAME\"`: the system that runs ROS 2",
            );
            None
        }
    };
    ok &= robot.is_some();
    // The DDS keys read exactly as a `ros2` transport's.
    let dds = ros2::parse(s).and_then(|r| r.downcast_ref::<Ros2Settings>().cloned());
    ok &= dds.is_some();
    // A ROS node cannot acknowledge hetcomm messages nor open hetcomm's secured sessions.
    if s.string("delivery", "").as_deref() != Some("unacknowledged") {
        s.error(
            "delivery",
            format!(
                "transport `{}` (kind ros2_bridge) carries plain ROS messages, which nobody \
                 acknowledges",
                s.transport()
            ),
            "add `delivery = \"unacknowledged\"`: sends end as Sent (without confirmation)",
        );
        ok = false;
    }
    if s.string("security", "").as_deref() != Some("none") {
        s.error(
            "security",
            format!(
                "transport `{}` (kind ros2_bridge) carries plain ROS messages: a ROS node cannot \
                 open hetcomm's secured sessions",
                s.transport()
            ),
            "add `security = \"none\"` (see docs/ros-bridges.md, \"Security\")",
        );
        ok = false;
    }
    let publish = mappings(s, "publish", &mut ok);
    let subscribe = mappings(s, "subscribe", &mut ok);
    if ok && publish.is_empty() && subscribe.is_empty() {
        s.error(
            "publish",
            "a ros2_bridge maps no topic",
            "add a [transports.NAME.publish] or [transports.NAME.subscribe] section",
        );
        ok = false;
    }
    if !ok {
        return None;
    }
    Some(RegisteredSettings::new(BridgeSettings {
        robot: robot?,
        dds: dds?,
        publish,
        subscribe,
    }))
}
