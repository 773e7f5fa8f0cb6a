//! The stream-link layer shared by every connection-oriented transport: TCP ([`crate::tcp`]),
//! Unix stream sockets ([`crate::unix`]) and Bluetooth RFCOMM (`hetcomm-link-bluetooth`).
//!
//! A transport plugs in through three small traits: [`StreamSocket`] (a connected byte
//! stream), [`StreamListener`] (accepts connections) and [`StreamTransport`] (connects to an
//! address and says how a receiver learns who is on the other end). [`StreamLink`] does the
//! rest: framing, one cached outgoing connection per peer, reconnection with backoff, write
//! deadlines, batching of held frames, receiving on one poller thread (not a thread per
//! connection), a bound on accepted connections, statistics and clean shutdown.
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
//! # Sending and batching
//!
//! [`Link::send`] writes the record header and the frame with one vectored write, straight
//! from the caller's buffer (no copy in user space), on the caller's thread.
//!
//! [`Link::send_held`] instead appends the record to the peer's outgoing batch, a reused
//! buffer of at most [`StreamConfig::batch_bytes`] (64 KiB by default), so that many small
//! frames leave in one write. The batch goes out, always before any later frame to that peer:
//! - when the next frame would not fit: the batch is written first, then the frame is held
//!   (a frame larger than the whole batch is written right after the batch, in the same
//!   vectored write);
//! - at the next plain `send` to that peer, in the same vectored write as the new frame;
//! - at [`Link::flush`], which writes every peer's batch. A batch that fails to write is
//!   counted in [`StreamStats::held_frames_dropped`] (part of [`LinkStats::frames_dropped`])
//!   and `flush` returns the first error. With nothing held, `flush` only reads an atomic flag;
//! - when the link is dropped (a best-effort flush).
//!
//! Holding is cheap: one uncontended lock and one copy of the frame per `send_held`, no
//! allocation once the batch buffer has grown. [`Link::batches`] is true unless
//! `batch_bytes` is 0 (then `send_held` writes at once, like `send`).
//!
//! Held frames to a peer whose connection is still being made wait with the frames queued for
//! it (below), in send order: the connector writes the frames that were sent or flushed as soon
//! as the connection is up, and leaves the ones still held in the batch.
//!
//! # Receiving
//!
//! A listener that can be polled ([`StreamListener::raw_fd`]: TCP and Unix sockets) is served
//! by one poller thread per link, whatever the number of connections: it accepts, reads each
//! connection's hello without blocking (a connection waiting for its hello costs a descriptor
//! and a few bytes, no thread), and reads the records of identified connections, all through
//! one `epoll` instance. A connection whose peer closes is closed as soon as its end of stream
//! is read, so its descriptor does not outlive the peer's. Frames are handed to the sink on
//! that thread, one connection after the other (at most 64 records of one connection before
//! the others get their turn), so a sink that blocks delays every connection of the link.
//! Listeners that cannot be polled (RFCOMM) keep an accept thread and a reader thread per
//! connection; that thread's descriptors are closed when the connection ends.
//!
//! Each connection has a 64 KiB read buffer, allocated when its first record arrives (an
//! idle connection holds none). Small records are read through it, as many per read as have
//! arrived, and handed to the sink straight from the buffer. A frame larger than 16 KiB that
//! is not already in the buffer is read directly into a reused buffer of its own size (the
//! bytes already buffered are copied once; after a large frame the reader reads at most 1 KiB
//! ahead into its buffer, so a run of large frames costs almost no copy in user space). A
//! record interrupted by an empty socket is resumed when more bytes arrive. Nothing is
//! allocated per frame in steady state, unless the sink keeps frames
//! ([`FrameSink::takes_frames`], as the runtime's does): then each such large frame is read
//! into a fresh buffer of exactly its size (not zero-filled first when the socket offers
//! [`StreamSocket::raw_fd`]) and handed over with [`FrameSink::on_frame_owned`], so that it
//! becomes the message's payload without a copy. Those buffers come from a pool per
//! connection ([`BufferPool`], up to 8 MiB) and go back to it when the sink drops them, so
//! that a steady stream of large frames allocates nothing either.
//!
//! # Connection limits
//!
//! At most [`StreamConfig::max_connections`] accepted connections (256 by default) are open
//! at once, counting those still waiting for their hello. A connection beyond that is accepted
//! and closed at once, counted in [`StreamStats::refused_connections`] and as one dropped
//! frame (what its sender wrote on it is lost). [`StreamStats::open_connections`] says how
//! many are open now. A connection that has not sent its whole hello within
//! [`StreamConfig::hello_timeout`] is closed and counted as rejected (below), so idle
//! connections cannot hold the slots for long.
//!
//! # Driven receive
//!
//! With [`StreamConfig::driven`] (what the runtime uses for TCP) the poller thread only
//! accepts and reads hellos. Identified connections are registered with one `epoll` instance
//! per link, and [`Link::readable`] offers that descriptor: whoever calls
//! [`Readable::read_ready`] (in the runtime, the module waiting for a message) reads every
//! connection that has bytes, up to the budget of records each plus whatever records are
//! already buffered, and closes connections that ended. Nothing is received until someone
//! calls it. Ends of streams are counted as without `driven`. Sockets without
//! [`StreamSocket::raw_fd`] or [`StreamSocket::set_nonblocking`] (RFCOMM) are read by a thread
//! each, as without `driven`.
//!
//! The point is the hand-off: with a reader thread, every message read wakes the module's
//! thread, and three threads (sender, reader, module) share the CPUs that two would use. Read
//! by the module itself, a 64 KiB stream reached 83–90% of raw TCP's throughput on the 2-core
//! test VM, against about 65% through a reader thread (`benchmarks/RESULTS.md`).
//!
//! # Integrity
//!
//! TCP, Unix and RFCOMM transports declare [`StreamTransport::checksums_payload`], reported as
//! [`Link::checksums_payload`]: the router then sends frames whose CRC covers the header only
//! (`FLAG_HEADER_CRC`, see `docs/wire-format.md`).
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
//! is read, and counted as one dropped frame and one rejected connection; so is a connection
//! whose hello does not arrive in full within the timeout, or that ends before it does.
//!
//! # Failures and backpressure
//!
//! - A send never waits for a connection to be made: the first send (or `send_held`) to a
//!   peer queues its frame and starts a connector thread (connect within
//!   [`StreamConfig::connect_timeout`], which for Bluetooth is seconds); later frames queue
//!   behind it, up to [`StreamConfig::connect_queue_frames`] frames, held ones included (then
//!   [`LinkError::Congested`]). When the connection is up the queue is written in order. A
//!   failed connect drops the queued and held frames (counted in
//!   [`StreamStats::frames_lost_connecting`]; the router's acknowledgements retransmit them)
//!   and starts an exponential backoff ([`StreamConfig::backoff_initial`] doubling up to
//!   [`StreamConfig::backoff_max`]); sends during the backoff fail at once with `Unreachable`
//!   and a reason such as `"reconnecting in 80 ms after: connection refused (os error 111)"`.
//!   A successful connect resets the backoff.
//! - A write blocks at most [`StreamConfig::write_timeout`]. If the peer does not take the
//!   bytes in time the send (or flush) fails with [`LinkError::Congested`]; any other write
//!   error fails with [`LinkError::Unreachable`]. Either way the connection is dropped (a
//!   partly written frame would desynchronise it), held frames written with it are counted as
//!   dropped, and the next send reconnects at once.
//! - A frame written into the kernel just before the peer died can be lost without an error
//!   (TCP reports the reset on a later write). The link does not retry: acknowledgements and
//!   retries are the router's.

mod poller;

use std::collections::{BTreeMap, HashMap};
use std::fmt;
use std::io::{self, IoSlice, IoSliceMut, Read, Write};
use std::os::fd::AsRawFd;
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use hetcomm_core::wire::{HEADER_LEN, MAX_PAYLOAD};
use hetcomm_core::{BufferPool, FrameBuf, SystemId};
use hetcomm_link::{FrameSink, Link, LinkCaps, LinkError, LinkStats, Peer, Readable};

pub(crate) use crate::common::{add, bump, lock};
use poller::{refuse, reject, ConnSet, Permit, Poller, Waker};

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
/// Default of [`StreamConfig::batch_bytes`]: 64 KiB.
pub const DEFAULT_BATCH_BYTES: usize = 64 * 1024;
/// Default of [`StreamConfig::max_connections`].
pub const DEFAULT_MAX_CONNECTIONS: usize = 256;

