//! The stream-link layer shared by every connection-oriented transport: TCP ([`crate::tcp`]),
//! Unix stream sockets ([`crate::unix`]) and, later, Bluetooth RFCOMM.
//!
//! A transport plugs in through three small traits: [`StreamSocket`] (a connected byte
//! stream), [`StreamListener`] (accepts connections) and [`StreamTransport`] (connects to an
//! address and says how a receiver learns who is on the other end). [`StreamLink`] does the
//! rest: framing, one cached outgoing connection per peer, reconnection with backoff, write
//! deadlines, a listener thread with one reader thread per accepted connection, statistics and
//! clean shutdown.
//!
//! # Connections
//!
//! Connections are one-way: system A sends to B over the connection A opened to B's listener,
//! and B sends to A over the connection B opened to A's. The acceptor never writes. This keeps
//! each direction's ordering and failure handling independent, and is what makes "one
//! outgoing connection per peer, opened on first send" simple.
//!
//! # Byte format
//!
//! All integers are little-endian.
//!
//! **Hello** (only in [`IdentityMode::Hello`]): the connector's first 8 bytes on a new
//! connection.
//!
//! | offset | size | field |
//! |---|---|---|
//! | 0 | 2 | magic `"HL"` |
//! | 2 | 1 | version, 1 |
//! | 3 | 1 | reserved, 0 |
//! | 4 | 2 | the connecting system's [`SystemId`] |
//! | 6 | 2 | reserved, 0 |
//!
//! **Record**: each frame is preceded by an 8-byte record header.
//!
//! | offset | size | field |
//! |---|---|---|
//! | 0 | 2 | magic `"HR"` |
//! | 2 | 1 | version, 1 |
//! | 3 | 1 | reserved, 0 |
//! | 4 | 4 | frame length in bytes (u32) |
//!
//! followed by exactly that many frame bytes. The reader checks the magic, version and
//! reserved byte and compares the length against its own `max_frame` *before* it allocates;
//! any failure means the stream is desynchronised, so the reader counts a dropped frame and
//! closes that connection (other connections are not affected).
//!
//! Why a record header rather than the 48-byte frame header's own length field
//! ([`hetcomm_core::wire::peek_frame_len`]): a [`Link`] carries whatever bytes the router hands
//! it, and the conformance suite sends frames of 1 byte and frames that are not wire frames at
//! all. Framing on the record header keeps the link content-agnostic at a cost of 8 bytes per
//! frame; the magic still catches a desynchronised stream at the first bad record.
//!
//! # Identity
//!
//! How the receiver labels a connection's frames is the transport's [`IdentityMode`]:
//! - [`IdentityMode::Hello`] (TCP, Unix sockets): the connector sends the hello above; the
//!   receiver reads it (within [`StreamConfig::hello_timeout`]) and labels every frame of that
//!   connection [`Peer::System`]. The hello is a label, not authentication.
//! - [`IdentityMode::Address`] (RFCOMM, where the remote device address names the system):
//!   no hello; [`StreamTransport::peer_identity`] maps the accepted address to a system.
//! - [`IdentityMode::Anonymous`]: no hello; frames are labelled [`Peer::Unknown`] and the
//!   router relies on the frame header.
//!
//! In the first two modes a connection from a system that is not in the fleet (a hello naming
//! an unknown system, a malformed hello, an address with no system) is closed before any frame
//! is read, and counted as one dropped frame and one rejected connection.
//!
//! # Failures and backpressure
//!
//! - A send never waits for a connection to be made: the first send to a peer queues its
//!   frame and starts a connector thread (connect within [`StreamConfig::connect_timeout`],
//!   which for Bluetooth is seconds); later sends queue behind it, up to
//!   [`StreamConfig::connect_queue_frames`] frames (then [`LinkError::Congested`]). When the
//!   connection is up the queue is written in order. A failed connect drops the queued frames
//!   (counted in [`StreamStats::frames_lost_connecting`]; the router's acknowledgements
//!   retransmit them) and starts an exponential backoff ([`StreamConfig::backoff_initial`]
//!   doubling up to [`StreamConfig::backoff_max`]); sends during the backoff fail at once with
//!   `Unreachable` and a reason such as
//!   `"reconnecting in 80 ms after: connection refused (os error 111)"`. A successful connect
//!   resets the backoff.
//! - A send blocks at most [`StreamConfig::write_timeout`] writing its frame. If the peer does
//!   not take the bytes in time the send fails with [`LinkError::Congested`]; any other write
//!   error fails with [`LinkError::Unreachable`]. Either way the connection is dropped (a
//!   partly written frame would desynchronise it) and the next send reconnects at once.
//! - A frame written into the kernel just before the peer died can be lost without an error
//!   (TCP reports the reset on a later write). The link does not retry: acknowledgements and
//!   retries are the router's.

