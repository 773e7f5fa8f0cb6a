//! The security layer: goes over any link ([`LinkLayer`]), seals every frame the router sends
//! and opens every frame the link receives, before the router sees a byte of it.
//!
//! Send side: a frame to a peer goes out sealed in the current session with that peer; with
//! no session yet it waits (bounded) while the handshake runs, and leaves when it completes.
//! Receive side, in this order: the clear prefix (is it for us, from a system with a key?),
//! the session, authentication, the replay window, then the inner frame's header against the
//! authenticated sender and the communication table. Only then does the router see it.

use parking_lot::Mutex;
use std::collections::{HashMap, HashSet, VecDeque};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, OnceLock, Weak};
use std::time::{Duration, Instant};

use hetcomm_core::{BufferPool, FrameBuf, SystemId};
use hetcomm_link::layer::{LayerContext, LayerError, LinkLayer, OpenBelow};
use hetcomm_link::readiness;
use hetcomm_link::relay::RelayPromise;
use hetcomm_link::{
    forward_link, forward_sink, FrameSink, Link, LinkError, LinkEvent, Peer, SecurityStats,
};
use rustc_hash::FxHashMap;

use crate::envelope::OVERHEAD;
use crate::keys::{Keypair, PublicKey};
use crate::session::{Initiation, Session};

mod data;
mod handshake;
mod sim;

use data::{Incoming, Leave};
use handshake::{send_handshake, try_send_handshake};
pub use sim::SimSessions;

/// Who may say what to this system over one transport: its keys, its peers' public keys, and
/// the communication table's answer for each peer.
#[derive(Clone, Debug)]
pub struct Policy {
    /// The system this link belongs to.
    pub local: SystemId,
    /// Its key pair.
    pub keypair: Keypair,
    /// The public key of every member of the fleet that has one. Frames from a member that
    /// is in neither `data_from` nor `acks_from` are refused as the table's
    /// (`rejected_table`), frames from a system not here as unknown
    /// (`rejected_unknown_sender`).
    pub peers: HashMap<SystemId, PublicKey>,
    /// Systems whose messages (data frames) to `local` the table puts on this transport.
    pub data_from: HashSet<SystemId>,
    /// Systems `local` sends messages to on this transport: their acknowledgements come back
    /// on it.
    pub acks_from: HashSet<SystemId>,
}

/// Handshakes run over the link (real time), or in memory between systems of one simulation.
#[derive(Clone)]
pub enum Handshakes {
    /// Over the link, with the operating system's randomness.
    OverTheLink,
    /// In memory: every system's keys are in this process (a simulation).
    InMemory(Arc<SimSessions>),
}

/// The security layer of one system's links on one transport: each [`LinkLayer::wrap`] makes
/// the sessions of the link it opens.
pub struct SecurityLayer {
    transport: String,
    policy: Policy,
    handshakes: Handshakes,
}

impl SecurityLayer {
    /// A layer for the link of `policy.local` on the transport named `transport`.
    pub fn new(transport: &str, policy: Policy, handshakes: Handshakes) -> SecurityLayer {
        SecurityLayer {
            transport: transport.to_string(),
            policy,
            handshakes,
        }
    }
}

/// How long frames wait for a handshake before they are dropped (and counted).
const HANDSHAKE_GIVE_UP: Duration = Duration::from_secs(5);
/// How long an initiation waits for its response before it is sent again.
const HANDSHAKE_RETRY: Duration = Duration::from_millis(250);
/// At most one handshake started per peer per this long because of frames for an unknown
/// session (which anyone can forge).
const TRIGGER_INTERVAL: Duration = Duration::from_secs(1);
/// Frames (and bytes) that may wait for one peer's handshake.
const QUEUE_FRAMES: usize = 1024;
const QUEUE_BYTES: usize = 16 << 20;

#[derive(Default)]
struct Counters {
    handshakes: AtomicU64,
    auth: AtomicU64,
    replay: AtomicU64,
    table: AtomicU64,
    unknown: AtomicU64,
    no_session: AtomicU64,
    timeouts: AtomicU64,
}

fn bump(c: &AtomicU64) {
    c.fetch_add(1, Ordering::Relaxed);
}

struct PeerSlot {
    public: PublicKey,
    /// The table puts this peer's messages to us on this transport ([`Policy::data_from`]).
    sends_data: bool,
    /// Our messages to this peer go on this transport: its acknowledgements come back here
    /// ([`Policy::acks_from`]).
    sends_acks: bool,
    state: Mutex<PeerState>,
    /// Frames the router let wait, to leave together (locked before `state`, never after).
    held: Mutex<Held>,
}