/// Each reader's buffer for small records.
const READ_BUF_LEN: usize = 64 * 1024;
/// Frames longer than this that are not already buffered are read straight into a buffer of
/// their own size; shorter ones are read through the read buffer (where the occasional
/// partial record is moved to its front, which stays cheap only for short records).
const DIRECT_READ_MIN: usize = 16 * 1024;
/// After a directly read frame, how far the reader reads ahead into its buffer: enough for the
/// next record header and a few small records, little enough that the start of another large
/// frame is hardly copied.
const READ_AHEAD_AFTER_LARGE: usize = 1024;
/// Most bytes of large-frame buffers a connection's reader keeps for reuse, when it hands
/// frames out: the buffers come back as the module drops the messages.
const RECEIVE_POOL_BYTES: usize = 8 * 1024 * 1024;
/// Pooled large-frame buffers are allocated in multiples of this many bytes.
const POOLED_BUF_STEP: usize = 4096;
/// A reader's large-frame buffer above this size is released when a much smaller large frame
/// follows, so that one rare huge frame does not pin its memory for the connection's life.
const LARGE_BUF_KEEP: usize = 4 * 1024 * 1024;

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
    /// The connection's file descriptor, if reading it with `readv(2)` is exactly what
    /// [`Read`] does (no buffering or transformation in user space). The reader then reads
    /// large frames into fresh, not yet initialised buffers instead of zero-filling them
    /// first. `None` (the default) is always correct.
    fn raw_fd(&self) -> Option<std::os::fd::RawFd> {
        None
    }
    /// Makes reads return [`io::ErrorKind::WouldBlock`] instead of waiting. Needed for
    /// [`StreamConfig::driven`] receiving, which falls back to a reader thread per connection
    /// when this fails (the default: unsupported) or [`raw_fd`](StreamSocket::raw_fd) is
    /// `None`.
    fn set_nonblocking(&self, _on: bool) -> io::Result<()> {
        Err(io::ErrorKind::Unsupported.into())
    }
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
    /// link sets its closing flag first, so whatever `accept` returns then is discarded. Not
    /// used for listeners the link polls ([`raw_fd`](StreamListener::raw_fd)).
    fn wake(&self);
    /// The listening socket's descriptor, if it polls readable (`POLLIN`) when a connection
    /// waits and [`accept`](StreamListener::accept) can be made non-blocking with
    /// [`set_nonblocking`](StreamListener::set_nonblocking). The link then accepts, reads
    /// hellos and receives on one thread for all connections (see "Receiving" in the module
    /// docs). `None` (the default): an accept thread and a thread per connection.
    fn raw_fd(&self) -> Option<std::os::fd::RawFd> {
        None
    }
    /// Makes [`accept`](StreamListener::accept) return [`io::ErrorKind::WouldBlock`] instead
    /// of waiting. The default: unsupported.
    fn set_nonblocking(&self, _on: bool) -> io::Result<()> {
        Err(io::ErrorKind::Unsupported.into())
    }
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

    /// Whether the transport delivers bytes unaltered or not at all (a checksummed, reliable
    /// stream such as TCP, a Unix socket or RFCOMM), so that frames on it need a CRC of their
    /// header only ([`Link::checksums_payload`]). The default, false, is always safe.
    fn checksums_payload(&self) -> bool {
        false
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
    /// How long an accepted connection may take to send its whole hello, counted from the
    /// accept however the bytes are spread over reads (default 5 s).
    pub hello_timeout: Duration,
    /// Delay before the first reconnect attempt after a failed connect (default 10 ms).
    pub backoff_initial: Duration,
    /// The backoff doubles per failed connect up to this (default 1 s).
    pub backoff_max: Duration,
    /// Frames a peer's queue holds while its connection is being made, held frames included
    /// (default 1024).
    pub connect_queue_frames: usize,
    /// Largest message payload accepted, bytes; `None`: the codec's limit
    /// ([`MAX_PAYLOAD`]). Frames may be this plus the 48-byte header. Larger values than
    /// the codec's limit are capped to it.
    pub max_message_bytes: Option<usize>,
    /// Most bytes (record headers included) of held frames a peer's batch takes before
    /// [`Link::send_held`] writes it (default [`DEFAULT_BATCH_BYTES`]); 0 turns holding off.
    /// See the module docs.
    pub batch_bytes: usize,
    /// Accepted connections are read by whichever thread calls [`Readable::read_ready`]
    /// ([`Link::readable`]) instead of a reader thread each (see "Driven receive" in the
    /// module docs). Nothing is received until someone does. Default `false`.
    pub driven: bool,
    /// Most accepted connections open at once, those still waiting for their hello included;
    /// further ones are closed at once and counted in [`StreamStats::refused_connections`]
    /// (see "Connection limits" in the module docs). Default [`DEFAULT_MAX_CONNECTIONS`]; 0
    /// refuses every connection.
    pub max_connections: usize,
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
            batch_bytes: DEFAULT_BATCH_BYTES,
            driven: false,
            max_connections: DEFAULT_MAX_CONNECTIONS,
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
    /// Frames fully written to a connection (by `send`, a held batch, or the connector).
    pub frames_sent: u64,
    /// Frames handed to the sink.
    pub frames_received: u64,
    /// Frames dropped on receive: desynchronised or oversized records, frames cut short by a
    /// closed connection, and rejected and refused connections (one each).
    pub frames_dropped: u64,
    /// Outgoing connections established.
    pub connects: u64,
    /// Connections accepted by the listener (refused ones included).
    pub accepted: u64,
    /// Accepted connections closed because their sender is not a fleet system (or sent a
    /// malformed hello, or none within [`StreamConfig::hello_timeout`]).
    pub rejected_connections: u64,
    /// Accepted connections closed at once because [`StreamConfig::max_connections`] were
    /// open (or a thread to read one could not be started). Each is also counted in
    /// `frames_dropped`.
    pub refused_connections: u64,
    /// Accepted connections open now (a gauge, not a counter).
    pub open_connections: u64,
    /// Writes that failed after a connection was up (write errors and write timeouts).
    pub write_failures: u64,
    /// Frames queued or held while connecting whose connection then failed (never sent).
    pub frames_lost_connecting: u64,
    /// Held frames whose batch failed to write (the connection was dropped). [`Link::stats`]
    /// adds them to [`LinkStats::frames_dropped`].
    pub held_frames_dropped: u64,
    /// Connections closed because a record announced a frame larger than this link's
    /// `max_frame` (the sender's `max_message_bytes` is larger than ours). Each is also one of
    /// `frames_dropped`; the first is also logged to standard error.
    pub oversize_records: u64,
}

#[derive(Default)]
struct StreamCounters {
    frames_sent: AtomicU64,
    frames_received: AtomicU64,
    frames_dropped: AtomicU64,
    connects: AtomicU64,
    accepted: AtomicU64,
    rejected_connections: AtomicU64,
    refused_connections: AtomicU64,
    write_failures: AtomicU64,
    frames_lost_connecting: AtomicU64,
    held_frames_dropped: AtomicU64,
    oversize_records: AtomicU64,
    /// The first oversize record has been logged.
    oversize_logged: AtomicBool,
}

/// Sets `flag` unless it is already set, so that the common case only reads the cache line.
fn raise(flag: &AtomicBool) {
    if !flag.load(Ordering::Acquire) {
        flag.store(true, Ordering::Release);
    }
}

/// A peer's address and its outgoing-connection state, locked per peer so that senders to
/// different peers never wait for each other.
struct PeerEntry<T: StreamTransport> {
    addr: T::Addr,
    slot: Mutex<PeerSlot<T::Socket>>,
    /// Set (under the slot's lock) when a frame is held; cleared by `flush` before it looks.
    /// May be set with nothing held, never clear with something held that `flush` must write.
    held: AtomicBool,
}

/// What the link remembers about one peer's outgoing connection.
struct PeerSlot<S> {
    conn: Option<S>,
    backoff: Option<Backoff>,
    /// A connector thread is making the connection.
    connecting: bool,
    /// Records (header + frame) not written yet, in send order. While the connection is up
    /// these are all held frames. While connecting, the first `released` bytes are frames that
    /// were sent (or flushed) and go out as soon as the connection is up; the rest are held.
    /// Without a connection and without a connector it is empty.
    out: Vec<u8>,
    /// Bytes at the front of `out` waiting only for the connection.
    released: usize,
    /// Frames in `out[..released]`.
    released_frames: usize,
    /// Frames in `out[released..]`.
    held_frames: usize,
}

impl<S> PeerSlot<S> {
    fn new() -> Self {
        PeerSlot {
            conn: None,
            backoff: None,
            connecting: false,
            out: Vec::new(),
            released: 0,
            released_frames: 0,
            held_frames: 0,
        }
    }

    fn pending_frames(&self) -> usize {
        self.released_frames + self.held_frames
    }

    /// Forgets every pending frame and returns how many there were.
    fn clear_pending(&mut self, batch_bytes: usize) -> usize {
        let n = self.pending_frames();
        self.out.clear();
        // A burst queued while connecting may have grown the buffer far past one batch.
        self.out.shrink_to(batch_bytes);
        self.released = 0;
        self.released_frames = 0;
        self.held_frames = 0;
        n
    }

    /// Marks everything pending as released (written as soon as the connection is up).
    fn release_all(&mut self) {
        self.released = self.out.len();
        self.released_frames += self.held_frames;
        self.held_frames = 0;
    }
}

struct Backoff {
    retry_at: Instant,
    delay: Duration,
    reason: String,
}

/// State shared by the link, its poller (or accept) thread and any reader threads.
struct Shared<T: StreamTransport> {
    transport: T,
    sink: Arc<dyn FrameSink>,
    config: StreamConfig,
    /// Every fleet system other than this one (used to vet hellos).
    fleet: BTreeMap<SystemId, ()>,
    closing: AtomicBool,
    counters: StreamCounters,
    /// Accepted connections open now (each holds a [`Permit`]).
    open: Arc<AtomicUsize>,
    /// Connections read by a thread of their own, by reader number; a reader removes its
    /// entry (and so closes the second handle) when its connection ends.
    readers: Mutex<HashMap<u64, Reader<T::Socket>>>,
    next_reader: AtomicU64,
    /// Identified connections read without a thread each: by the driving thread with
    /// [`StreamConfig::driven`], otherwise by the poller thread. `None` when neither reads
    /// them (not driven, listener not polled: every connection has a reader thread).
    conns: Option<ConnSet<T::Socket>>,
}

