//! The router state machine.

use std::collections::{BTreeMap, BTreeSet, VecDeque};

// Keys are small integers chosen by us, not by an attacker: a fast hash is safe here.
use rustc_hash::FxHashMap as HashMap;
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::Duration;

use hetcomm_core::wire::{
    self, AckStatus, FLAG_ACK_REQUESTED, FLAG_BROADCAST, FLAG_HEADER_CRC, HEADER_LEN,
};
use hetcomm_core::{
    Address, FrameBuf, FrameKind, Header, MessageType, ModuleId, PayloadBuf, PayloadSource,
    Priority, SystemId, Time,
};

use crate::dedup::Dedup;
use crate::lane::DirectLane;
use crate::rtt::RttEstimator;

/// How traffic from this system to one destination system is carried.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Route {
    /// Index of the link (the driver's numbering).
    pub link: usize,
    /// The transport's one-byte tag written into each frame (the table letter).
    pub tag: u8,
    /// Whether the receiver must acknowledge.
    pub acknowledged: bool,
    /// Transmission attempts before the send fails (at least 1).
    pub attempts: u32,
    /// Largest frame the link takes.
    pub max_frame: usize,
    /// Sends to this destination that may await their outcome at once (an acknowledgement,
    /// or a retry after the link refused the frame). A send beyond it is refused with
    /// [`SendError::Backpressure`] before it is numbered, so a sender faster than the peer
    /// (or a peer that is gone) cannot make the router keep frames without bound.
    pub max_in_flight: u32,
}

/// Retransmission timing.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Timing {
    /// Retransmission timeout before the first RTT sample.
    pub initial_rto: Duration,
    /// Lower bound of the timeout.
    pub min_rto: Duration,
    /// Upper bound of the timeout (also of the backed-off timeout).
    pub max_rto: Duration,
    /// Factor the timeout grows by after each unanswered attempt.
    pub backoff: f64,
    /// After a link refuses a frame (peer unreachable, congested), how long before the next
    /// attempt; doubles per attempt. A reconnecting link gets a chance to come back instead of
    /// every attempt failing within the same millisecond.
    pub link_retry: Duration,
    /// Under in-order delivery, how long an early message waits for a missing earlier one
    /// before the gap is given up and delivery moves on.
    pub hold_timeout: Duration,
}

impl Default for Timing {
    fn default() -> Self {
        Timing {
            initial_rto: Duration::from_millis(100),
            min_rto: Duration::from_millis(2),
            max_rto: Duration::from_secs(5),
            backoff: 2.0,
            link_retry: Duration::from_millis(20),
            hold_timeout: Duration::from_secs(2),
        }
    }
}

/// Everything a router needs to know, built by the driver from the fleet.
#[derive(Clone, Debug)]
pub struct RouterConfig {
    /// This system.
    pub local: SystemId,
    /// A number new to each start of this system's process (see [`Header::incarnation`]).
    pub incarnation: u32,
    /// Routes from this system, by destination. A destination without a route is `X`.
    pub routes: Vec<(SystemId, Route)>,
    /// Every system of the fleet: frames claiming another origin are dropped.
    pub known_systems: BTreeSet<SystemId>,
    /// Retransmission timing.
    pub timing: Timing,
    /// Sequence numbers remembered per sender beyond the contiguous prefix.
    pub dedup_window: usize,
    /// Senders whose messages are delivered in the order sent (see [`Timing::hold_timeout`]).
    pub ordered_sources: BTreeSet<SystemId>,
}

impl RouterConfig {
    /// A configuration with default timing; the known systems are `local` and the route
    /// destinations.
    pub fn new(local: SystemId, incarnation: u32, routes: Vec<(SystemId, Route)>) -> Self {
        let mut known: BTreeSet<SystemId> = routes.iter().map(|(s, _)| *s).collect();
        known.insert(local);
        RouterConfig {
            local,
            incarnation,
            routes,
            known_systems: known,
            timing: Timing::default(),
            dedup_window: 4096,
            ordered_sources: BTreeSet::new(),
        }
    }
}

/// What a module asks to send.
#[derive(Clone, Copy, Debug)]
pub struct SendRequest<'a> {
    /// The sending module.
    pub from: ModuleId,
    /// The destination module and system.
    pub to: Address,
    /// The payload's message type.
    pub message_type: MessageType,
    /// Receive priority.
    pub priority: Priority,
    /// Encoded payload.
    pub payload: &'a [u8],
    /// Marks the frame as one copy of a broadcast.
    pub broadcast: bool,
}

impl<'a> SendRequest<'a> {
    /// A point-to-point request with normal priority.
    pub fn new(from: ModuleId, to: Address, message_type: MessageType, payload: &'a [u8]) -> Self {
        SendRequest {
            from,
            to,
            message_type,
            priority: Priority::NORMAL,
            payload,
            broadcast: false,
        }
    }
}

/// A send refused before anything was transmitted.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum SendError {
    /// The communication table says `X` for this pair.
    #[error("no traffic allowed from system {from} to system {to}: the communication table says X for this pair")]
    NoRoute {
        /// Sending system.
        from: SystemId,
        /// Destination system.
        to: SystemId,
    },
    /// The message does not fit the link.
    #[error("message of {len} bytes (with header) exceeds the {max}-byte limit of the transport to system {to}")]
    TooLarge {
        /// Frame length.
        len: usize,
        /// The limit.
        max: usize,
        /// Destination system.
        to: SystemId,
    },
    /// [`Route::max_in_flight`] sends to this destination already await their outcome.
    #[error("{limit} sends to system {to} already await their outcome (the transport's max_in_flight): wait for an earlier outcome and send again")]
    Backpressure {
        /// Destination system.
        to: SystemId,
        /// The limit.
        limit: u32,
    },
}

/// Names one send: the destination and the sequence number the router gave it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct SendId {
    /// Destination system.
    pub to: SystemId,
    /// Sequence number within (this incarnation, destination).
    pub seq: u64,
}

/// Why a send failed ([`Outcome::Failed`]) or why the sender stopped waiting for its
/// confirmation ([`Outcome::Unconfirmed`]).
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum FailReason {
    /// Frames went out but no acknowledgement came back within the attempt budget (only in
    /// [`Outcome::Unconfirmed`]: the message may have arrived and its acknowledgement been lost).
    #[error("no acknowledgement")]
    NoAcknowledgement,
    /// The link could not reach the peer on the last attempt.
    #[error("peer unreachable: {0}")]
    Unreachable(String),
    /// The destination module's inbox was full and refused the message.
    #[error("destination inbox full")]
    InboxFull,
    /// The destination system does not host that module.
    #[error("destination system has no such module")]
    UnknownModule,
    /// The link refused the frame for another reason.
    #[error("transport error: {0}")]
    Link(String),
    /// Not sent: the destination's [`Route::max_in_flight`] sends already awaited their
    /// outcome (a broadcast reports this per destination; a single send is refused with
    /// [`SendError::Backpressure`] instead).
    #[error("not sent: max_in_flight sends to that system already await their outcome")]
    Backpressure,
    /// The router was shut down with the send unresolved.
    #[error("shut down before an outcome")]
    Shutdown,
}

/// The one result every send ends with. Each variant says only what the sender knows:
///
/// | outcome | the message is … |
/// |---|---|
/// | [`Delivered`](Outcome::Delivered) | in the destination module's inbox (not necessarily read yet) |
/// | [`Sent`](Outcome::Sent) | handed to the transport, which cannot confirm (unacknowledged mode) |
/// | [`Unconfirmed`](Outcome::Unconfirmed) | maybe delivered: frames left, no acknowledgement came back |
/// | [`Failed`](Outcome::Failed) | certainly not delivered |
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Outcome {
    /// The destination router put the message into the module's inbox and said so. Delivered
    /// means in the inbox, not read by the module.
    Delivered {
        /// Transmissions it took.
        attempts: u32,
        /// From the first transmission to the acknowledgement.
        latency: Duration,
    },
    /// The transport took the frame; it cannot confirm delivery (unacknowledged mode).
    Sent {
        /// Transmissions it took (more than one if the transport refused earlier ones).
        attempts: u32,
    },
    /// At least one frame left this system but no acknowledgement came back before the
    /// attempt budget ran out (or the link was lost, or the router shut down): the message may
    /// or may not have arrived. The sender cannot tell which; only the receiver can.
    Unconfirmed {
        /// Why the sender stopped waiting.
        reason: FailReason,
        /// Transmissions attempted.
        attempts: u32,
    },
    /// Certainly not delivered: no frame left this system (refused, unreachable on every
    /// attempt, too large, shut down before sending), or the receiver answered that it did not
    /// take the message (inbox full, no such module).
    Failed {
        /// Why.
        reason: FailReason,
        /// Transmissions attempted.
        attempts: u32,
    },
}

