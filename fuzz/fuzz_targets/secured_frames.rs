//! Received frames into a real `hetcomm_security::SecurityLayer` (system 2, over a link that
//! captures what the layer sends), checked frame by frame against a model of
//! `docs/wire-format.md`, "Secured frames".
//!
//! The target plays systems 1 and 3 with their real key pairs, through the public API only
//! (`session::initiate` / `respond` / `Initiation::complete`, `Session::seal`): it starts
//! handshakes, answers the layer's, seals data frames in its sessions, asks the layer to send
//! (so the layer queues, initiates and seals), and feeds the layer arbitrary bytes, frames
//! with a valid-looking prefix, and any earlier frame again, each as it is or mutated (a bit
//! flipped, a byte set, cut short, a byte added, sender and receiver swapped), through
//! `on_frame`, `on_frame_owned` or `on_frames`. Half the inputs run with handshakes over the
//! link, half with a simulation's in-memory sessions (`Handshakes::InMemory`).
//!
//! Checked after every step:
//! - no panic;
//! - every frame fed has exactly the outcome the model predicts from the document's order of
//!   checks (prefix → receiver → known sender → sender the table connects → session index →
//!   authentication → replay
//!   window → inner source / destination / table; a data batch, type 4, like a data message):
//!   one refusal counter up by exactly one, or
//!   the inner frame handed up once (labelled with the authenticated sender), or a handshake
//!   completed, or — for the two silent cases the layer has, an authenticated empty inner frame
//!   and an initiation it ignores because it is the lower id with a handshake of its own under
//!   way — nothing at all; no other counter moves;
//! - nothing reaches the inner sink unless it is the inner frame of a data frame the target
//!   sealed, in the session the layer holds under that index, not seen before: a frame "authenticates" in the
//!   model only if it is byte for byte one the target sealed (a forgery that the layer accepted
//!   would be handed up unpredicted and fail the run);
//! - what the layer sends is well-formed: initiations and responses from system 2 to the right
//!   system, and data frames that open in the target's half of the session with the inner
//!   frames it was asked to send, in order, with counters 0, 1, 2, … per session.
//!
//! The layer's upkeep thread resends initiations after 250 ms; an input stops after 200 ms so
//! that the model never races it. `HETCOMM_FUZZ_VERBOSE=1` prints each frame's expected
//! outcome.
#![no_main]

#[path = "common/mod.rs"]
mod common;

use std::collections::{HashMap, HashSet, VecDeque};
use std::sync::{Arc, Mutex, OnceLock};
use std::time::{Duration, Instant};

use common::Cursor;
use hetcomm_core::{wire, FrameBuf, FrameKind, Header, SystemId};
use hetcomm_link::conformance::CollectSink;
use hetcomm_link::layer::{LayerContext, LinkLayer};
use hetcomm_link::{FrameSink, Link, LinkCaps, LinkError, Peer, SecurityStats};
use hetcomm_security::envelope::{DATA_HEADER_LEN, TAG_LEN};
use hetcomm_security::replay::WINDOW;
use hetcomm_security::session::{self, Entropy, Initiation, Session};
use hetcomm_security::{Handshakes, Keypair, Policy, PrivateKey, SecurityLayer, SimSessions};
use libfuzzer_sys::fuzz_target;

const LOCAL: SystemId = SystemId(2);
/// The systems the target plays.
const PLAYED: [SystemId; 2] = [SystemId(1), SystemId(3)];
const SIM_SEED: u64 = 0x5ec0;
const MAX_OPS: usize = 48;
const TIME_LIMIT: Duration = Duration::from_millis(200);

fn keys() -> &'static HashMap<SystemId, Keypair> {
    static K: OnceLock<HashMap<SystemId, Keypair>> = OnceLock::new();
    K.get_or_init(|| {
        [1u16, 2, 3]
            .into_iter()
            .map(|id| {
                let private = PrivateKey([id as u8 * 0x11; 32]);
                (SystemId(id), Keypair::from_private(private).expect("key"))
            })
            .collect()
    })
}

