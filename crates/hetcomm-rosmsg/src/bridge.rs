//! What the `ros1_bridge` and `ros2_bridge` transport kinds share besides the conversion:
//! reading their fleet-file tables ([`parse_common`]: `robot`, `msg_paths`, the `publish` and
//! `subscribe` mappings, the required `delivery` and `security`), naming the robot and modules
//! ([`robot_id`], [`module_id`]), converting what is sent to the robot ([`Outbound`]),
//! counting and reporting bad input once ([`Tally`]; `module_id`, `hosts` and `Tally` are
//! `hetcomm_link::bridge`'s, which every bridge kind shares), turning a ROS message into a hetcomm
//! frame from the robot ([`FrameMaker`]), what the link promises ([`caps`]), and the kind's
//! registration ([`BridgeFactory`] of a [`BridgeKind`]).

use std::collections::HashMap;
use std::marker::PhantomData;
use std::sync::Arc;

use hetcomm_config::{Fleet, KindSettings, KindSpec, RegisteredSettings, SettingsReader};
use hetcomm_config::{TransportDef, TransportKind};
use hetcomm_core::wire::{self, FrameKind};
use hetcomm_core::{MessageType, ModuleId, SystemId};
pub use hetcomm_link::bridge::{hosts, module_id, Tally};
use hetcomm_link::registry::{OpenFailure, OpenRequest, Opened, TransportFactory};
use hetcomm_link::shape::MessageShapes;
use hetcomm_link::{FrameSink, Link, LinkCaps, LinkError};
use rmpv::Value;

use crate::check::{self, Direction};
use crate::codec::{self, Wire};
use crate::registry::Registry;
use crate::schema::{Flavour, RosType};

/// One mapping between a hetcomm (module, message type) and a ROS topic of a ROS type.
#[derive(Clone, Debug)]
pub struct Mapping {
    /// The ROS topic, e.g. `/tango/cmd_vel`.
    pub topic: String,
    /// The hetcomm module: on the robot (publish) or on this system (subscribe).
    pub module: String,
    /// The hetcomm message type id.
    pub message: u32,
    /// The ROS type's schema (its `name` is `pkg/Type`).
    pub schema: &'static RosType,
}

impl Mapping {
    /// The ROS type's name, `pkg/Type`.
    pub fn ros_type(&self) -> &'static str {
        self.schema.name
    }
}

impl PartialEq for Mapping {
    fn eq(&self, other: &Mapping) -> bool {
        (&self.topic, &self.module, self.message, self.schema.name)
            == (
                &other.topic,
                &other.module,
                other.message,
                other.schema.name,
            )
    }
}

impl Eq for Mapping {}

/// The keys every bridge kind reads (besides the shared ones and its own).
pub const COMMON_KEYS: [&str; 4] = ["robot", "publish", "subscribe", "msg_paths"];

/// What every bridge's table says: the robot and the mappings.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Common {
    /// The external system (it runs ROS, not hetcomm): `robot = "Tango"`.
    pub robot: String,
    /// `[transports.x.publish]`: sends to (robot, module) of a message type become ROS
    /// messages on a topic.
    pub publish: Vec<Mapping>,
    /// `[transports.x.subscribe]`: ROS messages on a topic become messages of a type from the
    /// robot, to this system's module.
    pub subscribe: Vec<Mapping>,
    /// `msg_paths = ["…"]`: directories searched for `PKG/msg/TYPE.msg` before the installed
    /// ROS and the shipped definitions (relative to the fleet file).
    pub msg_paths: Vec<std::path::PathBuf>,
}

const MSG_PATHS_HELP: &str = "write directories that hold ROS packages (PKG/msg/TYPE.msg), \
                              relative to the fleet file, e.g. msg_paths = [\"ros/src\"]";

const MAPPING_HELP: &str =
    "write \"MODULE TYPE_ID ROS_TYPE\", e.g. \"Drive 40 geometry_msgs/Twist\"";