use std::collections::BTreeMap;
use std::fmt;
use std::io::{self, IoSlice, Read, Write};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use hetcomm_core::wire::{HEADER_LEN, MAX_PAYLOAD};
use hetcomm_core::SystemId;
use hetcomm_link::{FrameSink, Link, LinkCaps, LinkError, LinkStats, Peer};

/// Size of the hello a connector sends in [`IdentityMode::Hello`].
pub const HELLO_LEN: usize = 8;
/// Magic of the hello: `"HL"`.
pub const HELLO_MAGIC: [u8; 2] = *b"HL";
/// Size of the record header in front of every frame.
pub const RECORD_HEADER_LEN: usize = 8;
/// Magic of the record header: `"HR"`.
pub const RECORD_MAGIC: [u8; 2] = *b"HR";
/// Version of the hello and record formats.
pub const STREAM_VERSION: u8 = 1;

/// A connected byte stream a [`StreamLink`] reads or writes frames on.
pub trait StreamSocket: Read + Write + Send + Sized + 'static {
    /// A second handle to the same connection; the link keeps one to shut the connection down
    /// from another thread.
    fn try_clone(&self) -> io::Result<Self>;
    /// Shuts both directions down, so that a read blocked on another thread returns.
    fn shutdown_both(&self) -> io::Result<()>;
    /// Bounds each blocking write (`None`: no bound).
    fn set_write_timeout(&self, timeout: Option<Duration>) -> io::Result<()>;
    /// Bounds each blocking read (`None`: no bound).
    fn set_read_timeout(&self, timeout: Option<Duration>) -> io::Result<()>;
}

/// A bound, listening socket that accepts [`StreamSocket`]s.
pub trait StreamListener: Send + Sync + 'static {
    /// The sockets it accepts.
    type Socket: StreamSocket;
    /// The remote address of an accepted connection.
    type PeerAddr: fmt::Debug + Send + 'static;
    /// Blocks until a connection arrives.
    fn accept(&self) -> io::Result<(Self::Socket, Self::PeerAddr)>;
    /// Makes an `accept` blocked on another thread return (with a connection or an error). The
    /// link sets its closing flag first, so whatever `accept` returns then is discarded.
    fn wake(&self);
}

/// How a receiver learns which system is on the other end of an accepted connection.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum IdentityMode {
    /// The connector sends a hello naming its system (see the module docs).
    Hello,
    /// The accepted connection's remote address names the system
    /// ([`StreamTransport::peer_identity`]); no hello is sent.
    Address,
    /// Nobody says; frames are labelled [`Peer::Unknown`].
    Anonymous,
}

/// A connection-oriented transport: how to connect, and how peers are identified.
pub trait StreamTransport: Send + Sync + 'static {
    /// The connected stream type.
    type Socket: StreamSocket;
    /// The listener type, accepting the same stream type.
    type Listener: StreamListener<Socket = Self::Socket>;
    /// Where a peer listens (shown in error reasons).
    type Addr: fmt::Display + Send + Sync + 'static;

    /// A short name for thread names and error reasons, e.g. `"tcp"`.
    const NAME: &'static str;

    /// Connects to `addr`, giving up after `timeout`.
    fn connect(&self, addr: &Self::Addr, timeout: Duration) -> io::Result<Self::Socket>;

    /// Sets per-connection options on a new connection of either side (e.g. `TCP_NODELAY`).
    fn configure(&self, _socket: &Self::Socket) -> io::Result<()> {
        Ok(())
    }

    /// How receivers learn the sender's system.
    fn identity_mode(&self) -> IdentityMode {
        IdentityMode::Hello
    }

    /// In [`IdentityMode::Address`], the system behind an accepted connection's address
    /// (`None`: not a fleet system, the connection is refused).
    fn peer_identity(
        &self,
        _addr: &<Self::Listener as StreamListener>::PeerAddr,
    ) -> Option<SystemId> {
        None
    }
}