struct Reader<S> {
    /// A second handle, to unblock the reader at shutdown.
    socket: S,
    handle: JoinHandle<()>,
}

/// A [`Link`] over any [`StreamTransport`]: see the module docs for its behaviour.
pub struct StreamLink<T: StreamTransport> {
    local: SystemId,
    shared: Arc<Shared<T>>,
    listener: Arc<T::Listener>,
    peers: Arc<BTreeMap<SystemId, PeerEntry<T>>>,
    /// Set when any peer's `held` flag is; lets `flush` return at once when nothing is held.
    held_any: AtomicBool,
    /// The poller thread, or the accept thread of a listener that cannot be polled.
    accept_thread: Option<JoinHandle<()>>,
    /// Wakes the poller thread (`None`: the accept thread, woken through the listener).
    waker: Option<Arc<Waker>>,
}

impl<T: StreamTransport> StreamLink<T> {
    /// Starts a link for system `local` that accepts on `listener` and connects to the
    /// addresses in `peers` (an entry for `local` itself is ignored). Received frames go to
    /// `sink`. Fails only if the receiving thread (or its `epoll` instance) cannot be set up.
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
                let entry = PeerEntry {
                    addr,
                    slot: Mutex::new(PeerSlot::new()),
                    held: AtomicBool::new(false),
                };
                (id, entry)
            })
            .collect();
        let polled = listener
            .raw_fd()
            .filter(|_| listener.set_nonblocking(true).is_ok());
        let conns = if config.driven || polled.is_some() {
            Some(ConnSet::new()?)
        } else {
            None
        };
        let shared = Arc::new(Shared {
            transport,
            sink,
            conns,
            config,
            fleet: peers.keys().map(|id| (*id, ())).collect(),
            closing: AtomicBool::new(false),
            counters: StreamCounters::default(),
            open: Arc::new(AtomicUsize::new(0)),
            readers: Mutex::new(HashMap::new()),
            next_reader: AtomicU64::new(1),
        });
        let listener = Arc::new(listener);
        let (accept_thread, waker) = {
            let shared = shared.clone();
            let listener = listener.clone();
            let thread = std::thread::Builder::new();
            match polled {
                Some(fd) => {
                    let waker = Arc::new(Waker::new()?);
                    let poller = Poller::new(shared, listener, fd, waker.clone())?;
                    let handle = thread
                        .name(format!("hetcomm-{}-rx-{local}", T::NAME))
                        .spawn(move || poller.run())?;
                    (handle, Some(waker))
                }
                None => {
                    let handle = thread
                        .name(format!("hetcomm-{}-accept-{local}", T::NAME))
                        .spawn(move || accept_loop(&shared, &listener))?;
                    (handle, None)
                }
            }
        };
        Ok(StreamLink {
            local,
            shared,
            listener,
            peers: Arc::new(peers),
            held_any: AtomicBool::new(false),
            accept_thread: Some(accept_thread),
            waker,
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

    /// The connections a driving thread reads, with [`StreamConfig::driven`].
    fn driven(&self) -> Option<&ConnSet<T::Socket>> {
        self.shared
            .conns
            .as_ref()
            .filter(|_| self.shared.config.driven)
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
            refused_connections: get(&c.refused_connections),
            open_connections: self.shared.open.load(Ordering::Relaxed) as u64,
            write_failures: get(&c.write_failures),
            frames_lost_connecting: get(&c.frames_lost_connecting),
            held_frames_dropped: get(&c.held_frames_dropped),
            oversize_records: get(&c.oversize_records),
        }
    }

    /// Bytes of frames queued for connections or held in batches, over all peers.
    pub fn pending_bytes(&self) -> usize {
        self.peers.values().map(|p| lock(&p.slot).out.len()).sum()
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

    /// The peer entry of `to`, after checking the size of a frame of `len` bytes.
    fn entry_for(&self, to: SystemId, len: usize) -> Result<&PeerEntry<T>, LinkError> {
        let max = self.shared.config.max_frame();
        if len > max {
            return Err(LinkError::TooLarge { len, max });
        }
        self.peers.get(&to).ok_or_else(|| {
            let reason = if to == self.local {
                "it is this system itself".to_string()
            } else {
                format!("system {to} has no endpoint on this {} link", T::NAME)
            };
            LinkError::Unreachable { peer: to, reason }
        })
    }

    /// [`Link::send`] of a frame in one or two pieces.
    fn send_frame(&self, to: SystemId, frame: FrameParts<'_>) -> Result<(), LinkError> {
        let entry = self.entry_for(to, frame.len())?;
        let mut slot = lock(&entry.slot);
        if slot.conn.is_none() {
            return self.queue_for_connection(to, entry, &mut slot, frame, true);
        }
        // Held frames first, in the same write: order kept, one syscall for both.
        self.write_batch(to, entry, &mut slot, Some(frame))
    }

    fn mark_held(&self, entry: &PeerEntry<T>) {
        raise(&entry.held);
        raise(&self.held_any);
    }

    /// Queues `frame` for `to`'s connection, which is not up, starting a connector if none
    /// runs. `release`: the frame (and everything held before it) goes out as soon as the
    /// connection is up; otherwise it is held like the batch of a live connection.
    fn queue_for_connection(
        &self,
        to: SystemId,
        entry: &PeerEntry<T>,
        slot: &mut PeerSlot<T::Socket>,
        frame: FrameParts<'_>,
        release: bool,
    ) -> Result<(), LinkError> {
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
        if slot.pending_frames() >= self.shared.config.connect_queue_frames {
            return Err(LinkError::Congested {
                peer: to,
                reason: format!(
                    "{} frames already wait for the connection to {}",
                    slot.pending_frames(),
                    entry.addr
                ),
            });
        }
        append_record(&mut slot.out, frame);
        slot.held_frames += 1;
        if release {
            slot.release_all();
        } else {
            self.mark_held(entry);
        }
        if !slot.connecting {
            slot.connecting = true;
            if let Err(e) = self.start_connector(to) {
                slot.connecting = false;
                // Only this frame can be pending here (no connection and no connector means
                // nothing was queued), and it is refused rather than lost.
                slot.clear_pending(self.shared.config.batch_bytes);
                return Err(LinkError::Io(e));
            }
        }
        Ok(())
    }

    /// Writes `slot`'s held records followed by `frame`, if any, on its live connection in one
    /// vectored write. On failure the connection is dropped and the held frames are counted
    /// as dropped (the caller learns about `frame` from the error).
    fn write_batch(
        &self,
        to: SystemId,
        entry: &PeerEntry<T>,
        slot: &mut PeerSlot<T::Socket>,
        frame: Option<FrameParts<'_>>,
    ) -> Result<(), LinkError> {
        let cfg = &self.shared.config;
        let counters = &self.shared.counters;
        let PeerSlot {
            conn,
            out,
            held_frames,
            ..
        } = slot;
        let Some(socket) = conn.as_mut() else {
            // Callers check the connection first; fail soft rather than panic.
            return Err(LinkError::Closed);
        };
        let head = frame.map_or([0; RECORD_HEADER_LEN], |f| record_header(f.len()));
        let parts: [&[u8]; 4] = match frame {
            Some(f) => [&out[..], &head, f.head, f.body],
            None => [&out[..], &[], &[], &[]],
        };
        let result = write_parts(socket, &parts, cfg.write_timeout);
        let held = std::mem::take(held_frames);
        out.clear();
        if held > 0 && entry.held.load(Ordering::Relaxed) {
            // Nothing is held any more (we hold the lock), so the next flush can skip this peer.
            entry.held.store(false, Ordering::Release);
        }
        match result {
            Ok(()) => {
                add(&counters.frames_sent, held + usize::from(frame.is_some()));
                Ok(())
            }
            Err(e) => {
                // Something may be half written: this connection can no longer be framed.
                if let Some(s) = conn.take() {
                    let _ = s.shutdown_both();
                }
                bump(&counters.write_failures);
                add(&counters.held_frames_dropped, held);
                Err(write_error(to, &entry.addr, &e, cfg.write_timeout))
            }
        }
    }
}

/// The error a failed write on a live connection is reported as.
fn write_error(
    to: SystemId,
    addr: &impl fmt::Display,
    e: &io::Error,
    timeout: Duration,
) -> LinkError {
    let ms = timeout.as_millis();
    if matches!(
        e.kind(),
        io::ErrorKind::WouldBlock | io::ErrorKind::TimedOut
    ) {
        LinkError::Congested {
            peer: to,
            reason: format!(
                "{addr} did not take the data within the {ms} ms write timeout; \
                 connection dropped"
            ),
        }
    } else {
        LinkError::Unreachable {
            peer: to,
            reason: format!(
                "write to {addr} failed: {e}; connection dropped, the next send reconnects"
            ),
        }
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
/// queueing meanwhile), then installs it and writes the released frames in order (held ones
/// stay in the batch), or drops them all and starts the backoff.
fn run_connector<T: StreamTransport>(shared: &Shared<T>, local: SystemId, entry: &PeerEntry<T>) {
    let result = connect(shared, local, &entry.addr);
    let mut slot = lock(&entry.slot);
    slot.connecting = false;
    if shared.closing.load(Ordering::SeqCst) {
        return;
    }
    let cfg = &shared.config;
    let error = match result {
        Ok(mut socket) => {
            bump(&shared.counters.connects);
            let released = slot.released;
            match write_parts(&mut socket, &[&slot.out[..released]], cfg.write_timeout) {
                Ok(()) => {
                    add(&shared.counters.frames_sent, slot.released_frames);
                    slot.out.drain(..released);
                    slot.out.shrink_to(cfg.batch_bytes);
                    slot.released = 0;
                    slot.released_frames = 0;
                    slot.conn = Some(socket);
                    slot.backoff = None;
                    return;
                }
                Err(e) => {
                    bump(&shared.counters.write_failures);
                    let _ = socket.shutdown_both();
                    e
                }
            }
        }
        Err(e) => e,
    };
    let lost = slot.clear_pending(cfg.batch_bytes);
    add(&shared.counters.frames_lost_connecting, lost);
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
        self.send_frame(to, FrameParts::whole(frame))
    }

    /// Writes the record header, `head` and `body` with one vectored write: a large payload
    /// goes from the caller's buffer to the socket without a copy in user space.
    fn send_parts(&self, to: SystemId, head: &[u8], body: &[u8]) -> Result<(), LinkError> {
        self.send_frame(to, FrameParts { head, body })
    }

    fn readable(&self) -> Option<&dyn Readable> {
        self.driven().map(|_| self as &dyn Readable)
    }

    fn send_held(&self, to: SystemId, frame: &[u8]) -> Result<(), LinkError> {
        let entry = self.entry_for(to, frame.len())?;
        let frame = FrameParts::whole(frame);
        let cap = self.shared.config.batch_bytes;
        let mut slot = lock(&entry.slot);
        if slot.conn.is_none() {
            return self.queue_for_connection(to, entry, &mut slot, frame, false);
        }
        let record = RECORD_HEADER_LEN + frame.len();
        if record > cap {
            // Too big to hold: write it now, right behind what is held.
            return self.write_batch(to, entry, &mut slot, Some(frame));
        }
        if slot.out.len() + record > cap {
            self.write_batch(to, entry, &mut slot, None)?;
        }
        if slot.out.capacity() < cap {
            // Grow to the full batch once, rather than by doubling.
            let more = cap - slot.out.len();
            slot.out.reserve_exact(more);
        }
        append_record(&mut slot.out, frame);
        slot.held_frames += 1;
        self.mark_held(entry);
        Ok(())
    }

    fn flush(&self) -> Result<(), LinkError> {
        if !self.held_any.load(Ordering::Acquire) || !self.held_any.swap(false, Ordering::AcqRel) {
            return Ok(());
        }
        let mut first_error = None;
        for (&to, entry) in self.peers.iter() {
            // Cleared before the lock is taken: a frame held after this is flagged anew.
            if !entry.held.load(Ordering::Acquire) || !entry.held.swap(false, Ordering::AcqRel) {
                continue;
            }
            let mut slot = lock(&entry.slot);
            if slot.held_frames == 0 {
                continue;
            }
            if slot.conn.is_none() {
                // The connector writes released frames as soon as the connection is up.
                slot.release_all();
                continue;
            }
            if let Err(e) = self.write_batch(to, entry, &mut slot, None) {
                first_error.get_or_insert(e);
            }
        }
        first_error.map_or(Ok(()), Err)
    }

    fn batches(&self) -> bool {
        self.shared.config.batch_bytes > 0
    }

    fn checksums_payload(&self) -> bool {
        self.shared.transport.checksums_payload()
    }

    fn stats(&self) -> LinkStats {
        let s = self.stream_stats();
        LinkStats {
            frames_sent: s.frames_sent,
            frames_received: s.frames_received,
            frames_dropped: s.frames_dropped + s.held_frames_dropped,
            connects: s.connects,
            buffered_bytes: self.pending_bytes() as u64,
            kernel_drops: 0,
            security: Default::default(),
        }
    }
}

/// With [`StreamConfig::driven`]: the receive side, read by whichever thread calls
/// `read_ready` (see "Driven receive" in the module docs).
impl<T: StreamTransport> Readable for StreamLink<T> {
    /// An epoll descriptor over every accepted connection (readable when any of them is).
    /// Without `driven`, a descriptor that never polls readable is not offered: -1.
    fn fd(&self) -> std::os::fd::RawFd {
        self.driven().map_or(-1, |d| d.epoll.as_raw_fd())
    }

    /// Reads up to `budget` records from each connection that has bytes (and then whatever
    /// records are already buffered), handing them to the sink; closes connections that
    /// ended, counted as without `driven`.
    fn read_ready(&self, budget: usize) -> io::Result<usize> {
        match self.driven() {
            Some(d) => d.read_ready(&self.shared, budget.max(1)),
            None => Ok(0),
        }
    }
}

impl<T: StreamTransport> Drop for StreamLink<T> {
    fn drop(&mut self) {
        // Best effort: held frames would otherwise be lost without a trace (a peer that does
        // not read makes this wait up to the write timeout).
        let _ = self.flush();
        self.shared.closing.store(true, Ordering::SeqCst);
        match &self.waker {
            Some(w) => w.wake(),
            None => self.listener.wake(),
        }
        if let Some(h) = self.accept_thread.take() {
            let _ = h.join();
        }
        // The accepting thread is gone, so no reader can be added any more.
        let readers = std::mem::take(&mut *lock(&self.shared.readers));
        for r in readers.values() {
            let _ = r.socket.shutdown_both();
        }
        for r in readers.into_values() {
            let _ = r.handle.join();
        }
        if let Some(conns) = &self.shared.conns {
            conns.shutdown();
        }
        for peer in self.peers.values() {
            if let Some(s) = lock(&peer.slot).conn.take() {
                let _ = s.shutdown_both();
            }
        }
    }
}

/// The record header of a frame of `len` bytes (callers have checked `len` against
/// `max_frame`, which is far below 4 GiB).
fn record_header(len: usize) -> [u8; RECORD_HEADER_LEN] {
    let len = u32::try_from(len).unwrap_or(u32::MAX);
    let mut head = [0u8; RECORD_HEADER_LEN];
    head[0..2].copy_from_slice(&RECORD_MAGIC);
    head[2] = STREAM_VERSION;
    head[4..8].copy_from_slice(&len.to_le_bytes());
    head
}

fn append_record(out: &mut Vec<u8>, frame: FrameParts<'_>) {
    out.extend_from_slice(&record_header(frame.len()));
    out.extend_from_slice(frame.head);
    out.extend_from_slice(frame.body);
}

/// One frame, given as `head` followed by `body` ([`Link::send_parts`]), or whole in `head`.
#[derive(Clone, Copy)]
struct FrameParts<'a> {
    head: &'a [u8],
    body: &'a [u8],
}

impl<'a> FrameParts<'a> {
    fn whole(frame: &'a [u8]) -> Self {
        FrameParts {
            head: frame,
            body: &[],
        }
    }

    fn len(&self) -> usize {
        self.head.len() + self.body.len()
    }
}

/// Writes all of `parts`, in order, with as few vectored writes as the socket allows, bounded
/// by `timeout` in total (the socket's own timeout bounds each call; it is shortened after a
/// partial write so that the sum stays within `timeout`, and restored at the end).
fn write_parts<S: StreamSocket, const N: usize>(
    socket: &mut S,
    parts: &[&[u8]; N],
    timeout: Duration,
) -> io::Result<()> {
    let total: usize = parts.iter().map(|p| p.len()).sum();
    let deadline = Instant::now() + timeout;
    let mut done = 0;
    let mut shortened = false;
    while done < total {
        // The slices of what is left: skip `done` bytes, then every empty part.
        let mut slices = [IoSlice::new(&[]); N];
        let mut n = 0;
        let mut skip = done;
        for part in parts {
            if skip >= part.len() {
                skip -= part.len();
                continue;
            }
            slices[n] = IoSlice::new(&part[skip..]);
            skip = 0;
            n += 1;
        }
        let result = match &slices[..n] {
            [one] => socket.write(one),
            many => socket.write_vectored(many),
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

/// The accept thread of a listener that cannot be polled: a reader thread per connection.
fn accept_loop<T: StreamTransport>(shared: &Arc<Shared<T>>, listener: &T::Listener) {
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
        match Permit::take(&shared.open, shared.config.max_connections) {
            Some(permit) => spawn_reader(shared, socket, addr, permit),
            None => refuse(shared, socket),
        }
    }
}

/// Identifies and reads an accepted connection on a thread of its own.
fn spawn_reader<T: StreamTransport>(
    shared: &Arc<Shared<T>>,
    socket: T::Socket,
    addr: <T::Listener as StreamListener>::PeerAddr,
    permit: Permit,
) {
    let Ok(handle) = socket.try_clone() else {
        refuse(shared, socket);
        return;
    };
    spawn_thread(shared, handle, move |shared| {
        serve_connection(shared, socket, addr, permit)
    });
}

/// Reads an identified connection whose socket cannot be polled on a thread of its own.
fn spawn_conn_reader<T: StreamTransport>(shared: &Arc<Shared<T>>, conn: Connection<T::Socket>) {
    let Ok(handle) = conn.socket.try_clone() else {
        refuse(shared, conn.socket);
        return;
    };
    spawn_thread(shared, handle, move |shared| read_on_thread(shared, conn));
}

/// Starts a reader thread running `run`, with `handle` (a second handle to its connection)
/// kept to shut the connection down when the link closes. The thread forgets its entry, and
/// so closes `handle`, when `run` returns. If no thread can be started the connection is
/// closed (with `run`) and counted as refused.
fn spawn_thread<T: StreamTransport>(
    shared: &Arc<Shared<T>>,
    handle: T::Socket,
    run: impl FnOnce(&Shared<T>) + Send + 'static,
) {
    let id = shared.next_reader.fetch_add(1, Ordering::Relaxed);
    let thread_shared = shared.clone();
    // Locked until the entry is in: a thread that ends at once waits to remove it.
    let mut readers = lock(&shared.readers);
    let spawned = std::thread::Builder::new()
        .name(format!("hetcomm-{}-rx-{id}", T::NAME))
        .spawn(move || {
            run(&thread_shared);
            lock(&thread_shared.readers).remove(&id);
        });
    match spawned {
        Ok(thread) => {
            readers.insert(
                id,
                Reader {
                    socket: handle,
                    handle: thread,
                },
            );
        }
        Err(_) => {
            drop(readers);
            refuse(shared, handle);
        }
    }
}

/// Reads exactly `buf.len()` bytes by `deadline` in total, however the peer spreads them over
/// its writes: the socket's read timeout is set to what is left before each read. An error if
/// the stream ends first (`UnexpectedEof`) or the deadline passes (`TimedOut`).
fn read_by<S: StreamSocket>(socket: &mut S, buf: &mut [u8], deadline: Instant) -> io::Result<()> {
    let mut got = 0;
    while got < buf.len() {
        let left = deadline.saturating_duration_since(Instant::now());
        if left.is_zero() {
            return Err(io::ErrorKind::TimedOut.into());
        }
        socket.set_read_timeout(Some(left))?;
        match socket.read(&mut buf[got..]) {
            Ok(0) => return Err(io::ErrorKind::UnexpectedEof.into()),
            Ok(n) => got += n,
            Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
            Err(e) => return Err(e),
        }
    }
    Ok(())
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
            // Exactly the hello: the records behind it belong to the record reader.
            let mut hello = [0u8; HELLO_LEN];
            read_by(
                socket,
                &mut hello,
                Instant::now() + shared.config.hello_timeout,
            )
            .ok()?;
            socket.set_read_timeout(None).ok()?;
            decode_hello(&hello).and_then(in_fleet)
        }
    }
}

/// Why a connection's record stream ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum StreamEnd {
    /// End of stream (or a read error) between records.
    Clean,
    /// End of stream or a read error inside a record: that frame is lost.
    Cut,
    /// A record header that is malformed.
    Bad,
    /// A well-formed record header announcing more than `max_frame` bytes (this many): the
    /// sender's `max_message_bytes` is larger than the receiver's.
    Oversize(usize),
    /// Not an end: a non-blocking socket has nothing more for now. The reader keeps what it
    /// has read and resumes with the next call.
    Pending,
}