fn mappings(
    s: &mut SettingsReader<'_, '_>,
    key: &str,
    registry: &Registry,
    check_topic: fn(&str) -> Result<(), String>,
    ok: &mut bool,
) -> Vec<Mapping> {
    let Some(entries) = s.string_table(key, MAPPING_HELP) else {
        *ok &= !s.has(key);
        return Vec::new();
    };
    let flavour = registry.flavour();
    let mut out = Vec::new();
    for (topic, text) in entries {
        if let Err(why) = check_topic(&topic) {
            s.error_entry(
                key,
                &topic,
                format!("`{topic}` is not a {} topic name: {why}", flavour.label()),
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
                format!("mapping of `{topic}` must have three parts, found {text:?}"),
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
        let schema = match registry.resolve(ros_type) {
            Ok(schema) => schema,
            Err(why) => {
                s.error_entry(
                    key,
                    &topic,
                    format!("mapping of `{topic}`: {why}"),
                    "add the directory that holds its package (PKG/msg/TYPE.msg) to `msg_paths`, \
                     or fix the file",
                );
                *ok = false;
                continue;
            }
        };
        out.push(Mapping {
            topic,
            module: module.to_string(),
            message,
            schema,
        });
    }
    out
}

/// Reads `robot`, `publish`, `subscribe` and checks `delivery = "unacknowledged"` and
/// `security = "none"` of a bridge table of `kind` (e.g. `ros1_bridge`); `check_topic` says
/// why a topic name is not valid. Problems are reported through `s`; None if there was one.
pub fn parse_common(
    s: &mut SettingsReader<'_, '_>,
    flavour: Flavour,
    kind: &str,
    check_topic: fn(&str) -> Result<(), String>,
) -> Option<Common> {
    let mut ok = true;
    let robot = match s.has("robot") {
        true => s.string(
            "robot",
            "the name of the ROS robot's system in quotes, e.g. \"Tango\"",
        ),
        false => {
            let help = format!(
                "add `robot = \"NAME\"`: the system that runs {}",
                flavour.label()
            );
            s.missing("robot", &help);
            None
        }
    };
    ok &= robot.is_some();
    // A ROS node cannot acknowledge hetcomm messages nor open hetcomm's secured sessions.
    if s.string("delivery", "").as_deref() != Some("unacknowledged") {
        s.error(
            "delivery",
            format!(
                "transport `{}` (kind {kind}) carries plain ROS messages, which nobody \
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
                "transport `{}` (kind {kind}) carries plain ROS messages: a ROS node cannot \
                 open hetcomm's secured sessions",
                s.transport()
            ),
            "add `security = \"none\"` (see docs/ros-bridges.md, \"Security\")",
        );
        ok = false;
    }
    let msg_paths: Vec<std::path::PathBuf> = match s.has("msg_paths") {
        true => match s.strings("msg_paths", MSG_PATHS_HELP) {
            Some(list) => list.iter().map(|p| s.path(p)).collect(),
            None => {
                ok = false;
                Vec::new()
            }
        },
        false => Vec::new(),
    };
    let registry = match Registry::for_bridge(flavour, &msg_paths) {
        Ok(r) => r,
        Err(why) => {
            s.error("msg_paths", format!("`msg_paths`: {why}"), MSG_PATHS_HELP);
            ok = false;
            Registry::shipped(flavour)
        }
    };
    let publish = mappings(s, "publish", &registry, check_topic, &mut ok);
    let subscribe = mappings(s, "subscribe", &registry, check_topic, &mut ok);
    if ok && publish.is_empty() && subscribe.is_empty() {
        s.error(
            "publish",
            format!("a {kind} maps no topic"),
            "add a [transports.NAME.publish] or [transports.NAME.subscribe] section",
        );
        ok = false;
    }
    ok.then_some(Common {
        robot: robot?,
        publish,
        subscribe,
        msg_paths,
    })
}

/// The id of the bridge's `robot`, which must be in the fleet and not be `local` (it runs
/// ROS, not hetcomm).
pub fn robot_id(
    fleet: &Fleet,
    local: SystemId,
    robot: &str,
    flavour: Flavour,
) -> Result<SystemId, String> {
    hetcomm_link::bridge::robot_id(fleet, local, robot, flavour.label())
}

/// What a bridge link promises: ordered per topic, not reliable (nobody acknowledges), any
/// frame size, no broadcast.
pub fn caps() -> LinkCaps {
    LinkCaps {
        max_frame: wire::HEADER_LEN + wire::MAX_PAYLOAD,
        mtu: wire::HEADER_LEN + wire::MAX_PAYLOAD,
        reliable: false,
        ordered: true,
        broadcast: false,
    }
}

/// Which mapping a message sent to the robot takes: (robot's module, message type).
pub type MappingKey = (ModuleId, MessageType);

/// A hetcomm payload sent to the robot, as the bridge will convert it: the mapping key and
/// the payload as a MessagePack value. None for frames that are not data (acknowledgements
/// have no ROS counterpart).
fn outgoing(frame: &[u8]) -> Result<Option<(MappingKey, Value)>, String> {
    let f = wire::decode(frame).map_err(|e| format!("not a frame: {e}"))?;
    if f.header.kind != FrameKind::Data {
        return Ok(None);
    }
    let key = (f.header.destination.module, f.header.message_type);
    let value = rmpv::decode::read_value(&mut &f.payload[..])
        .map_err(|e| format!("payload is not MessagePack: {e}"))?;
    Ok(Some((key, value)))
}

/// A message sent to the robot, ready to publish.
pub struct Converted<'a, T> {
    /// Its mapping.
    pub mapping: &'a Mapping,
    /// The mapping's publisher.
    pub publisher: &'a T,
    /// The ROS message body, in the bridge's wire encoding.
    pub body: Vec<u8>,
}

/// A bridge's publish mappings, by (robot's module, message type), each with the transport's
/// publisher `T`: turns a frame sent to the robot into the ROS message to publish.
pub struct Outbound<T> {
    kind: &'static str,
    robot: SystemId,
    robot_name: String,
    wire: Wire,
    by_key: HashMap<MappingKey, (Mapping, T)>,
}

impl<T> Outbound<T> {
    /// No mappings yet, for a bridge of `kind` to `robot` (named `robot_name`), writing `wire`.
    pub fn new(kind: &'static str, robot: SystemId, robot_name: &str, wire: Wire) -> Outbound<T> {
        Outbound {
            kind,
            robot,
            robot_name: robot_name.to_string(),
            wire,
            by_key: HashMap::new(),
        }
    }

    /// Maps sends of `mapping.message` to `module` onto `publisher`.
    pub fn insert(&mut self, module: ModuleId, mapping: Mapping, publisher: T) {
        let key = (module, MessageType(mapping.message));
        self.by_key.insert(key, (mapping, publisher));
    }

    /// The mapping, publisher and converted body of `frame`, sent to `to`; None for frames
    /// that are not data. A frame to another system, of an unmapped type, or whose payload
    /// does not convert (named by both types and the field) is [`LinkError::Refused`]: a
    /// retry cannot change it, so the send fails once with that reason.
    pub fn convert(
        &self,
        to: SystemId,
        frame: &[u8],
    ) -> Result<Option<Converted<'_, T>>, LinkError> {
        let refused = |reason: String| LinkError::Refused { peer: to, reason };
        if to != self.robot {
            let (kind, name) = (self.kind, &self.robot_name);
            return Err(refused(format!("this {kind} reaches only {name}")));
        }
        // Acknowledgements have no ROS counterpart (delivery is unacknowledged anyway).
        let Some((key, value)) = outgoing(frame).map_err(refused)? else {
            return Ok(None);
        };
        let Some((m, publisher)) = self.by_key.get(&key) else {
            return Err(refused(format!(
                "no ROS topic is mapped for message type {} to {}'s module {}",
                key.1 .0, self.robot_name, key.0 .0
            )));
        };
        let what = format!("message type {} for {}", m.message, m.module);
        let body = codec::encode(&value, m.schema, self.wire, &what).map_err(refused)?;
        Ok(Some(Converted {
            mapping: m,
            publisher,
            body,
        }))
    }
}

