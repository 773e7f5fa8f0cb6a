//! The router state machine, split along its concepts:
//!
//! | file | what |
//! |---|---|
//! | `types.rs` | what goes in and out: routes, requests, outcomes, transmits, events, stats |
//! | `mod.rs` | the router's state and accessors |
//! | `send.rs` | admitting a send: the window, numbering, framing, direct lanes |
//! | `retransmit.rs` | transmitting, link results, retransmission and giving up |
//! | `broadcast.rs` | native broadcasts: one frame for every destination on a link that reaches them all |
//! | `paths.rs` | paths to each destination: health, link events, failover |
//! | `receive.rs` | frames in: acknowledgements, duplicates, ordering, deliveries |
//! | `timers.rs` | the timer table, outcomes out, shutdown |

use std::collections::{BTreeMap, BTreeSet, VecDeque};

// Keys are small integers chosen by us, not by an attacker: a fast hash is safe here.
use rustc_hash::FxHashMap as HashMap;
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::Duration;

use hetcomm_core::wire::{
    self, AckPayload, AckStatus, ACK_RANGE_MAX, FLAG_ACK_REQUESTED, FLAG_BROADCAST,
    FLAG_BROADCAST_SEQ, FLAG_HEADER_CRC, FLAG_TO_ALL, HEADER_LEN, TO_ALL_SYSTEM,
};
use hetcomm_core::{
    Address, FrameBuf, FrameKind, Header, PayloadBuf, PayloadSource, SystemId, Time,
};

use crate::dedup::{Dedup, Verdict};
use crate::lane::DirectLane;
use crate::rtt::RttEstimator;

mod broadcast;
mod outcome;
mod paths;
mod receive;
mod retransmit;
mod send;
mod timers;
mod types;

pub use paths::PATH_CHANGES_KEPT;
pub use types::*;

/// One unresolved send.
struct Pending<T> {
    token: T,
    route: Route,
    /// The frame; `None` while the driver holds it in a [`Transmit`].
    frame: Option<Vec<u8>>,
    attempts: u32,
    /// The frame's length, counted against the destination's byte window.
    bytes: usize,
    /// Whether any attempt left this system (the link took the frame): from then on, giving up
    /// is [`Outcome::Unconfirmed`], never [`Outcome::Failed`].
    transmitted: bool,
    /// Offers of this send's frame that the link refused for want of a secure session, in a
    /// row ([`TransmitError::NoSession`]). They are not counted in `attempts` (nothing was
    /// put on the wire: the frame waited for a handshake), but bounded by the same budget;
    /// while non-zero, the session coming up ([`LinkEvent::PeerUp`]) sends the frame at once.
    session_waits: u32,
    first_sent: Option<Time>,
    /// When its frame was last handed out for transmission.
    offered: Time,
    /// When to retransmit (acknowledged sends that are on the wire).
    deadline: Option<Time>,
    /// For one destination's share of a native broadcast: the broadcast's sequence number.
    broadcast: Option<u64>,
    /// A broadcast share whose own frame (a copy for this destination alone, for a
    /// retransmission) is not written yet: `frame` is None because there is none, not
    /// because the driver holds it.
    unbuilt: bool,
    /// Its last frame left and its deadline waits for the acknowledgement: that deadline
    /// passing is an unconfirmed send on its path ([`Health::down_after`]), unlike a retry
    /// after a refusal.
    awaiting_ack: bool,
    /// Its last frame's wait for an acknowledgement ran out: on a route the router judges,
    /// the next frame goes on another healthy path when there is one (RFC 4960 s6.4).
    timed_out: bool,
    /// Its budget was spent and renewed for a path none of its frames took: the next frame
    /// goes on such a path even when it is judged down (see `Router::untried_path`).
    to_untried: bool,
    /// While its frame is out with the driver in a [`Transmit::presettled`]: what
    /// `transmitted` was before that attempt (restored if the link refuses the frame).
    presettled_from: Option<bool>,
    /// The links its frames were offered on, one bit per link index (links from 64 on are
    /// not tracked): a send whose budget is spent still gets one on a path of its route
    /// that no frame of it took (see `Router::untried_path`).
    tried: u64,
}

/// The bit of link `link` in [`Pending::tried`] (none for links from 64 on).
fn link_bit(link: usize) -> u64 {
    1u64.checked_shl(link as u32).unwrap_or(0)
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
    /// The frame's sequence number, with [`BROADCAST_SEND`] set when it counts in the
    /// sender's broadcast space.
    seq: u64,
    link: usize,
    ack_header: Header,
}

