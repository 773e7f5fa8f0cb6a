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
//! # Write-behind
//!
//! A frame given away with [`Link::send_owned`] (the security layer's sealed frames of 16 KiB
//! and more) is written on the caller's thread, like a `send`, unless the caller streams: it
//! comes back to the same peer within 20 µs of the return of its previous given-away frame.
//! Then the frame goes to the peer's write-behind queue and the link's writer thread (one per
//! link, started by the first such frame) writes it. It writes everything queued for the peer
//! in one vectored write, while the caller prepares its next frame. For a secured sender that
//! is the next seal. Senders that wait for an answer between frames never hand off, so their
//! latency does not change. That is [`StreamConfig::write_behind`]'s default,
//! [`WriteBehind::Streaming`]; `Always` hands every given-away frame to the writer (a sender
//! known to stream whose frames take longer than 20 µs to prepare, as a slow CPU's seal of
//! a 64 KiB frame does), `Never` none.
//! - Order: while the writer has a peer's frames, every other frame to that peer goes behind
//!   them. A `send`, `send_parts` or `send_held` frame is copied into the queue, and `flush`
//!   moves the held batch there. Nothing overtakes what was sent first.
//! - Room: a peer's queue holds at most 1 MiB (one larger frame when it is empty). A sender
//!   waits for room up to [`StreamConfig::write_timeout`], then gets [`LinkError::Congested`]
//!   and the frame is not taken. Peers take turns: one write each.
//! - Failures: a write that fails behind the sender drops the connection, as a failed `send`
//!   does. Every frame it had, and every frame still queued, is counted in
//!   [`StreamStats::held_frames_dropped`] (part of [`LinkStats::frames_dropped`]), and
//!   [`StreamStats::write_failures`] counts the write. The next send reconnects.
//! - Counting: [`StreamStats::frames_written_behind`] counts the frames the writer wrote.
//!   [`Link::stats`]' `buffered_bytes` includes queued bytes and bytes being written.
//! - Closing: dropping the link lets the writer finish its queue (each write bounded by the
//!   write timeout) before the connections are shut.
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

mod behind;
mod connection;
mod framing;
mod link;
mod poller;
mod reader;
#[cfg(test)]
mod tests;

use parking_lot::{Condvar, Mutex};
use std::collections::{BTreeMap, HashMap};
use std::fmt;
use std::io::{self, Read, Write};
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use hetcomm_core::wire::{HEADER_LEN, MAX_PAYLOAD};
use hetcomm_core::SystemId;
use hetcomm_link::FrameSink;

pub(crate) use crate::common::{add, bump, lock};
use crate::common::{WriteBehind, Writer};
use behind::Behind;
pub use framing::{decode_hello, decode_record_header, encode_hello};
use hetcomm_link::readiness::WakeFd;
use poller::ConnSet;

// Named only by doc links.
#[cfg(doc)]
use hetcomm_core::BufferPool;
#[cfg(doc)]
use hetcomm_link::{Link, LinkError, LinkStats, Peer, Readable};
#[cfg(doc)]
use poller::Permit;

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
    fn raw_fd(&self) -> Option<std::os::fd::BorrowedFd<'_>> {
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
    fn raw_fd(&self) -> Option<std::os::fd::BorrowedFd<'_>> {
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
    /// Which given-away frames the link's writer thread writes behind the sender (see
    /// "Write-behind" above). Default [`WriteBehind::Streaming`].
    pub write_behind: WriteBehind,
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
            write_behind: WriteBehind::default(),
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
    /// Frames the link's writer thread wrote behind a streaming sender (see "Write-behind" in
    /// the module docs); also counted in `frames_sent`.
    pub frames_written_behind: u64,
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
    frames_written_behind: AtomicU64,
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
    /// Signalled when the writer takes this peer's queued records or finishes with them
    /// (see "Write-behind" in the module docs).
    room: Condvar,
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
    /// Frames the writer thread writes (see "Write-behind" in the module docs).
    behind: Behind<S>,
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
            behind: Behind::new(),
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

    /// Shuts the connection down and forgets it, the write-behind handle with it: after a
    /// failed (perhaps half-done) write it can no longer be framed. The next send reconnects.
    fn drop_connection(&mut self)
    where
        S: StreamSocket,
    {
        if let Some(s) = self.conn.take() {
            let _ = s.shutdown_both();
        }
        self.behind.connection_dropped();
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
    /// Reader threads that have finished their connection and are ending: joined at the
    /// next reader's start and when the link drops, so no thread outlives the link.
    finished_readers: Mutex<Vec<std::thread::JoinHandle<()>>>,
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
    waker: Option<Arc<WakeFd>>,
    /// The thread that writes behind streaming senders, once one has.
    writer: Arc<Writer>,
}
