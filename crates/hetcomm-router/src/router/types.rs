//! What goes into a router and what comes out of it.

use std::collections::BTreeSet;
use std::time::Duration;

use hetcomm_core::{Address, Header, MessageType, ModuleId, PayloadBuf, Priority, SystemId, Time};

#[cfg(doc)]
use super::{Router, SPLIT_PAYLOAD_MIN};

pub use super::outcome::{FailReason, Outcome};

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
    /// Bytes of frames to this destination that may await their outcome at once. A send
    /// that would go past it is refused with [`SendError::Backpressure`] while earlier sends
    /// are pending (one larger than the limit goes when nothing else is), so a sender of
    /// large acknowledged messages cannot overrun the receiver's socket buffer.
    pub max_in_flight_bytes: usize,
}

impl Route {
    /// The route's own path (its first choice).
    pub fn path(&self) -> Path {
        Path {
            link: self.link,
            tag: self.tag,
        }
    }
}

/// One way to reach a destination: a link and the tag its frames carry there. A route has
/// its own path first and may have fallbacks ([`RouterConfig::fallbacks`]); the router sends
/// on the first path that is up and fails over when a link says the peer is gone.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Path {
    /// Index of the link (the driver's numbering).
    pub link: usize,
    /// The transport's one-byte tag written into frames sent on this path.
    pub tag: u8,
}

/// What a link reports about a peer, as an input to the router
/// ([`Router::handle_link_event`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LinkEvent {
    /// The link can reach `peer` (a connection came up, frames from it arrived, or a secure
    /// session with it was made): sends waiting for a session with it go at once.
    PeerUp {
        /// Which link.
        link: usize,
        /// The peer system.
        peer: SystemId,
    },
    /// The link lost `peer` (a connection closed, a presence service said it left).
    PeerDown {
        /// Which link.
        link: usize,
        /// The peer system.
        peer: SystemId,
    },
    /// The link to `peer` is congested (its queue is full): frames are refused for now.
    Congested {
        /// Which link.
        link: usize,
        /// The peer system.
        peer: SystemId,
    },
}

/// What the router knows of one path to a destination ([`Router::paths`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PathHealth {
    /// The path.
    pub path: Path,
    /// Whether sends may take it: false after its link said the peer is down or refused a
    /// frame as unreachable, until it says the peer is up or a frame goes through (under
    /// [`Health::failover`]: also after a run of unconfirmed sends, and until acknowledgements
    /// on it and its hold time say it is back).
    pub up: bool,
    /// Whether its link last refused a frame as congested.
    pub congested: bool,
    /// The smoothed round-trip time measured on this path, once measured.
    pub srtt: Option<Duration>,
    /// Its retransmission timeout now (before back-off): from its RTT once measured
    /// (RFC 6298), [`Timing::initial_rto`] until then.
    pub rto: Duration,
    /// Whether sends take this path now.
    pub active: bool,
    /// Unconfirmed sends and link errors in a row on it (see [`Health::down_after`]).
    pub bad_run: u32,
    /// While down: acknowledgements heard on it in a row (see [`Health::up_after`]).
    pub good_run: u32,
    /// Its hold time now (see [`Health::hold`]).
    pub hold: Duration,
}

/// Sends to a destination moved from one path to another ([`Router::poll_path_change`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PathChange {
    /// The destination system.
    pub to: SystemId,
    /// The path sends took until now.
    pub from: Path,
    /// The path they take from now on.
    pub now: Path,
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

/// How the router judges the health of a destination's paths and when it moves the
/// destination's sends between them (`docs/failover.md`). It matters only for routes with
/// more than one path ([`RouterConfig::fallbacks`]); a route with one path sends on it
/// whatever happens.
///
/// [`Health::default`] is the original rule: a path is down only while its link says so
/// (a [`LinkEvent::PeerDown`], a refusal as unreachable) and up again at the first sign that
/// it works (a [`LinkEvent::PeerUp`], a frame the link takes, a frame heard from the peer on
/// it). [`Health::failover`] also judges what the router sees: a run of unconfirmed sends or
/// link errors takes a path down, a path that is down is probed, and it comes back only after
/// several acknowledgements on it and a hold time that grows when it flaps.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Health {
    /// Retransmission timeouts (a frame left on the path and no acknowledgement came back)
    /// and link errors in a row on a path, with no acknowledgement heard on it between them,
    /// that make it unhealthy (SCTP's `Path.Max.Retrans`, RFC 4960 s8.2). 0: the router does
    /// not judge paths itself (the original rule; the fields below are then unused). Counted
    /// once per round: timeouts of sends whose frames all left before the last one counted
    /// are one sign (a stall of this process times many sends out at once). Under judging,
    /// a send whose acknowledgement timed out sends its next frame on another healthy path
    /// when there is one, so a path going silent costs a message one timeout, not this many.
    pub down_after: u32,
    /// Acknowledgements heard on a path that is down (answers to its probes, or a
    /// [`LinkEvent::PeerUp`] from its link), in a row, before sends return to it. A probe left
    /// unanswered until the next one restarts the count.
    pub up_after: u32,
    /// The least time a path stays down once it went down. Doubled (up to 32 times) each
    /// time the path goes down again within twice its hold time of coming back, and back to
    /// this once it stayed up longer: a flapping link does not make traffic flap.
    pub hold: Duration,
    /// The interval between probes of a path that is down: at most one frame per path per
    /// interval, a copy of the oldest acknowledged send waiting for its outcome (the
    /// receiver's duplicate filter drops the copy that arrives second and acknowledges both).
    /// No send waiting, no probe: the path is then judged by its link's events alone.
    pub probe_interval: Duration,
}

