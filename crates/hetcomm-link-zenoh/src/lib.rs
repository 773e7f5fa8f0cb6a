//! # hetcomm-link-zenoh — the `zenoh` transport kind
//!
//! Carries hetcomm frames as [Zenoh](https://zenoh.io) puts, so that systems on many hosts find
//! each other through Zenoh (peer-to-peer with multicast scouting, or through Zenoh routers
//! that span networks) instead of through addresses written in the fleet file. This crate
//! writes no Zenoh protocol itself: it opens one Zenoh session per system with the `zenoh`
//! crate (default features off, TCP links only).
//!
//! ## Key expressions
//!
//! With the transport's `prefix` (default `hetcomm`; give each fleet its own to share one Zenoh
//! network between fleets), a system named `Bravo`:
//!
//! | key expression | what |
//! |---|---|
//! | `<prefix>/sys/Bravo` | frames for Bravo: a put's payload is one frame byte for byte (`docs/wire-format.md`), or several held frames as a batch in the UDP batch layout (`"HB"` header, length-prefixed records) |
//! | `<prefix>/live/Bravo` | Bravo's liveliness token, declared while its link is open |
//! | `<prefix>/all` | native broadcasts: one put of one frame (`FLAG_TO_ALL`) that every system receives |
//!
//! A system subscribes to its own `sys` key and to the `all` key; the module a frame is for is
//! in the frame's header. A broadcast is one put on the `all` key ([`LinkCaps::broadcast`]:
//! a send to [`TO_ALL_SYSTEM`]); every system on the Zenoh network under that prefix receives
//! it, and its router takes it only if the communication table lets the sender send to it on
//! this transport. `docs/zenoh.md` describes the layout for programs that are not hetcomm
//! ([`data_key`], [`live_key`], [`all_key`]).
//!
//! ## What the link guarantees
//!
//! [`LinkCaps`]: `reliable = false`, `ordered = false`, `mtu` = [`UNSPLIT_FRAME`] (Zenoh
//! fragments larger puts, up to [`MAX_FRAME`]); the link batches ([`Link::send_held`]) and
//! checksums payloads (Zenoh over TCP delivers a message whole or not at all). Puts go on
//! Zenoh's reliable channel with
//! congestion control `Block` (a full queue makes the put wait, never drops the frame:
//! `Drop` congestion control discards messages without telling the application, zenoh issues
//! #1835, #2258, #2587), but Zenoh still loses what is put before the destination's
//! subscription has reached the sender and what is in flight when a connection or a router
//! goes away (Zenoh itself closes a connection whose blocking queue stays full longer than its
//! `wait_before_close`); none of these losses is reported to the application, so the link
//! cannot count them. A change of route (direct peer link ↔ through a router) can reorder. The
//! router's acknowledgements and retransmissions make delivery reliable on top, exactly as over
//! UDP; `ordered = true` on the transport restores each sender's order at the receiver.
//!
//! ## Presence
//!
//! Each link declares a liveliness token on its system's `live` key and follows the tokens of
//! every system of the fleet (a liveliness subscriber with history). A send to a system:
//!
//! * whose token is present: put at once;
//! * whose token has gone (it left, or its host was cut off and Zenoh's lease expired): fails
//!   at once with [`LinkError::Unreachable`] and that reason, instead of waiting for the
//!   router's retransmissions to run out;
//! * never seen: the first send to it waits for its token, at most `presence_timeout_ms`
//!   (default 5 s: discovery may still be going on); if it does not come, that send and every
//!   later one fails at once as unreachable, until the token appears. Waiting for the token also means the destination's subscription has
//!   reached this session (it is declared before the token), so the first put is not lost to
//!   discovery.
//!
//! [`ZenohLink::presence`] lists who is present; [`ZenohLink::presence_events`] yields systems
//! joining and leaving (`hetcomm listen` prints them).
//!
//! ## Threads
//!
//! Zenoh runs its own tokio runtime (shared by every session of the process). Received frames
//! are handed to the [`FrameSink`] on Zenoh's receiving thread (a subscriber callback): no
//! hand-off to another thread. A send made from there (the router's acknowledgement, a
//! callback's reply) never waits for presence: to a system never seen it puts anyway (that
//! system has just sent a frame), to one seen leaving it fails at once. A sink that blocks
//! (an inbox full under the `block` policy) holds Zenoh's reader: backpressure, not loss.
//! [`Link::send`] puts on the caller's thread, `express`: the runtime sends a frame on its own
//! only when none came just before it (a stream's frames are held, [`Link::send_held`], and
//! put together). Only a put of held frames that filled up, with more on the way, and a large
//! frame right behind another put (a stream of large frames, never held) are left to Zenoh's
//! batching; the put that ends a burst ([`Link::flush`]) is express again.

