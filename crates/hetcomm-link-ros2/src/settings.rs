//! The `ros2` transport's fleet-file settings ([`Ros2Settings`]) and how they are read
//! ([`parse`], called by the factory's `KindSpec`).

use std::net::IpAddr;

use hetcomm_config::{RegisteredSettings, SettingsReader};

use crate::names;

/// DDS reliability of the transport's topics.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Reliability {
    /// RTPS reliable: the writer keeps each sample (up to the history depth) and resends it
    /// until every matched reliable reader has acknowledged it.
    Reliable,
    /// RTPS best effort: each sample is sent once.
    BestEffort,
}

/// The DDS implementation under a `ros2` transport (`dds` key). Both put the same bytes on
/// the same topics (ROS 2 names, `std_msgs/msg/UInt8MultiArray` in CDR), so systems on
/// either backend talk to each other and to any ROS 2 / DDS program.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Backend {
    /// rustdds, pure Rust (`dds = "rustdds"`, the default).
    #[default]
    RustDds,
    /// Cyclone DDS, the C library, through the `cyclors` bindings (`dds = "cyclone"`; needs
    /// this crate's cargo feature `cyclone`, which builds Cyclone DDS from source).
    Cyclone,
}

/// Settings of a `ros2` transport (fleet keys in parentheses).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Ros2Settings {
    /// The ROS 2 domain id (`domain_id`, 0–232, default 0): `ROS_DOMAIN_ID`.
    pub domain_id: u16,
    /// The ROS namespace of the systems' topics (`namespace`, default `/hetcomm`): system
    /// `Bravo` listens on `/hetcomm/Bravo`, DDS topic `rt/hetcomm/Bravo`.
    pub namespace: String,
    /// Reliability (`reliability = "reliable" | "best_effort"`, default reliable).
    pub reliability: Reliability,
    /// KeepLast history depth of the writers and readers (`history_depth`, 1–100000, default
    /// 1000).
    pub history_depth: i32,
    /// Only this local address is used and announced for discovery and data (`interface`,
    /// an IP address; default: every interface).
    pub interface: Option<IpAddr>,
    /// Whether participants of this host discover each other over loopback without multicast
    /// (`same_host`, default true).
    pub same_host: bool,
    /// How long a send to a system waits for its subscriber to be matched (`connect_timeout_ms`,
    /// 0–60000, default 2000).
    pub connect_timeout_ms: u64,
    /// The DDS implementation (`dds = "rustdds" | "cyclone"`, default rustdds).
    pub dds: Backend,
    /// Cyclone DDS only (`deliver_on_receive_thread`, default false): frames are handed to the
    /// router on Cyclone's receive thread, inside the reader's listener, instead of waking
    /// the thread that drives the link. A module with inline callbacks
    /// (`Module::set_inline_callbacks`) then answers without a thread hand-off, as
    /// `ddsperf`'s listener mode does; writes made on that thread never wait for a writer's
    /// history to drain (docs/ros2.md, "Delivering on the receive thread").
    pub deliver_on_receive_thread: bool,
}

impl Default for Ros2Settings {
    fn default() -> Self {
        Ros2Settings {
            domain_id: 0,
            namespace: "/hetcomm".to_string(),
            reliability: Reliability::Reliable,
            history_depth: 1000,
            interface: None,
            same_host: true,
            connect_timeout_ms: 2000,
            dds: Backend::RustDds,
            deliver_on_receive_thread: false,
        }
    }
}

/// The keys of a `ros2` transport table, besides the ones every transport shares.
pub const KEYS: [&str; 9] = [
    "domain_id",
    "namespace",
    "reliability",
    "history_depth",
    "interface",
    "same_host",
    "connect_timeout_ms",
    "dds",
    "deliver_on_receive_thread",
];

/// Reads a `ros2` transport's table; every problem is reported through `s` (located).
pub fn parse(s: &mut SettingsReader<'_, '_>) -> Option<RegisteredSettings> {
    let mut ok = true;
    let mut out = Ros2Settings::default();
    if s.has("domain_id") {
        match s.int_in("domain_id", 0, 232, "a ROS_DOMAIN_ID, e.g. 0") {
            Some(d) => out.domain_id = d as u16,
            None => ok = false,
        }
    }
    if s.has("namespace") {
        match s.string("namespace", "a ROS namespace in quotes, e.g. \"/hetcomm\"") {
            Some(ns) => match names::check_namespace(&ns) {
                Ok(ns) => out.namespace = ns,
                Err(why) => {
                    s.error(
                        "namespace",
                        format!("`namespace` {ns:?} is not a ROS 2 namespace: {why}"),
                        "use letters, digits and underscores between slashes, e.g. \"/fleet_a\"",
                    );
                    ok = false;
                }
            },
            None => ok = false,
        }
    }
    if s.has("reliability") {
        match s.choice(
            "reliability",
            ("reliability", "reliabilities"),
            &["reliable", "best_effort"],
        ) {
            Some(0) => out.reliability = Reliability::Reliable,
            Some(_) => out.reliability = Reliability::BestEffort,
            None => ok = false,
        }
    }
    if s.has("history_depth") {
        match s.int_in(
            "history_depth",
            1,
            100_000,
            "samples kept per topic, e.g. 1000",
        ) {
            Some(d) => out.history_depth = d as i32,
            None => ok = false,
        }
    }
    if s.has("interface") {
        match s.string(
            "interface",
            "a local IP address in quotes, e.g. \"10.0.0.2\"",
        ) {
            Some(text) => match text.parse::<IpAddr>() {
                Ok(ip) => out.interface = Some(ip),
                Err(_) => {
                    s.error(
                        "interface",
                        format!("`interface` {text:?} is not an IP address"),
                        "write the address of a local interface, e.g. \"10.0.0.2\"",
                    );
                    ok = false;
                }
            },
            None => ok = false,
        }
    }
    if s.has("same_host") {
        match s.boolean("same_host", "true or false") {
            Some(b) => out.same_host = b,
            None => ok = false,
        }
    }
    if s.has("connect_timeout_ms") {
        match s.int_in("connect_timeout_ms", 0, 60_000, "milliseconds, e.g. 2000") {
            Some(ms) => out.connect_timeout_ms = ms as u64,
            None => ok = false,
        }
    }
    if s.has("dds") {
        match s.choice(
            "dds",
            ("DDS implementation", "DDS implementations"),
            &["rustdds", "cyclone"],
        ) {
            Some(0) => out.dds = Backend::RustDds,
            Some(_) if cfg!(feature = "cyclone") => out.dds = Backend::Cyclone,
            Some(_) => {
                s.error(
                    "dds",
                    "`dds = \"cyclone\"` needs Cyclone DDS, which this build does not include",
                    "rebuild with the cargo feature `ros2-cyclone` (of hetcomm, hetcomm-cli or \
                     hetcomm-bench; `cyclone` of hetcomm-link-ros2), or use `dds = \"rustdds\"`",
                );
                ok = false;
            }
            None => ok = false,
        }
    }
    if s.has("deliver_on_receive_thread") {
        match s.boolean("deliver_on_receive_thread", "true or false") {
            Some(true) if out.dds != Backend::Cyclone => {
                s.error(
                    "deliver_on_receive_thread",
                    "`deliver_on_receive_thread` needs `dds = \"cyclone\"` (rustdds has no \
                     receive thread that could deliver)",
                    "add `dds = \"cyclone\"` to this transport, or remove the key",
                );
                ok = false;
            }
            Some(b) => out.deliver_on_receive_thread = b,
            None => ok = false,
        }
    }
    ok.then(|| RegisteredSettings::new(out))
}