/// The link under the layer: keeps what the layer sends.
#[derive(Default)]
struct Capture(Mutex<Vec<(SystemId, Vec<u8>)>>);

impl Link for Capture {
    fn caps(&self) -> LinkCaps {
        LinkCaps {
            max_frame: 1 << 20,
            mtu: 1 << 20,
            reliable: true,
            ordered: true,
            broadcast: false,
        }
    }
    fn send(&self, to: SystemId, frame: &[u8]) -> Result<(), LinkError> {
        self.0.lock().unwrap().push((to, frame.to_vec()));
        Ok(())
    }
}

fn u16_at(b: &[u8], at: usize) -> u16 {
    u16::from_le_bytes([b[at], b[at + 1]])
}
fn u32_at(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes(b[at..at + 4].try_into().unwrap())
}
fn u64_at(b: &[u8], at: usize) -> u64 {
    u64::from_le_bytes(b[at..at + 8].try_into().unwrap())
}

/// A session the layer holds with one played system, as the model sees it.
struct Held {
    /// The layer's index (in the data frames it receives).
    index: u32,
    /// The index the layer puts in the data frames it sends.
    peer_index: u32,
    /// The target's half (its index in `Run::mine`), if it has one.
    mine: Option<usize>,
    seen: HashSet<u64>,
    top: Option<u64>,
    /// The counter of the next data frame the layer seals in it.
    next_out: u64,
}

impl Held {
    fn new(index: u32, peer_index: u32, mine: Option<usize>) -> Held {
        Held {
            index,
            peer_index,
            mine,
            seen: HashSet::new(),
            top: None,
            next_out: 0,
        }
    }

    /// The replay window (RFC 6479, as the document says): accepts and records, or refuses.
    fn accept(&mut self, counter: u64) -> bool {
        let too_old = self
            .top
            .is_some_and(|t| counter < t && t - counter >= WINDOW);
        if counter == u64::MAX || too_old || !self.seen.insert(counter) {
            return false;
        }
        self.top = Some(self.top.map_or(counter, |t| t.max(counter)));
        true
    }
}

#[derive(Default)]
struct PeerModel {
    current: Option<Held>,
    previous: Option<Held>,
    /// Sessions the layer answered (as responder) that no authentic frame has used yet, the
    /// newest last (at most two): the first frame that passes in one makes it current.
    unconfirmed: Vec<Held>,
    /// The layer's initiation under way: its index and bytes.
    pending: Option<(u32, Vec<u8>)>,
    last_init: Option<u64>,
    /// In-memory sessions: whether the layer has taken its half yet.
    taken: bool,
    /// Inner frames the layer was asked to send and has not sent sealed yet.
    out: VecDeque<Vec<u8>>,
}

impl PeerModel {
    fn install(&mut self, held: Held) {
        self.previous = self.current.replace(held);
    }
    fn held(&mut self, index: u32) -> Option<&mut Held> {
        [self.current.as_mut(), self.previous.as_mut()]
            .into_iter()
            .flatten()
            .chain(self.unconfirmed.iter_mut())
            .find(|h| h.index == index)
    }

    /// A frame passed in the session `index`: if it is an unconfirmed one, it becomes current
    /// (the others are forgotten, and the layer's own handshake is over).
    fn confirm(&mut self, index: u32) {
        if let Some(i) = self.unconfirmed.iter().position(|h| h.index == index) {
            let held = self.unconfirmed.remove(i);
            self.unconfirmed.clear();
            self.pending = None;
            self.install(held);
        }
    }
}

struct Sealed {
    sid: usize,
    inner: Vec<u8>,
}

struct InitRecord {
    timestamp: u64,
    initiation: Option<Initiation>,
}