/// Frames held for one peer: the plaintext of a data batch being filled.
#[derive(Default)]
struct Held {
    /// The frames, each behind its length ([`crate::envelope::push_record`]).
    records: Vec<u8>,
    frames: usize,
}

#[derive(Default)]
struct PeerState {
    current: Option<Arc<Session>>,
    /// The session before the current one: frames sealed in it may still be in flight.
    previous: Option<Arc<Session>>,
    /// Sessions this side answered (as responder) that the peer has not used yet, the
    /// newest last (at most two: the peer may complete with the response to an initiation
    /// it has since retried). One becomes current with the first frame that opens in it. So
    /// an initiation replayed to a restarted system (which cannot tell it from a fresh one)
    /// makes a session nobody uses, and never displaces a working one or a handshake in
    /// progress.
    unconfirmed: Vec<Arc<Session>>,
    pending: Option<(Initiation, Instant)>,
    /// The initiation `pending` replaced when it was retried: its response may still come
    /// (a round trip longer than the retry interval) and completes the handshake as well.
    earlier: Option<Initiation>,
    /// Frames waiting for the handshake, and since when the oldest waits.
    queue: VecDeque<Waiting>,
    /// The queue is being sent after a handshake: later frames join it, so nothing
    /// overtakes a frame that waited.
    flushing: bool,
    queued_bytes: usize,
    waiting_since: Option<Instant>,
    /// Since when initiations to this peer go unanswered (the first of the series that is
    /// still running), for the reason a frame refused for want of a session gives.
    unanswered_since: Option<Instant>,
    /// The newest initiation timestamp accepted from this peer.
    last_init: Option<u64>,
    last_trigger: Option<Instant>,
}

/// A frame waiting for its pair's handshake, with the promise of the receipt its send was
/// given when it asked for one ([`Link::send_relayed`]): kept with the link below's verdict
/// when the frame leaves, refused if it never does.
struct Waiting {
    frame: Vec<u8>,
    promise: Option<RelayPromise>,
}

impl PeerSlot {
    /// Whether the table connects this peer to us on this transport, either way.
    fn connected(&self) -> bool {
        self.sends_data || self.sends_acks
    }
}

impl PeerState {
    fn session(&self, index: u32) -> Option<Arc<Session>> {
        [&self.current, &self.previous]
            .into_iter()
            .flatten()
            .chain(&self.unconfirmed)
            .find(|s| s.my_index == index)
            .cloned()
    }

    fn install(&mut self, session: Arc<Session>) {
        self.previous = self.current.replace(session);
        self.unanswered_since = None;
    }

    /// Whether frames to this peer are sealed now (a session, and nothing that waited for it
    /// still leaving), rather than waiting for a handshake.
    fn sealing(&self) -> bool {
        self.current.is_some() && !self.flushing
    }
}

/// The state shared by a secured link's two sides.
struct Secured {
    transport: String,
    policy: Policy,
    handshakes: Handshakes,
    /// Looked up for every frame, by ids from the fleet file only (never inserted into from
    /// the wire): a fast hash is enough.
    peers: FxHashMap<SystemId, PeerSlot>,
    /// The router's sink (above us).
    sink: Arc<dyn FrameSink>,
    /// The link below us, for handshake frames sent from the receive side. Weak: the link
    /// holds our sink, which holds us.
    below: OnceLock<Weak<dyn Link>>,
    counters: Counters,
    last_timestamp: AtomicU64,
    /// Held frames the link refused when their batch left (counted in `frames_dropped`).
    held_dropped: AtomicU64,
    /// Buffers of large sealed frames given to the link below ([`Link::send_owned`]), back
    /// once the link has written them.
    sealed_pool: Arc<BufferPool>,
}

impl Secured {
    fn stats(&self) -> SecurityStats {
        let c = &self.counters;
        let get = |a: &AtomicU64| a.load(Ordering::Relaxed);
        SecurityStats {
            enabled: true,
            handshakes: get(&c.handshakes),
            rejected_auth: get(&c.auth),
            rejected_replay: get(&c.replay),
            rejected_table: get(&c.table),
            rejected_unknown_sender: get(&c.unknown),
            rejected_no_session: get(&c.no_session),
            handshake_timeouts: get(&c.timeouts),
        }
    }

    /// Frames waiting for a handshake (or leaving after one), over every peer.
    fn queued_frames(&self) -> usize {
        self.connected()
            .map(|(_, p)| {
                let st = p.state.lock();
                st.queue.len() + usize::from(st.flushing)
            })
            .sum()
    }

    fn queued_bytes(&self) -> usize {
        self.connected()
            .map(|(_, p)| {
                let held = p.held.lock().records.len();
                held + p.state.lock().queued_bytes
            })
            .sum()
    }

