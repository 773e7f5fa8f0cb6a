//! The security layer: goes over any link ([`LinkLayer`]), seals every frame the router sends
//! and opens every frame the link receives, before the router sees a byte of it.
//!
//! Send side: a frame to a peer goes out sealed in the current session with that peer; with
//! no session yet it waits (bounded) while the handshake runs, and leaves when it completes.
//! Receive side, in this order: the clear prefix (is it for us, from a system with a key?),
//! the session, authentication, the replay window, then the inner frame's header against the
//! authenticated sender and the communication table. Only then does the router see it.

use std::collections::{HashMap, HashSet, VecDeque};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, OnceLock, Weak};
use std::time::{Duration, Instant};

use hetcomm_core::{FrameBuf, SystemId};
use hetcomm_link::layer::{LayerContext, LayerError, LinkLayer};
use hetcomm_link::{forward_link, forward_sink, FrameSink, Link, LinkError, Peer, SecurityStats};

use crate::envelope::{self, Kind, DATA_HEADER_LEN, OVERHEAD, TAG_LEN};
use crate::keys::{Keypair, PublicKey};
use crate::session::{self, Entropy, Initiation, Session};

/// Who may say what to this system over one transport: its keys, its peers' public keys, and
/// the communication table's answer for each peer.
#[derive(Clone, Debug)]
pub struct Policy {
    /// The system this link belongs to.
    pub local: SystemId,
    /// Its key pair.
    pub keypair: Keypair,
    /// The public key of every system it may exchange frames with over this transport.
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

/// Sessions of a simulated fleet, made in memory from the seed: the same seed gives the same
/// keys and sessions, and no handshake frame is drawn through the simulated network (so a
/// secured simulation loses, delays and orders frames exactly as an unsecured one with the
/// same seed).
pub struct SimSessions {
    seed: u64,
    keys: HashMap<SystemId, Keypair>,
    /// Per (transport, lower id, higher id): the two halves of the pair's session.
    pairs: Mutex<HashMap<PairKey, [Option<Arc<Session>>; 2]>>,
}

/// A pair of systems on a transport: (transport name, lower id, higher id).
type PairKey = (String, SystemId, SystemId);

impl SimSessions {
    /// Sessions for systems with these keys, from `seed`.
    pub fn new(seed: u64, keys: HashMap<SystemId, Keypair>) -> Arc<SimSessions> {
        Arc::new(SimSessions {
            seed,
            keys,
            pairs: Mutex::new(HashMap::new()),
        })
    }

    /// The key pair of `system`.
    pub fn keypair(&self, system: SystemId) -> Option<&Keypair> {
        self.keys.get(&system)
    }

    /// `me`'s half of the session with `peer` on `transport` (made on first use).
    fn half(&self, transport: &str, me: SystemId, peer: SystemId) -> Option<Arc<Session>> {
        let (lo, hi) = if me < peer { (me, peer) } else { (peer, me) };
        let mut pairs = self.pairs.lock().unwrap_or_else(|e| e.into_inner());
        let entry = pairs.entry((transport.to_string(), lo, hi)).or_default();
        if entry[0].is_none() && entry[1].is_none() {
            let seed = self.seed ^ ((lo.0 as u64) << 16) ^ ((hi.0 as u64) << 32);
            let (a, b) =
                session::in_memory((lo, self.keys.get(&lo)?), (hi, self.keys.get(&hi)?), seed)
                    .ok()?;
            *entry = [Some(Arc::new(a)), Some(Arc::new(b))];
        }
        entry[usize::from(me != lo)].clone()
    }
}

/// The security layer of one system's link on one transport. Build one per link opened.
pub struct SecurityLayer {
    transport: String,
    policy: Policy,
    handshakes: Handshakes,
    secured: OnceLock<Arc<Secured>>,
}

impl SecurityLayer {
    /// A layer for the link of `policy.local` on the transport named `transport`.
    pub fn new(transport: &str, policy: Policy, handshakes: Handshakes) -> SecurityLayer {
        SecurityLayer {
            transport: transport.to_string(),
            policy,
            handshakes,
            secured: OnceLock::new(),
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
    state: Mutex<PeerState>,
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
    queue: VecDeque<Vec<u8>>,
    queued_bytes: usize,
    waiting_since: Option<Instant>,
    /// The newest initiation timestamp accepted from this peer.
    last_init: Option<u64>,
    last_trigger: Option<Instant>,
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
    }
}

/// The state shared by a secured link's two sides.
struct Secured {
    transport: String,
    policy: Policy,
    handshakes: Handshakes,
    peers: HashMap<SystemId, PeerSlot>,
    /// The router's sink (above us).
    sink: Arc<dyn FrameSink>,
    /// The link below us, for handshake frames sent from the receive side. Weak: the link
    /// holds our sink, which holds us.
    below: OnceLock<Weak<dyn Link>>,
    counters: Counters,
    last_timestamp: AtomicU64,
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