/// What a fed frame should do.
#[derive(Debug)]
enum Expect {
    Refused(&'static str),
    HandedUp(Vec<u8>, SystemId),
    Silent,
    /// An initiation the layer answers: from whom, its timestamp, the index in its clear bytes,
    /// and its key in `Run::inits`.
    InitAccepted(SystemId, u64, u32, Vec<u8>),
    /// A response that completes the layer's handshake: from whom, the target's session.
    ResponseAccepted(SystemId, usize),
}

struct Run {
    in_memory: bool,
    data_from: HashSet<SystemId>,
    acks_from: HashSet<SystemId>,
    known: HashSet<SystemId>,
    up: Arc<CollectSink>,
    link: Arc<dyn Link>,
    sink: Arc<dyn FrameSink>,
    below: Arc<Capture>,
    peers: HashMap<SystemId, PeerModel>,
    /// The target's halves of sessions: (played system, session).
    mine: Vec<(SystemId, Session)>,
    sealed: HashMap<Vec<u8>, Sealed>,
    inits: HashMap<(SystemId, Vec<u8>), InitRecord>,
    /// Responses the target wrote: (played system, Noise message) → (the layer's index it
    /// answers, the target's session).
    responses: HashMap<(SystemId, Vec<u8>), (u32, usize)>,
    history: Vec<Vec<u8>>,
    stats: SecurityStats,
    handed: usize,
}

fn stat<'a>(s: &'a mut SecurityStats, name: &str) -> &'a mut u64 {
    match name {
        "rejected_auth" => &mut s.rejected_auth,
        "rejected_replay" => &mut s.rejected_replay,
        "rejected_table" => &mut s.rejected_table,
        "rejected_unknown_sender" => &mut s.rejected_unknown_sender,
        "rejected_no_session" => &mut s.rejected_no_session,
        "handshakes" => &mut s.handshakes,
        _ => unreachable!("{name}"),
    }
}

impl Run {
    fn new(c: &mut Cursor) -> Run {
        let config = c.u8();
        let in_memory = config & 1 != 0;
        let set = |bits: u8| -> HashSet<SystemId> {
            PLAYED
                .iter()
                .enumerate()
                .filter(|(i, _)| bits >> i & 1 != 0)
                .map(|(_, &s)| s)
                .collect()
        };
        let data_from = set(config >> 1);
        let acks_from = set(config >> 3);
        let mut known: HashSet<SystemId> = PLAYED.into_iter().collect();
        if config & 0x20 != 0 {
            known.remove(&SystemId(3));
        }
        let keys = keys();
        let policy = Policy {
            local: LOCAL,
            keypair: keys[&LOCAL].clone(),
            peers: known.iter().map(|p| (*p, keys[p].public)).collect(),
            data_from: data_from.clone(),
            acks_from: acks_from.clone(),
        };
        let handshakes = if in_memory {
            Handshakes::InMemory(SimSessions::new(SIM_SEED, keys.clone()))
        } else {
            Handshakes::OverTheLink
        };
        let layer = SecurityLayer::new("udp", policy, handshakes);
        let ctx = LayerContext::new(LOCAL);
        let up = CollectSink::new();
        let below = Arc::new(Capture::default());
        let mut sink = None;
        let link = layer
            .wrap(&ctx, up.clone(), &mut |s| {
                sink = Some(s);
                Ok(below.clone())
            })
            .expect("wraps");
        let sink = sink.expect("opened");
        let mut run = Run {
            in_memory,
            data_from,
            acks_from,
            known,
            up,
            link,
            sink,
            below,
            peers: PLAYED.iter().map(|p| (*p, PeerModel::default())).collect(),
            mine: Vec::new(),
            sealed: HashMap::new(),
            inits: HashMap::new(),
            responses: HashMap::new(),
            history: Vec::new(),
            stats: SecurityStats {
                enabled: true,
                ..SecurityStats::default()
            },
            handed: 0,
        };
        if in_memory {
            // The sessions a simulation makes (SimSessions: the lower id initiates, with index
            // 1; the responder's index is 2). The target's halves are made when first needed.
            for p in PLAYED.into_iter().filter(|p| run.known.contains(p)) {
                let (index, peer_index) = if p < LOCAL { (2, 1) } else { (1, 2) };
                run.peers.get_mut(&p).unwrap().current = Some(Held::new(index, peer_index, None));
            }
        }
        run
    }