/// Tunables of a [`StreamLink`]. `Default` gives values suited to a LAN.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct StreamConfig {
    /// How long a connect may take before the send fails (default 2 s).
    pub connect_timeout: Duration,
    /// How long one send may block writing its frame before it fails with
    /// [`LinkError::Congested`] (default 2 s).
    pub write_timeout: Duration,
    /// How long an accepted connection may take to send its hello (default 5 s).
    pub hello_timeout: Duration,
    /// Delay before the first reconnect attempt after a failed connect (default 10 ms).
    pub backoff_initial: Duration,
    /// The backoff doubles per failed connect up to this (default 1 s).
    pub backoff_max: Duration,
    /// Frames a peer's queue holds while its connection is being made (default 1024).
    pub connect_queue_frames: usize,
    /// Largest message payload accepted, bytes; `None`: the codec's limit
    /// ([`MAX_PAYLOAD`]). Frames may be this plus the 48-byte header. Larger values than
    /// the codec's limit are capped to it.
    pub max_message_bytes: Option<usize>,
}

impl Default for StreamConfig {
    fn default() -> Self {
        StreamConfig {
            connect_timeout: Duration::from_secs(2),
            write_timeout: Duration::from_secs(2),
            hello_timeout: Duration::from_secs(5),
            backoff_initial: Duration::from_millis(10),
            backoff_max: Duration::from_secs(1),
            connect_queue_frames: 1024,
            max_message_bytes: None,
        }
    }
}

impl StreamConfig {
    /// The largest frame (header + payload) this configuration accepts, on send and receive.
    pub fn max_frame(&self) -> usize {
        HEADER_LEN
            + self
                .max_message_bytes
                .unwrap_or(MAX_PAYLOAD)
                .min(MAX_PAYLOAD)
    }
}

/// Counters of a [`StreamLink`]; [`Link::stats`] reports the subset [`LinkStats`] has.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct StreamStats {
    /// Frames fully written by `send`.
    pub frames_sent: u64,
    /// Frames handed to the sink.
    pub frames_received: u64,
    /// Frames dropped on receive: desynchronised or oversized records, frames cut short by a
    /// closed connection, and rejected connections (one each).
    pub frames_dropped: u64,
    /// Outgoing connections established.
    pub connects: u64,
    /// Connections accepted by the listener.
    pub accepted: u64,
    /// Accepted connections closed because their sender is not a fleet system (or sent a
    /// malformed hello).
    pub rejected_connections: u64,
    /// Sends that failed after a connection was up (write errors and write timeouts).
    pub write_failures: u64,
    /// Frames queued while connecting whose connection then failed (never sent).
    pub frames_lost_connecting: u64,
}

#[derive(Default)]
struct Counters {
    frames_sent: AtomicU64,
    frames_received: AtomicU64,
    frames_dropped: AtomicU64,
    connects: AtomicU64,
    accepted: AtomicU64,
    rejected_connections: AtomicU64,
    write_failures: AtomicU64,
    frames_lost_connecting: AtomicU64,
}

fn bump(c: &AtomicU64) {
    c.fetch_add(1, Ordering::Relaxed);
}

/// A peer's address and its outgoing-connection state, locked per peer so that senders to
/// different peers never wait for each other.
struct PeerEntry<T: StreamTransport> {
    addr: T::Addr,
    slot: Mutex<PeerSlot<T::Socket>>,
}

/// What the link remembers about one peer's outgoing connection.
struct PeerSlot<S> {
    conn: Option<S>,
    backoff: Option<Backoff>,
    /// A connector thread is making the connection.
    connecting: bool,
    /// Frames waiting for that connection, in send order.
    queue: std::collections::VecDeque<Vec<u8>>,
}