/// Where [`RecordReader::next_record`] left a complete frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum FrameAt {
    /// In the read buffer, at this range.
    Buffered(usize, usize),
    /// At the start of the large-frame buffer, this long.
    Large(usize),
}

/// What a [`RecordReader`] reads from: any [`Read`], and, when it has one, the file
/// descriptor behind it (see [`StreamSocket::raw_fd`]).
trait RecordSource: Read {
    /// A descriptor that `readv(2)` may read instead of [`Read`] (`None`: never).
    fn fd(&self) -> Option<std::os::fd::RawFd> {
        None
    }
}

impl<S: StreamSocket> RecordSource for S {
    fn fd(&self) -> Option<std::os::fd::RawFd> {
        self.raw_fd()
    }
}

impl RecordSource for &[u8] {}

/// `readv(2)` of `fd` into `spare` (memory not yet initialised), then `ahead`. Returns the
/// number of bytes read; the first `min(n, spare.len())` bytes of `spare` are then initialised.
fn readv_uninit(
    fd: std::os::fd::RawFd,
    spare: &mut [std::mem::MaybeUninit<u8>],
    ahead: &mut [u8],
) -> io::Result<usize> {
    let iov = [
        libc::iovec {
            iov_base: spare.as_mut_ptr().cast(),
            iov_len: spare.len(),
        },
        libc::iovec {
            iov_base: ahead.as_mut_ptr().cast(),
            iov_len: ahead.len(),
        },
    ];
    // SAFETY: both iovecs describe memory we hold exclusively for the call, with their true
    // lengths; the kernel only writes into them. Writing into uninitialised bytes is fine.
    let n = unsafe { libc::readv(fd, iov.as_ptr(), 2) };
    if n < 0 {
        Err(io::Error::last_os_error())
    } else {
        Ok(n as usize)
    }
}