impl Outcome {
    /// The outcome an acknowledgement with `status` reports.
    pub(crate) fn acknowledged(status: AckStatus, attempts: u32, latency: Duration) -> Outcome {
        match status {
            AckStatus::Delivered => Outcome::Delivered { attempts, latency },
            AckStatus::InboxFull => Outcome::Failed {
                reason: FailReason::InboxFull,
                attempts,
            },
            AckStatus::UnknownModule => Outcome::Failed {
                reason: FailReason::UnknownModule,
                attempts,
            },
        }
    }

    /// Delivered, or sent without confirmation on a transport that cannot confirm.
    pub fn is_success(&self) -> bool {
        matches!(self, Outcome::Delivered { .. } | Outcome::Sent { .. })
    }

    /// Maybe delivered: frames left but no acknowledgement came back.
    pub fn is_unconfirmed(&self) -> bool {
        matches!(self, Outcome::Unconfirmed { .. })
    }

    /// Certainly not delivered.
    pub fn is_failed(&self) -> bool {
        matches!(self, Outcome::Failed { .. })
    }

    /// Why the send failed or went unconfirmed (`None` for the two successes).
    pub fn reason(&self) -> Option<&FailReason> {
        match self {
            Outcome::Unconfirmed { reason, .. } | Outcome::Failed { reason, .. } => Some(reason),
            Outcome::Delivered { .. } | Outcome::Sent { .. } => None,
        }
    }

    /// Transmissions attempted.
    pub fn attempts(&self) -> u32 {
        match *self {
            Outcome::Delivered { attempts, .. }
            | Outcome::Sent { attempts }
            | Outcome::Unconfirmed { attempts, .. }
            | Outcome::Failed { attempts, .. } => attempts,
        }
    }
}

impl std::fmt::Display for Outcome {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Outcome::Delivered { attempts, latency } => {
                write!(
                    f,
                    "delivered (attempts: {attempts}, {} µs)",
                    latency.as_micros()
                )
            }
            Outcome::Sent { attempts } => {
                write!(f, "sent without confirmation (attempts: {attempts})")
            }
            Outcome::Unconfirmed { reason, attempts } => {
                write!(
                    f,
                    "unconfirmed: {reason}; it may or may not have arrived (attempts: {attempts})"
                )
            }
            Outcome::Failed { reason, attempts } => {
                write!(f, "failed: {reason} (attempts: {attempts})")
            }
        }
    }
}

/// A frame for the driver to put on a link. Hand it back through
/// [`Router::transmit_result`] if [`Transmit::send`] is set.
#[derive(Debug)]
pub struct Transmit {
    /// Which link.
    pub link: usize,
    /// Destination system.
    pub to: SystemId,
    /// The encoded frame.
    pub frame: Vec<u8>,
    /// The send this frame belongs to (None for acknowledgements, which need no result).
    pub send: Option<SendId>,
}

/// Why a link refused a frame, as the router needs to know it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum TransmitError {
    /// The peer cannot be reached now (retried while attempts remain).
    Unreachable(String),
    /// The frame can never fit (not retried).
    TooLarge(String),
    /// Anything else (retried while attempts remain).
    Other(String),
}

/// How [`Router::send_unqueued`] took a send.
#[derive(Debug)]
pub enum Admitted<'a> {
    /// Queued exactly as by [`Router::send`]: its frame comes out of
    /// [`Router::poll_transmit`], its outcome out of [`Router::poll_event`]. Acknowledged sends
    /// take this way, since the router must keep them for retransmission.
    Queued(SendId),
    /// An unacknowledged send, numbered and counted but kept nowhere: put its frame on the
    /// link now and report what the link did through [`Router::unqueued_result`].
    Transmit(Unqueued<'a>),
}

/// The frame of an unacknowledged send that the router handed straight to the driver
/// ([`Admitted::Transmit`]). It must go back through [`Router::unqueued_result`]: until then
/// the send counts as in flight.
#[derive(Debug)]
#[must_use = "an unqueued send stays in flight until given to Router::unqueued_result"]
pub struct Unqueued<'a> {
    /// Which link.
    pub link: usize,
    /// Destination system.
    pub to: SystemId,
    /// The encoded frame; only its header when `body` is not empty.
    pub frame: Vec<u8>,
    /// The rest of the frame: the caller's payload, left where it is. A payload of at least
    /// [`SPLIT_PAYLOAD_MIN`] bytes on a link that checksums payloads is not copied behind its
    /// header; the driver writes both pieces with one vectored write (`Link::send_parts`).
    /// Empty otherwise.
    pub body: &'a [u8],
    /// The send it carries.
    id: SendId,
}

impl Unqueued<'_> {
    /// The send this frame carries.
    pub fn id(&self) -> SendId {
        self.id
    }
}

/// A message for a local module's inbox.
#[derive(Debug)]
pub struct Delivery {
    /// The envelope header.
    pub header: Header,
    /// The encoded payload.
    pub payload: PayloadBuf,
    /// The link it arrived on.
    pub link: usize,
    /// Present when the sender wants an acknowledgement: report what the inbox did through
    /// [`Router::delivery_result`].
    pub token: Option<DeliveryToken>,
}

/// Names a delivery awaiting its inbox's verdict.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct DeliveryToken(u64);

/// Something the driver should know.
#[derive(Debug)]
pub enum Event<T> {
    /// A send ended.
    Outcome {
        /// Which send.
        id: SendId,
        /// The token given to [`Router::send`].
        token: T,
        /// How it ended.
        outcome: Outcome,
    },
}

/// Counters of everything the router did and dropped.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct RouterStats {
    /// Sends accepted.
    pub sends: u64,
    /// Frames handed out for transmission (first attempts and retransmissions).
    pub transmissions: u64,
    /// Retransmissions after a timeout or a link error.
    pub retransmissions: u64,
    /// Sends that ended delivered.
    pub delivered: u64,
    /// Sends that ended [`Outcome::Sent`]: taken by a transport that cannot confirm
    /// (unacknowledged mode).
    pub sent: u64,
    /// Sends that ended [`Outcome::Unconfirmed`]: frames left, no acknowledgement came back.
    pub unconfirmed: u64,
    /// Sends that ended [`Outcome::Failed`]: certainly not delivered.
    pub failed: u64,
    /// Messages handed to local inboxes.
    pub received: u64,
    /// Acknowledgements sent.
    pub acks_sent: u64,
    /// Acknowledgements received for a pending send.
    pub acks_received: u64,
    /// Acknowledgements for nothing pending (late duplicates): ignored.
    pub stale_acks: u64,
    /// Duplicate data frames suppressed.
    pub duplicates: u64,
    /// Frames that failed to decode (truncated, bad version, bad checksum, …).
    pub malformed: u64,
    /// Frames from a system not in the fleet.
    pub unknown_origin: u64,
    /// Frames addressed to another system.
    pub misrouted: u64,
    /// Messages that arrived early and waited for an earlier one (in-order delivery).
    pub held: u64,
    /// Gaps given up after the hold timeout (in-order delivery moved past a missing message).
    pub gaps_skipped: u64,
    /// Sends refused because their destination's [`Route::max_in_flight`] was reached.
    pub backpressured: u64,
}

impl RouterStats {
    /// Sends accepted but not yet ended.
    pub fn in_flight(&self) -> u64 {
        self.sends - self.delivered - self.sent - self.unconfirmed - self.failed
    }
}

/// One unresolved send.
struct Pending<T> {
    token: T,
    route: Route,
    /// The frame; `None` while the driver holds it in a [`Transmit`].
    frame: Option<Vec<u8>>,
    attempts: u32,
    /// Whether any attempt left this system (the link took the frame): from then on, giving up
    /// is [`Outcome::Unconfirmed`], never [`Outcome::Failed`].
    transmitted: bool,
    first_sent: Option<Time>,
    /// When to retransmit (acknowledged sends that are on the wire).
    deadline: Option<Time>,
}