    /// Starts a handshake with `peer` (under its lock): the initiation to send.
    fn start_handshake(
        &self,
        peer: SystemId,
        slot: &PeerSlot,
        st: &mut PeerState,
    ) -> Option<Vec<u8>> {
        let index = loop {
            let i = rand::random::<u32>();
            if i != 0 && st.session(i).is_none() {
                break i;
            }
        };
        let (init, pending) = session::initiate(
            (self.policy.local, &self.policy.keypair),
            (peer, &slot.public),
            index,
            self.timestamp(),
            Entropy::Os,
        )
        .ok()?;
        st.earlier = st
            .pending
            .replace((pending, Instant::now()))
            .map(|(p, _)| p);
        Some(init)
    }

    /// Seals and sends `head` + `body` to `to`, or queues it until a session exists.
    fn send(&self, to: SystemId, head: &[u8], body: &[u8], held: bool) -> Result<(), LinkError> {
        let slot = self.peers.get(&to).ok_or_else(|| LinkError::Unreachable {
            peer: to,
            reason: format!(
                "system {to} has no public key on transport `{}`: frames to it could not be authenticated",
                self.transport
            ),
        })?;
        let below = self.below().ok_or(LinkError::Closed)?;
        let session = {
            let mut st = slot.state.lock().unwrap_or_else(|e| e.into_inner());
            if st.current.is_none() {
                if let Handshakes::InMemory(sim) = &self.handshakes {
                    if let Some(s) = sim.half(&self.transport, self.policy.local, to) {
                        st.install(s);
                        bump(&self.counters.handshakes);
                    }
                }
            }
            match st.current.clone() {
                Some(s) => s,
                None => {
                    // Wait for the handshake; start (or restart) it if needed.
                    if st.queue.len() >= QUEUE_FRAMES
                        || st.queued_bytes + head.len() + body.len() > QUEUE_BYTES
                    {
                        return Err(LinkError::Congested {
                            peer: to,
                            reason: "frames waiting for the security handshake".into(),
                        });
                    }
                    let mut frame = Vec::with_capacity(head.len() + body.len());
                    frame.extend_from_slice(head);
                    frame.extend_from_slice(body);
                    st.queued_bytes += frame.len();
                    st.queue.push_back(frame);
                    st.waiting_since.get_or_insert_with(Instant::now);
                    let stale = st
                        .pending
                        .as_ref()
                        .is_none_or(|(_, at)| at.elapsed() >= HANDSHAKE_RETRY);
                    let init = if stale {
                        self.start_handshake(to, slot, &mut st)
                    } else {
                        None
                    };
                    drop(st);
                    if let Some(init) = init {
                        send_handshake(&*below, to, &init);
                    }
                    return Ok(());
                }
            }
        };
        with_scratch(&TX, |buf| {
            session.seal(buf, self.policy.local, to, head, body);
            if held {
                below.send_held(to, buf)
            } else {
                below.send(to, buf)
            }
        })
    }

    /// Sends what waited for `peer`'s handshake, now that `session` exists.
    fn flush_queue(&self, peer: SystemId, session: &Session, queue: VecDeque<Vec<u8>>) {
        let Some(below) = self.below() else { return };
        let mut buf = Vec::new();
        for frame in queue {
            session.seal(&mut buf, self.policy.local, peer, &frame, &[]);
            let _ = below.send(peer, &buf);
        }
    }