mod config;
pub mod factory;
mod presence;
pub mod router;

use parking_lot::{Mutex, RwLock};
use std::collections::HashMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;

use hetcomm_core::wire::TO_ALL_SYSTEM;
use hetcomm_core::{BufferPool, SystemId};
use hetcomm_link::batch::{batch_records, BATCH_MAGIC, BATCH_VERSION};
use hetcomm_link::{FrameSink, Link, LinkCaps, LinkError, LinkEvent, LinkStats, Peer};
use zenoh::pubsub::Publisher;
use zenoh::qos::CongestionControl;
use zenoh::sample::Locality;
use zenoh::Wait;

pub use config::{validate_prefix, Mode, ZenohSettings};
pub use presence::{watch_all as watch_presence, PresenceEvent, PresenceEvents};
use presence::{Presence, Seen};

/// Registers the `zenoh` transport factory ([`factory::ZenohFactory`]).
pub fn register_transports(registry: &mut hetcomm_link::registry::Registry) {
    registry.register(factory::ZenohFactory);
}

/// Largest frame a `zenoh` link accepts: the wire format's largest frame (16 MiB payload plus
/// the 48-byte header). Zenoh fragments it on the way.
pub const MAX_FRAME: usize = hetcomm_core::wire::HEADER_LEN + hetcomm_core::wire::MAX_PAYLOAD;

/// The largest frame a put carries in one of Zenoh's batches (65 535 bytes by default, less
/// room for Zenoh's own headers); Zenoh fragments a larger one ([`LinkCaps::mtu`]).
pub const UNSPLIT_FRAME: usize = 65_535 - 1_024;

/// The key expression frames for system `name` are put on: `<prefix>/sys/<name>`.
pub fn data_key(prefix: &str, name: &str) -> String {
    format!("{prefix}/sys/{name}")
}

/// The key expression native broadcasts are put on: `<prefix>/all`.
pub fn all_key(prefix: &str) -> String {
    format!("{prefix}/all")
}

/// The key expression of system `name`'s liveliness token: `<prefix>/live/<name>`.
pub fn live_key(prefix: &str, name: &str) -> String {
    format!("{prefix}/live/{name}")
}

/// Everything a `zenoh` link needs to open.
#[derive(Clone, Debug)]
pub struct ZenohLinkConfig {
    /// The system the link is for.
    pub local: SystemId,
    /// Every system the link may send to (and whose presence it follows), by id, with its
    /// name (the last chunk of its key expressions).
    pub systems: HashMap<SystemId, String>,
    /// The transport's settings.
    pub settings: ZenohSettings,
}

/// Why a `zenoh` link could not open.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ZenohOpenError {
    /// The local system is not among the configured systems.
    #[error("system {0} is not a system of this fleet")]
    UnknownSystem(SystemId),
    /// A setting Zenoh refused (an endpoint that does not parse, a key expression).
    #[error("zenoh setting {key}: {reason}")]
    Setting {
        /// The Zenoh configuration key or the key expression.
        key: String,
        /// Zenoh's reason.
        reason: String,
    },
    /// No endpoint of `connect` answered within `open_timeout_ms` (or a `listen` endpoint
    /// could not be bound).
    #[error("cannot open a Zenoh {mode} session: {endpoints} did not answer within {timeout_ms} ms ({reason})")]
    Unreachable {
        /// `peer` or `client`.
        mode: &'static str,
        /// The endpoints tried, comma-separated.
        endpoints: String,
        /// The time allowed.
        timeout_ms: u32,
        /// Zenoh's reason.
        reason: String,
    },
    /// Zenoh failed to open the session or to declare an entity.
    #[error("zenoh: {0}")]
    Zenoh(String),
}