    /// In-memory sessions: the target's half of the session with `p`, made on first use.
    fn sim_half(&mut self, p: SystemId) -> Option<usize> {
        if !self.in_memory || !self.known.contains(&p) {
            return None;
        }
        if let Some(sid) = self.peers[&p].current.as_ref().and_then(|h| h.mine) {
            return Some(sid);
        }
        let keys = keys();
        let (lo, hi) = if p < LOCAL { (p, LOCAL) } else { (LOCAL, p) };
        let seed = SIM_SEED ^ ((lo.0 as u64) << 16) ^ ((hi.0 as u64) << 32);
        let (a, b) =
            session::in_memory((lo, &keys[&lo]), (hi, &keys[&hi]), seed).expect("sessions");
        let ours = if p == lo { a } else { b };
        self.mine.push((p, ours));
        let sid = self.mine.len() - 1;
        self.peers
            .get_mut(&p)
            .unwrap()
            .current
            .as_mut()
            .unwrap()
            .mine = Some(sid);
        Some(sid)
    }

    fn may_talk(&self, p: SystemId) -> bool {
        self.data_from.contains(&p) || self.acks_from.contains(&p)
    }

    /// What the layer should do with `b`, updating the model where the outcome does not
    /// depend on what the layer sends back.
    fn predict(&mut self, b: &[u8]) -> Expect {
        use Expect::Refused;
        if b.len() < 8 || &b[..2] != b"HS" || b[2] != 1 || !(1..=4).contains(&b[3]) {
            return Refused("rejected_auth");
        }
        let (sender, receiver) = (SystemId(u16_at(b, 4)), SystemId(u16_at(b, 6)));
        if receiver != LOCAL {
            return Refused("rejected_table");
        }
        if !self.known.contains(&sender) {
            return Refused("rejected_unknown_sender");
        }
        // A member the table does not connect is refused before anything is opened.
        if !self.may_talk(sender) {
            return Refused("rejected_table");
        }
        match b[3] {
            // A data batch (type 4) is checked as a data message up to its authentication;
            // the target seals none, so none of them authenticates.
            3 | 4 => self.predict_data(sender, b),
            1 => {
                if self.in_memory {
                    return Refused("rejected_auth");
                }
                let key = (sender, b.get(12..).unwrap_or_default().to_vec());
                let Some(rec) = self.inits.get(&key).filter(|_| b.len() >= 12) else {
                    return Refused("rejected_auth");
                };
                let pm = &self.peers[&sender];
                if pm.last_init.is_some_and(|l| rec.timestamp <= l) {
                    return Refused("rejected_replay");
                }
                if pm.pending.is_some() && LOCAL < sender {
                    return Expect::Silent;
                }
                Expect::InitAccepted(sender, rec.timestamp, u32_at(b, 8), key.1)
            }
            _ => {
                let pm = self.peers.get_mut(&sender).unwrap();
                let Some((index, _)) = pm.pending.clone() else {
                    return Refused("rejected_replay");
                };
                if b.len() < 16 || u32_at(b, 12) != index {
                    return Refused("rejected_replay");
                }
                pm.pending = None;
                match self.responses.get(&(sender, b[16..].to_vec())) {
                    Some(&(answers, sid)) if answers == index => {
                        Expect::ResponseAccepted(sender, sid)
                    }
                    _ => Refused("rejected_auth"),
                }
            }
        }
    }