    /// Drops frames that waited too long for a handshake; restarts initiations that got no
    /// response. Called periodically (real time only).
    fn upkeep(&self) {
        let Some(below) = self.below() else { return };
        for (&peer, slot) in &self.peers {
            let mut st = slot.state.lock().unwrap_or_else(|e| e.into_inner());
            if st.queue.is_empty() {
                // A handshake started because the peer sent frames of a session we do not
                // have (nothing of ours waits): retried like any other while it is due, and
                // abandoned after TRIGGER_INTERVAL so that the peer's next frame starts
                // another. (Left pending, a lost response would block every later one.)
                let Some((_, at)) = &st.pending else { continue };
                if st
                    .last_trigger
                    .is_none_or(|t| t.elapsed() >= TRIGGER_INTERVAL)
                {
                    st.pending = None;
                    st.earlier = None;
                } else if at.elapsed() >= HANDSHAKE_RETRY {
                    if let Some(init) = self.start_handshake(peer, slot, &mut st) {
                        drop(st);
                        send_handshake(&*below, peer, &init);
                    }
                }
                continue;
            }
            if st
                .waiting_since
                .is_some_and(|t| t.elapsed() >= HANDSHAKE_GIVE_UP)
            {
                let n = st.queue.len() as u64;
                st.queue.clear();
                st.queued_bytes = 0;
                st.waiting_since = None;
                st.pending = None;
                st.earlier = None;
                self.counters.timeouts.fetch_add(n, Ordering::Relaxed);
                continue;
            }
            if st
                .pending
                .as_ref()
                .is_none_or(|(_, at)| at.elapsed() >= HANDSHAKE_RETRY)
            {
                if let Some(init) = self.start_handshake(peer, slot, &mut st) {
                    drop(st);
                    send_handshake(&*below, peer, &init);
                }
            }
        }
    }

    /// A frame from the link: checked, opened, and handed to the router if it passes.
    fn receive(&self, frame: Incoming<'_>) {
        let bytes = frame.bytes();
        let Some(prefix) = envelope::prefix(bytes) else {
            // Not a secured frame: an unsecured sender, or garbage. Nothing is trusted.
            bump(&self.counters.auth);
            return;
        };
        if prefix.receiver != self.policy.local {
            bump(&self.counters.table);
            return;
        }
        let Some(slot) = self.peers.get(&prefix.sender) else {
            bump(&self.counters.unknown);
            return;
        };
        match prefix.kind {
            Kind::Data => self.receive_data(prefix.sender, slot, frame),
            Kind::Init => self.receive_init(prefix.sender, slot, bytes),
            Kind::Response => self.receive_response(prefix.sender, slot, bytes),
        }
    }

    fn receive_data(&self, sender: SystemId, slot: &PeerSlot, frame: Incoming<'_>) {
        let bytes = frame.bytes();
        if bytes.len() < OVERHEAD {
            bump(&self.counters.auth);
            return;
        }
        let index = envelope::u32_at(bytes, 8);
        let counter = envelope::data_counter(bytes);
        let mut unconfirmed = false;
        let session = {
            let mut st = slot.state.lock().unwrap_or_else(|e| e.into_inner());
            match st.session(index) {
                Some(s) => {
                    unconfirmed = st.unconfirmed.iter().any(|n| Arc::ptr_eq(n, &s));
                    s
                }
                None => {
                    if let Handshakes::InMemory(sim) = &self.handshakes {
                        // The peer made the session first: take our half.
                        match sim.half(&self.transport, self.policy.local, sender) {
                            Some(s) if s.my_index == index => {
                                st.install(s.clone());
                                bump(&self.counters.handshakes);
                                s
                            }
                            _ => {
                                bump(&self.counters.no_session);
                                return;
                            }
                        }
                    } else {
                        bump(&self.counters.no_session);
                        // The peer has a session we do not (it or we restarted): start a new
                        // one, at most once a second, since anyone can forge this.
                        let due = st.pending.is_none()
                            && st
                                .last_trigger
                                .is_none_or(|t| t.elapsed() >= TRIGGER_INTERVAL);
                        if due {
                            st.last_trigger = Some(Instant::now());
                            let init = self.start_handshake(sender, slot, &mut st);
                            drop(st);
                            if let (Some(init), Some(below)) = (init, self.below()) {
                                send_handshake(&*below, sender, &init);
                            }
                        }
                        return;
                    }
                }
            }
        };
        let inner = match frame.open(&session) {
            Some(inner) => inner,
            None => {
                bump(&self.counters.auth);
                return;
            }
        };
        if !session.accept_counter(counter) {
            bump(&self.counters.replay);
            return;
        }
        if !self.allowed(sender, inner.bytes()) {
            bump(&self.counters.table);
            return;
        }
        if unconfirmed {
            self.confirmed(sender, slot, &session);
        }
        inner.deliver(&*self.sink, Peer::System(sender));
    }