struct Backoff {
    retry_at: Instant,
    delay: Duration,
    reason: String,
}

/// State shared by the link, its listener thread and its reader threads.
struct Shared<T: StreamTransport> {
    transport: T,
    sink: Arc<dyn FrameSink>,
    config: StreamConfig,
    /// Every fleet system other than this one (used to vet hellos).
    fleet: BTreeMap<SystemId, ()>,
    closing: AtomicBool,
    counters: Counters,
    readers: Mutex<Vec<Reader<T::Socket>>>,
}

struct Reader<S> {
    /// A second handle, to unblock the reader at shutdown.
    socket: S,
    handle: JoinHandle<()>,
}

fn lock<X>(m: &Mutex<X>) -> MutexGuard<'_, X> {
    // A panic in a sink must not wedge the whole link: the data under these locks stays
    // consistent between statements, so a poisoned lock is still usable.
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// A [`Link`] over any [`StreamTransport`]: see the module docs for its behaviour.
pub struct StreamLink<T: StreamTransport> {
    local: SystemId,
    shared: Arc<Shared<T>>,
    listener: Arc<T::Listener>,
    peers: Arc<BTreeMap<SystemId, PeerEntry<T>>>,
    accept_thread: Option<JoinHandle<()>>,
}

impl<T: StreamTransport> StreamLink<T> {
    /// Starts a link for system `local` that accepts on `listener` and connects to the
    /// addresses in `peers` (an entry for `local` itself is ignored). Received frames go to
    /// `sink`. Fails only if the listener thread cannot be started.
    pub fn new(
        transport: T,
        local: SystemId,
        listener: T::Listener,
        peers: BTreeMap<SystemId, T::Addr>,
        sink: Arc<dyn FrameSink>,
        config: StreamConfig,
    ) -> io::Result<StreamLink<T>> {
        let peers: BTreeMap<_, _> = peers
            .into_iter()
            .filter(|(id, _)| *id != local)
            .map(|(id, addr)| {
                let slot = PeerSlot {
                    conn: None,
                    backoff: None,
                    connecting: false,
                    queue: std::collections::VecDeque::new(),
                };
                (
                    id,
                    PeerEntry {
                        addr,
                        slot: Mutex::new(slot),
                    },
                )
            })
            .collect();
        let shared = Arc::new(Shared {
            transport,
            sink,
            config,
            fleet: peers.keys().map(|id| (*id, ())).collect(),
            closing: AtomicBool::new(false),
            counters: Counters::default(),
            readers: Mutex::new(Vec::new()),
        });
        let listener = Arc::new(listener);
        let accept_thread = {
            let shared = shared.clone();
            let listener = listener.clone();
            std::thread::Builder::new()
                .name(format!("hetcomm-{}-accept-{local}", T::NAME))
                .spawn(move || accept_loop(&shared, &listener))?
        };
        Ok(StreamLink {
            local,
            shared,
            listener,
            peers: Arc::new(peers),
            accept_thread: Some(accept_thread),
        })
    }

    /// The system this link belongs to.
    pub fn local(&self) -> SystemId {
        self.local
    }

    /// The listener this link accepts on (e.g. to read its bound address).
    pub fn listener(&self) -> &T::Listener {
        &self.listener
    }

    /// All counters, including those [`LinkStats`] has no field for.
    pub fn stream_stats(&self) -> StreamStats {
        let c = &self.shared.counters;
        let get = |a: &AtomicU64| a.load(Ordering::Relaxed);
        StreamStats {
            frames_sent: get(&c.frames_sent),
            frames_received: get(&c.frames_received),
            frames_dropped: get(&c.frames_dropped),
            connects: get(&c.connects),
            accepted: get(&c.accepted),
            rejected_connections: get(&c.rejected_connections),
            write_failures: get(&c.write_failures),
            frames_lost_connecting: get(&c.frames_lost_connecting),
        }
    }

    /// Starts a connector thread for `to` (its slot is already marked `connecting`).
    fn start_connector(&self, to: SystemId) -> io::Result<()> {
        let shared = self.shared.clone();
        let peers = self.peers.clone();
        let local = self.local;
        std::thread::Builder::new()
            .name(format!("hetcomm-{}-connect-{to}", T::NAME))
            .spawn(move || {
                if let Some(entry) = peers.get(&to) {
                    run_connector(&shared, local, entry);
                }
            })
            .map(|_| ())
    }
}