impl<T> Pending<T> {
    /// The outcome of giving up on this send for `reason`: unconfirmed once any frame left
    /// (it may have arrived), failed while none has.
    fn give_up(&self, reason: FailReason) -> Outcome {
        let attempts = self.attempts;
        if self.transmitted {
            Outcome::Unconfirmed { reason, attempts }
        } else {
            Outcome::Failed { reason, attempts }
        }
    }
}

/// In-order delivery state for one (origin, incarnation).
#[derive(Default)]
struct OrderState {
    /// The sequence number to deliver next.
    next: u64,
    /// Early arrivals, by sequence number.
    held: BTreeMap<u64, Held>,
    /// When the oldest early arrival gives up on the gap.
    deadline: Option<Time>,
}

struct Held {
    header: Header,
    payload: PayloadBuf,
    link: usize,
    ack_header: Header,
}

struct PendingDelivery {
    origin: SystemId,
    incarnation: u32,
    seq: u64,
    link: usize,
    ack_header: Header,
}

/// What a router keeps per destination system.
#[derive(Default)]
struct Towards {
    /// The last sequence number given (the first send gets 1), when there is no lane.
    last_seq: u64,
    /// Numbers given by the router itself while a lane exists (the rest are the lane's).
    numbered_here: u64,
    /// Sends handed straight to an inbox of this process, numbered from the same counter.
    lane: Option<Arc<DirectLane>>,
    /// Sends awaiting their outcome (bounded by [`Route::max_in_flight`]).
    pending: u32,
}

/// The per-system routing and reliability state machine. `T` is an opaque token the driver
/// attaches to each send and gets back with its outcome.
pub struct Router<T> {
    config: RouterConfig,
    routes: HashMap<SystemId, Route>,
    /// Numbering and the window, per destination (one lookup per send).
    towards: HashMap<SystemId, Towards>,
    rtt: HashMap<SystemId, RttEstimator>,
    pending: HashMap<SendId, Pending<T>>,
    /// Retransmission deadlines, possibly stale (checked against `Pending::deadline`).
    timers: BTreeSet<(Time, SendId)>,
    transmits: VecDeque<TransmitItem>,
    deliveries: VecDeque<Delivery>,
    awaiting: HashMap<DeliveryToken, PendingDelivery>,
    next_token: u64,
    events: VecDeque<Event<T>>,
    dedup: Dedup,
    order: BTreeMap<(SystemId, u32), OrderState>,
    stats: RouterStats,
    /// Per link index: whether the link guarantees the payload's integrity itself (see
    /// [`Router::set_link_checksums_payload`]). Links past the end do not.
    link_checks_payload: Vec<bool>,
    /// Frame buffers of ended sends, reused by the next sends (see [`SPARE_FRAMES`]).
    spare_frames: Vec<Vec<u8>>,
}

/// How many buffers of ended sends a router keeps for reuse: a sender that keeps sending
/// large messages then neither allocates nor frees a frame per message (an allocation of tens
/// of kilobytes, freed at once, is returned to the system and faulted in again each time).
const SPARE_FRAMES: usize = 4;
/// Buffers larger than this are freed rather than kept.
const SPARE_FRAME_MAX: usize = 4 << 20;
/// Unacknowledged payloads this large, on a link that checksums payloads, are not copied into
/// the frame buffer but sent from the caller's memory behind their header
/// ([`Unqueued::body`]). Smaller ones cost less to copy than the extra piece costs the link
/// (and stay eligible for batching, which needs the whole frame).
pub const SPLIT_PAYLOAD_MIN: usize = 16 * 1024;

enum TransmitItem {
    Send(SendId),
    Ack {
        link: usize,
        to: SystemId,
        frame: Vec<u8>,
    },
}

impl<T> Router<T> {
    /// A router for `config.local`.
    pub fn new(config: RouterConfig) -> Self {
        let routes = config.routes.iter().copied().collect::<HashMap<_, _>>();
        let dedup = Dedup::new(config.dedup_window);
        Router {
            config,
            routes,
            towards: HashMap::default(),
            rtt: HashMap::default(),
            pending: HashMap::default(),
            timers: BTreeSet::new(),
            transmits: VecDeque::new(),
            deliveries: VecDeque::new(),
            awaiting: HashMap::default(),
            next_token: 0,
            events: VecDeque::new(),
            dedup,
            order: BTreeMap::new(),
            stats: RouterStats::default(),
            link_checks_payload: Vec::new(),
            spare_frames: Vec::new(),
        }
    }

    /// Declares whether link `link` guarantees the integrity of the bytes it carries (a
    /// reliable, checksummed byte stream such as TCP: `Link::checksums_payload` in
    /// `hetcomm-link`). Data frames sent on such a link carry a CRC of their header only
    /// ([`FLAG_HEADER_CRC`]), which spares both sides a pass over every payload byte; frames
    /// with a header-only CRC are accepted only from such links (elsewhere they count as
    /// malformed). Links are assumed not to until declared.
    pub fn set_link_checksums_payload(&mut self, link: usize, checks: bool) {
        if self.link_checks_payload.len() <= link {
            self.link_checks_payload.resize(link + 1, false);
        }
        self.link_checks_payload[link] = checks;
    }

    /// Whether link `link` was declared to guarantee payload integrity.
    pub fn link_checksums_payload(&self, link: usize) -> bool {
        self.link_checks_payload.get(link).copied().unwrap_or(false)
    }

    /// This system.
    pub fn local(&self) -> SystemId {
        self.config.local
    }

    /// The route to `to`, if the table allows traffic.
    pub fn route(&self, to: SystemId) -> Option<Route> {
        self.routes.get(&to).copied()
    }

    /// Destinations this system may send to, ascending.
    pub fn destinations(&self) -> Vec<SystemId> {
        let mut d: Vec<_> = self.routes.keys().copied().collect();
        d.sort_unstable();
        d
    }

    /// Counters, including the sends of [direct lanes](Router::direct_lane).
    pub fn stats(&self) -> RouterStats {
        let mut stats = self.stats.clone();
        for t in self.towards.values() {
            if let Some(lane) = &t.lane {
                lane.add_to(&mut stats, t.numbered_here);
            }
        }
        stats
    }

    /// The smoothed round-trip time to `to`, once measured.
    pub fn srtt(&self, to: SystemId) -> Option<Duration> {
        self.rtt.get(&to).and_then(|r| r.srtt())
    }

    /// Accepts a send: assigns its sequence number and queues its frame. Its outcome arrives
    /// later through [`Router::poll_event`].
    pub fn send(&mut self, now: Time, req: SendRequest<'_>, token: T) -> Result<SendId, SendError> {
        let (route, header) = self.admit(now, &req)?;
        Ok(self.queue(route, header, req.payload, token))
    }

    /// Encodes a send's frame (into a spare buffer when one is big enough).
    fn encode(&mut self, route: &Route, header: Header, payload: &[u8]) -> Vec<u8> {
        let (header, mut frame) = self.frame_buffer(route, header, HEADER_LEN + payload.len());
        wire::encode_into(&header, payload, &mut frame);
        frame
    }

    /// Only the header of the frame [`Router::encode`] would make.
    fn encode_header(&mut self, route: &Route, header: Header, payload: &[u8]) -> Vec<u8> {
        let (header, mut frame) = self.frame_buffer(route, header, HEADER_LEN);
        wire::encode_header_into(&header, payload, &mut frame);
        frame
    }

    /// The header as sent on `route`'s link, and an empty buffer for `len` bytes of frame.
    fn frame_buffer(&mut self, route: &Route, mut header: Header, len: usize) -> (Header, Vec<u8>) {
        if self.link_checksums_payload(route.link) {
            header.flags |= FLAG_HEADER_CRC;
        }
        let frame = match self.spare_frames.pop() {
            Some(mut f) if f.capacity() >= len => {
                f.clear();
                f
            }
            _ => Vec::with_capacity(len),
        };
        (header, frame)
    }

    /// Keeps an admitted send as pending and queues its first transmission.
    fn queue(&mut self, route: Route, header: Header, payload: &[u8], token: T) -> SendId {
        let id = SendId {
            to: header.destination.system,
            seq: header.seq,
        };
        let frame = self.encode(&route, header, payload);
        self.keep_pending(
            id,
            Pending {
                token,
                route,
                frame: Some(frame),
                attempts: 0,
                transmitted: false,
                first_sent: None,
                deadline: None,
            },
        );
        self.transmits.push_back(TransmitItem::Send(id));
        self.stats.sends += 1;
        id
    }

