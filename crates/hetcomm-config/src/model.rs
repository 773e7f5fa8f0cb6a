//! The validated fleet: what every other crate reads. Built only by the loaders in this crate,
//! so holding a [`Fleet`] means it passed validation.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::Duration;

use hetcomm_core::{ModuleId, SystemId};

/// A validated fleet configuration.
#[derive(Clone, Debug, PartialEq)]
pub struct Fleet {
    /// Optional human name of the fleet.
    pub name: Option<String>,
    /// The file it was loaded from (None when built from a string).
    pub source: Option<PathBuf>,
    /// Systems, sorted by id.
    pub systems: Vec<SystemDef>,
    /// Modules, sorted by id.
    pub modules: Vec<ModuleDef>,
    /// Transport instances, in file order. The communication table refers to them by index.
    pub transports: Vec<TransportDef>,
    /// (source, destination) → index into `transports` of the pair's first choice; a missing
    /// pair is `X` (no traffic). A cell listing several transports (`"wifi,bt"`) puts its
    /// first here and the others in [`Fleet::fallbacks`]; [`Fleet::transports_for`] gives the
    /// whole list.
    pub table: BTreeMap<(SystemId, SystemId), usize>,
    /// (source, destination) → the transports after the first, in order of preference, for
    /// the pairs whose cell lists more than one (`"wifi,bt"`, `"W,B"`). Pairs of one
    /// transport are not here, so a large table of one-letter cells costs nothing more.
    pub fallbacks: BTreeMap<(SystemId, SystemId), Vec<usize>>,
    /// `[security] keys = "DIR"`: the directory `hetcomm keygen` wrote, resolved against the
    /// fleet file's directory (systems' keys were read from it).
    pub keys_dir: Option<PathBuf>,
    /// `[security] in_process = true`: secure the links that stay inside a process too
    /// (in-process and emulated transports), as a test of the secured path; network
    /// transports are secured whatever this says, unless they say `security = "none"`.
    pub secure_in_process: bool,
    /// `[[tap]]` tables of the fleet file: taps placed on every system of the fleet when it
    /// opens, for the whole run (the same syntax and checks as a scenario file's `[[tap]]`;
    /// a window's times count from when the system opens).
    pub taps: Vec<crate::scenario::ScenarioTap>,
}

/// One system (robot or virtual environment).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SystemDef {
    /// Numeric id (on the wire).
    pub id: SystemId,
    /// Friendly name (unique).
    pub name: String,
    /// The modules this system hosts, sorted by id; None means every module of the fleet
    /// (the fleet file's `modules = [...]` long form is the only way to narrow it).
    pub modules: Option<Vec<ModuleId>>,
    /// The system's public key (X25519, 32 bytes): from `public_key` (base64), from
    /// `public_key_file`, or from `<keys dir>/<name>.pub`. None: the system has no key, and
    /// secured transports cannot authenticate it.
    pub public_key: Option<[u8; 32]>,
    /// Where the process that runs this system finds its private key: `private_key_file`, or
    /// `<keys dir>/<name>.key` when that file exists. Read (and its permissions checked) when
    /// the system is opened, not at load time: other machines' private keys are not here.
    pub private_key_file: Option<PathBuf>,
}

/// One module kind; the same id on every system.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ModuleDef {
    /// Numeric id (on the wire).
    pub id: ModuleId,
    /// Name (unique).
    pub name: String,
    /// The module's inbox bound and overflow policy.
    pub inbox: InboxConfig,
}

/// How big a module's inbox is and what happens when it is full.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct InboxConfig {
    /// Most messages held at once.
    pub capacity: usize,
    /// What to do with a message that arrives when the inbox is full.
    pub overflow: OverflowPolicy,
}

impl Default for InboxConfig {
    fn default() -> Self {
        InboxConfig {
            capacity: 1024,
            overflow: OverflowPolicy::DropOldest,
        }
    }
}

/// Overflow policy of a full inbox. Every drop is counted.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum OverflowPolicy {
    /// Evict the oldest queued message of the lowest priority present (at or below the new
    /// message's priority) to make room; if every queued message outranks the new one, the new
    /// one is dropped instead.
    DropOldest,
    /// Drop the arriving message.
    DropNewest,
    /// Make the delivering side wait for room up to `timeout`, then drop the arriving message.
    Block {
        /// Longest wait.
        timeout: Duration,
    },
}