    /// An authentic frame from `sender` opened in `session`: if that is the session we
    /// answered last, the peer holds it too, so it becomes current (and what waited for a
    /// session leaves in it).
    fn confirmed(&self, sender: SystemId, slot: &PeerSlot, session: &Arc<Session>) {
        let mut st = slot.state.lock().unwrap_or_else(|e| e.into_inner());
        if !st.unconfirmed.iter().any(|n| Arc::ptr_eq(n, session)) {
            return;
        }
        st.unconfirmed.clear();
        st.pending = None;
        st.earlier = None;
        st.install(session.clone());
        let queue = std::mem::take(&mut st.queue);
        st.queued_bytes = 0;
        st.waiting_since = None;
        drop(st);
        self.flush_queue(sender, session, queue);
    }

    /// Whether the inner frame's header agrees with its authenticated sender and the table.
    fn allowed(&self, sender: SystemId, inner: &[u8]) -> bool {
        // Too short to have a header: the router counts it as malformed.
        if inner.len() < 16 {
            return true;
        }
        let source = SystemId(u16::from_le_bytes([inner[8], inner[9]]));
        let destination = SystemId(u16::from_le_bytes([inner[12], inner[13]]));
        if source != sender || destination != self.policy.local {
            return false;
        }
        match inner[3] {
            0 => self.policy.data_from.contains(&sender),
            1 => self.policy.acks_from.contains(&sender),
            // Unknown kinds: the router refuses them.
            _ => true,
        }
    }

    fn may_talk(&self, peer: SystemId) -> bool {
        self.policy.data_from.contains(&peer) || self.policy.acks_from.contains(&peer)
    }

    fn receive_init(&self, sender: SystemId, slot: &PeerSlot, bytes: &[u8]) {
        if matches!(self.handshakes, Handshakes::InMemory(_)) {
            bump(&self.counters.auth);
            return;
        }
        if !self.may_talk(sender) {
            bump(&self.counters.table);
            return;
        }
        let mut st = slot.state.lock().unwrap_or_else(|e| e.into_inner());
        let index = loop {
            let i = rand::random::<u32>();
            if i != 0 && st.session(i).is_none() {
                break i;
            }
        };
        let answer = match session::respond(
            (self.policy.local, &self.policy.keypair),
            (sender, &slot.public),
            bytes,
            index,
            Entropy::Os,
        ) {
            Ok(a) => a,
            Err(_) => {
                bump(&self.counters.auth);
                return;
            }
        };
        if st.last_init.is_some_and(|last| answer.timestamp <= last) {
            bump(&self.counters.replay);
            return;
        }
        // Both sides started at once: the lower system id stays the initiator.
        if st.pending.is_some() && self.policy.local < sender {
            return;
        }
        st.last_init = Some(answer.timestamp);
        // The session waits for the peer's first frame in it (`confirmed`); a handshake of
        // our own in progress goes on (this initiation may be a replay).
        if st.unconfirmed.len() == 2 {
            st.unconfirmed.remove(0);
        }
        st.unconfirmed.push(Arc::new(answer.session));
        drop(st);
        bump(&self.counters.handshakes);
        if let Some(below) = self.below() {
            send_handshake(&*below, sender, &answer.response);
        }
    }