/// Splits a connection's byte stream into frames: small records through a read buffer (as
/// many per read as have arrived), large frames straight into a buffer of their own size.
struct RecordReader {
    max_frame: usize,
    /// The read buffer, [`READ_BUF_LEN`] bytes once the first read needs it (empty before, so
    /// that idle connections cost no buffer).
    buf: Box<[u8]>,
    /// Unconsumed bytes are `buf[start..end]`.
    start: usize,
    end: usize,
    /// The last frame was read directly: read only a little ahead into `buf` (see
    /// [`READ_AHEAD_AFTER_LARGE`]), since another large frame is likely next.
    after_large: bool,
    /// Reused for frames over [`DIRECT_READ_MIN`]; at least as long as the longest recent one.
    /// When handing out, a buffer from `pool` each time instead.
    large: Vec<u8>,
    /// Large frames are given away ([`take_large`](Self::take_large)) rather than reused, in
    /// buffers that come back to this pool when the sink drops them.
    pool: Option<Arc<BufferPool>>,
    /// A large frame whose reading a non-blocking socket interrupted: its length, and how
    /// many of its bytes are in `large`.
    partial: Option<(usize, usize)>,
}

impl RecordReader {
    fn new(max_frame: usize) -> Self {
        RecordReader {
            max_frame,
            buf: Box::default(),
            start: 0,
            end: 0,
            after_large: false,
            large: Vec::new(),
            pool: None,
            partial: None,
        }
    }

    /// A reader that gives large frames away: each one is read into a buffer of its own from
    /// `pool`, taken with [`take_large`](Self::take_large).
    fn handing_out(max_frame: usize, pool: Arc<BufferPool>) -> Self {
        RecordReader {
            pool: Some(pool),
            ..RecordReader::new(max_frame)
        }
    }

    /// Whether large frames are given away.
    fn hands_out(&self) -> bool {
        self.pool.is_some()
    }

    /// The buffer of a [`FrameAt::Large`] frame, exactly its bytes, for a reader
    /// [`handing_out`](Self::handing_out) (the next large frame gets another buffer).
    fn take_large(&mut self) -> FrameBuf {
        let frame = std::mem::take(&mut self.large);
        match &self.pool {
            Some(pool) => pool.wrap(frame),
            None => frame.into(),
        }
    }

    /// The bytes of a frame [`next_record`](Self::next_record) returned.
    fn frame(&self, at: FrameAt) -> &[u8] {
        match at {
            FrameAt::Buffered(from, to) => &self.buf[from..to],
            FrameAt::Large(len) => &self.large[..len],
        }
    }

    /// Reads until `buf[start..]` holds at least `need` bytes (`need` ≤ the buffer's size),
    /// first moving what is left to the front if it would not fit.
    fn fill<R: Read>(&mut self, r: &mut R, need: usize) -> Result<(), StreamEnd> {
        if self.buf.is_empty() {
            self.buf = vec![0; READ_BUF_LEN].into_boxed_slice();
        }
        if self.start == self.end {
            self.start = 0;
            self.end = 0;
        } else if self.start + need > self.buf.len() {
            self.buf.copy_within(self.start..self.end, 0);
            self.end -= self.start;
            self.start = 0;
        }
        while self.end - self.start < need {
            let limit = if self.after_large {
                (self.start + READ_AHEAD_AFTER_LARGE.max(need)).min(self.buf.len())
            } else {
                self.buf.len()
            };
            match r.read(&mut self.buf[self.end..limit]) {
                Ok(0) => break,
                Ok(n) => self.end += n,
                Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                Err(e) if e.kind() == io::ErrorKind::WouldBlock => return Err(StreamEnd::Pending),
                Err(_) => break,
            }
        }
        match self.end - self.start {
            n if n >= need => Ok(()),
            0 => Err(StreamEnd::Clean),
            _ => Err(StreamEnd::Cut),
        }
    }