impl Default for Health {
    /// The original rule (see [`Health`]): links alone say when a path is down.
    fn default() -> Self {
        Health {
            down_after: 0,
            up_after: 1,
            hold: Duration::ZERO,
            probe_interval: Duration::ZERO,
        }
    }
}

impl Health {
    /// The router judges paths too: down after 5 rounds of unconfirmed sends or link errors
    /// in a row (SCTP's default `Path.Max.Retrans`: a few losses in a row on a lossy radio do
    /// not move the traffic, and the sends caught go on the other path at their first
    /// timeout meanwhile), probed every 50 ms, back after 3 acknowledgements on it and a hold
    /// of 500 ms.
    pub fn failover() -> Health {
        Health {
            down_after: 5,
            up_after: 3,
            hold: Duration::from_millis(500),
            probe_interval: Duration::from_millis(50),
        }
    }

    /// Whether the router judges paths itself (`down_after > 0`).
    pub fn judges(&self) -> bool {
        self.down_after > 0
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
    /// Sequence numbers remembered per sender incarnation beyond the contiguous prefix (and,
    /// as many again, gaps skipped and refusals): a data frame older than that memory is
    /// neither delivered nor acknowledged ([`RouterStats::too_old`]).
    pub dedup_window: usize,
    /// Senders whose messages are delivered in the order sent (see [`Timing::hold_timeout`]).
    pub ordered_sources: BTreeSet<SystemId>,
    /// Fallback paths, in order of preference after each route's own path: a destination's
    /// sends fail over to the first that is up when the paths before it are down. The
    /// route's delivery settings (acknowledgement, attempts, sizes) hold on every path.
    pub fallbacks: Vec<(SystemId, Path)>,
    /// How paths are judged healthy and when sends move between them (routes with fallbacks
    /// only).
    pub health: Health,
    /// (sender, link) pairs the communication table allows to send to this system: a native
    /// broadcast (one frame every system on a transport receives, `FLAG_TO_ALL`) is taken
    /// only from a sender on the link the table names for that pair; others are dropped and
    /// counted ([`RouterStats::misrouted`]). [`RouterConfig::new`] assumes the table is
    /// symmetric (a route's own link carries both ways).
    pub inbound: BTreeSet<(SystemId, usize)>,
}

impl RouterConfig {
    /// A configuration with default timing; the known systems are `local` and the route
    /// destinations.
    pub fn new(local: SystemId, incarnation: u32, routes: Vec<(SystemId, Route)>) -> Self {
        let mut known: BTreeSet<SystemId> = routes.iter().map(|(s, _)| *s).collect();
        known.insert(local);
        let inbound = routes.iter().map(|(s, r)| (*s, r.link)).collect();
        RouterConfig {
            inbound,
            local,
            incarnation,
            routes,
            known_systems: known,
            timing: Timing::default(),
            dedup_window: 4096,
            ordered_sources: BTreeSet::new(),
            fallbacks: Vec::new(),
            health: Health::default(),
        }
    }