    /// Sends every peer's held frames; the first error is returned.
    fn flush_held(&self, below: &dyn Link) -> Result<(), LinkError> {
        let mut first = Ok(());
        for (&to, slot) in self.connected() {
            let mut h = slot.held.lock();
            if let Err(e) = self.send_held_batch(below, to, slot, &mut h) {
                if first.is_ok() {
                    first = Err(e);
                }
            }
        }
        first
    }

    /// The peers the table connects to this system on this transport: only they have
    /// frames held, queued or in handshakes (the others' slots only tell members from
    /// strangers).
    fn connected(&self) -> impl Iterator<Item = (&SystemId, &PeerSlot)> {
        self.peers.iter().filter(|(_, p)| p.connected())
    }

    fn below(&self) -> Option<Arc<dyn Link>> {
        self.below.get().and_then(Weak::upgrade)
    }

    /// A timestamp greater than every earlier one from this link (wall-clock nanoseconds, so
    /// that it also grows across restarts).
    fn timestamp(&self) -> u64 {
        let now = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .unwrap_or_default()
            .as_nanos() as u64;
        let mut last = self.last_timestamp.load(Ordering::Relaxed);
        loop {
            let next = now.max(last + 1);
            match self.last_timestamp.compare_exchange_weak(
                last,
                next,
                Ordering::Relaxed,
                Ordering::Relaxed,
            ) {
                Ok(_) => return next,
                Err(seen) => last = seen,
            }
        }
    }
}

/// The router's side of a secured link: seals what it sends.
struct SecureLink {
    below: Arc<dyn Link>,
    secured: Arc<Secured>,
    /// The upkeep thread (handshakes over the link only), stopped and joined on drop so that
    /// no thread outlives its link.
    upkeep: Option<Upkeep>,
}

/// A running upkeep thread and its stop flag.
struct Upkeep {
    thread: std::thread::JoinHandle<()>,
    stop: Arc<AtomicBool>,
}

forward_link! {
    [impl] SecureLink => below;
    fn caps(&self) -> hetcomm_link::LinkCaps {
        let mut caps = self.below.caps();
        caps.max_frame = caps.max_frame.saturating_sub(OVERHEAD);
        caps.mtu = caps.mtu.saturating_sub(OVERHEAD);
        // Frames are sealed per pair session: one frame cannot be sealed for every receiver,
        // and a frame under a key shared by all would not tell a receiver which member sent
        // it. So no native broadcasts: the router sends a copy per destination.
        caps.broadcast = false;
        caps
    }
    fn send(&self, to: SystemId, frame: &[u8]) -> Result<(), LinkError> {
        self.secured.send(&*self.below, to, frame, &[], Leave::Now).map(drop)
    }
    fn send_parts(&self, to: SystemId, head: &[u8], body: &[u8]) -> Result<(), LinkError> {
        self.secured.send(&*self.below, to, head, body, Leave::Now).map(drop)
    }
    fn send_held(&self, to: SystemId, frame: &[u8]) -> Result<(), LinkError> {
        self.secured.send(&*self.below, to, frame, &[], Leave::Held).map(drop)
    }
    // The sealed frame goes to the link below's `send_relayed`, so that a broker's receipt
    // reaches the outcome of a secured send too.
    fn send_relayed(
        &self,
        to: SystemId,
        head: &[u8],
        body: &[u8],
    ) -> Result<Option<hetcomm_link::relay::RelayReceipt>, LinkError> {
        self.secured.send(&*self.below, to, head, body, Leave::Relayed)
    }
    fn flush(&self) -> Result<(), LinkError> {
        let held = self.secured.flush_held(&*self.below);
        let below = self.below.flush();
        held.and(below)
    }
    fn stats(&self) -> hetcomm_link::LinkStats {
        let mut stats = self.below.stats();
        stats.security = self.secured.stats();
        // Frames waiting for a handshake, or held to leave together, are in this link too.
        stats.buffered_bytes += self.secured.queued_bytes() as u64;
        stats.frames_dropped += self.secured.held_dropped.load(Ordering::Relaxed);
        stats
    }
    // Authenticated encryption protects every byte: the router need not checksum payloads.
    fn checksums_payload(&self) -> bool {
        true
    }
}

/// What a secured link keeps of the buffers its large sealed frames were written from: enough
/// for a stream of 64 KiB frames that a link writes behind its sender, and a few 1 MiB ones.
const SEALED_POOL_BYTES: usize = 8 << 20;

/// How long closing a secured link waits for frames that wait for a handshake.
const CLOSE_WAIT: Duration = Duration::from_secs(2);