    fn predict_data(&mut self, sender: SystemId, b: &[u8]) -> Expect {
        use Expect::Refused;
        if b.len() < DATA_HEADER_LEN + TAG_LEN {
            return Refused("rejected_auth");
        }
        let (index, counter) = (u32_at(b, 8), u64_at(b, 12));
        let in_memory = self.in_memory;
        let sealed = self.sealed.get(b);
        let pm = self.peers.get_mut(&sender).unwrap();
        // An in-memory layer takes its half of the session at the first frame in it.
        let taken = in_memory && !pm.taken;
        let Some(held) = pm.held(index) else {
            return Refused("rejected_no_session");
        };
        let authentic = sealed.filter(|s| Some(s.sid) == held.mine);
        let verdict = match authentic {
            None => Refused("rejected_auth"),
            Some(_) if !held.accept(counter) => Refused("rejected_replay"),
            Some(s) => {
                let inner = &s.inner;
                // Not a hetcomm frame (short, or without the magic "HC"): the router refuses it.
                let allowed = inner.len() < 16 || inner[..2] != wire::MAGIC || {
                    let (source, destination) =
                        (SystemId(u16_at(inner, 8)), SystemId(u16_at(inner, 12)));
                    source == sender
                        && destination == LOCAL
                        && match inner[3] {
                            0 => self.data_from.contains(&sender),
                            1 => self.acks_from.contains(&sender),
                            _ => true,
                        }
                };
                if !allowed {
                    Refused("rejected_table")
                } else if inner.is_empty() {
                    Expect::Silent
                } else {
                    Expect::HandedUp(inner.clone(), sender)
                }
            }
        };
        if matches!(verdict, Expect::HandedUp(..) | Expect::Silent) {
            self.peers.get_mut(&sender).unwrap().confirm(index);
        }
        if taken {
            self.peers.get_mut(&sender).unwrap().taken = true;
            *stat(&mut self.stats, "handshakes") += 1;
        }
        verdict
    }

    /// Feeds `b` to the layer and checks what it does.
    fn feed(&mut self, b: Vec<u8>, how: u8) {
        let expect = self.predict(&b);
        if verbose() {
            eprintln!("feed {} bytes: expect {expect:?}", b.len());
        }
        self.history.push(b.clone());
        let from = Peer::Unknown;
        match how % 3 {
            0 => self.sink.on_frame(&b, from),
            1 => self.sink.on_frame_owned(FrameBuf::from(b.clone()), from),
            _ => self.sink.on_frames(&mut std::iter::once(&b[..]), from),
        }
        let mut want = self.stats;
        let mut handed = None;
        match &expect {
            Expect::Refused(name) => *stat(&mut want, name) += 1,
            Expect::HandedUp(inner, sender) => handed = Some((inner.clone(), *sender)),
            Expect::Silent => {}
            Expect::InitAccepted(..) | Expect::ResponseAccepted(..) => want.handshakes += 1,
        }
        let got = self.link.stats().security;
        assert_eq!(got, want, "stats after {expect:?} for {}", hex(&b));
        self.stats = got;
        let frames = self.up.frames();
        let new: Vec<_> = frames[self.handed..]
            .iter()
            .map(|f| (f.bytes.clone(), f.from))
            .collect();
        self.handed = frames.len();
        match handed {
            Some((inner, sender)) => {
                assert_eq!(
                    new,
                    [(inner, Peer::System(sender))],
                    "handed up for {}",
                    hex(&b)
                )
            }
            None => assert!(
                new.is_empty(),
                "{expect:?} but handed up {new:?} for {}",
                hex(&b)
            ),
        }
        match expect {
            Expect::InitAccepted(p, timestamp, clear_index, noise) => {
                let sent = self.take_sent();
                let (to, response) = sent.first().cloned().expect("a response");
                assert_eq!(to, p);
                assert!(response.len() >= 16 && response[..4] == *b"HS\x01\x02");
                assert_eq!((u16_at(&response, 4), u16_at(&response, 6)), (LOCAL.0, p.0));
                assert_eq!(
                    u32_at(&response, 12),
                    clear_index,
                    "the response answers the index sent"
                );
                let mine = self
                    .inits
                    .get_mut(&(p, noise))
                    .unwrap()
                    .initiation
                    .take()
                    .map(|init| {
                        let mut r = response.clone();
                        r[12..16].copy_from_slice(&init.index.to_le_bytes());
                        let s = init
                            .complete(&r)
                            .expect("the layer's response completes the handshake");
                        self.mine.push((p, s));
                        self.mine.len() - 1
                    });
                let pm = self.peers.get_mut(&p).unwrap();
                pm.last_init = Some(timestamp);
                // Held apart until the peer's first frame in it; the layer's own handshake
                // (if any) goes on.
                if pm.unconfirmed.len() == 2 {
                    pm.unconfirmed.remove(0);
                }
                pm.unconfirmed
                    .push(Held::new(u32_at(&response, 8), clear_index, mine));
                self.history.push(response);
                self.check_sent(sent[1..].to_vec());
            }
            Expect::ResponseAccepted(p, sid) => {
                let pm = self.peers.get_mut(&p).unwrap();
                let index = self.mine[sid].1.peer_index;
                pm.install(Held::new(index, u32_at(&b, 8), Some(sid)));
                if pm.out.is_empty() {
                    // With nothing waiting, the initiator confirms the session with one data
                    // message whose inner frame is empty.
                    pm.out.push_back(Vec::new());
                }
                let sent = self.take_sent();
                self.check_sent(sent);
            }
            _ => {
                let sent = self.take_sent();
                self.check_sent(sent);
            }
        }
    }

