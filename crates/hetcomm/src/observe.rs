//! One observation point: every send, every receipt and every outcome of a system, whichever
//! way the message went (the router's transmit loop, the unacknowledged fast path, or the
//! in-process hand-over that builds no frame), in real time and under simulation alike.
//!
//! Register an [`Observer`] with [`Comm::observe`](crate::Comm::observe). While no observer
//! is registered, each of those places costs one relaxed atomic load: nothing is allocated,
//! copied or formatted.
//!
//! What a system's observers see:
//!
//! | callback | when | how often |
//! |---|---|---|
//! | [`Observer::on_send`] | a send of this system leaves (first attempt) | exactly once per send |
//! | [`Observer::on_retransmit`] | a later attempt of the same send leaves | once per extra attempt |
//! | [`Observer::on_receipt`] | a message for one of this system's modules reached its inbox (or was refused) | once per message handed to an inbox (duplicates the router suppressed are not) |
//! | [`Observer::on_outcome`] | a send of this system ended | exactly once per send |
//! | [`Observer::on_path_change`] | a destination's sends moved to another transport (docs/failover.md) | exactly once per switch |
//!
//! A send and its outcome share a [`SendId`] (destination system, sequence number); the
//! receiver's [`ReceiptRecord::header`] carries the same source system and sequence number.
//! An observer registered while sends are under way may see outcomes, retransmissions and
//! receipts of sends whose `on_send` came before it was registered.
//!
//! Sends refused before they were numbered (an `Err` from `send`, or a broadcast's
//! [`Backpressure`](crate::FailReason::Backpressure) ticket) are not sends: no record.

use parking_lot::RwLock;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Weak};

pub use hetcomm_core::wire::AckStatus;
use hetcomm_core::wire::{FrameKind, HEADER_LEN};
use hetcomm_core::{Address, Header, MessageType, ModuleId, Priority, SystemId, Time};
pub use hetcomm_router::{Outcome, SendId};

use crate::runtime::SystemCore;

/// Which way a message left its system.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum RouteKind {
    /// Framed by the router and put on a link by its transmit loop: acknowledged sends, and
    /// every retransmission (also of an unacknowledged send whose link refused the first
    /// attempt).
    Routed,
    /// An unacknowledged send's first attempt, put on the link by the sending thread
    /// without a trip through the router's queue.
    Unqueued,
    /// Handed straight into an inbox of another system of this process (an in-process
    /// route): no frame, no link, no destination router.
    Direct,
}

/// Where a received message came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum Via {
    /// A frame on this system's link with this index (the order of
    /// [`Comm::endpoints`](crate::Comm::endpoints)).
    Link(usize),
    /// Handed over directly by another system of this process.
    Direct,
}

/// One attempt of a send leaving its system ([`Observer::on_send`],
/// [`Observer::on_retransmit`]).
#[derive(Clone, Copy, Debug)]
#[non_exhaustive]
pub struct SendRecord<'a> {
    /// The message's header as it left: source and destination addresses, sequence number,
    /// message type, priority, transport tag (`transport`), flags (acknowledgement asked,
    /// broadcast) and the send's timestamp.
    pub header: Header,
    /// The encoded payload (its length is the message's size; the frame adds
    /// [`HEADER_LEN`] bytes on links).
    pub payload: &'a [u8],
    /// When this attempt left, on the system's clock: monotonic in real time
    /// ([`Time::now_mono`]), virtual under simulation. (The header's timestamp is the
    /// wall clock's.)
    pub time: Time,
    /// Which way it left.
    pub route: RouteKind,
    /// The link index it was handed to (None for a direct hand-over).
    pub link: Option<usize>,
    /// 1 for the send itself, 2 and more for retransmissions.
    pub attempt: u32,
}

impl SendRecord<'_> {
    /// The send this attempt belongs to: the same id its [`OutcomeRecord`] carries (for a
    /// native broadcast, one destination's share: see `SendId::is_broadcast`).
    pub fn id(&self) -> SendId {
        let seq = match self.header.broadcast_seq() {
            true => hetcomm_router::BROADCAST_SEND | self.header.seq,
            false => self.header.seq,
        };
        SendId {
            to: self.header.destination.system,
            seq,
        }
    }
}

/// A message handed to one of this system's inboxes ([`Observer::on_receipt`]).
#[derive(Clone, Copy, Debug)]
#[non_exhaustive]
pub struct ReceiptRecord<'a> {
    /// The message's header (its source system and sequence number name it, as at the sender).
    pub header: Header,
    /// The encoded payload.
    pub payload: &'a [u8],
    /// When it was handed to the inbox, on the system's (monotonic) clock, as
    /// [`SendRecord::time`]. (The envelope's `received_at` is the wall clock's.)
    pub time: Time,
    /// Which link it came on, or a direct hand-over.
    pub via: Via,
    /// What the inbox answered: delivered, inbox full, or no such module.
    pub status: AckStatus,
}