/// Whether a transport instance confirms delivery.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DeliveryMode {
    /// The receiving router acknowledges; the sender retransmits until acknowledged or the
    /// attempt budget is spent. Outcome: delivered or failed.
    Acknowledged,
    /// Fire and forget (after retrying local transport errors). Outcome: sent without
    /// confirmation, or failed.
    Unacknowledged,
}

/// A transport kind: the name a fleet file gives in `kind = "…"`. One type for every kind,
/// built in or registered by a link crate ([`TransportKind::new`] and a
/// [`crate::kinds::KindSpec`], see `docs/architecture.md`, "A new transport"); the
/// constants below are the kinds the fleet loader knows by itself ([`TransportKind::ALL`],
/// the one built-in list). Whether a kind is compiled into a program is decided when the
/// fleet is opened, not here. Kinds order by name.
#[derive(Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct TransportKind(&'static str);

// The built-in kinds keep the spelling they had as enum variants (`TransportKind::Udp`), so
// that code matching on them reads as before.
#[allow(non_upper_case_globals)]
impl TransportKind {
    /// Between systems of one process.
    pub const Inproc: TransportKind = TransportKind("inproc");
    /// UDP datagrams.
    pub const Udp: TransportKind = TransportKind("udp");
    /// TCP streams.
    pub const Tcp: TransportKind = TransportKind("tcp");
    /// ROS 1 topics through a ROS master.
    pub const Ros1: TransportKind = TransportKind("ros1");
    /// Bluetooth Classic RFCOMM.
    pub const Bluetooth: TransportKind = TransportKind("bluetooth");
    /// Zenoh (known to the fleet file; its keys are kept raw until a crate registers it).
    pub const Zenoh: TransportKind = TransportKind("zenoh");
    /// MQTT through a broker (likewise).
    pub const Mqtt: TransportKind = TransportKind("mqtt");
    /// DDS (likewise).
    pub const Dds: TransportKind = TransportKind("dds");
    /// A wrapper that emulates a radio link (loss, latency, range, …) over another transport.
    pub const Emulated: TransportKind = TransportKind("emulated");
}

impl TransportKind {
    /// The kinds the fleet loader knows by itself, in documentation order. Kinds registered
    /// by link crates come on top of these (`crate::kinds::Kinds`).
    pub const ALL: [TransportKind; 9] = [
        TransportKind::Inproc,
        TransportKind::Udp,
        TransportKind::Tcp,
        TransportKind::Ros1,
        TransportKind::Bluetooth,
        TransportKind::Zenoh,
        TransportKind::Mqtt,
        TransportKind::Dds,
        TransportKind::Emulated,
    ];

    /// The kind named `name` in fleet files (e.g. `TransportKind::new("ros2")`); the same
    /// value as the built-in constant of that name, if there is one.
    pub const fn new(name: &'static str) -> TransportKind {
        TransportKind(name)
    }

    /// The name used in fleet files (`kind = "…"`).
    pub fn as_str(self) -> &'static str {
        self.0
    }

    /// Parses the fleet-file name of a built-in kind ([`TransportKind::ALL`]).
    pub fn parse(s: &str) -> Option<TransportKind> {
        Self::ALL.into_iter().find(|k| k.as_str() == s)
    }
}

impl std::fmt::Debug for TransportKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.0)
    }
}

impl std::fmt::Display for TransportKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// A named transport instance.
#[derive(Clone, Debug, PartialEq)]
pub struct TransportDef {
    /// Its name in the fleet file (for a letter of a legacy table, the letter itself).
    pub name: String,
    /// One byte written into each frame's "communication type" field: the table letter when
    /// the transport was named by one, else the first byte of the name.
    pub tag: u8,
    /// The kind.
    pub kind: TransportKind,
    /// Acknowledged or not.
    pub delivery: DeliveryMode,
    /// Transmission attempts before a send is reported failed (the thesis used 3).
    pub attempts: u32,
    /// Sends to one destination that may await their outcome at once; a send beyond it is
    /// refused (backpressure) instead of being kept without bound.
    pub max_in_flight: u32,
    /// Bytes of frames to one destination that may await their outcome at once: a send that
    /// would go past it is refused (backpressure) while earlier ones are pending, so an
    /// acknowledged sender of large messages cannot overrun the receiver's socket buffer
    /// (frames the kernel drops there end unconfirmed). One message larger than the limit is
    /// still sent when nothing else is pending.
    pub max_in_flight_bytes: usize,
    /// Receivers deliver each sender's messages carried by this transport in the order they
    /// were sent (holding early arrivals until the gap fills or a hold timeout passes).
    pub ordered: bool,
    /// How long a frame may wait to share a write or datagram with the frames after it, in
    /// microseconds; 0 sends every frame at once. Only links that batch use it.
    pub batch_linger_us: u32,
    /// Whether frames on this transport are authenticated and encrypted (the default for
    /// every transport that leaves the process) or, by `security = "none"`, not.
    pub security: SecurityMode,
    /// Kind-specific settings.
    pub settings: TransportSettings,
    /// The transport this one is layered over (an `emulated` transport's `over`): its frames
    /// travel on that one's link. None for a transport with a link of its own.
    pub over: Option<String>,
    /// Whether its own link never leaves the process (`inproc`, the private hub of an
    /// `emulated` transport without `over`), as its kind says
    /// ([`crate::KindSpec::in_process`]). A transport layered `over` another is judged by
    /// that one ([`Fleet::leaves_process`]).
    pub in_process: bool,
}