/// Opens a connection to `addr` and sends the hello if the transport uses one.
fn connect<T: StreamTransport>(
    shared: &Shared<T>,
    local: SystemId,
    addr: &T::Addr,
) -> io::Result<T::Socket> {
    let cfg = &shared.config;
    let mut socket = shared.transport.connect(addr, cfg.connect_timeout)?;
    shared.transport.configure(&socket)?;
    socket.set_write_timeout(Some(cfg.write_timeout))?;
    if shared.transport.identity_mode() == IdentityMode::Hello {
        socket.write_all(&encode_hello(local))?;
    }
    Ok(socket)
}

/// The connector thread: makes the connection without holding the peer's lock (senders keep
/// queueing meanwhile), then installs it and writes the queued frames in order, or drops them
/// and starts the backoff.
fn run_connector<T: StreamTransport>(shared: &Shared<T>, local: SystemId, entry: &PeerEntry<T>) {
    let result = connect(shared, local, &entry.addr);
    let mut slot = lock(&entry.slot);
    slot.connecting = false;
    if shared.closing.load(Ordering::SeqCst) {
        return;
    }
    let error = match result {
        Ok(mut socket) => {
            bump(&shared.counters.connects);
            let mut failed = None;
            while let Some(frame) = slot.queue.pop_front() {
                match write_record(&mut socket, &frame, shared.config.write_timeout) {
                    Ok(()) => bump(&shared.counters.frames_sent),
                    Err(e) => {
                        bump(&shared.counters.write_failures);
                        failed = Some(e);
                        break;
                    }
                }
            }
            match failed {
                None => {
                    slot.conn = Some(socket);
                    slot.backoff = None;
                    return;
                }
                Some(e) => {
                    let _ = socket.shutdown_both();
                    e
                }
            }
        }
        Err(e) => e,
    };
    let lost = slot.queue.len() as u64;
    slot.queue.clear();
    shared
        .counters
        .frames_lost_connecting
        .fetch_add(lost, Ordering::Relaxed);
    let cfg = &shared.config;
    let delay = match &slot.backoff {
        Some(b) => (b.delay * 2).min(cfg.backoff_max),
        None => cfg.backoff_initial,
    };
    slot.backoff = Some(Backoff {
        retry_at: Instant::now() + delay,
        delay,
        reason: format!("{} connect to {} failed: {error}", T::NAME, entry.addr),
    });
}

impl<T: StreamTransport> StreamLink<T> {
    /// The capabilities a stream link with `config` declares.
    pub fn caps_for(config: &StreamConfig) -> LinkCaps {
        let max = config.max_frame();
        LinkCaps {
            max_frame: max,
            mtu: max,
            reliable: true,
            ordered: true,
            broadcast: false,
        }
    }
}

impl<T: StreamTransport> Link for StreamLink<T> {
    fn caps(&self) -> LinkCaps {
        Self::caps_for(&self.shared.config)
    }