/// A send that ended ([`Observer::on_outcome`]).
#[derive(Clone, Copy, Debug)]
#[non_exhaustive]
pub struct OutcomeRecord<'a> {
    /// Which send: its destination system and sequence number.
    pub id: SendId,
    /// How it ended (what its ticket says).
    pub outcome: &'a Outcome,
    /// When it ended, on the system's (monotonic) clock, as [`SendRecord::time`].
    pub time: Time,
}

/// A destination's sends moved from one transport to another ([`Observer::on_path_change`]):
/// a failover, a return to the preferred transport, or a change made with
/// [`Comm::set_transports`](crate::Comm::set_transports) or a reload.
#[derive(Clone, Copy, Debug)]
#[non_exhaustive]
pub struct PathChangeRecord<'a> {
    /// The destination system.
    pub to: SystemId,
    /// The destination system's name.
    pub to_name: &'a str,
    /// The transport (fleet-file name) its sends took until then.
    pub from: &'a str,
    /// The transport they take from then on.
    pub now: &'a str,
    /// The link indexes of `from` and `now` (the order of
    /// [`Comm::endpoints`](crate::Comm::endpoints)).
    pub links: (usize, usize),
    /// When the router decided it, on the system's (monotonic) clock, as
    /// [`SendRecord::time`].
    pub time: Time,
    /// This system's switches so far, this one included (1 for the first): a consumer that
    /// sees a gap lost some.
    pub number: u64,
}

/// Sees every send, receipt and outcome of the systems it is registered with
/// ([`Comm::observe`](crate::Comm::observe)). Every method does nothing unless written.
///
/// The methods run on the thread doing the work (a sending thread, a link's receive thread,
/// the timer thread, or the simulator's thread), synchronously, so they should be quick:
/// copy what is needed and hand it elsewhere. No lock of the system is held while they run,
/// so they may drop their own handle or send (a send from `on_send` is observed in turn:
/// beware of endless recursion).
pub trait Observer: Send + Sync {
    /// A send's first attempt left (exactly once per send).
    fn on_send(&self, record: &SendRecord<'_>) {
        let _ = record;
    }
    /// A later attempt of a send left ([`SendRecord::attempt`] > 1).
    fn on_retransmit(&self, record: &SendRecord<'_>) {
        let _ = record;
    }
    /// A message was handed to one of this system's inboxes.
    fn on_receipt(&self, record: &ReceiptRecord<'_>) {
        let _ = record;
    }
    /// A send of this system ended (exactly once per send).
    fn on_outcome(&self, record: &OutcomeRecord<'_>) {
        let _ = record;
    }
    /// A destination's sends moved to another transport (exactly once per switch).
    fn on_path_change(&self, record: &PathChangeRecord<'_>) {
        let _ = record;
    }
}

type Entries = Arc<[(u64, Arc<dyn Observer>)]>;

/// A system's observers. `active` is the gate every observation point checks first.
pub(crate) struct Observers {
    active: AtomicBool,
    list: RwLock<Entries>,
    next_id: AtomicU64,
}

impl Default for Observers {
    fn default() -> Self {
        Observers {
            active: AtomicBool::new(false),
            list: RwLock::new(Arc::new([])),
            next_id: AtomicU64::new(0),
        }
    }
}

impl Observers {
    /// Whether anyone observes: one relaxed load, the whole cost of an observation point
    /// while nobody does.
    #[inline(always)]
    pub(crate) fn active(&self) -> bool {
        self.active.load(Ordering::Relaxed)
    }

    fn snapshot(&self) -> Entries {
        self.list.read().clone()
    }

    fn add(&self, observer: Arc<dyn Observer>) -> u64 {
        let id = self.next_id.fetch_add(1, Ordering::Relaxed);
        let mut list = self.list.write();
        let mut v: Vec<_> = list.iter().cloned().collect();
        v.push((id, observer));
        *list = v.into();
        self.active.store(true, Ordering::Release);
        id
    }

    fn remove(&self, id: u64) {
        let mut list = self.list.write();
        let v: Vec<_> = list.iter().filter(|(i, _)| *i != id).cloned().collect();
        self.active.store(!v.is_empty(), Ordering::Release);
        *list = v.into();
    }

    /// Reports one attempt of a send (first or later by `record.attempt`).
    #[cold]
    fn send(&self, record: &SendRecord<'_>) {
        for (_, o) in self.snapshot().iter() {
            if record.attempt <= 1 {
                o.on_send(record);
            } else {
                o.on_retransmit(record);
            }
        }
    }

    /// Reports a direct hand-over (no frame, no link, one attempt).
    #[cold]
    #[inline(never)]
    pub(crate) fn send_direct(&self, header: &Header, payload: &[u8], time: Time) {
        self.send(&SendRecord {
            header: *header,
            payload,
            time,
            route: RouteKind::Direct,
            link: None,
            attempt: 1,
        });
    }