impl Drop for SecureLink {
    /// Frames taken while a handshake ran (e.g. `hetcomm send` of an unacknowledged message,
    /// which exits at once) leave before the link closes: wait, bounded, for the handshakes to
    /// complete and the queues to drain, reading the link meanwhile if nobody else does (a
    /// driven link whose reader has stopped).
    fn drop(&mut self) {
        let _ = self.secured.flush_held(&*self.below);
        let deadline = Instant::now() + CLOSE_WAIT;
        while self.secured.queued_frames() > 0 && Instant::now() < deadline {
            match self.below.readable() {
                Some(r) => {
                    readiness::wait_readable(readiness::readable_fd(r), Duration::from_millis(5));
                    let _ = r.read_ready(64);
                }
                None => std::thread::sleep(Duration::from_millis(2)),
            }
        }
        let _ = self.below.flush();
        if let Some(upkeep) = self.upkeep.take() {
            upkeep.stop.store(true, Ordering::Relaxed);
            upkeep.thread.thread().unpark();
            let _ = upkeep.thread.join();
        }
    }
}

/// The link's side of a secured link: opens what arrives.
struct SecureSink {
    secured: Arc<Secured>,
}

forward_sink! {
    [impl] SecureSink => secured.sink;
    fn on_frame(&self, frame: &[u8], _from: Peer) {
        self.secured.receive(Incoming::Borrowed(frame));
    }
    fn on_frame_owned(&self, frame: FrameBuf, _from: Peer) {
        self.secured.receive(Incoming::Owned(frame));
    }
    fn on_frames(&self, frames: &mut dyn Iterator<Item = &[u8]>, _from: Peer) {
        self.secured.receive_batch(frames);
    }
    // Owned frames are opened where they lie and handed up in the same buffer: a large frame
    // is then neither copied here nor by the router (see `on_frame_owned`).
    fn takes_frames(&self) -> bool {
        self.secured.sink.takes_frames()
    }
    // A peer lost below is lost above. A peer up below (a connection came up) goes up only
    // when a session with it exists: without one, frames to it are still refused, and the
    // session's own `PeerUp` comes when the handshake completes.
    fn on_event(&self, event: LinkEvent) {
        let up_without_session = matches!(event, LinkEvent::PeerUp(_))
            && self.secured.peers.get(&event.peer()).is_none_or(|slot| {
                slot.state
                    .lock()
                    .current
                    .is_none()
            });
        if !up_without_session {
            self.secured.sink.on_event(event);
        }
    }
}

impl LinkLayer for SecurityLayer {
    fn name(&self) -> &str {
        "security"
    }

    /// The sessions of this link are made here, for it alone: the sink that opens what
    /// arrives and the link that seals what leaves share them.
    fn wrap(
        &self,
        _ctx: &LayerContext,
        sink: Arc<dyn FrameSink>,
        open: OpenBelow<'_>,
    ) -> Result<Arc<dyn Link>, LayerError> {
        let peers = self
            .policy
            .peers
            .iter()
            .filter(|(id, _)| **id != self.policy.local)
            .map(|(&id, &public)| {
                (
                    id,
                    PeerSlot {
                        public,
                        sends_data: self.policy.data_from.contains(&id),
                        sends_acks: self.policy.acks_from.contains(&id),
                        state: Mutex::new(PeerState::default()),
                        held: Mutex::new(Held::default()),
                    },
                )
            })
            .collect();
        let secured = Arc::new(Secured {
            transport: self.transport.clone(),
            policy: self.policy.clone(),
            handshakes: self.handshakes.clone(),
            peers,
            sink,
            below: OnceLock::new(),
            counters: Counters::default(),
            last_timestamp: AtomicU64::new(0),
            held_dropped: AtomicU64::new(0),
            sealed_pool: BufferPool::new(SEALED_POOL_BYTES),
        });
        let link = open(Arc::new(SecureSink {
            secured: secured.clone(),
        }))?;
        let _ = secured.below.set(Arc::downgrade(&link));
        let mut upkeep = None;
        if matches!(secured.handshakes, Handshakes::OverTheLink) {
            let weak = Arc::downgrade(&secured);
            let stop = Arc::new(AtomicBool::new(false));
            let stopped = stop.clone();
            let thread = std::thread::Builder::new()
                .name("hc-security".into())
                .spawn(move || loop {
                    // Parked, not slept: the link's drop wakes it to stop at once.
                    std::thread::park_timeout(Duration::from_millis(100));
                    if stopped.load(Ordering::Relaxed) {
                        return;
                    }
                    match weak.upgrade() {
                        Some(s) if s.below().is_some() => s.upkeep(),
                        _ => return,
                    }
                })
                .map_err(|e| LayerError::Wrap {
                    layer: "security".into(),
                    source: Box::new(e),
                })?;
            upkeep = Some(Upkeep { thread, stop });
        }
        Ok(Arc::new(SecureLink {
            below: link,
            secured,
            upkeep,
        }))
    }
}