    fn take_sent(&self) -> Vec<(SystemId, Vec<u8>)> {
        std::mem::take(&mut *self.below.0.lock().unwrap())
    }

    /// Checks what the layer sent (other than a response just accounted for).
    fn check_sent(&mut self, sent: Vec<(SystemId, Vec<u8>)>) {
        for (to, f) in sent {
            self.sim_half(to);
            assert!(
                PLAYED.contains(&to) && self.known.contains(&to),
                "sent to {to}"
            );
            assert!(f.len() >= 8 && f[..3] == *b"HS\x01", "sent {}", hex(&f));
            assert_eq!((u16_at(&f, 4), u16_at(&f, 6)), (LOCAL.0, to.0));
            let pm = self.peers.get_mut(&to).unwrap();
            match f[3] {
                1 => {
                    assert!(!self.in_memory, "an initiation from an in-memory layer");
                    pm.pending = Some((u32_at(&f, 8), f.clone()));
                }
                3 => {
                    let held = pm.current.as_mut().expect("data sent without a session");
                    assert_eq!(u32_at(&f, 8), held.peer_index);
                    assert_eq!(u64_at(&f, 12), held.next_out, "counters 0, 1, 2, …");
                    held.next_out += 1;
                    let inner = pm
                        .out
                        .pop_front()
                        .expect("a frame the layer was asked to send");
                    if let Some(sid) = held.mine {
                        let mut g = f.clone();
                        assert!(self.mine[sid].1.open(&mut g), "the layer's frame opens");
                        assert_eq!(&g[DATA_HEADER_LEN..g.len() - TAG_LEN], &inner[..]);
                    }
                }
                k => panic!("unexpected frame of type {k} sent: {}", hex(&f)),
            }
            self.history.push(f);
        }
        for (p, pm) in &self.peers {
            if pm.current.is_some() {
                assert!(pm.out.is_empty(), "frames to {p} still held with a session");
            }
        }
    }

