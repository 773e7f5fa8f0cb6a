//! # hetcomm-link-shm — the `shm` transport kind
//!
//! Carries hetcomm frames between processes of one host through shared memory, on
//! [iceoryx2](https://github.com/eclipse-iceoryx/iceoryx2)'s publish-subscribe and event
//! services; this crate writes no shared-memory protocol itself. `docs/shm.md` is the user's
//! guide (keys, permissions, Docker); this is the implementer's summary.
//!
//! ## Services
//!
//! One iceoryx2 service per **destination** system, named `PREFIX/FLEET/<System>` (payload
//! type `[u8]`, no user header): the destination holds its only subscriber and a listener on
//! the event service of the same name; every other system holds a publisher and a notifier
//! on it. One frame is one sample, byte for byte (`docs/wire-format.md`). Per destination
//! rather than per pair: a receiver then waits on one queue and one descriptor whatever the
//! number of senders, the number of services grows with the systems, not their square, and a
//! foreign peer needs one name to listen on. Each system's iceoryx2 node has the same name,
//! which is how a link tells which system a dead node was.
//!
//! ## What the link guarantees
//!
//! [`LinkCaps`](hetcomm_link::LinkCaps): reliable and ordered. A sample taken into the destination's queue arrives
//! unless the destination's process dies; a full queue is never overwritten (no safe
//! overflow): the send is refused with [`LinkError::Congested`](hetcomm_link::LinkError::Congested), counted
//! ([`ShmLink::shm_stats`], and in `frames_dropped`, since nothing of it left), and the
//! router's outcome for it says so. A send to a system with no subscriber on its service is
//! [`LinkError::Unreachable`](hetcomm_link::LinkError::Unreachable). Frames arrive unaltered (memory, no transit), so frames carry
//! a header-only CRC ([`Link::checksums_payload`](hetcomm_link::Link::checksums_payload)).
//!
//! ## Waking
//!
//! The link is driven ([`Link::readable`](hetcomm_link::Link::readable)): a send notifies
//! the destination's listener, whose descriptor (a Unix datagram socket) polls readable; the
//! runtime's reactor waits on it with its other links. A module that spins
//! (`Module::set_wait_spin`) reads the subscriber's queue without a system call
//! ([`Readable::pending`](hetcomm_link::Readable::pending)), and its senders skip the
//! notification while it spins: the receiver says so in a flag of its own on an iceoryx2
//! blackboard ([`Readable::set_spinning`](hetcomm_link::Readable::set_spinning); `spinning.rs`
//! says why no wake-up is lost).
//!
//! ## Crashes
//!
//! Every `liveness_ms` (from the reactor's upkeep, and at once when a send finds a queue full)
//! the link lists iceoryx2's nodes: a node of a fleet system whose process is gone is
//! cleaned up (its ports and segments removed, `remove_stale_resources`) and reported through
//! the link seam ([`LinkEvent::PeerDown`](hetcomm_link::LinkEvent::PeerDown)); a node that appears is reported up. Opening a link
//! cleans up dead nodes first, so a process restarted after a crash takes its place.

pub mod factory;
mod link;
mod liveness;
pub mod memory;
mod settings;
mod spinning;

use hetcomm_core::SystemId;

pub use link::{ShmLink, ShmStats};
pub use settings::{
    service_name, validate_part, ShmSettings, DEFAULT_INITIAL_FRAME, DEFAULT_MAX_FRAME,
};

/// Registers the `shm` transport factory ([`factory::ShmFactory`]).
pub fn register_transports(registry: &mut hetcomm_link::registry::Registry) {
    registry.register(factory::ShmFactory);
}

/// The iceoryx2 service flavour: ports that may be used from any thread (a link is shared by
/// the runtime's threads).
pub type IpcService = iceoryx2::service::ipc_threadsafe::Service;

/// Everything an `shm` link needs to open.
#[derive(Clone, Debug)]
pub struct ShmLinkConfig {
    /// The system the link is for.
    pub local: SystemId,
    /// Every system of the fleet, by id, with its name (the last part of its service's name).
    pub systems: Vec<(SystemId, String)>,
    /// The fleet part of the names (`PREFIX/FLEET/…`).
    pub fleet: String,
    /// The transport's settings.
    pub settings: ShmSettings,
}

/// Why an `shm` link could not open.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ShmOpenError {
    /// The local system is not among the configured systems.
    #[error("system {0} is not a system of this fleet")]
    UnknownSystem(SystemId),
    /// Shared memory is missing, too small, or not ours (the message says what to do).
    #[error("{0}")]
    Memory(String),
    /// iceoryx2 refused a node, service or port (the message names it and why).
    #[error("{0}")]
    Iceoryx(String),
}