    fn send(&self, to: SystemId, frame: &[u8]) -> Result<(), LinkError> {
        let max = self.shared.config.max_frame();
        if frame.len() > max {
            return Err(LinkError::TooLarge {
                len: frame.len(),
                max,
            });
        }
        let Some(PeerEntry { addr, slot }) = self.peers.get(&to) else {
            let reason = if to == self.local {
                "it is this system itself".to_string()
            } else {
                format!("system {to} has no endpoint on this {} link", T::NAME)
            };
            return Err(LinkError::Unreachable { peer: to, reason });
        };
        let mut slot = lock(slot);
        if slot.conn.is_none() {
            let now = Instant::now();
            if let Some(b) = &slot.backoff {
                if now < b.retry_at {
                    let left = b.retry_at - now;
                    return Err(LinkError::Unreachable {
                        peer: to,
                        reason: format!(
                            "reconnecting in {} ms after: {}",
                            left.as_millis().max(1),
                            b.reason
                        ),
                    });
                }
            }
            // Never wait for a connect on the caller's thread: queue behind a connector.
            if slot.queue.len() >= self.shared.config.connect_queue_frames {
                return Err(LinkError::Congested {
                    peer: to,
                    reason: format!(
                        "{} frames already wait for the connection to {addr}",
                        slot.queue.len()
                    ),
                });
            }
            slot.queue.push_back(frame.to_vec());
            if !slot.connecting {
                slot.connecting = true;
                if let Err(e) = self.start_connector(to) {
                    slot.connecting = false;
                    slot.queue.clear();
                    return Err(LinkError::Io(e));
                }
            }
            return Ok(());
        }
        let Some(socket) = slot.conn.as_mut() else {
            // Unreachable by construction (set just above); fail soft rather than panic.
            return Err(LinkError::Closed);
        };
        match write_record(socket, frame, self.shared.config.write_timeout) {
            Ok(()) => {
                bump(&self.shared.counters.frames_sent);
                Ok(())
            }
            Err(e) => {
                // The frame may be half written: this connection can no longer be framed.
                if let Some(s) = slot.conn.take() {
                    let _ = s.shutdown_both();
                }
                bump(&self.shared.counters.write_failures);
                let ms = self.shared.config.write_timeout.as_millis();
                if matches!(
                    e.kind(),
                    io::ErrorKind::WouldBlock | io::ErrorKind::TimedOut
                ) {
                    Err(LinkError::Congested {
                        peer: to,
                        reason: format!(
                            "{addr} did not take the frame within the {ms} ms write timeout; \
                             connection dropped"
                        ),
                    })
                } else {
                    Err(LinkError::Unreachable {
                        peer: to,
                        reason: format!(
                            "write to {addr} failed: {e}; connection dropped, the next send \
                             reconnects"
                        ),
                    })
                }
            }
        }
    }

    fn stats(&self) -> LinkStats {
        let s = self.stream_stats();
        LinkStats {
            frames_sent: s.frames_sent,
            frames_received: s.frames_received,
            frames_dropped: s.frames_dropped,
            connects: s.connects,
            buffered_bytes: 0,
        }
    }
}

impl<T: StreamTransport> Drop for StreamLink<T> {
    fn drop(&mut self) {
        self.shared.closing.store(true, Ordering::SeqCst);
        self.listener.wake();
        if let Some(h) = self.accept_thread.take() {
            let _ = h.join();
        }
        // The accept thread is gone, so no reader can be added any more.
        let readers = std::mem::take(&mut *lock(&self.shared.readers));
        for r in &readers {
            let _ = r.socket.shutdown_both();
        }
        for r in readers {
            let _ = r.handle.join();
        }
        for peer in self.peers.values() {
            if let Some(s) = lock(&peer.slot).conn.take() {
                let _ = s.shutdown_both();
            }
        }
    }
}

/// Writes the record header and `frame` as one vectored write where possible, bounded by
/// `timeout` in total (the socket's own timeout bounds each call; it is shortened after a
/// partial write so the sum stays within `timeout`).
fn write_record<S: StreamSocket>(
    socket: &mut S,
    frame: &[u8],
    timeout: Duration,
) -> io::Result<()> {
    let len = u32::try_from(frame.len())
        .map_err(|_| io::Error::new(io::ErrorKind::InvalidInput, "frame over 4 GiB"))?;
    let mut head = [0u8; RECORD_HEADER_LEN];
    head[0..2].copy_from_slice(&RECORD_MAGIC);
    head[2] = STREAM_VERSION;
    head[4..8].copy_from_slice(&len.to_le_bytes());
    let total = RECORD_HEADER_LEN + frame.len();
    let deadline = Instant::now() + timeout;
    let mut done = 0;
    let mut shortened = false;
    while done < total {
        let result = if done < RECORD_HEADER_LEN {
            socket.write_vectored(&[IoSlice::new(&head[done..]), IoSlice::new(frame)])
        } else {
            socket.write(&frame[done - RECORD_HEADER_LEN..])
        };
        match result {
            Ok(0) => return Err(io::ErrorKind::WriteZero.into()),
            Ok(n) => done += n,
            Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
            Err(e) => return Err(e),
        }
        if done < total {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Err(io::ErrorKind::TimedOut.into());
            }
            socket.set_write_timeout(Some(left))?;
            shortened = true;
        }
    }
    if shortened {
        socket.set_write_timeout(Some(timeout))?;
    }
    Ok(())
}