/// One destination: its name, the publishers on its data key (declared on first use) and the
/// frames held for it.
struct Dest {
    name: String,
    /// The key its frames are put on.
    key: String,
    publishers: RwLock<Option<Arc<Publishers>>>,
    /// [`micros`] at the last put to this destination.
    last_put_us: AtomicU64,
    /// Frames held back by [`Link::send_held`], for one put.
    held: Mutex<Held>,
}

/// Held frames to one destination are put together once they reach this many bytes.
const HELD_MAX: usize = 32 * 1024;

/// Two publishers on one data key, with the same reliability and congestion control: frames
/// put through `express` leave at once, each in its own Zenoh batch; frames put through
/// `batched` may share a batch with the frames put right after them. Both go through the same
/// Zenoh queue, in the order they are put.
struct Publishers {
    express: Publisher<'static>,
    batched: Publisher<'static>,
}

/// Whether more frames to the same destination are on the way right behind a put: only then
/// may Zenoh hold it back to share a batch. Anything else goes `express`, since the
/// destination may be waiting for it (a request, a reply, an acknowledgement) and a
/// non-express put waits in Zenoh's batch until something else moves it (up to its
/// `batching/time_limit`, 1 ms, in every peer and router on the way; an acknowledgement and a
/// reply put back to back used to leave the reply there). Express for every frame of a
/// stream would cost 64 B throughput 25-fold; the runtime holds a stream's frames and puts
/// them together, so a stream's puts are few and large. Large frames are not held (each
/// fills a put); one that follows another put to the same destination within
/// [`STREAM_GAP_US`] is taken for a stream's and may share Zenoh's last batch of the one
/// before (express would cost a 64 KiB stream about 15%: a small batch for each frame's last
/// fragment).
#[derive(Clone, Copy)]
enum Put {
    /// The end of a burst, or a frame on its own: express.
    Last,
    /// A full put of held frames, more coming: Zenoh may batch it.
    MoreFollow,
}

/// Frames this large are not held by the runtime: each is put on its own ([`Put`]).
const LARGE_FRAME: usize = 8 * 1024;
/// A large frame put this soon after the last put to its destination belongs to a stream.
const STREAM_GAP_US: u64 = 50;

/// Capacity of received large frames a link keeps for reuse ([`BufferPool`]).
const RECEIVE_POOL_BYTES: usize = 4 << 20;

/// The header of a put that carries several frames: the UDP batch header
/// (`docs/wire-format.md`, "UDP batches"), then one record per frame.
const BATCH_HEADER: [u8; 4] = [BATCH_MAGIC[0], BATCH_MAGIC[1], BATCH_VERSION, 0];

/// Frames held for one destination: a batch put being written.
#[derive(Default)]
struct Held {
    /// [`BATCH_HEADER`], then a record (u32 length, little-endian, and the frame) per frame.
    put: Vec<u8>,
    frames: u64,
}

impl Held {
    fn push(&mut self, head: &[u8], body: &[u8]) {
        if self.put.is_empty() {
            self.put.extend_from_slice(&BATCH_HEADER);
        }
        self.put
            .extend_from_slice(&((head.len() + body.len()) as u32).to_le_bytes());
        self.put.extend_from_slice(head);
        self.put.extend_from_slice(body);
        self.frames += 1;
    }

    /// The put for what is held (a lone frame as it is, unless it would read as a batch),
    /// and the number of frames in it; nothing is held after.
    fn take(&mut self) -> (Vec<u8>, u64) {
        let (mut put, frames) = (
            std::mem::take(&mut self.put),
            std::mem::take(&mut self.frames),
        );
        let record = BATCH_HEADER.len() + 4;
        if frames == 1 && !put[record..].starts_with(&BATCH_MAGIC) {
            put.drain(..record);
        }
        (put, frames)
    }
}