    /// Asks the layer to send `inner` to `p`.
    fn send(&mut self, p: SystemId, inner: Vec<u8>, how: u8) {
        if !self.known.contains(&p) {
            assert!(
                self.link.send(p, &inner).is_err(),
                "sent to a system without a key"
            );
            return;
        }
        let pm = self.peers.get_mut(&p).unwrap();
        if self.in_memory && !pm.taken {
            pm.taken = true;
            self.stats.handshakes += 1;
        }
        // Without a session, a frame that wants an acknowledgement is refused, not held (the
        // layer starts the handshake).
        let refused = pm.current.is_none() && !self.in_memory && requests_ack(&inner);
        if !refused {
            pm.out.push_back(inner.clone());
        }
        let r = match how % 3 {
            0 => self.link.send(p, &inner),
            1 => {
                let cut = inner.len() / 2;
                self.link.send_parts(p, &inner[..cut], &inner[cut..])
            }
            // The layer holds it until the flush (the runtime's, at the latest when its
            // linger runs out); alone, it leaves as a data message.
            _ => self
                .link
                .send_held(p, &inner)
                .and_then(|()| self.link.flush()),
        };
        if refused {
            assert!(
                matches!(r, Err(LinkError::NoSession { peer, .. }) if peer == p),
                "{r:?}"
            );
        } else {
            r.expect("the layer takes the frame");
        }
        assert_eq!(self.link.stats().security, self.stats);
        let sent = self.take_sent();
        self.check_sent(sent);
    }
}

/// Whether `frame` is a data frame that requests an acknowledgement (as the layer reads it).
fn requests_ack(frame: &[u8]) -> bool {
    frame.len() > 4
        && frame[..2] == wire::MAGIC
        && frame[3] == 0
        && frame[4] & wire::FLAG_ACK_REQUESTED != 0
}

/// `HETCOMM_FUZZ_VERBOSE=1`: print each frame's expected outcome (to see what a corpus reaches).
fn verbose() -> bool {
    static V: OnceLock<bool> = OnceLock::new();
    *V.get_or_init(|| std::env::var_os("HETCOMM_FUZZ_VERBOSE").is_some())
}

fn hex(b: &[u8]) -> String {
    b.iter().take(64).map(|x| format!("{x:02x}")).collect()
}

/// An inner frame: a valid frame with chosen fields, or raw bytes.
fn inner_frame(c: &mut Cursor, sender: SystemId) -> Vec<u8> {
    let sel = c.u8();
    if sel & 0x80 != 0 {
        let n = (c.u8() % 64) as usize;
        return c.bytes(n).to_vec();
    }
    let source = if sel & 1 != 0 {
        SystemId(c.u8() as u16 % 4)
    } else {
        sender
    };
    let destination = if sel & 2 != 0 {
        SystemId(c.u8() as u16 % 4)
    } else {
        LOCAL
    };
    let mut h = Header::data(
        hetcomm_core::Address {
            system: source,
            module: hetcomm_core::ModuleId(1),
        },
        hetcomm_core::Address {
            system: destination,
            module: hetcomm_core::ModuleId(2),
        },
        hetcomm_core::MessageType(5),
    );
    if sel & 4 != 0 {
        h.kind = FrameKind::Ack;
    }
    h.seq = c.u16() as u64;
    let n = (c.u8() % 80) as usize;
    let mut f = wire::encode(&h, c.bytes(n));
    if sel & 8 != 0 {
        f[3] = 7; // a kind the router does not know
    }
    f
}

fn mutate(c: &mut Cursor, mut f: Vec<u8>) -> Vec<u8> {
    let m = c.u8();
    let pos = c.u16() as usize;
    match m % 8 {
        1 if !f.is_empty() => {
            let i = pos % f.len();
            f[i] ^= 1 << (m >> 5);
        }
        2 if !f.is_empty() => {
            let i = pos % f.len();
            f[i] = c.u8();
        }
        3 => f.truncate(pos % (f.len() + 1)),
        4 => f.push(c.u8()),
        5 if f.len() >= 8 => {
            let (s, r) = ([f[4], f[5]], [f[6], f[7]]);
            f[4..6].copy_from_slice(&r);
            f[6..8].copy_from_slice(&s);
        }
        _ => {}
    }
    f
}