/// How a transport protects its frames (`security = ...` in its fleet-file section).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum SecurityMode {
    /// Authenticated and encrypted with the systems' keys (`security = "keys"`, the
    /// default). A transport that leaves the process refuses to open without keys.
    #[default]
    Keys,
    /// No authentication, no encryption (`security = "none"`): anyone who can reach the
    /// transport can pose as any system. Only by explicit choice.
    None,
}

/// The default [`TransportDef::batch_linger_us`]: long enough to gather a burst, short
/// against a robot's control period.
pub const DEFAULT_BATCH_LINGER_US: u32 = 50;

/// The default [`TransportDef::max_in_flight`]: far more than a round trip's worth of messages
/// on any link here, small enough that the frames kept for retransmission stay bounded.
pub const DEFAULT_MAX_IN_FLIGHT: u32 = 1024;

/// The default [`TransportDef::max_in_flight_bytes`]: half the 4 MiB receive buffer the UDP
/// link asks for, so a window's worth of frames (and their retransmissions) fits in it.
pub const DEFAULT_MAX_IN_FLIGHT_BYTES: usize = 2 << 20;

/// Kind-specific settings, checked against each kind's schema.
#[derive(Clone, Debug, PartialEq)]
pub enum TransportSettings {
    /// A kind known by name whose crate is not compiled into this program (or, loaded
    /// without the program's kinds, any kind): the raw keys, stringified.
    Raw(BTreeMap<String, String>),
    /// A kind registered by a link crate: the settings its [`crate::kinds::KindSpec`] parsed.
    Registered(RegisteredSettings),
}

impl TransportSettings {
    /// The settings of a registered kind as the type its [`crate::kinds::KindSpec`] built;
    /// None for another type, or for settings the loader models itself.
    pub fn registered<T: KindSettings>(&self) -> Option<&T> {
        match self {
            TransportSettings::Registered(s) => s.downcast_ref(),
            _ => None,
        }
    }
}

/// The typed settings of a registered kind, as its [`crate::kinds::KindSpec`] built them. The
/// link crate that registered the kind reads them back with [`RegisteredSettings::downcast_ref`].
#[derive(Clone)]
pub struct RegisteredSettings(std::sync::Arc<dyn KindSettings>);

impl RegisteredSettings {
    /// Wraps a kind's settings.
    pub fn new<T: KindSettings>(settings: T) -> RegisteredSettings {
        RegisteredSettings(std::sync::Arc::new(settings))
    }

    /// The settings as the type the kind's spec built, or None for another type.
    pub fn downcast_ref<T: KindSettings>(&self) -> Option<&T> {
        self.0.as_any().downcast_ref::<T>()
    }
}

impl std::fmt::Debug for RegisteredSettings {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        self.0.fmt(f)
    }
}

impl PartialEq for RegisteredSettings {
    fn eq(&self, other: &Self) -> bool {
        self.0.eq_dyn(other.0.as_any())
    }
}

/// What a registered kind's settings type must be: comparable, printable and shareable
/// between threads, like the built-in settings. Implemented for every such type.
pub trait KindSettings: std::any::Any + std::fmt::Debug + Send + Sync {
    /// The settings as `Any`, to downcast.
    fn as_any(&self) -> &dyn std::any::Any;
    /// Equal to `other` (false for another type).
    fn eq_dyn(&self, other: &dyn std::any::Any) -> bool;
}

impl<T> KindSettings for T
where
    T: std::any::Any + std::fmt::Debug + PartialEq + Send + Sync,
{
    fn as_any(&self) -> &dyn std::any::Any {
        self
    }

    fn eq_dyn(&self, other: &dyn std::any::Any) -> bool {
        other.downcast_ref::<T>() == Some(self)
    }
}