/// Hands the frames of one put to `sink`: a batch (it starts with [`BATCH_MAGIC`]) frame by
/// frame, anything else as one frame. A batch with a header this version does not read, or
/// with a malformed tail, counts one drop (its whole records still go up).
fn deliver(sink: &dyn FrameSink, counters: &Counters, put: &[u8]) {
    if !put.starts_with(&BATCH_MAGIC) {
        counters.received.fetch_add(1, Ordering::Relaxed);
        return sink.on_frame(put, Peer::Unknown);
    }
    let Some(records) = batch_records(put) else {
        counters.dropped.fetch_add(1, Ordering::Relaxed);
        return;
    };
    let mut walk = records.clone();
    counters
        .received
        .fetch_add(walk.by_ref().count() as u64, Ordering::Relaxed);
    if !walk.rest().is_empty() {
        counters.dropped.fetch_add(1, Ordering::Relaxed);
    }
    sink.on_frames(&mut records.clone(), Peer::Unknown);
}

/// What a subscription does with each put: hands its frames to `sink` on Zenoh's receiving
/// thread, with no hand-off to another thread (a wake-up that crosses CPUs costs tens of
/// microseconds a frame).
fn receiver(
    sink: Arc<dyn FrameSink>,
    counters: Arc<Counters>,
) -> Arc<dyn Fn(zenoh::sample::Sample) + Send + Sync> {
    let takes_frames = sink.takes_frames();
    let pool = BufferPool::new(RECEIVE_POOL_BYTES);
    Arc::new(move |sample| {
        let payload = sample.payload();
        if payload.is_empty() {
            counters.dropped.fetch_add(1, Ordering::Relaxed);
            return;
        }
        IN_CALLBACK.with(|c| c.set(true));
        let contiguous = payload.slices().nth(1).is_none();
        if !contiguous && takes_frames {
            // A frame Zenoh carried in fragments: joined into a buffer of the link's pool
            // that the sink keeps (as the message's payload) rather than copies once more;
            // it comes back to the pool when the message is dropped (a fresh allocation per
            // large frame costs page faults).
            let mut buf = pool.take(payload.len());
            payload.slices().for_each(|s| buf.extend_from_slice(s));
            if buf.starts_with(&BATCH_MAGIC) {
                deliver(&*sink, &counters, &buf);
            } else {
                counters.received.fetch_add(1, Ordering::Relaxed);
                sink.on_frame_owned(pool.wrap(buf), Peer::Unknown);
            }
        } else {
            deliver(&*sink, &counters, &payload.to_bytes());
        }
        IN_CALLBACK.with(|c| c.set(false));
    })
}

/// Microseconds since the first call in this process.
fn micros() -> u64 {
    static EPOCH: std::sync::OnceLock<std::time::Instant> = std::sync::OnceLock::new();
    EPOCH
        .get_or_init(std::time::Instant::now)
        .elapsed()
        .as_micros() as u64
}

#[derive(Default)]
struct Counters {
    sent: AtomicU64,
    received: AtomicU64,
    dropped: AtomicU64,
}

/// A system's endpoint on a Zenoh network: one session, a subscription to its own data key, a
/// liveliness token, and publishers towards the systems it sends to. See the crate docs.
pub struct ZenohLink {
    session: zenoh::Session,
    local: SystemId,
    prefix: String,
    /// Per destination system, and the broadcast key under [`TO_ALL_SYSTEM`].
    dests: HashMap<SystemId, Dest>,
    /// Whether sends to [`TO_ALL_SYSTEM`] are broadcasts ([`LinkCaps::broadcast`]).
    broadcast: bool,
    presence: Arc<Presence>,
    presence_timeout: Duration,
    counters: Arc<Counters>,
    _token: zenoh::liveliness::LivelinessToken,
    _live: zenoh::pubsub::Subscriber<()>,
    _sub: zenoh::pubsub::Subscriber<()>,
    _all: zenoh::pubsub::Subscriber<()>,
}