/// Makes the hetcomm frames of messages received from the robot: data from (robot, module) to
/// (this system, module), numbered per module under one random incarnation
/// ([`hetcomm_link::bridge::FrameMaker`], taking decoded ROS messages). Their CRC covers the
/// header only: a ROS bridge's frames never leave the process, and its link says so
/// (`Link::checksums_payload`), sparing a pass over every byte of an image or point cloud
/// each way (the ROS side has its own transport: TCPROS over TCP, RTPS over UDP).
pub struct FrameMaker(hetcomm_link::bridge::FrameMaker);

impl FrameMaker {
    /// Frames from `robot` to `local`.
    pub fn new(local: SystemId, robot: SystemId) -> FrameMaker {
        FrameMaker(hetcomm_link::bridge::FrameMaker::new(local, robot).header_crc())
    }

    /// The frame of `value` (a decoded ROS message) for `module` as message type `message`.
    pub fn frame(
        &mut self,
        module: ModuleId,
        message: u32,
        value: &Value,
    ) -> Result<Vec<u8>, String> {
        let mut payload = Vec::with_capacity(128);
        rmpv::encode::write_value(&mut payload, value)
            .map_err(|e| format!("could not be encoded: {e}"))?;
        Ok(self.0.frame_of(module, message, &payload))
    }
}