    /// Like [`Router::send`], except that an unacknowledged send is not kept: its outcome is
    /// known as soon as the link takes or refuses its one frame, so the router numbers and
    /// counts it and hands the frame straight back ([`Admitted::Transmit`]) instead of keeping
    /// a pending entry, a queued transmission and an event for it. The driver puts the frame
    /// on the link and reports with [`Router::unqueued_result`]. An acknowledged send is
    /// queued as by [`Router::send`] ([`Admitted::Queued`]); `token` is only called then,
    /// or later by `unqueued_result` should a refused frame be retried, so a driver whose
    /// token is costly (a shared slot for the outcome) makes one only when it is needed.
    pub fn send_unqueued<'a>(
        &mut self,
        now: Time,
        req: SendRequest<'a>,
        token: impl FnOnce() -> T,
    ) -> Result<Admitted<'a>, SendError> {
        let (route, header) = self.admit(now, &req)?;
        if route.acknowledged {
            return Ok(Admitted::Queued(self.queue(
                route,
                header,
                req.payload,
                token(),
            )));
        }
        let id = SendId {
            to: header.destination.system,
            seq: header.seq,
        };
        let split =
            req.payload.len() >= SPLIT_PAYLOAD_MIN && self.link_checksums_payload(route.link);
        let (frame, body) = if split {
            (self.encode_header(&route, header, req.payload), req.payload)
        } else {
            (self.encode(&route, header, req.payload), &[][..])
        };
        self.stats.sends += 1;
        self.stats.transmissions += 1;
        Ok(Admitted::Transmit(Unqueued {
            link: route.link,
            to: id.to,
            frame,
            body,
            id,
        }))
    }

    /// Reports what the link did with the frame of an unqueued send
    /// ([`Router::send_unqueued`]) and returns the send's outcome when it is known now: `Sent`
    /// when the link took the frame, `Failed` when it refused it for good (too large, or the
    /// route allows one attempt). A refusal with attempts left makes the send pending with
    /// `token` and retries it after [`Timing::link_retry`], exactly as a queued send; its
    /// outcome then comes out of [`Router::poll_event`] and this returns None.
    pub fn unqueued_result(
        &mut self,
        now: Time,
        tx: Unqueued<'_>,
        result: Result<(), TransmitError>,
        token: impl FnOnce() -> T,
    ) -> Option<Outcome> {
        let Unqueued {
            mut frame,
            body,
            id,
            ..
        } = tx;
        let err = match result {
            Ok(()) => {
                self.recycle(frame);
                self.stats.sent += 1;
                return Some(Outcome::Sent { attempts: 1 });
            }
            Err(err) => err,
        };
        let route = self.routes.get(&id.to).copied();
        let retry = match (&err, route) {
            (TransmitError::TooLarge(_), _) | (_, None) => None,
            (_, Some(route)) => Some(route).filter(|r| r.attempts > 1),
        };
        let Some(route) = retry else {
            self.recycle(frame);
            self.stats.failed += 1;
            let reason = match err {
                TransmitError::Unreachable(r) => FailReason::Unreachable(r),
                TransmitError::TooLarge(r) | TransmitError::Other(r) => FailReason::Link(r),
            };
            return Some(Outcome::Failed {
                reason,
                attempts: 1,
            });
        };
        // The first attempt failed: from here on the send is an ordinary pending one, which
        // keeps its whole frame.
        frame.extend_from_slice(body);
        let deadline = now + self.config.timing.link_retry;
        self.keep_pending(
            id,
            Pending {
                token: token(),
                route,
                frame: Some(frame),
                attempts: 1,
                transmitted: false,
                first_sent: Some(now),
                deadline: Some(deadline),
            },
        );
        self.timers.insert((deadline, id));
        None
    }

    /// Records an unresolved send (counted against its destination's window).
    fn keep_pending(&mut self, id: SendId, p: Pending<T>) {
        self.towards.entry(id.to).or_default().pending += 1;
        self.pending.insert(id, p);
    }

    /// Sends to `to` awaiting their outcome (at most its route's [`Route::max_in_flight`]).
    pub fn pending_to(&self, to: SystemId) -> u32 {
        self.towards.get(&to).map_or(0, |t| t.pending)
    }

    /// Keeps an ended send's frame buffer for the next sends (see [`SPARE_FRAMES`]).
    fn recycle(&mut self, frame: Vec<u8>) {
        if self.spare_frames.len() < SPARE_FRAMES && frame.capacity() <= SPARE_FRAME_MAX {
            self.spare_frames.push(frame);
        }
    }

    /// Checks a send against the routing table and the size limit, gives it the next
    /// sequence number towards its destination and builds its header.
    fn admit(&mut self, now: Time, req: &SendRequest<'_>) -> Result<(Route, Header), SendError> {
        let to = req.to.system;
        let route = self.routes.get(&to).copied().ok_or(SendError::NoRoute {
            from: self.config.local,
            to,
        })?;
        let len = HEADER_LEN + req.payload.len();
        let max = route.max_frame.min(HEADER_LEN + wire::MAX_PAYLOAD);
        if len > max {
            return Err(SendError::TooLarge { len, max, to });
        }
        let towards = self.towards.entry(to).or_default();
        // Refused before numbering: a refused send leaves no gap in the sequence.
        if towards.pending >= route.max_in_flight {
            self.stats.backpressured += 1;
            return Err(SendError::Backpressure {
                to,
                limit: route.max_in_flight,
            });
        }
        let seq = match &towards.lane {
            Some(lane) => {
                towards.numbered_here += 1;
                lane.last_seq.fetch_add(1, Ordering::Relaxed) + 1
            }
            None => {
                towards.last_seq += 1;
                towards.last_seq
            }
        };
        let mut flags = 0;
        if route.acknowledged {
            flags |= FLAG_ACK_REQUESTED;
        }
        if req.broadcast {
            flags |= FLAG_BROADCAST;
        }
        let header = Header {
            kind: FrameKind::Data,
            flags,
            priority: req.priority,
            transport: route.tag,
            source: Address {
                system: self.config.local,
                module: req.from,
            },
            destination: req.to,
            incarnation: self.config.incarnation,
            seq,
            message_type: req.message_type,
            timestamp: now,
        };
        Ok((route, header))
    }

    /// The link a send to `to` would take.
    pub fn route_link(&self, to: SystemId) -> Option<usize> {
        self.routes.get(&to).map(|r| r.link)
    }

    /// The lane for sends that the driver hands straight to `to` in the same process (an
    /// in-process link, which is reliable, ordered and synchronous), skipping the frame, its
    /// checksum, the destination's router and this router's lock ([`DirectLane`]). Made at
    /// the first call; later calls return the same lane.
    pub fn direct_lane(&mut self, to: SystemId) -> Result<Arc<DirectLane>, SendError> {
        let route = self.routes.get(&to).copied().ok_or(SendError::NoRoute {
            from: self.config.local,
            to,
        })?;
        let (local, incarnation) = (self.config.local, self.config.incarnation);
        let towards = self.towards.entry(to).or_default();
        if towards.lane.is_none() {
            // The numbers given so far were the router's.
            towards.numbered_here = towards.last_seq;
        }
        let lane = towards.lane.get_or_insert_with(|| {
            Arc::new(DirectLane::new(
                local,
                incarnation,
                to,
                route,
                towards.last_seq,
            ))
        });
        Ok(lane.clone())
    }

    /// The next frame to put on a link. `now` is when the driver hands it to the link: an
    /// acknowledgement may come back before [`Router::transmit_result`] is called (an
    /// in-process link delivers synchronously), and is accepted.
    pub fn poll_transmit(&mut self, now: Time) -> Option<Transmit> {
        while let Some(item) = self.transmits.pop_front() {
            match item {
                TransmitItem::Ack { link, to, frame } => {
                    return Some(Transmit {
                        link,
                        to,
                        frame,
                        send: None,
                    })
                }
                TransmitItem::Send(id) => {
                    // A send may have ended (acknowledged) while queued for retransmission.
                    let Some(p) = self.pending.get_mut(&id) else {
                        continue;
                    };
                    let Some(frame) = p.frame.take() else {
                        continue;
                    };
                    p.attempts += 1;
                    p.first_sent.get_or_insert(now);
                    self.stats.transmissions += 1;
                    if p.attempts > 1 {
                        self.stats.retransmissions += 1;
                    }
                    return Some(Transmit {
                        link: p.route.link,
                        to: id.to,
                        frame,
                        send: Some(id),
                    });
                }
            }
        }
        None
    }

    /// Reports what the link did with a frame from [`Router::poll_transmit`], handing the
    /// frame back (the router keeps it for retransmission).
    pub fn transmit_result(&mut self, now: Time, tx: Transmit, result: Result<(), TransmitError>) {
        let Some(id) = tx.send else { return };
        let Some(attempts) = self.pending.get(&id).map(|p| p.attempts) else {
            return; // already ended (an ack overtook the result)
        };
        let rto = self.rto_for(id.to, attempts);
        let Some(p) = self.pending.get_mut(&id) else {
            return;
        };
        p.frame = Some(tx.frame);
        if result.is_ok() {
            p.transmitted = true;
        }
        match result {
            Ok(()) => {
                if p.route.acknowledged {
                    let deadline = now + rto;
                    p.deadline = Some(deadline);
                    self.timers.insert((deadline, id));
                } else {
                    let attempts = p.attempts;
                    self.finish(id, Outcome::Sent { attempts });
                }
            }
            Err(TransmitError::TooLarge(reason)) => {
                let outcome = p.give_up(FailReason::Link(reason));
                self.finish(id, outcome);
            }
            Err(err) => {
                if p.attempts < p.route.attempts {
                    let factor = 1u32 << p.attempts.saturating_sub(1).min(16);
                    let deadline = now + self.config.timing.link_retry * factor;
                    p.deadline = Some(deadline);
                    self.timers.insert((deadline, id));
                } else {
                    let reason = match err {
                        TransmitError::Unreachable(r) => FailReason::Unreachable(r),
                        TransmitError::TooLarge(r) | TransmitError::Other(r) => FailReason::Link(r),
                    };
                    let outcome = p.give_up(reason);
                    self.finish(id, outcome);
                }
            }
        }
    }

    /// The timeout for the given attempt: the destination's RTO, backed off per earlier attempt.
    fn rto_for(&self, to: SystemId, attempt: u32) -> Duration {
        let t = self.config.timing;
        let base = self.rtt.get(&to).map(|r| r.rto()).unwrap_or(t.initial_rto);
        let factor = t
            .backoff
            .max(1.0)
            .powi(attempt.saturating_sub(1).min(30) as i32);
        base.mul_f64(factor).min(t.max_rto).max(t.min_rto)
    }

    fn finish(&mut self, id: SendId, outcome: Outcome) {
        if let Some(p) = self.pending.remove(&id) {
            if let Some(t) = self.towards.get_mut(&id.to) {
                t.pending -= 1;
            }
            // Its retransmission timer would only wake the driver for nothing.
            if let Some(deadline) = p.deadline {
                self.timers.remove(&(deadline, id));
            }
            if let Some(frame) = p.frame {
                self.recycle(frame);
            }
            match outcome {
                Outcome::Delivered { .. } => self.stats.delivered += 1,
                Outcome::Sent { .. } => self.stats.sent += 1,
                Outcome::Unconfirmed { .. } => self.stats.unconfirmed += 1,
                Outcome::Failed { .. } => self.stats.failed += 1,
            }
            self.events.push_back(Event::Outcome {
                id,
                token: p.token,
                outcome,
            });
        }
    }

    /// Handles a frame a link received. Bad frames are counted and dropped.
    pub fn handle_frame(&mut self, now: Time, link: usize, bytes: &[u8]) {
        let frame = match wire::decode(bytes) {
            Ok(f) => f,
            Err(_) => {
                self.stats.malformed += 1;
                return;
            }
        };
        self.handle_decoded(
            now,
            link,
            frame.header,
            PayloadSource::Borrowed(frame.payload),
        );
    }

    /// Like [`Router::handle_frame`], for a frame the link handed over in a buffer of its own:
    /// a data frame's payload is delivered in that same buffer, without a copy.
    pub fn handle_frame_owned(&mut self, now: Time, link: usize, frame: impl Into<FrameBuf>) {
        let frame = frame.into();
        let header = match wire::decode(&frame) {
            Ok(f) => f.header,
            Err(_) => {
                self.stats.malformed += 1;
                return;
            }
        };
        self.handle_decoded(
            now,
            link,
            header,
            PayloadSource::Owned(PayloadBuf::from_frame(frame, HEADER_LEN)),
        );
    }

    fn handle_decoded(&mut self, now: Time, link: usize, h: Header, body: PayloadSource<'_>) {
        if !h.payload_checked() && !self.link_checksums_payload(link) {
            // Only the header was checksummed, on a link that does not vouch for the rest.
            self.stats.malformed += 1;
            return;
        }
        if !self.config.known_systems.contains(&h.source.system) {
            self.stats.unknown_origin += 1;
            return;
        }
        if h.destination.system != self.config.local {
            self.stats.misrouted += 1;
            return;
        }
        match h.kind {
            FrameKind::Ack => self.handle_ack(now, &h, body.as_slice()),
            FrameKind::Data => self.handle_data(now, link, &h, body),
        }
    }

    fn handle_ack(&mut self, now: Time, h: &Header, payload: &[u8]) {
        let status = match payload {
            [b] => AckStatus::from_u8(*b),
            _ => None,
        };
        let Some(status) = status else {
            self.stats.malformed += 1;
            return;
        };
        let id = SendId {
            to: h.source.system,
            seq: h.seq,
        };
        let matches = h.incarnation == self.config.incarnation
            && self.pending.get(&id).is_some_and(|p| p.attempts > 0);
        if !matches {
            self.stats.stale_acks += 1;
            return;
        }
        self.stats.acks_received += 1;
        let p = &self.pending[&id];
        let attempts = p.attempts;
        let latency = now.saturating_since(p.first_sent.unwrap_or(now));
        if attempts == 1 {
            // Karn: only unambiguous samples.
            let t = self.config.timing;
            self.rtt
                .entry(id.to)
                .or_insert_with(|| RttEstimator::new(t.initial_rto, t.min_rto, t.max_rto))
                .sample(latency);
        }
        self.finish(id, Outcome::acknowledged(status, attempts, latency));
    }

    fn handle_data(&mut self, now: Time, link: usize, h: &Header, payload: PayloadSource<'_>) {
        let origin = h.source.system;
        let ack_header = Header {
            kind: FrameKind::Ack,
            flags: 0,
            priority: h.priority,
            transport: h.transport,
            source: h.destination,
            destination: h.source,
            incarnation: h.incarnation,
            seq: h.seq,
            message_type: h.message_type,
            timestamp: h.timestamp,
        };
        let key = (origin, h.incarnation);
        if !self.dedup.insert_new(origin, h.incarnation, h.seq) {
            self.stats.duplicates += 1;
            // The earlier acknowledgement may have been lost: say it again, unless the first
            // copy is still waiting for its inbox or its turn (its ack comes then).
            let waiting =
                self.awaiting.values().any(|d| {
                    d.origin == origin && d.incarnation == h.incarnation && d.seq == h.seq
                }) || self
                    .order
                    .get(&key)
                    .is_some_and(|o| o.held.contains_key(&h.seq));
            if h.ack_requested() && !waiting {
                self.queue_ack(link, ack_header, AckStatus::Delivered);
            }
            return;
        }
        if !self.config.ordered_sources.contains(&origin) {
            self.accept(link, *h, payload.into_buf(), ack_header);
            return;
        }
        let hold = self.config.timing.hold_timeout;
        let state = self.order.entry(key).or_insert_with(|| OrderState {
            next: 1,
            ..OrderState::default()
        });
        if h.seq > state.next {
            self.stats.held += 1;
            state.held.insert(
                h.seq,
                Held {
                    header: *h,
                    payload: payload.into_buf(),
                    link,
                    ack_header,
                },
            );
            state.deadline.get_or_insert(now + hold);
            return;
        }
        if h.seq == state.next {
            state.next += 1;
        }
        // In order (or older than a gap already given up): deliver, then whatever it unblocks.
        self.accept(link, *h, payload.into_buf(), ack_header);
        self.release_in_order(now, key);
    }

    /// Delivers held messages that are now next in line.
    fn release_in_order(&mut self, now: Time, key: (SystemId, u32)) {
        let hold = self.config.timing.hold_timeout;
        let mut ready = Vec::new();
        if let Some(state) = self.order.get_mut(&key) {
            while let Some(held) = state.held.remove(&state.next) {
                state.next += 1;
                ready.push(held);
            }
            state.deadline = if state.held.is_empty() {
                None
            } else {
                Some(now + hold)
            };
        }
        for held in ready {
            self.accept(held.link, held.header, held.payload, held.ack_header);
        }
    }

    /// Hands a message to the driver for its inbox (with a token when it wants an ack).
    fn accept(&mut self, link: usize, header: Header, payload: PayloadBuf, ack_header: Header) {
        self.stats.received += 1;
        let token = if header.ack_requested() {
            let token = DeliveryToken(self.next_token);
            self.next_token += 1;
            self.awaiting.insert(
                token,
                PendingDelivery {
                    origin: header.source.system,
                    incarnation: header.incarnation,
                    seq: header.seq,
                    link,
                    ack_header,
                },
            );
            Some(token)
        } else {
            None
        };
        self.deliveries.push_back(Delivery {
            header,
            payload,
            link,
            token,
        });
    }

    fn queue_ack(&mut self, link: usize, header: Header, status: AckStatus) {
        let frame = wire::encode(&header, &[status as u8]);
        self.stats.acks_sent += 1;
        self.transmits.push_back(TransmitItem::Ack {
            link,
            to: header.destination.system,
            frame,
        });
    }

    /// The next message for a local module.
    pub fn poll_delivery(&mut self) -> Option<Delivery> {
        self.deliveries.pop_front()
    }

    /// Reports what the destination inbox did with a delivery that carried a token; the
    /// router acknowledges accordingly. A refused message is forgotten by the duplicate filter,
    /// so a retransmission may try again.
    pub fn delivery_result(&mut self, _now: Time, token: DeliveryToken, status: AckStatus) {
        let Some(d) = self.awaiting.remove(&token) else {
            return;
        };
        if status != AckStatus::Delivered {
            self.dedup.remove(d.origin, d.incarnation, d.seq);
            self.stats.received -= 1;
        }
        self.queue_ack(d.link, d.ack_header, status);
    }

    /// When [`Router::handle_timeout`] should next be called.
    pub fn poll_timeout(&self) -> Option<Time> {
        let retransmit = self.timers.first().map(|(t, _)| *t);
        let hold = self.order.values().filter_map(|o| o.deadline).min();
        match (retransmit, hold) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }

    /// Retransmits or fails sends whose acknowledgement is overdue, and moves in-order
    /// delivery past gaps that waited longer than the hold timeout.
    pub fn handle_timeout(&mut self, now: Time) {
        let overdue: Vec<(SystemId, u32)> = self
            .order
            .iter()
            .filter(|(_, o)| o.deadline.is_some_and(|d| d <= now))
            .map(|(k, _)| *k)
            .collect();
        for key in overdue {
            if let Some(state) = self.order.get_mut(&key) {
                if let Some(&first) = state.held.keys().next() {
                    self.stats.gaps_skipped += 1;
                    state.next = first;
                }
            }
            self.release_in_order(now, key);
        }
        while let Some(&(deadline, id)) = self.timers.first() {
            if deadline > now {
                break;
            }
            self.timers.pop_first();
            let Some(p) = self.pending.get_mut(&id) else {
                continue;
            };
            if p.deadline != Some(deadline) {
                continue; // superseded
            }
            p.deadline = None;
            if p.attempts < p.route.attempts {
                self.transmits.push_back(TransmitItem::Send(id));
            } else {
                let outcome = p.give_up(FailReason::NoAcknowledgement);
                self.finish(id, outcome);
            }
        }
    }

    /// The next outcome.
    pub fn poll_event(&mut self) -> Option<Event<T>> {
        self.events.pop_front()
    }

    /// Fails every unresolved send with [`FailReason::Shutdown`] (their outcomes appear in
    /// [`Router::poll_event`]).
    pub fn shutdown(&mut self) {
        let ids: Vec<SendId> = self.pending.keys().copied().collect();
        for id in ids {
            let outcome = self.pending[&id].give_up(FailReason::Shutdown);
            self.finish(id, outcome);
        }
        self.timers.clear();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const A: SystemId = SystemId(0);
    const B: SystemId = SystemId(1);

    fn route(acknowledged: bool) -> Route {
        Route {
            link: 0,
            tag: b'T',
            acknowledged,
            attempts: 3,
            max_frame: 1 << 20,
            max_in_flight: 1024,
        }
    }

    fn pair(acknowledged: bool) -> (Router<()>, Router<()>) {
        let a = Router::new(RouterConfig::new(A, 1, vec![(B, route(acknowledged))]));
        let b = Router::new(RouterConfig::new(B, 2, vec![(A, route(acknowledged))]));
        (a, b)
    }

    fn to_b() -> Address {
        Address {
            system: B,
            module: ModuleId(0),
        }
    }

    fn payload(len: usize) -> Vec<u8> {
        (0..len).map(|i| (i % 251) as u8).collect()
    }

    /// Sends `bytes` from `a` and returns the frame it hands out (after reporting success).
    fn sent_frame(a: &mut Router<()>, now: Time, bytes: &[u8]) -> Vec<u8> {
        a.send(
            now,
            SendRequest::new(ModuleId(0), to_b(), MessageType(1), bytes),
            (),
        )
        .unwrap();
        let tx = a.poll_transmit(now).unwrap();
        let frame = tx.frame.clone();
        a.transmit_result(now, tx, Ok(()));
        frame
    }

    #[test]
    fn links_that_check_the_payload_get_a_header_only_crc() {
        let now = Time::from_micros(1_000);
        let (mut a, mut b) = pair(true);
        assert!(!a.link_checksums_payload(0));
        let full = sent_frame(&mut a, now, &payload(1000));
        assert!(wire::decode(&full).unwrap().header.payload_checked());
        a.set_link_checksums_payload(0, true);
        assert!(a.link_checksums_payload(0) && !a.link_checksums_payload(1));
        let frame = sent_frame(&mut a, now, &payload(1000));
        let h = wire::decode(&frame).unwrap().header;
        assert_eq!(h.flags, FLAG_ACK_REQUESTED | FLAG_HEADER_CRC);
        // The payload is not covered: a changed payload byte still decodes.
        let mut changed = frame.clone();
        changed[HEADER_LEN + 10] ^= 0xff;
        assert!(wire::decode(&changed).is_ok());

        // A receiver whose link does not vouch for payloads refuses such frames…
        b.handle_frame(now, 0, &frame);
        assert_eq!(b.stats().malformed, 1);
        assert!(b.poll_delivery().is_none());
        // …one whose link does accepts them, and full-CRC frames as before.
        b.set_link_checksums_payload(0, true);
        b.handle_frame(now, 0, &frame);
        b.handle_frame(now, 0, &full);
        let d = b.poll_delivery().unwrap();
        assert_eq!(d.payload, payload(1000));
        assert_eq!(d.header.seq, 2);
        assert_eq!(b.poll_delivery().unwrap().header.seq, 1);
        assert_eq!(b.stats().malformed, 1);
        // Acknowledgements keep flags 0 and a full CRC.
        b.delivery_result(now, d.token.unwrap(), AckStatus::Delivered);
        let ack = b.poll_transmit(now).unwrap();
        let ack_h = wire::decode(&ack.frame).unwrap().header;
        assert_eq!((ack_h.kind, ack_h.flags), (FrameKind::Ack, 0));
    }

    #[test]
    fn owned_frames_become_the_payload_without_a_copy() {
        let now = Time::from_micros(1_000);
        for ordered in [false, true] {
            let (mut a, mut b) = pair(false);
            if ordered {
                b.config.ordered_sources.insert(A);
            }
            let first = sent_frame(&mut a, now, &payload(5000));
            let second = sent_frame(&mut a, now, &payload(70_000));
            // The second arrives first when ordered: it is held, then released.
            let handed = second.clone();
            let ptr = handed.as_ptr();
            b.handle_frame_owned(now, 0, handed);
            if !ordered {
                let d = b.poll_delivery().unwrap();
                assert_eq!(d.payload.as_ptr(), ptr.wrapping_add(HEADER_LEN));
                assert_eq!(d.payload, payload(70_000));
            }
            let ptr_first = first.as_ptr();
            b.handle_frame_owned(now, 0, first);
            let d = b.poll_delivery().unwrap();
            assert_eq!(d.header.seq, 1, "ordered: {ordered}");
            assert_eq!(d.payload.as_ptr(), ptr_first.wrapping_add(HEADER_LEN));
            assert_eq!(d.payload, payload(5000));
            if ordered {
                // Held, then released: still the buffer it arrived in.
                let d = b.poll_delivery().unwrap();
                assert_eq!(d.header.seq, 2);
                assert_eq!(d.payload.as_ptr(), ptr.wrapping_add(HEADER_LEN));
                assert_eq!(d.payload, payload(70_000));
            }
            // A duplicate is dropped, a small payload copied inline, garbage counted.
            b.handle_frame_owned(now, 0, second);
            assert_eq!(b.stats().duplicates, 1);
            let small = sent_frame(&mut a, now, b"tiny");
            b.handle_frame_owned(now, 0, small);
            let d = b.poll_delivery().unwrap();
            assert!(d.payload.is_inline());
            assert_eq!(d.payload, b"tiny");
            b.handle_frame_owned(now, 0, vec![1, 2, 3]);
            assert_eq!(b.stats().malformed, 1);
            assert!(b.poll_delivery().is_none());
        }
    }

    fn unqueued<'a>(a: &mut Router<u32>, now: Time, bytes: &'a [u8]) -> Unqueued<'a> {
        let req = SendRequest::new(ModuleId(0), to_b(), MessageType(1), bytes);
        match a.send_unqueued(now, req, || panic!("no token for an unacknowledged send")) {
            Ok(Admitted::Transmit(tx)) => tx,
            other => panic!("expected an unqueued frame, got {other:?}"),
        }
    }

    fn router_with(acknowledged: bool, attempts: u32) -> Router<u32> {
        let r = Route {
            attempts,
            ..route(acknowledged)
        };
        Router::new(RouterConfig::new(A, 1, vec![(B, r)]))
    }

    #[test]
    fn an_unqueued_send_is_sent_when_the_link_takes_it() {
        let now = Time::from_micros(1_000);
        let mut a = router_with(false, 3);
        let (_, mut b) = pair(false);
        let tx = unqueued(&mut a, now, b"hello");
        assert_eq!((tx.link, tx.to, tx.id()), (0, B, SendId { to: B, seq: 1 }));
        // Counted as sent and in flight until the link answers; nothing queued or pending.
        assert_eq!((a.stats().sends, a.stats().transmissions), (1, 1));
        assert_eq!(a.stats().in_flight(), 1);
        assert!(a.poll_transmit(now).is_none() && a.poll_timeout().is_none());
        // The frame is an ordinary unacknowledged data frame.
        b.handle_frame(now, 0, &tx.frame);
        let d = b.poll_delivery().unwrap();
        assert_eq!((d.payload.as_slice(), d.header.seq), (&b"hello"[..], 1));
        assert!(d.token.is_none() && !d.header.ack_requested());
        let ptr = tx.frame.as_ptr();
        let outcome = a.unqueued_result(now, tx, Ok(()), || panic!("no token when sent"));
        assert_eq!(outcome, Some(Outcome::Sent { attempts: 1 }));
        let s = a.stats().clone();
        assert_eq!((s.sent, s.failed, s.in_flight()), (1, 0, 0));
        assert!(
            a.poll_event().is_none(),
            "the outcome was returned, not queued"
        );
        // The next send reuses the frame buffer and takes the next number.
        let tx = unqueued(&mut a, now, b"again");
        assert_eq!((tx.frame.as_ptr(), tx.id().seq), (ptr, 2));
        let _ = a.unqueued_result(now, tx, Ok(()), || 0);
    }

    #[test]
    fn a_large_unqueued_payload_is_left_out_of_the_frame_on_a_link_that_checksums_it() {
        let now = Time::from_micros(1_000);
        let big = payload(SPLIT_PAYLOAD_MIN);
        // A link that does not checksum payloads: the whole frame, as always.
        let mut a = router_with(false, 3);
        let tx = unqueued(&mut a, now, &big);
        assert_eq!((tx.frame.len(), tx.body.len()), (HEADER_LEN + big.len(), 0));
        let _ = a.unqueued_result(now, tx, Ok(()), || 0);
        // One that does: only the header, the payload is the caller's own bytes.
        let mut a = router_with(false, 3);
        a.set_link_checksums_payload(0, true);
        let (_, mut b) = pair(false);
        b.set_link_checksums_payload(0, true);
        let tx = unqueued(&mut a, now, &big);
        assert_eq!(tx.frame.len(), HEADER_LEN);
        assert_eq!(tx.body.as_ptr(), big.as_ptr());
        let mut whole = tx.frame.clone();
        whole.extend_from_slice(tx.body);
        b.handle_frame(now, 0, &whole);
        assert_eq!(b.poll_delivery().unwrap().payload, big);
        assert_eq!(
            a.unqueued_result(now, tx, Ok(()), || 0),
            Some(Outcome::Sent { attempts: 1 })
        );
        // Just under the threshold: copied.
        let tx = unqueued(&mut a, now, &big[1..]);
        assert!(tx.body.is_empty());
        let _ = a.unqueued_result(now, tx, Ok(()), || 0);
        // Refused with attempts left: the pending retry keeps the whole frame.
        let tx = unqueued(&mut a, now, &big);
        let err = Err(TransmitError::Other("congested".into()));
        assert_eq!(a.unqueued_result(now, tx, err, || 5), None);
        let later = a.poll_timeout().unwrap();
        a.handle_timeout(later);
        let tx = a.poll_transmit(later).expect("a retransmission");
        b.handle_frame(later, 0, &tx.frame);
        let d = b.poll_delivery().unwrap();
        assert_eq!((d.payload.as_slice(), d.header.seq), (&big[..], 3));
        a.transmit_result(later, tx, Ok(()));
    }

    #[test]
    fn an_unqueued_send_refused_by_its_link_is_retried_then_fails() {
        let t0 = Time::from_micros(1_000);
        let mut a = router_with(false, 3);
        let tx = unqueued(&mut a, t0, b"x");
        let refused = || Err(TransmitError::Unreachable("peer down".into()));
        // Attempts left: the send becomes pending with its token, retried after link_retry.
        assert_eq!(a.unqueued_result(t0, tx, refused(), || 7), None);
        let retry = a.config.timing.link_retry;
        assert_eq!(a.poll_timeout(), Some(t0 + retry));
        assert_eq!(a.stats().in_flight(), 1);
        for attempt in 2..=3u32 {
            let now = a.poll_timeout().unwrap();
            a.handle_timeout(now);
            let tx = a.poll_transmit(now).expect("a retransmission");
            assert_eq!(tx.send, Some(SendId { to: B, seq: 1 }));
            a.transmit_result(now, tx, refused());
            assert_eq!(a.stats().retransmissions, u64::from(attempt - 1));
        }
        match a.poll_event() {
            Some(Event::Outcome {
                token: 7,
                outcome:
                    Outcome::Failed {
                        reason: FailReason::Unreachable(why),
                        attempts: 3,
                    },
                ..
            }) => assert!(why.contains("peer down")),
            other => panic!("expected a failure after 3 attempts, got {other:?}"),
        }
        let s = a.stats().clone();
        assert_eq!(
            (s.sends, s.transmissions, s.retransmissions, s.failed),
            (1, 3, 2, 1)
        );
        assert_eq!((s.sent, s.in_flight()), (0, 0));
        assert!(a.poll_timeout().is_none());
    }

    #[test]
    fn an_unqueued_send_retried_after_a_refusal_can_still_be_sent() {
        let t0 = Time::from_micros(1_000);
        let mut a = router_with(false, 3);
        let tx = unqueued(&mut a, t0, b"x");
        let err = Err(TransmitError::Other("congested".into()));
        assert_eq!(a.unqueued_result(t0, tx, err, || 9), None);
        let now = a.poll_timeout().unwrap();
        a.handle_timeout(now);
        let tx = a.poll_transmit(now).unwrap();
        a.transmit_result(now, tx, Ok(()));
        assert!(matches!(
            a.poll_event(),
            Some(Event::Outcome {
                token: 9,
                outcome: Outcome::Sent { attempts: 2 },
                ..
            })
        ));
        let s = a.stats().clone();
        assert_eq!((s.sent, s.retransmissions, s.in_flight()), (1, 1, 0));
    }

    #[test]
    fn an_unqueued_send_fails_at_once_without_attempts_left_or_when_too_large() {
        let now = Time::from_micros(1_000);
        let mut a = router_with(false, 1);
        let tx = unqueued(&mut a, now, b"x");
        let err = Err(TransmitError::Unreachable("peer down".into()));
        let outcome = a.unqueued_result(now, tx, err, || panic!("nothing to retry"));
        assert!(matches!(
            outcome,
            Some(Outcome::Failed {
                reason: FailReason::Unreachable(_),
                attempts: 1
            })
        ));
        // A frame the link can never carry is not retried, whatever the budget.
        let mut a3 = router_with(false, 3);
        let tx = unqueued(&mut a3, now, b"x");
        let err = Err(TransmitError::TooLarge("too big".into()));
        let outcome = a3.unqueued_result(now, tx, err, || panic!("nothing to retry"));
        assert!(matches!(
            outcome,
            Some(Outcome::Failed {
                reason: FailReason::Link(_),
                attempts: 1
            })
        ));
        for r in [&a, &a3] {
            let s = r.stats();
            assert_eq!(
                (s.sends, s.transmissions, s.failed, s.in_flight()),
                (1, 1, 1, 0)
            );
            assert!(r.poll_timeout().is_none() && r.pending.is_empty());
        }
    }

    #[test]
    fn an_acknowledged_send_offered_unqueued_is_queued_with_its_token() {
        let now = Time::from_micros(1_000);
        let mut a = router_with(true, 3);
        let req = SendRequest::new(ModuleId(0), to_b(), MessageType(1), b"x");
        let admitted = a.send_unqueued(now, req, || 5).unwrap();
        assert!(matches!(admitted, Admitted::Queued(SendId { seq: 1, .. })));
        let tx = a.poll_transmit(now).unwrap();
        assert!(wire::decode(&tx.frame).unwrap().header.ack_requested());
        a.transmit_result(now, tx, Ok(()));
        assert!(a.poll_timeout().is_some(), "waits for its acknowledgement");
        a.shutdown();
        assert!(matches!(
            a.poll_event(),
            Some(Event::Outcome { token: 5, .. })
        ));
        // Refusals are the router's as with `send`.
        let far = Address {
            system: SystemId(9),
            module: ModuleId(0),
        };
        let req = SendRequest::new(ModuleId(0), far, MessageType(1), b"x");
        assert!(matches!(
            a.send_unqueued(now, req, || 0),
            Err(SendError::NoRoute { .. })
        ));
    }

    #[test]
    fn frame_buffers_of_ended_sends_are_reused() {
        let now = Time::from_micros(1_000);
        let (mut a, _) = pair(false);
        let big = payload(65_536);
        a.send(
            now,
            SendRequest::new(ModuleId(0), to_b(), MessageType(1), &big),
            (),
        )
        .unwrap();
        let tx = a.poll_transmit(now).unwrap();
        let ptr = tx.frame.as_ptr();
        a.transmit_result(now, tx, Ok(()));
        assert!(matches!(
            a.poll_event(),
            Some(Event::Outcome {
                outcome: Outcome::Sent { .. },
                ..
            })
        ));
        // The next send, no larger, is encoded into the same buffer; a larger one is not.
        let small = payload(100);
        a.send(
            now,
            SendRequest::new(ModuleId(0), to_b(), MessageType(1), &small),
            (),
        )
        .unwrap();
        let tx = a.poll_transmit(now).unwrap();
        assert_eq!(tx.frame.as_ptr(), ptr);
        assert_eq!(wire::decode(&tx.frame).unwrap().payload, &small[..]);
        a.transmit_result(now, tx, Ok(()));
        let bigger = payload(200_000);
        let frame = sent_frame(&mut a, now, &bigger);
        assert_eq!(wire::decode(&frame).unwrap().payload, &bigger[..]);
        assert!(a.spare_frames.len() <= SPARE_FRAMES);
    }

    /// A router from A with a route to each of `to` (acknowledged or not) and a window of
    /// `window` sends.
    fn windowed(acknowledged: bool, window: u32, to: &[SystemId]) -> Router<u32> {
        let r = Route {
            max_in_flight: window,
            ..route(acknowledged)
        };
        Router::new(RouterConfig::new(
            A,
            1,
            to.iter().map(|&s| (s, r)).collect(),
        ))
    }

    fn request(to: SystemId) -> SendRequest<'static> {
        let to = Address {
            system: to,
            module: ModuleId(0),
        };
        SendRequest::new(ModuleId(0), to, MessageType(1), b"w")
    }

    #[test]
    fn acknowledged_sends_beyond_the_window_are_refused_unnumbered_until_an_outcome_frees_a_place()
    {
        let now = Time::from_micros(1_000);
        let mut a = windowed(true, 3, &[B]);
        let (_, mut b) = pair(true);
        for seq in 1..=3 {
            assert_eq!(a.send(now, request(B), 0), Ok(SendId { to: B, seq }));
        }
        assert_eq!(a.pending_to(B), 3);
        for _ in 0..2 {
            assert_eq!(
                a.send(now, request(B), 0),
                Err(SendError::Backpressure { to: B, limit: 3 })
            );
        }
        let s = a.stats();
        assert_eq!((s.sends, s.backpressured, s.in_flight()), (3, 2, 3));
        // The first send is acknowledged: one place frees, and the next send takes the next
        // number (the refused ones left no gap for an ordered receiver to wait on).
        let tx = a.poll_transmit(now).unwrap();
        b.handle_frame(now, 0, &tx.frame);
        a.transmit_result(now, tx, Ok(()));
        let d = b.poll_delivery().unwrap();
        b.delivery_result(now, d.token.unwrap(), AckStatus::Delivered);
        let ack = b.poll_transmit(now).unwrap();
        a.handle_frame(now, ack.link, &ack.frame);
        assert!(matches!(
            a.poll_event(),
            Some(Event::Outcome {
                outcome: Outcome::Delivered { .. },
                ..
            })
        ));
        assert_eq!(a.pending_to(B), 2);
        assert_eq!(a.send(now, request(B), 0), Ok(SendId { to: B, seq: 4 }));
        assert_eq!(
            a.send(now, request(B), 0),
            Err(SendError::Backpressure { to: B, limit: 3 })
        );
    }

    #[test]
    fn a_send_that_fails_frees_its_place_and_windows_are_per_destination() {
        let c = SystemId(2);
        let t0 = Time::from_micros(1_000);
        let mut a = windowed(true, 1, &[B, c]);
        a.send(t0, request(B), 0).unwrap();
        assert!(matches!(
            a.send(t0, request(B), 0),
            Err(SendError::Backpressure { .. })
        ));
        // Another destination has a window of its own.
        assert_eq!(a.send(t0, request(c), 0), Ok(SendId { to: c, seq: 1 }));
        // Nothing answers: every attempt times out and both sends end unconfirmed.
        let mut now = t0;
        loop {
            while let Some(tx) = a.poll_transmit(now) {
                a.transmit_result(now, tx, Ok(()));
            }
            match a.poll_timeout() {
                Some(t) => {
                    now = t;
                    a.handle_timeout(now);
                }
                None => break,
            }
        }
        let mut unconfirmed = 0;
        while let Some(e) = a.poll_event() {
            if let Event::Outcome {
                outcome: Outcome::Unconfirmed { .. },
                ..
            } = e
            {
                unconfirmed += 1;
            }
        }
        assert_eq!(unconfirmed, 2);
        assert_eq!((a.pending_to(B), a.pending_to(c)), (0, 0));
        assert_eq!(a.send(now, request(B), 0), Ok(SendId { to: B, seq: 2 }));
    }

    #[test]
    fn unacknowledged_sends_wait_for_nothing_unless_their_link_refuses_them() {
        let now = Time::from_micros(1_000);
        let mut a = windowed(false, 1, &[B]);
        // Taken by the link: never pending, so the window of one never fills.
        for seq in 1..=5 {
            let tx = unqueued(&mut a, now, b"w");
            assert_eq!(tx.id().seq, seq);
            assert!(a.unqueued_result(now, tx, Ok(()), || 0).is_some());
        }
        assert_eq!(a.pending_to(B), 0);
        // Refused with attempts left: it waits for its retry, and fills the window.
        let tx = unqueued(&mut a, now, b"w");
        let refused = Err(TransmitError::Unreachable("peer down".into()));
        assert_eq!(a.unqueued_result(now, tx, refused, || 9), None);
        assert_eq!(a.pending_to(B), 1);
        assert!(matches!(
            a.send_unqueued(now, request(B), || 0),
            Err(SendError::Backpressure { to: B, limit: 1 })
        ));
    }
}