/// Encodes the hello of system `id`.
pub fn encode_hello(id: SystemId) -> [u8; HELLO_LEN] {
    let mut h = [0u8; HELLO_LEN];
    h[0..2].copy_from_slice(&HELLO_MAGIC);
    h[2] = STREAM_VERSION;
    h[4..6].copy_from_slice(&id.0.to_le_bytes());
    h
}

/// Decodes a hello; `None` if it is not one this version writes.
pub fn decode_hello(h: &[u8; HELLO_LEN]) -> Option<SystemId> {
    let ok = h[0..2] == HELLO_MAGIC && h[2] == STREAM_VERSION && h[3] == 0 && h[6..8] == [0, 0];
    ok.then(|| SystemId(u16::from_le_bytes([h[4], h[5]])))
}

/// Checks a record header against `max_frame` and returns the frame length it announces.
pub fn decode_record_header(h: &[u8; RECORD_HEADER_LEN], max_frame: usize) -> Option<usize> {
    if h[0..2] != RECORD_MAGIC || h[2] != STREAM_VERSION || h[3] != 0 {
        return None;
    }
    let len = u32::from_le_bytes([h[4], h[5], h[6], h[7]]) as usize;
    (len <= max_frame).then_some(len)
}

fn accept_loop<T: StreamTransport>(shared: &Arc<Shared<T>>, listener: &T::Listener) {
    let mut next_id = 0u64;
    loop {
        let accepted = listener.accept();
        if shared.closing.load(Ordering::SeqCst) {
            return;
        }
        let (socket, addr) = match accepted {
            Ok(x) => x,
            Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
            Err(_) => {
                // Typically EMFILE or an aborted handshake. Pause briefly so a persistent error
                // (out of file descriptors) does not spin a core; the error is per attempt.
                std::thread::sleep(Duration::from_millis(10));
                continue;
            }
        };
        bump(&shared.counters.accepted);
        reap_finished(shared);
        let Ok(handle_copy) = socket.try_clone() else {
            continue;
        };
        next_id += 1;
        let thread_shared = shared.clone();
        let spawned = std::thread::Builder::new()
            .name(format!("hetcomm-{}-rx-{next_id}", T::NAME))
            .spawn(move || serve_connection(&thread_shared, socket, addr));
        if let Ok(handle) = spawned {
            lock(&shared.readers).push(Reader {
                socket: handle_copy,
                handle,
            });
        }
    }
}

/// Joins reader threads whose connections have ended, so their entries do not pile up.
fn reap_finished<T: StreamTransport>(shared: &Shared<T>) {
    let finished: Vec<_> = {
        let mut readers = lock(&shared.readers);
        let (done, live): (Vec<_>, Vec<_>) = std::mem::take(&mut *readers)
            .into_iter()
            .partition(|r| r.handle.is_finished());
        *readers = live;
        done
    };
    for r in finished {
        let _ = r.handle.join();
    }
}

/// Reads `buf.len()` bytes unless the stream ends first; returns how many were read.
fn read_full<R: Read>(r: &mut R, buf: &mut [u8]) -> io::Result<usize> {
    let mut got = 0;
    while got < buf.len() {
        match r.read(&mut buf[got..]) {
            Ok(0) => break,
            Ok(n) => got += n,
            Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
            Err(e) => return Err(e),
        }
    }
    Ok(got)
}

/// Establishes who is on the other end of an accepted connection, per the identity mode.
fn identify<T: StreamTransport>(
    shared: &Shared<T>,
    socket: &mut T::Socket,
    addr: &<T::Listener as StreamListener>::PeerAddr,
) -> Option<Peer> {
    let in_fleet = |id: SystemId| shared.fleet.contains_key(&id).then_some(Peer::System(id));
    match shared.transport.identity_mode() {
        IdentityMode::Anonymous => Some(Peer::Unknown),
        IdentityMode::Address => shared.transport.peer_identity(addr).and_then(in_fleet),
        IdentityMode::Hello => {
            socket
                .set_read_timeout(Some(shared.config.hello_timeout))
                .ok()?;
            let mut hello = [0u8; HELLO_LEN];
            let got = read_full(socket, &mut hello).ok()?;
            if got < HELLO_LEN {
                return None;
            }
            socket.set_read_timeout(None).ok()?;
            decode_hello(&hello).and_then(in_fleet)
        }
    }
}