/// What a deadline in the timer table is for.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
enum Timer {
    /// A send's retransmission (or retry after its link refused it).
    Retransmit(SendId),
    /// In-order delivery of (origin, incarnation) gives up on its gap.
    Hold(SystemId, u32),
    /// The paths of a destination that are down are probed ([`Health::probe_interval`]).
    Probe(SystemId),
}

/// A route and the state of each of its paths.
struct RouteState {
    /// The delivery settings, with the route's own path.
    route: Route,
    /// The route's own path first, then its fallbacks.
    paths: Vec<PathState>,
    /// The index in `paths` sends take now.
    active: usize,
    /// When the paths that are down are probed next, while any is.
    probe_at: Option<Time>,
    /// When they were last probed (a probe goes at most once per interval).
    probed_at: Option<Time>,
}

/// What the router knows of one path.
struct PathState {
    path: Path,
    up: bool,
    congested: bool,
    rtt: Option<RttEstimator>,
    /// Unconfirmed sends and link errors in a row ([`Health::down_after`]).
    bad_run: u32,
    /// When the last of them was counted.
    last_bad: Option<Time>,
    /// While down: acknowledgements heard on it in a row ([`Health::up_after`]).
    good_run: u32,
    /// While down: whether anything answered since the last probe.
    answered: bool,
    /// It went down because its link refused a frame (not for want of acknowledgements): a
    /// frame the link takes again is a sign that it is back.
    refused: bool,
    /// When it last went down, and last came up.
    down_at: Time,
    up_at: Time,
    /// Its hold time now ([`Health::hold`], doubled while it flaps).
    hold: Duration,
}

impl RouteState {
    fn new(route: Route) -> RouteState {
        RouteState {
            route,
            paths: vec![PathState::new(route.path())],
            active: 0,
            probe_at: None,
            probed_at: None,
        }
    }

    /// The route as sends take it now: its settings on the active path.
    fn current(&self) -> Route {
        let path = self.paths[self.active].path;
        Route {
            link: path.link,
            tag: path.tag,
            ..self.route
        }
    }

    /// Where a send's next frame goes after its last one, on `last`, timed out: the first
    /// healthy path other than `last` that none of its frames took (`tried`), else the
    /// first healthy one other than `last`, else the active one. SCTP's rule (RFC 4960
    /// s6.4): a retransmission goes to an alternate path, so a path that has just gone
    /// silent costs a message one timeout, not the several it takes to judge the path down.
    fn retry_path(&self, last: usize, tried: u64) -> Path {
        let healthy = |p: &&PathState| p.up && !p.congested && p.path.link != last;
        let mut alternates = self.paths.iter().filter(healthy);
        let untried = self
            .paths
            .iter()
            .filter(healthy)
            .find(|p| tried & link_bit(p.path.link) == 0);
        untried
            .or_else(|| alternates.next())
            .map_or(self.paths[self.active].path, |p| p.path)
    }

    /// The first path none of a send's frames took (`tried`), healthy ones first: where a
    /// send whose budget was renewed for it goes (a path judged down may still carry it:
    /// judging may have been wrong, and the send has nowhere else to go).
    fn untried(&self, tried: u64) -> Option<Path> {
        let fresh = |p: &&PathState| tried & link_bit(p.path.link) == 0;
        let mut untried = self.paths.iter().filter(fresh);
        let healthy = untried.clone().find(|p| p.up && !p.congested);
        healthy.or_else(|| untried.next()).map(|p| p.path)
    }

    /// The first path that is up and not congested, else the first that is up, else the
    /// active one (with every path down, sends keep trying where they are).
    fn best(&self) -> usize {
        let first = |ok: &dyn Fn(&PathState) -> bool| self.paths.iter().position(ok);
        first(&|p| p.up && !p.congested)
            .or_else(|| first(&|p| p.up))
            .unwrap_or(self.active)
    }

    fn path_mut(&mut self, link: usize) -> Option<&mut PathState> {
        self.paths.iter_mut().find(|p| p.path.link == link)
    }
}