    fn receive_response(&self, sender: SystemId, slot: &PeerSlot, bytes: &[u8]) {
        let mut st = slot.state.lock().unwrap_or_else(|e| e.into_inner());
        let (initiation, at) = if st
            .pending
            .as_ref()
            .is_some_and(|(p, _)| p.answered_by(bytes))
        {
            st.pending.take().map(|(p, at)| (p, Some(at)))
        } else if st.earlier.as_ref().is_some_and(|p| p.answered_by(bytes)) {
            st.earlier.take().map(|p| (p, None))
        } else {
            None
        }
        .unzip();
        let Some(initiation) = initiation else {
            // Not an answer to a handshake in progress: an old one replayed, or forged.
            bump(&self.counters.replay);
            return;
        };
        let session = match initiation.complete(bytes) {
            Ok(s) => Arc::new(s),
            Err(_) => {
                // Forged: keep waiting for the real response (a fresh initiation follows).
                if let Some(at) = at.flatten() {
                    st.last_trigger = Some(at);
                }
                bump(&self.counters.auth);
                return;
            }
        };
        st.pending = None;
        st.earlier = None;
        st.install(session.clone());
        let mut queue = std::mem::take(&mut st.queue);
        st.queued_bytes = 0;
        st.waiting_since = None;
        drop(st);
        bump(&self.counters.handshakes);
        if queue.is_empty() {
            // Nothing to send: an empty frame tells the responder the session is in use
            // (receivers hand empty frames to nobody).
            queue.push_back(Vec::new());
        }
        self.flush_queue(sender, &session, queue);
    }
}

/// Sends a handshake message; once more if the link refused it (a stream link reconnects on
/// the next send after a write to a connection the peer closed, as a restarted peer's was).
fn send_handshake(below: &dyn Link, to: SystemId, message: &[u8]) {
    if below.send(to, message).is_err() {
        let _ = below.send(to, message);
    }
}

/// A received frame, borrowed or owned: opened in a scratch copy or where it lies.
enum Incoming<'a> {
    Borrowed(&'a [u8]),
    Owned(FrameBuf),
}

/// An opened inner frame, ready for the router.
enum Opened {
    Scratch(Vec<u8>),
    Owned(FrameBuf),
}

impl Incoming<'_> {
    fn bytes(&self) -> &[u8] {
        match self {
            Incoming::Borrowed(b) => b,
            Incoming::Owned(f) => f,
        }
    }

    fn open(self, session: &Session) -> Option<Opened> {
        match self {
            Incoming::Borrowed(b) => {
                let mut buf = take_scratch(&RX);
                buf.clear();
                buf.extend_from_slice(b);
                if !session.open(&mut buf) {
                    give_scratch(&RX, buf);
                    return None;
                }
                Some(Opened::Scratch(buf))
            }
            Incoming::Owned(mut f) => {
                if !session.open(f.as_mut_slice()) {
                    return None;
                }
                let len = f.len();
                f.truncate(len - TAG_LEN);
                f.strip_prefix(DATA_HEADER_LEN);
                Some(Opened::Owned(f))
            }
        }
    }
}

impl Opened {
    fn bytes(&self) -> &[u8] {
        match self {
            Opened::Scratch(b) => &b[DATA_HEADER_LEN..b.len() - TAG_LEN],
            Opened::Owned(f) => f,
        }
    }

