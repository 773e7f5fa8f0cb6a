//! # hetcomm — a heterogeneous communication layer for teams of robots
//!
//! Autonomy code sends user-defined messages to modules of other robots (or to a virtual
//! environment); a fleet file decides, per ordered pair of systems, which transport carries
//! them. Moving a robot from simulation to hardware changes the fleet file, never this code.
//!
//! ```
//! use hetcomm::{LocalFleet, Message, Outcome};
//! use serde::{Deserialize, Serialize};
//!
//! #[derive(Serialize, Deserialize, Message, Debug, PartialEq)]
//! #[message(id = 0)]
//! struct Command(u8);
//!
//! let fleet = hetcomm::config::parse_str(r#"
//!     [systems]
//!     Alpha = 0
//!     Charlie = 1
//!     [modules]
//!     Plan = 0
//!     Act = 1
//!     [transports.wired]
//!     kind = "inproc"
//!     [table]
//!     columns = ["Alpha", "Charlie"]
//!     Alpha   = ["X", "wired"]
//!     Charlie = ["wired", "X"]
//! "#, "fleet.toml", None).unwrap();
//! let fleet = LocalFleet::open(fleet).unwrap();
//! let plan = fleet.system("Alpha").unwrap().module("Plan").unwrap();
//! let act = fleet.system("Charlie").unwrap().module("Act").unwrap();
//!
//! let ticket = plan.send("Charlie", "Act", &Command(1)).unwrap();
//! assert!(matches!(ticket.wait(), Outcome::Delivered { attempts: 1, .. }));
//! let got = act.recv::<Command>().unwrap();
//! assert_eq!(got.message, Command(1));
//! assert_eq!(got.envelope.source_system, "Alpha");
//! ```
//!
//! Layers, bottom up: `hetcomm-core` (ids, envelope, wire codec), `hetcomm-config` (fleet
//! file), `hetcomm-link` (the `Link` trait and transports), `hetcomm-router` (sans-IO routing
//! and reliability), and this crate: the runtime that drives them with real time and threads,
//! and the API above.

mod comm;
mod error;
pub mod harness;
mod inbox;
mod module;
pub mod node;
pub mod observe;
mod reactor;
mod received;
mod reload;
mod runtime;
pub mod security;
mod shape;
pub mod signals;
pub mod sim;
mod switches;
mod ticket;
mod transports;

pub use comm::{Comm, LocalFleet, PathStatus, PathSwitch, PathsError, SystemStats};
pub use error::{OpenError, RecvError, SendError};
pub use harness::{
    HarnessStats, Replacement, TapAction, TapError, TapHandle, TapMessage, TapPath, TapVerdict,
};
pub use inbox::InboxStats;
pub use module::{Module, RawSender, SendOptions, Sender};
pub use node::{Node, Notification, Publisher, Subscription, TopicError};
pub use observe::{Observer, ObserverHandle};
pub use received::{Envelope, RawMessage, Received};
pub use reload::{describe_reload, Reload, ReloadError};
pub use runtime::{Clock, SystemClock};
pub use security::{security_lines, OpenOptions};
pub use switches::PathWatch;
pub use ticket::{BroadcastTicket, Ticket};
pub use transports::{load_fleet, parse_fleet, registry};

pub use hetcomm_core::{
    payload, wire, Address, Header, Message, MessageId, MessageType, ModuleId, Priority, SystemId,
    Time, TypeRegistryError,
};
pub use hetcomm_derive::Message;
pub use hetcomm_link::{LinkStats, SecurityStats};
pub use hetcomm_router::{FailReason, Outcome, RouterStats, SendId};

/// The fleet file: loading, validation and the validated model. The loaders here know every
/// transport kind compiled into this program (its registry, `hetcomm::transports`), so a
/// `udp` or `ros1` transport's settings are read and checked as the kind's crate says;
/// `hetcomm_config`'s own loaders know every kind by name only and keep its keys raw.
pub mod config {
    pub use hetcomm_config::*;
    /// The settings of `emulated` transports (their crate's, `hetcomm-link`).
    pub use hetcomm_link::emulation::EmulatedSettings;
    /// The settings of `inproc` transports (none; their crate's, `hetcomm-link`).
    pub use hetcomm_link::inproc::InprocSettings;
    /// The settings of `bluetooth` transports (their crate's, `hetcomm-link-bluetooth`).
    #[cfg(feature = "bluetooth")]
    pub use hetcomm_link_bluetooth::BluetoothSettings;
    /// The settings of `udp` and `tcp` transports (their crate's, `hetcomm-link-ip`).
    pub use hetcomm_link_ip::IpSettings;
    /// The settings of `ros1` transports (their crate's, `hetcomm-link-ros1`).
    #[cfg(feature = "ros1")]
    pub use hetcomm_link_ros1::Ros1Settings;

    use std::path::Path;

    /// Reads and validates the fleet file at `path` with every kind compiled in (see
    /// `hetcomm_config::load`).
    pub fn load(path: &Path) -> Result<Fleet, ConfigErrors> {
        crate::transports::load_fleet(path)
    }

    /// Validates fleet-file text with every kind compiled in (see `hetcomm_config::parse_str`).
    pub fn parse_str(
        text: &str,
        origin: &str,
        base_dir: Option<&Path>,
    ) -> Result<Fleet, ConfigErrors> {
        crate::transports::parse_fleet(text, origin, base_dir)
    }

    /// Loads the thesis's files alone with every kind compiled in (see
    /// `hetcomm_config::load_legacy`): `R` is a `ros1` transport when that kind is built in.
    pub fn load_legacy(
        ids: &Path,
        table: &Path,
        bluetooth: Option<&Path>,
    ) -> Result<Fleet, ConfigErrors> {
        hetcomm_config::load_legacy_with(
            ids,
            table,
            bluetooth,
            crate::transports::registry().kinds(),
        )
    }
}

/// Links: the transport trait, the in-process link and the conformance suite.
pub mod link {
    pub use hetcomm_link::*;
}