    /// Adds a fallback path to `to`, after its route's own path and earlier fallbacks.
    pub fn with_fallback(mut self, to: SystemId, path: Path) -> Self {
        self.fallbacks.push((to, path));
        self
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
    /// What the header's `timestamp` says: when the message was created, on the clock that
    /// crosses hosts (the wall clock, microseconds since the UNIX epoch, in real time; the
    /// virtual clock under simulation). The driver reads it, since the router reads no
    /// clock; the `now` the router is given with the request is the monotonic clock, which
    /// times the send and must not be stamped (it means nothing on another host).
    pub timestamp: Time,
}

impl<'a> SendRequest<'a> {
    /// A point-to-point request with normal priority, stamped [`Time::ZERO`] (see
    /// [`SendRequest::stamped`]).
    pub fn new(from: ModuleId, to: Address, message_type: MessageType, payload: &'a [u8]) -> Self {
        SendRequest {
            from,
            to,
            message_type,
            priority: Priority::NORMAL,
            payload,
            broadcast: false,
            timestamp: Time::ZERO,
        }
    }

    /// The request with the header timestamp `timestamp` (wall-clock time in real time).
    pub fn stamped(self, timestamp: Time) -> Self {
        SendRequest { timestamp, ..self }
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
    /// [`Route::max_in_flight`] sends (or [`Route::max_in_flight_bytes`] of frames) to this
    /// destination already await their outcome.
    #[error("sends to system {to} awaiting their outcome fill the transport's window (max_in_flight = {limit} sends, or max_in_flight_bytes): wait for an earlier outcome and send again")]
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
    /// Sequence number within (this incarnation, destination); for one destination's share
    /// of a native broadcast ([`Router::send_broadcast`]), [`BROADCAST_SEND`] plus the
    /// broadcast's number in this system's broadcast space.
    pub seq: u64,
}

/// Set in [`SendId::seq`] when the send is one destination's share of a native broadcast:
/// the rest of the number counts in the sender's broadcast space, not in the space towards
/// that destination (`FLAG_BROADCAST_SEQ` in `docs/wire-format.md`).
pub const BROADCAST_SEND: u64 = 1 << 63;

impl SendId {
    /// Whether this is one destination's share of a native broadcast.
    pub fn is_broadcast(&self) -> bool {
        self.seq & BROADCAST_SEND != 0
    }