    /// Reads the next record; its frame is then [`frame`](Self::frame)`(at)` until the next
    /// call.
    fn next_record<R: RecordSource>(&mut self, r: &mut R) -> Result<FrameAt, StreamEnd> {
        if let Some((len, got)) = self.partial {
            self.finish_large(r, len, got)?;
            return Ok(FrameAt::Large(len));
        }
        self.fill(r, RECORD_HEADER_LEN)?;
        let mut head = [0u8; RECORD_HEADER_LEN];
        head.copy_from_slice(&self.buf[self.start..self.start + RECORD_HEADER_LEN]);
        // Checked before anything is allocated or read for it.
        let len = match decode_record_header(&head, usize::MAX) {
            None => return Err(StreamEnd::Bad),
            Some(len) if len > self.max_frame => return Err(StreamEnd::Oversize(len)),
            Some(len) => len,
        };
        let body = self.start + RECORD_HEADER_LEN;
        if body + len <= self.end || len <= DIRECT_READ_MIN {
            if body + len > self.end {
                // A small partial record: completing it in the buffer costs at most a move of
                // DIRECT_READ_MIN bytes per buffer's worth of records.
                self.fill(r, RECORD_HEADER_LEN + len).map_err(|e| match e {
                    StreamEnd::Pending => StreamEnd::Pending,
                    _ => StreamEnd::Cut,
                })?;
            }
            let from = self.start + RECORD_HEADER_LEN;
            self.start = from + len;
            self.after_large = false;
            return Ok(FrameAt::Buffered(from, from + len));
        }
        self.read_large(r, body, len)?;
        Ok(FrameAt::Large(len))
    }

    /// Reads the frame of `len` bytes whose first bytes are `buf[body..end]` into `large`.
    fn read_large<R: RecordSource>(
        &mut self,
        r: &mut R,
        body: usize,
        len: usize,
    ) -> Result<(), StreamEnd> {
        let have = self.end - body;
        if let Some(pool) = &self.pool {
            // The last one left with its frame (or is still here after an error: replaced).
            // Rounded up so that frames of similar sizes can reuse each other's buffers.
            self.large = pool.take(len.next_multiple_of(POOLED_BUF_STEP));
            self.large.extend_from_slice(&self.buf[body..self.end]);
            if r.fd().is_none() {
                // Read through `Read`, which needs initialised memory.
                self.large.resize(len, 0);
            }
        } else {
            if self.large.len() > LARGE_BUF_KEEP && len < LARGE_BUF_KEEP / 4 {
                self.large = Vec::new();
            }
            if self.large.len() < len {
                // A fresh zeroed allocation rather than `resize`, which would copy the old
                // bytes.
                self.large = vec![0; len];
            }
            self.large[..have].copy_from_slice(&self.buf[body..self.end]);
        }
        self.start = 0;
        self.end = 0;
        self.after_large = true;
        self.finish_large(r, len, have)
    }

    /// Reads the rest of a large frame, of which `got` bytes are in `large`: in place, with
    /// whatever follows it (the next record header, with luck) into the front of the read
    /// buffer in the same read, but at most [`READ_AHEAD_AFTER_LARGE`] bytes of it. A handed-out
    /// buffer is read into straight from the descriptor, uninitialised (`large.len()` is then
    /// `got`). On [`StreamEnd::Pending`] the progress is kept in `partial`.
    fn finish_large<R: RecordSource>(
        &mut self,
        r: &mut R,
        len: usize,
        mut got: usize,
    ) -> Result<(), StreamEnd> {
        self.partial = None;
        let uninit = if self.pool.is_some() { r.fd() } else { None };
        while got < len {
            let want = len - got;
            let ahead = &mut self.buf[..READ_AHEAD_AFTER_LARGE];
            let result = match uninit {
                Some(fd) => readv_uninit(fd, &mut self.large.spare_capacity_mut()[..want], ahead),
                None => r.read_vectored(&mut [
                    IoSliceMut::new(&mut self.large[got..len]),
                    IoSliceMut::new(ahead),
                ]),
            };
            match result {
                Ok(0) => return Err(StreamEnd::Cut),
                Ok(n) => {
                    let into_frame = n.min(want);
                    if uninit.is_some() {
                        // SAFETY: the kernel wrote the first `into_frame` bytes of the spare
                        // capacity (and the rest of n into `buf`).
                        unsafe { self.large.set_len(got + into_frame) };
                    }
                    got += into_frame;
                    if n > want {
                        self.end = n - want;
                    }
                }
                Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                Err(e) if e.kind() == io::ErrorKind::WouldBlock => {
                    self.partial = Some((len, got));
                    return Err(StreamEnd::Pending);
                }
                Err(_) => return Err(StreamEnd::Cut),
            }
        }
        Ok(())
    }

    /// Whether the read buffer holds a whole record (or a bad header) that
    /// [`next_record`](Self::next_record) can return without reading the socket.
    fn has_buffered_record(&self) -> bool {
        if self.partial.is_some() || self.end - self.start < RECORD_HEADER_LEN {
            return false;
        }
        let mut head = [0u8; RECORD_HEADER_LEN];
        head.copy_from_slice(&self.buf[self.start..self.start + RECORD_HEADER_LEN]);
        match decode_record_header(&head, self.max_frame) {
            None => true,
            Some(len) => self.start + RECORD_HEADER_LEN + len <= self.end,
        }
    }
}

/// The reader thread of one accepted connection.
fn serve_connection<T: StreamTransport>(
    shared: &Shared<T>,
    mut socket: T::Socket,
    addr: <T::Listener as StreamListener>::PeerAddr,
    permit: Permit,
) {
    let _ = shared.transport.configure(&socket);
    let Some(from) = identify(shared, &mut socket, &addr) else {
        reject(shared, socket);
        return;
    };
    let mut conn = Connection {
        reader: new_reader(shared),
        socket,
        from,
        _permit: permit,
    };
    if let Some(conns) = &shared.conns {
        // From here on whoever drives the link reads this connection.
        match conns.register(conn) {
            Ok(()) => return,
            Err(back) => conn = back,
        }
    }
    read_on_thread(shared, conn);
}

/// Reads an identified connection with blocking reads until it ends, then closes it.
fn read_on_thread<T: StreamTransport>(shared: &Shared<T>, mut conn: Connection<T::Socket>) {
    let end = loop {
        match conn.read_records(shared, usize::MAX).1 {
            Ok(()) => continue,
            // A blocking socket has no "later": treat it as cut.
            Err(StreamEnd::Pending) => break StreamEnd::Cut,
            Err(end) => break end,
        }
    };
    conn.end(shared, end);
}

/// A reader for a new connection. A sink that keeps frames gets each large one in a buffer of
/// its own (its payload then needs no copy); others borrow from the reader's reused buffers.
fn new_reader<T: StreamTransport>(shared: &Shared<T>) -> RecordReader {
    if shared.sink.takes_frames() {
        RecordReader::handing_out(
            shared.config.max_frame(),
            BufferPool::new(RECEIVE_POOL_BYTES),
        )
    } else {
        RecordReader::new(shared.config.max_frame())
    }
}

/// An accepted, identified connection and its record reader.
struct Connection<S> {
    socket: S,
    reader: RecordReader,
    from: Peer,
    /// Its share of `max_connections`, given back when the connection is dropped (closed).
    _permit: Permit,
}

impl<S: StreamSocket> Connection<S> {
    /// Hands records to the sink: `budget` of them at most, then any more that are already
    /// buffered (a driven socket reports readable only for bytes it still holds). Returns how
    /// many, and why it stopped: `Ok` at the budget, `Err` when the stream ended or is
    /// [`StreamEnd::Pending`].
    fn read_records<T>(
        &mut self,
        shared: &Shared<T>,
        budget: usize,
    ) -> (usize, Result<(), StreamEnd>)
    where
        T: StreamTransport<Socket = S>,
    {
        let mut n = 0;
        while n < budget || self.reader.has_buffered_record() {
            let at = match self.reader.next_record(&mut self.socket) {
                Ok(at) => at,
                Err(end) => return (n, Err(end)),
            };
            n += 1;
            // Counted first so that whoever the sink wakes sees the counter already updated.
            bump(&shared.counters.frames_received);
            match at {
                FrameAt::Large(_) if self.reader.hands_out() => shared
                    .sink
                    .on_frame_owned(self.reader.take_large(), self.from),
                _ => shared.sink.on_frame(self.reader.frame(at), self.from),
            }
        }
        (n, Ok(()))
    }

    /// Closes the connection after its stream ended with `end`.
    fn end<T: StreamTransport>(self, shared: &Shared<T>, end: StreamEnd) {
        // Truncated, desynchronised or oversized: nothing after it can be trusted. A record
        // cut by our own shutdown is not the peer's fault.
        let count = match end {
            StreamEnd::Clean | StreamEnd::Pending => false,
            StreamEnd::Cut => !shared.closing.load(Ordering::SeqCst),
            StreamEnd::Bad => true,
            StreamEnd::Oversize(len) => {
                bump(&shared.counters.oversize_records);
                if !shared
                    .counters
                    .oversize_logged
                    .swap(true, Ordering::Relaxed)
                {
                    eprintln!(
                        "hetcomm {} link: closed a connection from {:?} whose record announces \
                         {len} bytes, more than this link's largest frame of {} bytes: the \
                         sender's max_message_bytes is larger than ours (further such records \
                         are only counted in oversize_records)",
                        T::NAME,
                        self.from,
                        shared.config.max_frame()
                    );
                }
                true
            }
        };
        if count {
            bump(&shared.counters.frames_dropped);
        }
        let _ = self.socket.shutdown_both();
    }
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
        assert_eq!(record_header(100), h);
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