    fn deliver(self, sink: &dyn FrameSink, from: Peer) {
        match self {
            Opened::Scratch(buf) => {
                let inner = &buf[DATA_HEADER_LEN..buf.len() - TAG_LEN];
                if !inner.is_empty() {
                    sink.on_frame(inner, from);
                }
                give_scratch(&RX, buf);
            }
            Opened::Owned(f) => {
                if !f.is_empty() {
                    sink.on_frame_owned(f, from);
                }
            }
        }
    }
}

thread_local! {
    /// Per-thread buffers for sealing (TX) and opening (RX), so the common path allocates
    /// nothing. Taken out while in use: a nested call (a receive that sends an
    /// acknowledgement on the same thread) gets a fresh one.
    static TX: std::cell::Cell<Vec<u8>> = const { std::cell::Cell::new(Vec::new()) };
    static RX: std::cell::Cell<Vec<u8>> = const { std::cell::Cell::new(Vec::new()) };
}

type Scratch = std::thread::LocalKey<std::cell::Cell<Vec<u8>>>;

fn take_scratch(key: &'static Scratch) -> Vec<u8> {
    key.with(|c| c.take())
}

fn give_scratch(key: &'static Scratch, buf: Vec<u8>) {
    // Large buffers are not kept: one 16 MiB frame should not pin 16 MiB per thread.
    if buf.capacity() <= 256 << 10 {
        key.with(|c| c.set(buf));
    }
}

fn with_scratch<R>(key: &'static Scratch, f: impl FnOnce(&mut Vec<u8>) -> R) -> R {
    let mut buf = take_scratch(key);
    let r = f(&mut buf);
    give_scratch(key, buf);
    r
}

/// The router's side of a secured link: seals what it sends.
struct SecureLink {
    below: Arc<dyn Link>,
    secured: Arc<Secured>,
}

forward_link! {
    [impl] SecureLink => below;
    fn caps(&self) -> hetcomm_link::LinkCaps {
        let mut caps = self.below.caps();
        caps.max_frame = caps.max_frame.saturating_sub(OVERHEAD);
        caps.mtu = caps.mtu.saturating_sub(OVERHEAD);
        caps
    }
    fn send(&self, to: SystemId, frame: &[u8]) -> Result<(), LinkError> {
        self.secured.send(to, frame, &[], false)
    }
    fn send_parts(&self, to: SystemId, head: &[u8], body: &[u8]) -> Result<(), LinkError> {
        self.secured.send(to, head, body, false)
    }
    fn send_held(&self, to: SystemId, frame: &[u8]) -> Result<(), LinkError> {
        self.secured.send(to, frame, &[], true)
    }
    fn stats(&self) -> hetcomm_link::LinkStats {
        let mut stats = self.below.stats();
        stats.security = self.secured.stats();
        stats
    }
    // Authenticated encryption protects every byte: the router need not checksum payloads.
    fn checksums_payload(&self) -> bool {
        true
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
        for frame in frames {
            self.secured.receive(Incoming::Borrowed(frame));
        }
    }
}

impl LinkLayer for SecurityLayer {
    fn name(&self) -> &str {
        "security"
    }

    fn wrap_sink(&self, _ctx: &LayerContext, sink: Arc<dyn FrameSink>) -> Arc<dyn FrameSink> {
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
                        state: Mutex::new(PeerState::default()),
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
        });
        let _ = self.secured.set(secured.clone());
        Arc::new(SecureSink { secured })
    }

    fn wrap_link(
        &self,
        _ctx: &LayerContext,
        link: Arc<dyn Link>,
    ) -> Result<Arc<dyn Link>, LayerError> {
        let secured = self
            .secured
            .get()
            .cloned()
            .ok_or_else(|| LayerError::Wrap {
                layer: "security".into(),
                source: "the security layer wraps a link's sink before the link".into(),
            })?;
        let _ = secured.below.set(Arc::downgrade(&link));
        if matches!(secured.handshakes, Handshakes::OverTheLink) {
            let weak = Arc::downgrade(&secured);
            std::thread::Builder::new()
                .name("hc-security".into())
                .spawn(move || loop {
                    std::thread::sleep(Duration::from_millis(100));
                    match weak.upgrade() {
                        Some(s) if s.below().is_some() => s.upkeep(),
                        _ => return,
                    }
                })
                .map_err(|e| LayerError::Wrap {
                    layer: "security".into(),
                    source: Box::new(e),
                })?;
        }
        Ok(Arc::new(SecureLink {
            below: link,
            secured,
        }))
    }
}