/// One bridge kind (`ros1_bridge`, `ros2_bridge`), as [`BridgeFactory`] registers it: its
/// name, keys, settings and how it opens.
pub trait BridgeKind: Send + Sync + 'static {
    /// Its settings, as [`BridgeKind::parse`] reads them.
    type Settings: KindSettings;
    /// The kind's name in fleet files.
    const NAME: &'static str;
    /// Its keys, besides the shared ones.
    const KEYS: &'static [&'static str];
    /// Reads its table; problems are reported through `s`.
    fn parse(s: &mut SettingsReader<'_, '_>) -> Option<Self::Settings>;
    /// The external robot its settings name (`robot = "Tango"`).
    fn robot(settings: &Self::Settings) -> &str;
    /// Its `publish` and `subscribe` mappings, checked against the program's declared
    /// message types before [`BridgeKind::open`].
    fn mappings(settings: &Self::Settings) -> (&[Mapping], &[Mapping]);
    /// Opens the bridge on system `local` of `fleet`: the link and its local address.
    fn open(
        fleet: &Fleet,
        local: SystemId,
        settings: &Self::Settings,
        sink: Arc<dyn FrameSink>,
    ) -> Result<(Arc<dyn Link>, String), OpenFailure>;
}

/// Reads a bridge kind's tables and opens them ([`KindSpec`] and [`TransportFactory`]).
pub struct BridgeFactory<K>(PhantomData<K>);

impl<K> Default for BridgeFactory<K> {
    fn default() -> Self {
        BridgeFactory(PhantomData)
    }
}

impl<K: BridgeKind> KindSpec for BridgeFactory<K> {
    fn kind(&self) -> TransportKind {
        TransportKind::new(K::NAME)
    }

    fn keys(&self) -> &[&'static str] {
        K::KEYS
    }

    fn parse(&self, s: &mut SettingsReader<'_, '_>) -> Option<RegisteredSettings> {
        K::parse(s).map(RegisteredSettings::new)
    }
}

impl<K: BridgeKind> TransportFactory for BridgeFactory<K> {
    fn kind(&self) -> TransportKind {
        TransportKind::new(K::NAME)
    }

    fn spec(self: Arc<Self>) -> Option<Arc<dyn KindSpec>> {
        Some(self)
    }

    fn bridged_robot(&self, transport: &TransportDef) -> Option<String> {
        let settings = transport.settings.registered::<K::Settings>()?;
        Some(K::robot(settings).to_string())
    }

    fn open(&self, request: OpenRequest<'_>) -> Result<Opened, OpenFailure> {
        let settings: &K::Settings = request.settings()?;
        let (publish, subscribe) = K::mappings(settings);
        check_declared(publish, subscribe, request.shapes)?;
        let (link, address) = K::open(request.fleet, request.local, settings, request.sink)?;
        Ok(Opened {
            link,
            local_address: Some(address),
        })
    }
}

/// Checks every mapping of a message type the program declared (its shape is known) against
/// the mapping's ROS type: the first mismatch, with both types, the topic and the field.
pub fn check_declared(
    publish: &[Mapping],
    subscribe: &[Mapping],
    shapes: &MessageShapes,
) -> Result<(), String> {
    for m in publish {
        if let Some(declared) = shapes.get(m.message) {
            check::check(&declared.shape, m.schema, Direction::ToRos).map_err(|why| {
                format!(
                    "message type {} ({}) does not convert to {} for topic {}: {why}",
                    m.message,
                    declared.name,
                    m.ros_type(),
                    m.topic
                )
            })?;
        }
    }
    for m in subscribe {
        if let Some(declared) = shapes.get(m.message) {
            check::check(&declared.shape, m.schema, Direction::FromRos).map_err(|why| {
                format!(
                    "{} from topic {} does not convert to message type {} ({}): {why}",
                    m.ros_type(),
                    m.topic,
                    m.message,
                    declared.name
                )
            })?;
        }
    }
    Ok(())
}