/// The reader thread of one accepted connection.
fn serve_connection<T: StreamTransport>(
    shared: &Shared<T>,
    mut socket: T::Socket,
    addr: <T::Listener as StreamListener>::PeerAddr,
) {
    let counters = &shared.counters;
    let _ = shared.transport.configure(&socket);
    let Some(from) = identify(shared, &mut socket, &addr) else {
        if !shared.closing.load(Ordering::SeqCst) {
            bump(&counters.rejected_connections);
            bump(&counters.frames_dropped);
        }
        let _ = socket.shutdown_both();
        return;
    };
    let max_frame = shared.config.max_frame();
    let mut buf = Vec::new();
    loop {
        let mut head = [0u8; RECORD_HEADER_LEN];
        let got = match read_full(&mut socket, &mut head) {
            Ok(n) => n,
            Err(_) => break,
        };
        if got == 0 {
            break; // clean end of stream between records
        }
        let len = match (got == RECORD_HEADER_LEN)
            .then(|| decode_record_header(&head, max_frame))
            .flatten()
        {
            Some(len) => len,
            None => {
                // Truncated, desynchronised or oversized: nothing after this can be trusted.
                bump(&counters.frames_dropped);
                break;
            }
        };
        // Keep one buffer per connection, but do not pin a huge one after a rare big frame.
        if buf.capacity() > 4 * 1024 * 1024 && len < 64 * 1024 {
            buf = Vec::new();
        }
        buf.clear();
        buf.resize(len, 0);
        match read_full(&mut socket, &mut buf) {
            Ok(n) if n == len => {}
            _ => {
                if !shared.closing.load(Ordering::SeqCst) {
                    bump(&counters.frames_dropped);
                }
                break;
            }
        }
        // Counted first so that whoever the sink wakes sees the counter already updated.
        bump(&counters.frames_received);
        shared.sink.on_frame(&buf, from);
    }
    let _ = socket.shutdown_both();
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hello_round_trips_and_rejects_noise() {
        let h = encode_hello(SystemId(513));
        assert_eq!(decode_hello(&h), Some(SystemId(513)));
        let mut bad = h;
        bad[0] = b'X';
        assert_eq!(decode_hello(&bad), None);
        let mut bad = h;
        bad[2] = 9;
        assert_eq!(decode_hello(&bad), None);
        let mut bad = h;
        bad[7] = 1;
        assert_eq!(decode_hello(&bad), None);
    }

    #[test]
    fn record_header_is_checked_before_use() {
        let mut h = [0u8; RECORD_HEADER_LEN];
        h[0..2].copy_from_slice(&RECORD_MAGIC);
        h[2] = STREAM_VERSION;
        h[4..8].copy_from_slice(&100u32.to_le_bytes());
        assert_eq!(decode_record_header(&h, 100), Some(100));
        assert_eq!(decode_record_header(&h, 99), None);
        h[4..8].copy_from_slice(&u32::MAX.to_le_bytes());
        assert_eq!(
            decode_record_header(&h, StreamConfig::default().max_frame()),
            None
        );
        h[0] = b'H';
        h[1] = b'C';
        assert_eq!(decode_record_header(&h, usize::MAX), None);
    }

    #[test]
    fn max_frame_follows_max_message_bytes() {
        let mut c = StreamConfig::default();
        assert_eq!(c.max_frame(), HEADER_LEN + MAX_PAYLOAD);
        c.max_message_bytes = Some(1000);
        assert_eq!(c.max_frame(), HEADER_LEN + 1000);
        c.max_message_bytes = Some(usize::MAX);
        assert_eq!(c.max_frame(), HEADER_LEN + MAX_PAYLOAD);
    }
}