impl PathState {
    fn new(path: Path) -> PathState {
        PathState {
            path,
            up: true,
            congested: false,
            rtt: None,
            bad_run: 0,
            last_bad: None,
            good_run: 0,
            answered: false,
            refused: false,
            down_at: Time::ZERO,
            up_at: Time::ZERO,
            hold: Duration::ZERO,
        }
    }
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
    /// Their frames' bytes (bounded by [`Route::max_in_flight_bytes`]).
    pending_bytes: usize,
}

/// The per-system routing and reliability state machine. `T` is an opaque token the driver
/// attaches to each send and gets back with its outcome.
pub struct Router<T> {
    config: RouterConfig,
    /// Per destination: the route and its paths, with the one sends take now.
    routes: HashMap<SystemId, RouteState>,
    /// Numbering and the window, per destination (one lookup per send).
    towards: HashMap<SystemId, Towards>,
    pending: HashMap<SendId, Pending<T>>,
    /// Every deadline: retransmissions and in-order holds, possibly stale (checked against
    /// `Pending::deadline` and `OrderState::deadline`).
    timers: BTreeSet<(Time, Timer)>,
    /// Path changes not yet polled.
    path_changes: VecDeque<PathChange>,
    /// Paths marked down or congested: while there are none, frames and link results need
    /// not look their path up.
    unhealthy_paths: u32,
    /// Some route has more than one path and [`Health::judges`]: acknowledgements and
    /// timeouts then feed the paths' health (routes of one path never look it up).
    judging: bool,
    transmits: VecDeque<TransmitItem>,
    deliveries: VecDeque<Delivery>,
    awaiting: HashMap<DeliveryToken, PendingDelivery>,
    next_token: u64,
    events: VecDeque<Event<T>>,
    dedup: Dedup,
    /// Duplicate filter of the senders' broadcast sequence spaces.
    broadcast_dedup: Dedup,
    /// The last sequence number given in this system's broadcast space.
    broadcast_seq: u64,
    /// Native broadcasts with a destination still awaiting its outcome.
    broadcasts: HashMap<u64, broadcast::BroadcastPut>,
    order: BTreeMap<(SystemId, u32), OrderState>,
    stats: RouterStats,
    /// Per link index: whether the link guarantees the payload's integrity itself (see
    /// [`Router::set_link_checksums_payload`]). Links past the end do not.
    link_checks_payload: Vec<bool>,
    /// Frame buffers of ended sends, reused by the next sends (see [`SPARE_FRAMES`]).
    spare_frames: Vec<Vec<u8>>,
    /// The capacity of `spare_frames`' buffers, in bytes (at most [`SPARE_BYTES`]).
    spare_bytes: usize,
    /// When a link last reported a secure session with each peer up ([`LinkEvent::PeerUp`]).
    session_up_at: HashMap<SystemId, Time>,
}

/// How many buffers of ended sends a router keeps for reuse: a sender that keeps sending
/// then neither allocates nor frees a frame per message. Large frames: an allocation of tens
/// of kilobytes, freed at once, is returned to the system and faulted in again each time.
/// Small ones: an acknowledgement ends tens of sends at once, on the thread that received it,
/// and an allocator's per-thread cache holds only a few buffers freed by another thread, so
/// the sending thread would otherwise go to the shared heap for every frame.
const SPARE_FRAMES: usize = 1024;
/// At most this many bytes of spare buffers are kept (4 large frames, or every small one).
const SPARE_BYTES: usize = 16 << 20;
/// Buffers larger than this are freed rather than kept.
const SPARE_FRAME_MAX: usize = 4 << 20;
/// Unacknowledged payloads this large, on a link that checksums payloads, are not copied into
/// the frame buffer but sent from the caller's memory behind their header
/// ([`Unqueued::body`]). Smaller ones cost less to copy than the extra piece costs the link
/// (and stay eligible for batching, which needs the whole frame).
pub const SPLIT_PAYLOAD_MIN: usize = 16 * 1024;

enum TransmitItem {
    Send(SendId),
    /// The one frame of a native broadcast.
    Broadcast(u64),
    /// An acknowledgement, encoded when polled: until then the next acknowledgement of the
    /// same sender's next frame, with the same status, widens it into a range
    /// ([`AckPayload`]) instead of queueing a frame of its own.
    Ack {
        link: usize,
        /// Its header; `seq` is the range's last number.
        header: Header,
        status: AckStatus,
        /// The range's first number (`header.seq` for one frame).
        first: u64,
    },
    /// A copy of a waiting send's frame, as a probe of a path that is down.
    Probe {
        id: SendId,
        path: Path,
    },
}