thread_local! {
    /// True while this thread runs the sink for a frame Zenoh delivered: a send made from
    /// there (an acknowledgement, a reply) must not wait for presence on Zenoh's thread.
    static IN_CALLBACK: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

impl ZenohLink {
    /// Opens `config.local`'s session and starts delivering the frames put on its data key to
    /// `sink`. Fails within `open_timeout_ms` when a `connect` endpoint (a router) does not
    /// answer, naming it.
    pub fn open(
        config: ZenohLinkConfig,
        sink: Arc<dyn FrameSink>,
    ) -> Result<ZenohLink, ZenohOpenError> {
        let s = &config.settings;
        let local_name = config
            .systems
            .get(&config.local)
            .ok_or(ZenohOpenError::UnknownSystem(config.local))?
            .clone();
        validate_prefix(&s.prefix).map_err(|reason| ZenohOpenError::Setting {
            key: s.prefix.clone(),
            reason,
        })?;
        let session = config::open_session(s)?;
        let zerr = |what: &str| {
            let what = what.to_string();
            move |e: zenoh::Error| ZenohOpenError::Zenoh(format!("{what}: {e}"))
        };

        let names: HashMap<String, SystemId> = config
            .systems
            .iter()
            .map(|(id, n)| (n.clone(), *id))
            .collect();
        let presence = Arc::new(Presence::new(config.local));
        let live_prefix = format!("{}/live/", s.prefix);
        let follower = presence.clone();
        let events = sink.clone();
        let local = config.local;
        let live = session
            .liveliness()
            .declare_subscriber(format!("{}/live/*", s.prefix))
            .history(true)
            .callback(move |sample| {
                let key = sample.key_expr().as_str();
                let Some(id) = key.strip_prefix(&live_prefix).and_then(|n| names.get(n)) else {
                    return;
                };
                let seen = match sample.kind() {
                    zenoh::sample::SampleKind::Put => Seen::Present,
                    zenoh::sample::SampleKind::Delete => Seen::Left,
                };
                // Through the link seam: `PeerUp` sends what waited for the system at once,
                // `PeerDown` takes a pair with another transport off this one (failover).
                match follower.set(*id, seen) {
                    Some(PresenceEvent::Joined(id)) if id != local => {
                        events.on_event(LinkEvent::PeerUp(id))
                    }
                    Some(PresenceEvent::Left(id)) if id != local => {
                        events.on_event(LinkEvent::PeerDown(id))
                    }
                    _ => {}
                }
            })
            .wait()
            .map_err(zerr("liveliness subscriber"))?;

        // The subscriptions before the token: whoever sees the token can put to us.
        let counters = Arc::new(Counters::default());
        let on_sample = receiver(sink, counters.clone());
        let sub = session
            .declare_subscriber(data_key(&s.prefix, &local_name))
            .callback({
                let on_sample = on_sample.clone();
                move |sample| on_sample(sample)
            })
            .wait()
            .map_err(zerr("subscriber"))?;
        // Native broadcasts: put once on the `all` key, received by every system.
        let all = session
            .declare_subscriber(all_key(&s.prefix))
            .callback(move |sample| on_sample(sample))
            .wait()
            .map_err(zerr("broadcast subscriber"))?;
        let token = session
            .liveliness()
            .declare_token(live_key(&s.prefix, &local_name))
            .wait()
            .map_err(zerr("liveliness token"))?;

        let dest = |name: &str, key: String| Dest {
            name: name.to_string(),
            key,
            publishers: RwLock::new(None),
            last_put_us: AtomicU64::new(0),
            held: Mutex::new(Held::default()),
        };
        let mut dests: HashMap<SystemId, Dest> = config
            .systems
            .iter()
            .filter(|(id, _)| **id != config.local)
            .map(|(id, name)| (*id, dest(name, data_key(&s.prefix, name))))
            .collect();
        // Sends to TO_ALL_SYSTEM are broadcasts, unless a system of the fleet has that id
        // (then the link does not offer broadcasts, and that id names the system).
        let broadcast = !config.systems.contains_key(&TO_ALL_SYSTEM);
        if broadcast {
            dests.insert(TO_ALL_SYSTEM, dest("every system", all_key(&s.prefix)));
        }
        Ok(ZenohLink {
            session,
            local: config.local,
            prefix: s.prefix.clone(),
            dests,
            broadcast,
            presence,
            presence_timeout: Duration::from_millis(s.presence_timeout_ms as u64),
            counters,
            _token: token,
            _live: live,
            _sub: sub,
            _all: all,
        })
    }

    /// The system this link is for.
    pub fn local(&self) -> SystemId {
        self.local
    }

    /// The systems whose liveliness token this link sees now, by id.
    pub fn presence(&self) -> Vec<SystemId> {
        self.presence.present()
    }

    /// Systems joining and leaving from now on (tokens appearing and disappearing).
    pub fn presence_events(&self) -> PresenceEvents {
        self.presence.events()
    }

    /// This session's Zenoh id, as `zenoh` tools print it.
    pub fn zenoh_id(&self) -> String {
        self.session.zid().to_string()
    }

    /// The destination `to`, if a frame of `len` bytes may be put to it now (see the crate
    /// docs on presence).
    fn reachable(&self, to: SystemId, len: usize) -> Result<&Dest, LinkError> {
        if len > MAX_FRAME {
            return Err(LinkError::TooLarge {
                len,
                max: MAX_FRAME,
            });
        }
        let Some(dest) = self.dests.get(&to) else {
            return Err(LinkError::Unreachable {
                peer: to,
                reason: "not a system of this zenoh transport".into(),
            });
        };
        if to == TO_ALL_SYSTEM && self.broadcast {
            // Every system present receives it; the router follows up on those that miss it.
            return Ok(dest);
        }
        // On Zenoh's receiving thread (a sink answering a frame): never wait; a system never
        // seen gets the frame anyway (it has just sent us one, so it is probably there).
        let seen = match IN_CALLBACK.with(|c| c.get()) {
            true => match self.presence.peek(to) {
                Seen::Never => Seen::Present,
                seen => seen,
            },
            false => self.presence.wait_present(to, self.presence_timeout),
        };
        match seen {
            Seen::Present => {}
            Seen::Left => {
                return Err(LinkError::Unreachable {
                    peer: to,
                    reason: format!(
                        "{} is absent: its liveliness token `{}` is gone",
                        dest.name,
                        live_key(&self.prefix, &dest.name)
                    ),
                })
            }
            Seen::Never => {
                return Err(LinkError::Unreachable {
                    peer: to,
                    reason: format!(
                    "{} is not on the Zenoh network: its liveliness token `{}` has not been seen",
                    dest.name,
                    live_key(&self.prefix, &dest.name),
                ),
                })
            }
        }
        Ok(dest)
    }

    /// Puts `payload` (one frame or several back to back) on `dest`'s data key: `express`
    /// unless more frames follow right behind it ([`Put`]).
    fn put(
        &self,
        to: SystemId,
        dest: &Dest,
        payload: Vec<u8>,
        frames: u64,
        kind: Put,
    ) -> Result<(), LinkError> {
        let publishers = self.publishers(to, dest)?;
        let now = micros();
        let last = dest.last_put_us.swap(now, Ordering::Relaxed);
        let kind = match kind {
            Put::Last
                if payload.len() >= LARGE_FRAME && now.saturating_sub(last) < STREAM_GAP_US =>
            {
                Put::MoreFollow
            }
            kind => kind,
        };
        let publisher = match kind {
            Put::Last => &publishers.express,
            Put::MoreFollow => &publishers.batched,
        };
        if let Err(e) = publisher.put(payload).wait() {
            return Err(LinkError::Unreachable {
                peer: to,
                reason: format!("zenoh put to {}: {e}", dest.name),
            });
        }
        self.counters.sent.fetch_add(frames, Ordering::Relaxed);
        Ok(())
    }

    /// Puts what is held for `dest` now; the frames of a put that fails are counted dropped.
    fn put_held(
        &self,
        to: SystemId,
        dest: &Dest,
        held: &mut Held,
        kind: Put,
    ) -> Result<(), LinkError> {
        if held.frames == 0 {
            return Ok(());
        }
        let (put, frames) = held.take();
        let result = self.put(to, dest, put, frames, kind);
        if result.is_err() {
            self.counters.dropped.fetch_add(frames, Ordering::Relaxed);
        }
        result
    }

    fn publishers(&self, to: SystemId, dest: &Dest) -> Result<Arc<Publishers>, LinkError> {
        if let Some(p) = &*dest.publishers.read() {
            return Ok(p.clone());
        }
        let mut slot = dest.publishers.write();
        if let Some(p) = &*slot {
            return Ok(p.clone());
        }
        let locality = match to == TO_ALL_SYSTEM && self.broadcast {
            // A broadcast is for the other systems: this session does not hear its own.
            true => Locality::Remote,
            false => Locality::Any,
        };
        let declare = |express: bool| {
            self.session
                .declare_publisher(dest.key.clone())
                .congestion_control(CongestionControl::Block)
                .allowed_destination(locality)
                .express(express)
                .wait()
                .map_err(|e| LinkError::Unreachable {
                    peer: to,
                    reason: format!("zenoh publisher for {}: {e}", dest.name),
                })
        };
        let publishers = Arc::new(Publishers {
            express: declare(true)?,
            batched: declare(false)?,
        });
        *slot = Some(publishers.clone());
        Ok(publishers)
    }
}

impl Link for ZenohLink {
    fn caps(&self) -> LinkCaps {
        LinkCaps {
            max_frame: MAX_FRAME,
            mtu: UNSPLIT_FRAME,
            reliable: false,
            ordered: false,
            broadcast: self.broadcast,
        }
    }

    fn send(&self, to: SystemId, frame: &[u8]) -> Result<(), LinkError> {
        self.send_parts(to, frame, &[])
    }

    fn send_parts(&self, to: SystemId, head: &[u8], body: &[u8]) -> Result<(), LinkError> {
        let dest = self.reachable(to, head.len() + body.len())?;
        let mut held = dest.held.lock();
        if held.frames == 0 && !head.starts_with(&BATCH_MAGIC) {
            drop(held);
            // The one copy of the frame: Zenoh keeps the put's payload until it is sent.
            let mut frame = Vec::with_capacity(head.len() + body.len());
            frame.extend_from_slice(head);
            frame.extend_from_slice(body);
            return self.put(to, dest, frame, 1, Put::Last);
        }
        // After the frames held for the same destination, in the same put.
        held.push(head, body);
        self.put_held(to, dest, &mut held, Put::Last)
    }

    /// True: this build carries Zenoh over TCP only, whose checksummed connections deliver
    /// each Zenoh message whole and unaltered or not at all, hop by hop (through routers
    /// too), as the `tcp` transport's stream does. So frames may carry a header-only CRC
    /// (`FLAG_HEADER_CRC`) and large payloads go to [`Link::send_parts`] uncopied.
    fn checksums_payload(&self) -> bool {
        true
    }

    fn send_held(&self, to: SystemId, frame: &[u8]) -> Result<(), LinkError> {
        let dest = self.reachable(to, frame.len())?;
        let mut held = dest.held.lock();
        held.push(frame, &[]);
        if held.put.len() < HELD_MAX {
            return Ok(());
        }
        self.put_held(to, dest, &mut held, Put::MoreFollow)
    }

    fn flush(&self) -> Result<(), LinkError> {
        let mut first = Ok(());
        for (to, dest) in &self.dests {
            let mut held = dest.held.lock();
            let result = self.put_held(*to, dest, &mut held, Put::Last);
            if first.is_ok() {
                first = result;
            }
        }
        first
    }

    fn batches(&self) -> bool {
        true
    }

    fn stats(&self) -> LinkStats {
        LinkStats {
            frames_sent: self.counters.sent.load(Ordering::Relaxed),
            frames_received: self.counters.received.load(Ordering::Relaxed),
            frames_dropped: self.counters.dropped.load(Ordering::Relaxed),
            connects: self.presence.joins(),
            ..LinkStats::default()
        }
    }
}

impl Drop for ZenohLink {
    fn drop(&mut self) {
        self.presence.close();
        for dest in self.dests.values() {
            dest.publishers.write().take();
        }
        // Closing undeclares the token (others see this system leave) and the subscription.
        let _ = self.session.close().wait();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn held_frames_make_a_batch_and_a_lone_frame_goes_bare() {
        let mut held = Held::default();
        held.push(b"HCone", &[]);
        assert_eq!(held.take(), (b"HCone".to_vec(), 1));
        held.push(b"HC", b"two");
        held.push(b"", &[]);
        let (put, frames) = held.take();
        assert_eq!(frames, 2);
        let got: Vec<&[u8]> = batch_records(&put).unwrap().collect();
        assert_eq!(got, [&b"HCtwo"[..], &b""[..]]);
        // A lone frame that would read as a batch stays one.
        held.push(b"HBnot a batch", &[]);
        let (put, _) = held.take();
        let got: Vec<&[u8]> = batch_records(&put).unwrap().collect();
        assert_eq!(got, [&b"HBnot a batch"[..]]);
        assert_eq!(held.take(), (Vec::new(), 0));
    }
}