/// A Bluetooth device address, `XX:XX:XX:XX:XX:XX`, as fleet files and the thesis's address
/// files write it (read by [`crate::SettingsReader::bluetooth_addresses`] for the `bluetooth`
/// kind's crate).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct BdAddr(pub [u8; 6]);

impl std::fmt::Display for BdAddr {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let b = self.0;
        write!(
            f,
            "{:02X}:{:02X}:{:02X}:{:02X}:{:02X}:{:02X}",
            b[0], b[1], b[2], b[3], b[4], b[5]
        )
    }
}

impl Fleet {
    /// The system with this friendly name.
    pub fn system_by_name(&self, name: &str) -> Option<&SystemDef> {
        self.systems.iter().find(|s| s.name == name)
    }

    /// The system with this id.
    pub fn system(&self, id: SystemId) -> Option<&SystemDef> {
        self.systems.iter().find(|s| s.id == id)
    }

    /// The module with this name.
    pub fn module_by_name(&self, name: &str) -> Option<&ModuleDef> {
        self.modules.iter().find(|m| m.name == name)
    }

    /// The module with this id.
    pub fn module(&self, id: ModuleId) -> Option<&ModuleDef> {
        self.modules.iter().find(|m| m.id == id)
    }

    /// The transport that carries traffic from `src` to `dst`, or None for `X`.
    pub fn route(&self, src: SystemId, dst: SystemId) -> Option<&TransportDef> {
        self.table.get(&(src, dst)).map(|&i| &self.transports[i])
    }

    /// Every transport that may carry traffic from `src` to `dst`, in order of preference
    /// (indices into `transports`): the cell's first choice, then its fallbacks. Empty for `X`.
    pub fn transports_for(&self, src: SystemId, dst: SystemId) -> Vec<usize> {
        let Some(&first) = self.table.get(&(src, dst)) else {
            return Vec::new();
        };
        let mut out = vec![first];
        if let Some(rest) = self.fallbacks.get(&(src, dst)) {
            out.extend_from_slice(rest);
        }
        out
    }

    /// Whether the table lets `src` send to `dst` on transport `i` (first choice or fallback).
    pub fn carries(&self, src: SystemId, dst: SystemId, i: usize) -> bool {
        self.table.get(&(src, dst)) == Some(&i)
            || self
                .fallbacks
                .get(&(src, dst))
                .is_some_and(|rest| rest.contains(&i))
    }

    /// Every (source, destination, transport) the table allows, first choices and fallbacks.
    pub fn table_entries(&self) -> impl Iterator<Item = (SystemId, SystemId, usize)> + '_ {
        let first = self.table.iter().map(|(&(s, d), &i)| (s, d, i));
        let rest = self
            .fallbacks
            .iter()
            .flat_map(|(&(s, d), v)| v.iter().map(move |&i| (s, d, i)));
        first.chain(rest)
    }

    /// The transport with this name.
    pub fn transport(&self, name: &str) -> Option<&TransportDef> {
        self.transports.iter().find(|t| t.name == name)
    }

    /// Systems the table connects to nobody, in either direction (every pair `X`): valid, but
    /// usually a name left out of the table by mistake. `hetcomm validate` warns of them.
    pub fn isolated_systems(&self) -> Vec<&str> {
        let mut connected = std::collections::BTreeSet::new();
        for (from, to) in self.table.keys() {
            connected.insert(*from);
            connected.insert(*to);
        }
        self.systems
            .iter()
            .filter(|s| !connected.contains(&s.id))
            .map(|s| s.name.as_str())
            .collect()
    }

    /// One line: systems, modules, and pairs per transport — what `hetcomm validate` prints.
    pub fn summary(&self) -> String {
        // One pass over the pairs, however many transports: a big fleet has millions.
        let mut counts = vec![0usize; self.transports.len()];
        for &i in self.table.values().chain(self.fallbacks.values().flatten()) {
            if let Some(c) = counts.get_mut(i) {
                *c += 1;
            }
        }
        let mut per: Vec<(String, usize)> = self
            .transports
            .iter()
            .zip(counts)
            .map(|(t, n)| (t.name.clone(), n))
            .collect();
        per.retain(|(_, n)| *n > 0);
        let pairs = per
            .iter()
            .map(|(name, n)| format!("{name}: {n}"))
            .collect::<Vec<_>>()
            .join(", ");
        format!(
            "{} systems, {} modules, {} pairs ({})",
            self.systems.len(),
            self.modules.len(),
            self.table.len(),
            if pairs.is_empty() {
                "no traffic".to_string()
            } else {
                pairs
            }
        )
    }
}
