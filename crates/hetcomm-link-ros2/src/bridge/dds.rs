//! The `dds` transport kind: an external robot that runs plain DDS (no ROS naming), through
//! typed DDS topics: the `ros2_bridge` with DDS topic and type names as the robot's own
//! programs write them.
//!
//! * A topic is its DDS name as written (`"fleet_command"`, `"Fleet/Command"`; no `rt/`
//!   prefix).
//! * A type is its definition (a ROS 2 `.msg` from `msg_paths`, the installed ROS or the
//!   shipped packages, which fixes its fields and CDR layout: the same bytes as the
//!   equivalent IDL struct), named on DDS `pkg::Type` (not ROS's `pkg::msg::dds_::Type_`),
//!   or per topic as `[transports.NAME.dds_types]` says: `"fleet_command" =
//!   "fleet::Command"`.
//! * Everything else is the `ros2_bridge`'s: the same keys (`robot`, `domain_id`,
//!   `reliability`, `history_depth`, `interface`, `same_host`, `connect_timeout_ms`,
//!   `msg_paths`, `publish`, `subscribe`), the same conversion, the same waits for readers
//!   and outcomes (docs/ros-bridges.md, "Plain DDS").

use std::collections::BTreeMap;
use std::sync::Arc;

use hetcomm_config::{Fleet, SettingsReader};
use hetcomm_core::SystemId;
use hetcomm_link::registry::OpenFailure;
use hetcomm_link::{FrameSink, Link};
use hetcomm_rosmsg::bridge::{parse_common, BridgeFactory, BridgeKind, COMMON_KEYS};
use hetcomm_rosmsg::schema::Flavour;

use super::{BridgeSettings, Mapping, Naming, Ros2Bridge};
use crate::settings::{self as ros2, Ros2Settings};

/// Settings of a `dds` transport: a bridge's, and the DDS type name of each topic that does
/// not use the default `pkg::Type`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct DdsSettings {
    /// The robot, its DDS settings and its mappings, read as a `ros2_bridge`'s.
    pub bridge: BridgeSettings,
    /// `[transports.NAME.dds_types]`: topic → DDS type name.
    pub types: BTreeMap<String, String>,
}

/// The keys of a `dds` table, besides the shared ones.
pub const KEYS: [&str; 11] = [
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
    "dds_types",
];

/// The default DDS type name of ROS type `pkg/Type` or `pkg/msg/Type`: `pkg::Type`.
pub fn plain_type(ros_type: &str) -> String {
    let mut parts = ros_type.split('/');
    let pkg = parts.next().unwrap_or_default();
    let name = parts.next_back().unwrap_or_default();
    format!("{pkg}::{name}")
}

/// Why `topic` is not a DDS topic name this kind takes: letters, digits, `_` and `/`,
/// starting with a letter or `_`.
pub fn check_topic(topic: &str) -> Result<(), String> {
    let mut chars = topic.chars();
    let first_ok = chars
        .next()
        .is_some_and(|c| c.is_ascii_alphabetic() || c == '_');
    if !first_ok || !chars.all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '/') {
        return Err("use letters, digits, `_` and `/`, starting with a letter or `_`".into());
    }
    Ok(())
}

/// Why `name` is not a DDS type name: IDL scoped names, `a::b::C`.
fn check_type(name: &str) -> Result<(), String> {
    let ok = name.split("::").all(|part| {
        let mut chars = part.chars();
        chars
            .next()
            .is_some_and(|c| c.is_ascii_alphabetic() || c == '_')
            && chars.all(|c| c.is_ascii_alphanumeric() || c == '_')
    });
    match ok {
        true => Ok(()),
        false => Err(format!(
            "`{name}` is not a DDS type name (identifiers joined by `::`, e.g. \"fleet::Command\")"
        )),
    }
}

/// Reads a `dds` table.
pub fn parse(s: &mut SettingsReader<'_, '_>) -> Option<DdsSettings> {
    let dds = ros2::parse(s).and_then(|r| r.downcast_ref::<Ros2Settings>().cloned());
    let common = parse_common(s, Flavour::Ros2, "dds", check_topic);
    let help = "write \"TOPIC\" = \"DDS_TYPE\", e.g. \"fleet_command\" = \"fleet::Command\"";
    let mut types = BTreeMap::new();
    let mut ok = true;
    if s.has("dds_types") {
        match s.string_table("dds_types", help) {
            Some(entries) => {
                for (topic, name) in entries {
                    let mapped = common.as_ref().is_none_or(|c| {
                        c.publish
                            .iter()
                            .chain(&c.subscribe)
                            .any(|m| m.topic == topic)
                    });
                    let why = match check_type(&name) {
                        Err(why) => Some(why),
                        Ok(()) if !mapped => Some(format!(
                            "`dds_types` names topic `{topic}`, which no `publish` or \
                             `subscribe` entry maps"
                        )),
                        Ok(()) => None,
                    };
                    match why {
                        Some(why) => {
                            s.error_entry("dds_types", &topic, why, help);
                            ok = false;
                        }
                        None => {
                            types.insert(topic, name);
                        }
                    }
                }
            }
            None => ok = false,
        }
    }
    let common = common?;
    let bridge = BridgeSettings {
        robot: common.robot,
        dds: dds?,
        publish: common.publish,
        subscribe: common.subscribe,
        msg_paths: common.msg_paths,
    };
    ok.then_some(DdsSettings { bridge, types })
}

/// The `dds` kind, registered as a [`BridgeFactory`] ([`DdsFactory`]).
pub struct DdsKind;

/// Reads `dds` tables and opens them as [`Ros2Bridge`]s with plain DDS names.
pub type DdsFactory = BridgeFactory<DdsKind>;

impl BridgeKind for DdsKind {
    type Settings = DdsSettings;
    const NAME: &'static str = "dds";
    const KEYS: &'static [&'static str] = &KEYS;

    fn parse(s: &mut SettingsReader<'_, '_>) -> Option<DdsSettings> {
        parse(s)
    }

    fn robot(settings: &DdsSettings) -> &str {
        &settings.bridge.robot
    }

    fn mappings(settings: &DdsSettings) -> (&[Mapping], &[Mapping]) {
        (&settings.bridge.publish, &settings.bridge.subscribe)
    }

    fn open(
        fleet: &Fleet,
        local: SystemId,
        settings: &DdsSettings,
        sink: Arc<dyn FrameSink>,
    ) -> Result<(Arc<dyn Link>, String), OpenFailure> {
        let naming = Naming::Plain(settings.types.clone());
        let bridge = Ros2Bridge::open_named(fleet, local, &settings.bridge, &naming, sink)?;
        let address = format!(
            "dds://{}/{}",
            settings.bridge.dds.domain_id, settings.bridge.robot
        );
        Ok((Arc::new(bridge), address))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plain_names() {
        assert_eq!(plain_type("fleet_msgs/Command"), "fleet_msgs::Command");
        assert_eq!(plain_type("fleet_msgs/msg/Command"), "fleet_msgs::Command");
        assert!(check_topic("fleet_command").is_ok());
        assert!(check_topic("Fleet/Command").is_ok());
        assert!(check_topic("/fleet").is_err());
        assert!(check_topic("rt fleet").is_err());
        assert!(check_type("fleet::Command").is_ok());
        assert!(check_type("fleet:Command").is_err());
    }
}