impl<T> Router<T> {
    /// A router for `config.local`.
    pub fn new(config: RouterConfig) -> Self {
        let mut routes: HashMap<SystemId, RouteState> = config
            .routes
            .iter()
            .map(|(to, route)| (*to, RouteState::new(*route)))
            .collect();
        for (to, path) in &config.fallbacks {
            if let Some(r) = routes.get_mut(to) {
                if !r.paths.iter().any(|p| p.path.link == path.link) {
                    r.paths.push(PathState::new(*path));
                }
            }
        }
        for r in routes.values_mut() {
            for p in &mut r.paths {
                p.hold = config.health.hold;
            }
        }
        let judging = config.health.judges() && routes.values().any(|r| r.paths.len() > 1);
        let dedup = Dedup::new(config.dedup_window);
        let broadcast_dedup = Dedup::new(config.dedup_window);
        Router {
            config,
            routes,
            towards: HashMap::default(),
            pending: HashMap::default(),
            timers: BTreeSet::new(),
            path_changes: VecDeque::new(),
            unhealthy_paths: 0,
            judging,
            transmits: VecDeque::new(),
            deliveries: VecDeque::new(),
            awaiting: HashMap::default(),
            next_token: 0,
            events: VecDeque::new(),
            dedup,
            broadcast_dedup,
            broadcast_seq: 0,
            broadcasts: HashMap::default(),
            order: BTreeMap::new(),
            stats: RouterStats::default(),
            link_checks_payload: Vec::new(),
            spare_frames: Vec::new(),
            spare_bytes: 0,
            session_up_at: HashMap::default(),
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

    /// The route to `to` as sends take it now (on its active path), if the table allows
    /// traffic.
    pub fn route(&self, to: SystemId) -> Option<Route> {
        self.routes.get(&to).map(RouteState::current)
    }

    /// Every path to `to`, in order of preference, with what the router knows of each.
    pub fn paths(&self, to: SystemId) -> Vec<PathHealth> {
        let Some(r) = self.routes.get(&to) else {
            return Vec::new();
        };
        r.paths
            .iter()
            .enumerate()
            .map(|(i, p)| PathHealth {
                path: p.path,
                up: p.up,
                congested: p.congested,
                srtt: p.rtt.as_ref().and_then(|r| r.srtt()),
                rto: p
                    .rtt
                    .as_ref()
                    .map_or(self.config.timing.initial_rto, |r| r.rto()),
                active: i == r.active,
                bad_run: p.bad_run,
                good_run: p.good_run,
                hold: p.hold,
            })
            .collect()
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

    /// Transmissions handed out so far for the unresolved send `id` (the one just polled
    /// from [`Router::poll_transmit`] included); None once it ended.
    pub fn attempts(&self, id: SendId) -> Option<u32> {
        if id.to == TO_ALL_SYSTEM {
            // A broadcast's one frame goes once (retransmissions are copies to one system).
            return self.broadcasts.contains_key(&id.wire_seq()).then_some(1);
        }
        self.pending.get(&id).map(|p| p.attempts)
    }

    /// Whether send `id` (or, for a broadcast's frame, its shares) ends when its frame leaves,
    /// unacknowledged: then a receipt from an intermediary the link passes it through may
    /// say more than [`Outcome::Sent`]. False once it ended.
    pub fn unacknowledged(&self, id: SendId) -> bool {
        let acknowledged = match id.to == TO_ALL_SYSTEM {
            true => self.broadcast_acknowledged(id.wire_seq()),
            false => self.pending.get(&id).map(|p| p.route.acknowledged),
        };
        acknowledged == Some(false)
    }

    /// Whether the frame of send `id` just polled repeats an offer the link refused for want
    /// of a secure session ([`TransmitError::NoSession`]): the same attempt again, which an
    /// observer has seen already.
    pub fn repeats_refused_offer(&self, id: SendId) -> bool {
        self.pending.get(&id).is_some_and(|p| p.session_waits > 0)
    }

    /// The smoothed round-trip time to `to` on its active path, once measured.
    pub fn srtt(&self, to: SystemId) -> Option<Duration> {
        let r = self.routes.get(&to)?;
        r.paths[r.active].rtt.as_ref().and_then(|r| r.srtt())
    }
}

#[cfg(test)]
mod ack_tests;
#[cfg(test)]
mod broadcast_tests;
#[cfg(test)]
mod presettle_tests;
#[cfg(test)]
mod tests;