    /// The sequence number the send's frames carry.
    pub fn wire_seq(&self) -> u64 {
        self.seq & !BROADCAST_SEND
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
    /// For a probe of a path that is down ([`Health::probe_interval`]): the send whose frame
    /// it copies (`send` is None: it is no attempt of that send). Hand it back through
    /// [`Router::transmit_result`] too: whether its link took it decides whether a copy of
    /// the message may have left.
    pub probe: Option<SendId>,
    /// The router has already counted this frame as taken by its link: an attempt of an
    /// acknowledged send on a route with every path healthy, whose retransmission is armed
    /// as [`Router::transmit_result`] with `Ok` would arm it. A refusal is reported through
    /// `transmit_result` as for any frame (the router undoes what it assumed); a frame the
    /// link took may be handed back later (`transmit_result` with `Ok`, with the time it
    /// was handed to the link), e.g. at the driver's next call into the router, so that a
    /// stream of acknowledged sends locks the router once per send rather than twice. Until
    /// it is back, a retransmission that falls due waits for it ([`Timing::link_retry`]).
    pub presettled: bool,
}

/// Why a link refused a frame, as the router needs to know it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum TransmitError {
    /// The peer cannot be reached now (retried while attempts remain; the path counts as down
    /// until it works again, so a fallback path takes the retries).
    Unreachable(String),
    /// The link's queue towards the peer is full (retried while attempts remain).
    Congested(String),
    /// The frame can never fit (not retried).
    TooLarge(String),
    /// The link will never carry this frame as it is: its content cannot be put on that
    /// transport (a bridge's conversion to a ROS type failed). Not retried; says nothing about
    /// the path's health. The text is the link's reason.
    Refused(String),
    /// The link has no secure session with the peer yet and did not send the frame; it has
    /// started the handshake. The frame goes again when the link reports the session up
    /// ([`LinkEvent::PeerUp`]), else after a round trip's wait; such offers count as attempts
    /// only if the send gives up. The path stays up. The text is the whole reason, naming the
    /// peer.
    NoSession(String),
    /// An operating-system error, its kind kept (retried while attempts remain). Kinds that
    /// say the peer cannot be reached (`ConnectionRefused`, `ConnectionReset`, `BrokenPipe`,
    /// `HostUnreachable`, …) take the path down as [`TransmitError::Unreachable`] does;
    /// others count towards [`Health::down_after`].
    Io {
        /// The error's kind.
        kind: std::io::ErrorKind,
        /// The whole reason.
        reason: String,
    },
    /// The link is closed (retried while attempts remain; the path counts as down).
    Closed(String),
    /// Anything else (retried while attempts remain; counts towards [`Health::down_after`]).
    Other(String),
}

impl TransmitError {
    /// Whether the error says the peer cannot be reached on this link now.
    pub fn unreachable(&self) -> bool {
        use std::io::ErrorKind as K;
        match self {
            TransmitError::Unreachable(_) | TransmitError::Closed(_) => true,
            TransmitError::Io { kind, .. } => matches!(
                kind,
                K::ConnectionRefused
                    | K::ConnectionReset
                    | K::ConnectionAborted
                    | K::NotConnected
                    | K::BrokenPipe
                    | K::HostUnreachable
                    | K::NetworkUnreachable
                    | K::NetworkDown
                    | K::AddrNotAvailable
            ),
            _ => false,
        }
    }
}

impl From<TransmitError> for FailReason {
    /// The reason a send gives up with after its link refused the last attempt.
    fn from(err: TransmitError) -> FailReason {
        match err {
            TransmitError::Unreachable(r) => FailReason::Unreachable(r),
            TransmitError::Congested(r) => FailReason::Congested(r),
            TransmitError::NoSession(r) => FailReason::NoSession(r),
            TransmitError::Refused(r) => FailReason::Refused(r),
            TransmitError::Io { reason, .. } => FailReason::Link(reason),
            TransmitError::TooLarge(r) | TransmitError::Other(r) | TransmitError::Closed(r) => {
                FailReason::Link(r)
            }
        }
    }
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
    pub(super) id: SendId,
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
pub struct DeliveryToken(pub(super) u64);

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
        /// The path that carried it: for a delivery or a refusal by the receiver, the one its
        /// acknowledgement came back on (each copy is acknowledged on the path it came by);
        /// otherwise the one its last frame was offered on. None when no frame was offered.
        path: Option<Path>,
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
    /// (unacknowledged mode). Counted when the link takes the frame, so this includes the
    /// sends whose outcome a broker's confirmation turned into [`Outcome::Relayed`] (or its
    /// silence into [`Outcome::Unconfirmed`]) afterwards, outside the router.
    pub sent: u64,
    /// Sends that ended [`Outcome::Unconfirmed`]: frames left, no acknowledgement came back.
    pub unconfirmed: u64,
    /// Sends that ended [`Outcome::Failed`]: certainly not delivered.
    pub failed: u64,
    /// Messages handed to local inboxes.
    pub received: u64,
    /// Messages acknowledged (one count per message, however many share an ACK frame).
    pub acks_sent: u64,
    /// ACK frames sent: one acknowledges a run of consecutive messages with the same status
    /// (an ACK range, docs/wire-format.md), so this is at most [`RouterStats::acks_sent`].
    pub ack_frames_sent: u64,
    /// Acknowledgements received for a pending send (one count per message acknowledged).
    pub acks_received: u64,
    /// Acknowledgements for nothing pending (late duplicates): ignored.
    pub stale_acks: u64,
    /// Duplicate data frames suppressed (acknowledged again, with the first copy's status).
    pub duplicates: u64,
    /// Data frames older than the duplicate filter remembers ([`RouterConfig::dedup_window`]):
    /// whether an earlier copy was delivered is not known, so they are neither delivered
    /// nor acknowledged (their sender's outcome stays unconfirmed).
    pub too_old: u64,
    /// Frames that failed to decode (truncated, bad version, bad checksum, …).
    pub malformed: u64,
    /// Frames from a system not in the fleet.
    pub unknown_origin: u64,
    /// Frames addressed to another system, and native broadcasts the communication table does
    /// not allow from their sender to this system on the link they came by (an `X` pair, or
    /// a pair on another transport; see [`RouterConfig::inbound`]).
    pub misrouted: u64,
    /// Messages that arrived early and waited for an earlier one (in-order delivery).
    pub held: u64,
    /// Gaps given up after the hold timeout (in-order delivery moved past a missing message).
    pub gaps_skipped: u64,
    /// Sends refused because their destination's [`Route::max_in_flight`] was reached.
    pub backpressured: u64,
    /// Times a destination's sends moved to another path ([`PathChange`]).
    pub path_changes: u64,
    /// Probe frames sent on paths that are down ([`Health::probe_interval`]): copies of
    /// waiting sends, not counted in `transmissions`.
    pub probes: u64,
    /// Frames whose header claimed another origin than the system their link saw them come
    /// from ([`Router::handle_frame_from`]): counted, still handled.
    pub peer_mismatch: u64,
}

impl RouterStats {
    /// Sends accepted but not yet ended.
    pub fn in_flight(&self) -> u64 {
        self.sends - self.delivered - self.sent - self.unconfirmed - self.failed
    }
}