fn played(c: &mut Cursor) -> SystemId {
    PLAYED[(c.u8() & 1) as usize]
}

fn run(data: &[u8]) {
    let started = Instant::now();
    let mut c = Cursor::new(data);
    let mut run = Run::new(&mut c);
    let keys = keys();
    for _ in 0..MAX_OPS {
        if c.is_empty() || started.elapsed() > TIME_LIMIT {
            break;
        }
        let op = c.u8();
        let how = op >> 4;
        match op % 8 {
            // A handshake started by a played system.
            0 => {
                let p = played(&mut c);
                let (index, timestamp, seed) = (c.u32(), c.u16() as u64, c.u8() as u64);
                let (init, pending) = session::initiate(
                    (p, &keys[&p]),
                    (LOCAL, &keys[&LOCAL].public),
                    index,
                    timestamp,
                    Entropy::Seeded(seed),
                )
                .expect("initiates");
                let rec = InitRecord {
                    timestamp,
                    initiation: Some(pending),
                };
                run.inits.insert((p, init[12..].to_vec()), rec);
                let f = mutate(&mut c, init);
                run.feed(f, how);
            }
            // The layer's handshake answered.
            1 => {
                let p = played(&mut c);
                let (index, seed) = (c.u32(), c.u8() as u64);
                let Some((theirs, init)) = run.peers[&p].pending.clone() else {
                    continue;
                };
                let answer = session::respond(
                    (p, &keys[&p]),
                    (LOCAL, &keys[&LOCAL].public),
                    &init,
                    index,
                    Entropy::Seeded(seed),
                )
                .expect("the layer's initiation is authentic");
                run.mine.push((p, answer.session));
                let sid = run.mine.len() - 1;
                run.responses
                    .insert((p, answer.response[16..].to_vec()), (theirs, sid));
                let f = mutate(&mut c, answer.response);
                run.feed(f, how);
            }
            // A data frame sealed in one of the target's sessions.
            2 | 3 => {
                let p = played(&mut c);
                run.sim_half(p);
                let ours: Vec<usize> = (0..run.mine.len())
                    .filter(|&i| run.mine[i].0 == p)
                    .collect();
                let Some(&sid) = ours.get(c.u8() as usize % ours.len().max(1)) else {
                    continue;
                };
                let inner = inner_frame(&mut c, p);
                let mut f = Vec::new();
                run.mine[sid].1.seal(&mut f, p, LOCAL, &inner, &[]);
                run.sealed.insert(f.clone(), Sealed { sid, inner });
                let f = mutate(&mut c, f);
                run.feed(f, how);
            }
            // The layer sends.
            4 => {
                let p = if c.u8() & 0x80 != 0 {
                    SystemId(9)
                } else {
                    played(&mut c)
                };
                let inner = inner_frame(&mut c, LOCAL);
                run.send(p, inner, how);
            }
            // An earlier frame again.
            5 => {
                if run.history.is_empty() {
                    continue;
                }
                let f = run.history[c.u16() as usize % run.history.len()].clone();
                let f = mutate(&mut c, f);
                run.feed(f, how);
            }
            // A valid-looking prefix and any tail.
            6 => {
                let ids = [0u16, 1, 2, 3, 9];
                let mut f = b"HS\x01".to_vec();
                f.push(c.u8() % 4);
                f.extend_from_slice(&ids[c.u8() as usize % 5].to_le_bytes());
                f.extend_from_slice(&ids[c.u8() as usize % 5].to_le_bytes());
                let n = c.u8() as usize;
                f.extend_from_slice(c.bytes(n));
                run.feed(f, how);
            }
            // Raw bytes.
            _ => {
                let n = (c.u8() % 128) as usize;
                let f = c.bytes(n).to_vec();
                run.feed(f, how);
            }
        }
    }
}

fuzz_target!(|data: &[u8]| run(data));