    /// Reports one attempt of a send from its encoded frame (`frame`, followed by `body`
    /// when the payload was left in the caller's memory).
    #[cold]
    #[inline(never)]
    pub(crate) fn send_frame(
        &self,
        frame: &[u8],
        body: &[u8],
        time: Time,
        route: RouteKind,
        link: usize,
        attempt: u32,
    ) {
        let Some(header) = frame_header(frame) else {
            return;
        };
        let payload = if body.is_empty() {
            &frame[HEADER_LEN..]
        } else {
            body
        };
        self.send(&SendRecord {
            header,
            payload,
            time,
            route,
            link: Some(link),
            attempt,
        });
    }

    /// Reports the one frame of a native broadcast as one attempt of each destination's
    /// share, each record naming its destination (as the copies of a broadcast did).
    pub(crate) fn send_broadcast_frame(
        &self,
        frame: &[u8],
        dests: &[SystemId],
        time: Time,
        link: usize,
    ) {
        let Some(header) = frame_header(frame) else {
            return;
        };
        for &system in dests {
            let mut header = header;
            header.destination.system = system;
            self.send(&SendRecord {
                header,
                payload: &frame[HEADER_LEN..],
                time,
                route: RouteKind::Routed,
                link: Some(link),
                attempt: 1,
            });
        }
    }

    /// Reports a message handed to an inbox.
    #[cold]
    pub(crate) fn receipt(&self, record: &ReceiptRecord<'_>) {
        for (_, o) in self.snapshot().iter() {
            o.on_receipt(record);
        }
    }

    /// Reports a path switch.
    #[cold]
    pub(crate) fn path_change(&self, record: &PathChangeRecord<'_>) {
        for (_, o) in self.snapshot().iter() {
            o.on_path_change(record);
        }
    }

    /// Reports a send's end.
    #[cold]
    pub(crate) fn outcome(&self, record: &OutcomeRecord<'_>) {
        for (_, o) in self.snapshot().iter() {
            o.on_outcome(record);
        }
    }
}

/// The header of a data frame this system just encoded (`docs/wire-format.md`: fixed
/// little-endian fields). No checks beyond the length and kind: the router wrote it.
fn frame_header(f: &[u8]) -> Option<Header> {
    if f.len() < HEADER_LEN || f[3] != FrameKind::Data as u8 {
        return None;
    }
    let u16_at = |at: usize| u16::from_le_bytes([f[at], f[at + 1]]);
    let u32_at = |at: usize| u32::from_le_bytes([f[at], f[at + 1], f[at + 2], f[at + 3]]);
    let u64_at = |at: usize| {
        let mut a = [0; 8];
        a.copy_from_slice(&f[at..at + 8]);
        u64::from_le_bytes(a)
    };
    Some(Header {
        kind: FrameKind::Data,
        flags: f[4],
        priority: Priority(f[5]),
        transport: f[6],
        source: Address {
            system: SystemId(u16_at(8)),
            module: ModuleId(u16_at(10)),
        },
        destination: Address {
            system: SystemId(u16_at(12)),
            module: ModuleId(u16_at(14)),
        },
        incarnation: u32_at(16),
        seq: u64_at(20),
        message_type: MessageType(u32_at(28)),
        timestamp: Time(u64_at(32)),
    })
}

/// Keeps an [`Observer`] registered with a system; dropping it (or [`ObserverHandle::remove`])
/// unregisters it. No report that starts after that returned calls the observer; one already
/// under way on another thread may still call it.
#[must_use = "dropping the handle unregisters the observer"]
pub struct ObserverHandle {
    pub(crate) core: Weak<SystemCore>,
    pub(crate) id: u64,
}

impl ObserverHandle {
    pub(crate) fn register(core: &Arc<SystemCore>, observer: Arc<dyn Observer>) -> Self {
        ObserverHandle {
            id: core.observers.add(observer),
            core: Arc::downgrade(core),
        }
    }

    /// Unregisters the observer (as dropping the handle does).
    pub fn remove(self) {}
}

impl Drop for ObserverHandle {
    fn drop(&mut self) {
        if let Some(core) = self.core.upgrade() {
            core.observers.remove(self.id);
        }
    }
}

impl std::fmt::Debug for ObserverHandle {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ObserverHandle")
            .field("id", &self.id)
            .finish()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_header_reads_what_the_codec_wrote() {
        let mut h = Header::data(
            Address {
                system: SystemId(3),
                module: ModuleId(7),
            },
            Address {
                system: SystemId(513),
                module: ModuleId(2),
            },
            MessageType(0xdead_beef),
        );
        h.flags = hetcomm_core::wire::FLAG_ACK_REQUESTED;
        h.priority = Priority(9);
        h.transport = b'R';
        h.incarnation = 0x1234_5678;
        h.seq = 0x0102_0304_0506_0708;
        h.timestamp = Time(987_654_321);
        let frame = hetcomm_core::wire::encode(&h, b"payload");
        assert_eq!(frame_header(&frame), Some(h));
        assert_eq!(
            hetcomm_core::wire::decode(&frame).unwrap().header,
            frame_header(&frame).unwrap()
        );
        assert_eq!(frame_header(&frame[..HEADER_LEN - 1]), None);
    }
}