    /// A stream that hands out its bytes in pieces of varying size (at most `max` per call),
    /// filling only the first buffer of a vectored read, as many sockets do. A blocking one is
    /// interrupted now and then; a `non_blocking` one would block between most pieces (in the
    /// middle of large frames too) and once it has nothing left.
    struct Chunky<'a> {
        data: &'a [u8],
        max: usize,
        calls: usize,
        non_blocking: bool,
    }

    impl<'a> Chunky<'a> {
        fn new(data: &'a [u8], max: usize) -> Self {
            Chunky {
                data,
                max,
                calls: 0,
                non_blocking: false,
            }
        }

        fn non_blocking(data: &'a [u8], max: usize) -> Self {
            Chunky {
                non_blocking: true,
                ..Chunky::new(data, max)
            }
        }
    }

    impl Read for Chunky<'_> {
        fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
            self.calls += 1;
            if self.non_blocking && (!self.calls.is_multiple_of(3) || self.data.is_empty()) {
                return Err(io::ErrorKind::WouldBlock.into());
            }
            if !self.non_blocking && self.calls % 5 == 4 {
                return Err(io::ErrorKind::Interrupted.into());
            }
            // 1, 2, … max, 1, 2, …: every split point shows up sooner or later.
            let n = (self.calls % self.max + 1)
                .min(buf.len())
                .min(self.data.len());
            buf[..n].copy_from_slice(&self.data[..n]);
            self.data = &self.data[n..];
            Ok(n)
        }
    }

    impl RecordSource for Chunky<'_> {}

    fn frame_of(len: usize, seed: u8) -> Vec<u8> {
        (0..len)
            .map(|i| (i as u8).wrapping_mul(31).wrapping_add(seed))
            .collect()
    }

    /// Frames around every size boundary of the reader, in an order that exercises the switch
    /// between buffered and direct reads both ways.
    fn mixed_frames() -> Vec<Vec<u8>> {
        let sizes = [
            0,
            1,
            64,
            DIRECT_READ_MIN,
            DIRECT_READ_MIN + 1,
            64,
            READ_BUF_LEN - RECORD_HEADER_LEN,
            READ_BUF_LEN + 48,
            READ_BUF_LEN + 48,
            3,
            1 << 20,
            READ_AHEAD_AFTER_LARGE,
            70_000,
            5,
        ];
        sizes
            .iter()
            .enumerate()
            .map(|(i, &n)| frame_of(n, i as u8))
            .collect()
    }

    fn stream_of(frames: &[Vec<u8>]) -> Vec<u8> {
        let mut s = Vec::new();
        for f in frames {
            append_record(&mut s, FrameParts::whole(f));
        }
        s
    }

    fn read_all<R: RecordSource>(r: &mut R, max_frame: usize) -> (Vec<Vec<u8>>, StreamEnd) {
        let mut reader = RecordReader::new(max_frame);
        let mut got = Vec::new();
        loop {
            match reader.next_record(r) {
                Ok(at) => got.push(reader.frame(at).to_vec()),
                Err(end) => return (got, end),
            }
        }
    }

    /// Like [`read_all`] with a reader that hands large frames out; also says which frames
    /// came out as their own buffer (with less than a step of spare capacity).
    fn read_all_handed_out<R: RecordSource>(
        r: &mut R,
        max_frame: usize,
    ) -> (Vec<(Vec<u8>, bool)>, StreamEnd) {
        let mut reader = RecordReader::handing_out(max_frame, BufferPool::new(1 << 20));
        let mut got = Vec::new();
        loop {
            match reader.next_record(r) {
                Ok(FrameAt::Large(len)) => {
                    let frame = reader.take_large();
                    assert!(frame.is_pooled());
                    // Kept, so none came back to the pool: each is a new buffer.
                    let frame = frame.into_vec();
                    assert_eq!(frame.len(), len);
                    assert!(
                        frame.capacity() < len + POOLED_BUF_STEP,
                        "a buffer of about the frame"
                    );
                    got.push((frame, true));
                }
                Ok(at) => got.push((reader.frame(at).to_vec(), false)),
                Err(end) => return (got, end),
            }
        }
    }

    #[test]
    fn a_reader_resumes_where_a_non_blocking_socket_left_it() {
        let frames = mixed_frames();
        let stream = stream_of(&frames);
        for hand_out in [false, true] {
            for max in [7, 5000, 200_000] {
                let mut reader = if hand_out {
                    RecordReader::handing_out(2 << 20, BufferPool::new(1 << 20))
                } else {
                    RecordReader::new(2 << 20)
                };
                let mut r = Chunky::non_blocking(&stream, max);
                let (mut got, mut pending) = (Vec::new(), 0);
                while got.len() < frames.len() {
                    match reader.next_record(&mut r) {
                        Ok(FrameAt::Large(len)) if hand_out => {
                            got.push(reader.take_large().into_vec());
                            assert_eq!(got.last().unwrap().len(), len);
                        }
                        Ok(at) => got.push(reader.frame(at).to_vec()),
                        Err(StreamEnd::Pending) => pending += 1,
                        Err(end) => panic!("hand_out {hand_out}, max {max}: ended with {end:?}"),
                    }
                    assert!(pending < 10_000_000, "no progress");
                }
                assert!(pending > 0);
                for (i, (g, f)) in got.iter().zip(&frames).enumerate() {
                    assert!(g == f, "hand_out {hand_out}, max {max}: frame {i}");
                }
                assert!(!reader.has_buffered_record());
                assert_eq!(reader.next_record(&mut r), Err(StreamEnd::Pending));
            }
        }
    }

    #[test]
    fn buffered_records_are_seen_without_reading() {
        let stream = stream_of(&[vec![1; 10], vec![2; 20], vec![3; 100_000]]);
        let mut reader = RecordReader::new(1 << 20);
        let mut r = &stream[..];
        // One read fills the buffer: the first record comes from it, the second is whole in
        // it, the third (large) is not.
        assert_eq!(reader.next_record(&mut r), Ok(FrameAt::Buffered(8, 18)));
        assert!(reader.has_buffered_record());
        assert!(matches!(
            reader.next_record(&mut r),
            Ok(FrameAt::Buffered(..))
        ));
        assert!(!reader.has_buffered_record());
        // A bad header counts as "there is something to report".
        let mut bad = stream_of(&[vec![1; 10], vec![2; 10]]);
        bad[18] = b'X';
        let mut reader = RecordReader::new(1 << 20);
        let mut r = &bad[..];
        assert!(reader.next_record(&mut r).is_ok());
        assert!(reader.has_buffered_record());
        assert_eq!(reader.next_record(&mut r), Err(StreamEnd::Bad));
    }

    #[test]
    fn handed_out_frames_come_back_to_the_readers_pool() {
        let frames: Vec<Vec<u8>> = (0..6u8)
            .map(|i| vec![i; 100_000 + usize::from(i)])
            .collect();
        let stream = stream_of(&frames);
        let pool = BufferPool::new(1 << 20);
        let mut reader = RecordReader::handing_out(2 << 20, pool.clone());
        let mut r = &stream[..];
        let mut first_ptr = None;
        for (i, f) in frames.iter().enumerate() {
            assert!(matches!(reader.next_record(&mut r), Ok(FrameAt::Large(_))));
            let frame = reader.take_large();
            assert_eq!(frame.as_slice(), &f[..], "frame {i}");
            // Each frame is dropped before the next is read: one buffer serves them all.
            let ptr = frame.as_ptr();
            assert_eq!(*first_ptr.get_or_insert(ptr), ptr, "frame {i}");
            drop(frame);
            assert!(pool.kept_bytes() >= f.len());
        }
        assert_eq!(reader.next_record(&mut r), Err(StreamEnd::Clean));
    }

    #[test]
    fn handing_out_reader_gives_each_large_frame_its_own_buffer() {
        let frames = mixed_frames();
        let stream = stream_of(&frames);
        let check = |got: &[(Vec<u8>, bool)], what: &str| {
            assert_eq!(got.len(), frames.len(), "{what}");
            for (i, ((g, own), f)) in got.iter().zip(&frames).enumerate() {
                assert!(g == f, "{what}: frame {i}");
                // Only frames read directly (large, not already buffered) are handed out.
                if *own {
                    assert!(f.len() > DIRECT_READ_MIN, "{what}: frame {i}");
                }
            }
            assert!(got.iter().any(|(_, own)| *own), "{what}: none handed out");
        };
        // No descriptor: the zero-filled path, whole reads and odd pieces.
        let (got, end) = read_all_handed_out(&mut &stream[..], 2 << 20);
        assert_eq!(end, StreamEnd::Clean);
        check(&got, "whole reads");
        for max in [1, 4096, 100_000] {
            let mut r = Chunky::new(&stream, max);
            let (got, end) = read_all_handed_out(&mut r, 2 << 20);
            assert_eq!(end, StreamEnd::Clean, "chunks of up to {max}");
            check(&got, &format!("chunks of up to {max}"));
        }
        // A real socket: read with readv(2) into uninitialised buffers.
        let (mut tx, mut rx) = std::os::unix::net::UnixStream::pair().unwrap();
        assert!(rx.raw_fd().is_some());
        let writer = std::thread::spawn(move || {
            tx.write_all(&stream).unwrap();
            // Cut in the middle of a large frame at the end.
            let mut last = Vec::new();
            append_record(&mut last, FrameParts::whole(&frame_of(100_000, 9)));
            tx.write_all(&last[..50_000]).unwrap();
        });
        let (got, end) = read_all_handed_out(&mut rx, 2 << 20);
        writer.join().unwrap();
        assert_eq!(end, StreamEnd::Cut);
        check(&got, "unix socket");
    }

    #[test]
    fn record_reader_splits_any_chunking_into_the_frames_sent() {
        let frames = mixed_frames();
        let stream = stream_of(&frames);
        // Whole reads (a slice fills every buffer of a vectored read), then odd pieces.
        let (got, end) = read_all(&mut &stream[..], 2 << 20);
        assert_eq!(end, StreamEnd::Clean);
        assert!(got == frames, "whole reads");
        for max in [1, 7, 4096, 100_000] {
            let mut r = Chunky::new(&stream, max);
            let (got, end) = read_all(&mut r, 2 << 20);
            assert_eq!(end, StreamEnd::Clean, "chunks of up to {max}");
            assert!(got == frames, "chunks of up to {max}");
        }
    }

    #[test]
    fn record_reader_reports_cut_and_bad_records() {
        let frames = mixed_frames();
        let stream = stream_of(&frames);
        // Cut inside a header, inside a small frame, inside a large one.
        for cut in [3, RECORD_HEADER_LEN + 1 + 4, stream.len() - 2] {
            let (got, end) = read_all(&mut &stream[..cut], 2 << 20);
            assert_eq!(end, StreamEnd::Cut, "cut at {cut}");
            assert!(got.len() < frames.len());
        }
        // A frame over max_frame ends the stream before its bytes are read.
        let (got, end) = read_all(&mut &stream[..], 100_000);
        assert!(
            matches!(end, StreamEnd::Oversize(n) if n > 100_000),
            "{end:?}"
        );
        assert_eq!(got.len(), 10);
        // Garbage after a good record.
        let mut s = stream_of(&frames[..3]);
        s.extend_from_slice(b"\xde\xad\xbe\xef garbage");
        let (got, end) = read_all(&mut &s[..], 2 << 20);
        assert_eq!((got.len(), end), (3, StreamEnd::Bad));
    }

    #[test]
    fn record_reader_reuses_its_buffers() {
        let frames: Vec<Vec<u8>> = (0..50).map(|i| frame_of(65_584, i)).collect();
        let stream = stream_of(&frames);
        let mut r = Chunky::new(&stream, 70_000);
        let mut reader = RecordReader::new(1 << 20);
        let first = reader.next_record(&mut r).unwrap();
        assert_eq!(first, FrameAt::Large(65_584));
        let ptr = reader.large.as_ptr();
        for f in &frames[1..] {
            let at = reader.next_record(&mut r).unwrap();
            assert!(reader.frame(at) == &f[..]);
        }
        assert_eq!(reader.large.as_ptr(), ptr, "large buffer reallocated");
    }

    /// A socket that takes at most `max` bytes per write, across buffers of a vectored write.
    struct Slow {
        out: Vec<u8>,
        max: usize,
        calls: usize,
    }

    impl Read for Slow {
        fn read(&mut self, _: &mut [u8]) -> io::Result<usize> {
            Ok(0)
        }
    }

    impl Write for Slow {
        fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
            self.write_vectored(&[IoSlice::new(buf)])
        }
        fn write_vectored(&mut self, bufs: &[IoSlice<'_>]) -> io::Result<usize> {
            self.calls += 1;
            if self.calls % 4 == 3 {
                return Err(io::ErrorKind::Interrupted.into());
            }
            let mut left = self.max;
            for b in bufs {
                let n = b.len().min(left);
                self.out.extend_from_slice(&b[..n]);
                left -= n;
            }
            Ok(self.max - left)
        }
        fn flush(&mut self) -> io::Result<()> {
            Ok(())
        }
    }

    impl StreamSocket for Slow {
        fn try_clone(&self) -> io::Result<Self> {
            Err(io::ErrorKind::Unsupported.into())
        }
        fn shutdown_both(&self) -> io::Result<()> {
            Ok(())
        }
        fn set_write_timeout(&self, _: Option<Duration>) -> io::Result<()> {
            Ok(())
        }
        fn set_read_timeout(&self, _: Option<Duration>) -> io::Result<()> {
            Ok(())
        }
    }

    /// Unix sockets whose connects wait until the test opens the gate, so that a test
    /// controls exactly when a connection comes up.
    #[cfg(unix)]
    struct GatedUnix {
        gate: Mutex<std::sync::mpsc::Receiver<()>>,
    }

    #[cfg(unix)]
    impl StreamTransport for GatedUnix {
        type Socket = std::os::unix::net::UnixStream;
        type Listener = std::os::unix::net::UnixListener;
        type Addr = crate::unix::UnixAddr;
        const NAME: &'static str = "gated";

        fn connect(&self, addr: &Self::Addr, _: Duration) -> io::Result<Self::Socket> {
            let _ = lock(&self.gate).recv();
            std::os::unix::net::UnixStream::connect(&addr.0)
        }
    }

    #[cfg(unix)]
    #[test]
    fn held_frames_count_against_the_connect_queue_and_stay_held_after_connecting() {
        use std::os::unix::net::UnixListener;

        let dir = std::env::temp_dir().join(format!("hetcomm-gated-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let (path_a, path_b) = (dir.join("a.sock"), dir.join("b.sock"));
        // B is a raw listener, so the test sees the bytes A writes.
        let raw_b = UnixListener::bind(&path_b).unwrap();
        let (open, gate) = std::sync::mpsc::channel();
        let transport = GatedUnix {
            gate: Mutex::new(gate),
        };
        let config = StreamConfig {
            connect_queue_frames: 4,
            ..StreamConfig::default()
        };
        struct Nobody;
        impl FrameSink for Nobody {
            fn on_frame(&self, _: &[u8], _: Peer) {}
        }
        let (a_id, b_id) = (SystemId(1), SystemId(2));
        let a = StreamLink::new(
            transport,
            a_id,
            UnixListener::bind(&path_a).unwrap(),
            BTreeMap::from([(b_id, crate::unix::UnixAddr(path_b.clone()))]),
            Arc::new(Nobody),
            config,
        )
        .unwrap();
        let f: Vec<Vec<u8>> = (0..5).map(|i| frame_of(20 + i, i as u8)).collect();
        a.send_held(b_id, &f[0]).unwrap();
        a.send_held(b_id, &f[1]).unwrap();
        a.send(b_id, &f[2]).unwrap(); // releases 0 and 1 with it
        a.send_held(b_id, &f[3]).unwrap();
        // Four frames wait, held ones included: the fifth is refused either way.
        for result in [a.send(b_id, &f[4]), a.send_held(b_id, &f[4])] {
            assert!(
                matches!(result, Err(LinkError::Congested { .. })),
                "{result:?}"
            );
        }
        assert_eq!(a.pending_bytes(), stream_of(&f[..4]).len());

        open.send(()).unwrap();
        let (mut conn, _) = raw_b.accept().unwrap();
        let mut expected = encode_hello(a_id).to_vec();
        expected.extend_from_slice(&stream_of(&f[..3]));
        let mut got = vec![0; expected.len()];
        conn.set_read_timeout(Some(Duration::from_secs(10)))
            .unwrap();
        conn.read_exact(&mut got).unwrap();
        assert!(got == expected, "hello and the released frames, in order");
        // The frame held after the send stays held on the new connection...
        conn.set_read_timeout(Some(Duration::from_millis(150)))
            .unwrap();
        let mut more = [0u8; 1];
        assert!(conn.read(&mut more).is_err(), "a held frame went out");
        assert_eq!(a.stream_stats().frames_sent, 3);
        // ...until the flush.
        a.flush().unwrap();
        let record = stream_of(&f[3..4]);
        let mut got = vec![0; record.len()];
        conn.set_read_timeout(Some(Duration::from_secs(10)))
            .unwrap();
        conn.read_exact(&mut got).unwrap();
        assert_eq!(got, record);
        assert_eq!(a.stream_stats().frames_sent, 4);
        assert_eq!(a.pending_bytes(), 0);
        drop(a);
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn partial_vectored_writes_are_resumed_exactly() {
        let held = stream_of(&mixed_frames()[..4]);
        let frame = frame_of(100_000, 9);
        let head = record_header(frame.len());
        let mut whole = held.clone();
        whole.extend_from_slice(&head);
        whole.extend_from_slice(&frame);
        for max in [1, 5, 8, 4096, 1 << 20] {
            let mut s = Slow {
                out: Vec::new(),
                max,
                calls: 0,
            };
            write_parts(&mut s, &[&held, &head, &frame], Duration::from_secs(5)).unwrap();
            assert!(s.out == whole, "writes of up to {max} bytes");
        }
        // Empty parts are skipped, and nothing to write is no write at all.
        let mut s = Slow {
            out: Vec::new(),
            max: 3,
            calls: 0,
        };
        write_parts(&mut s, &[&[], &head, &[]], Duration::from_secs(5)).unwrap();
        assert_eq!(s.out, head);
        let calls = s.calls;
        write_parts(&mut s, &[&[], &[]], Duration::from_secs(5)).unwrap();
        assert_eq!(s.calls, calls);
    }
}
