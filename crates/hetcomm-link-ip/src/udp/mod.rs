//! UDP: one socket per system, bound to its endpoint; sends go out with `send_to` on the
//! caller's thread (a streaming sender's given-away frames on the link's writer thread, see
//! "Write-behind"), and a receive thread hands frames to the sink — or, with
//! [`UdpConfig::driven`], a waiting thread reads the socket itself through
//! [`Link::readable`]. Unreliable and unordered, as declared in its [`LinkCaps`].
//!
//! # Datagram format
//!
//! Every datagram is one of three kinds, told apart by its first two bytes alone (the link never
//! reads a frame's own header: frames may be any bytes, sealed ones included):
//!
//! - **A whole frame**: a frame no longer than the datagram payload size
//!   ([`UdpConfig::datagram_payload`], the link's `mtu`) travels as one datagram holding
//!   exactly the frame, with nothing added. Anything that starts neither with `"HF"` nor with
//!   `"HB"` is handed up whole.
//! - **A batch** (starts with `"HB"`): frames held back by [`Link::send_held`] travel together
//!   as one datagram: a 4-byte batch header (magic `"HB"`, version 1, a reserved 0 byte), then
//!   one record per frame — its length as a u32 (little-endian) and the frame — at most `mtu`
//!   bytes in all. It is the stream links' record header split in two: magic and version once
//!   per datagram, the length once per frame. Any frame whose record fits is batched. A
//!   receiver hands every complete record's frame up in order, with one
//!   [`FrameSink::on_frames`] call labelled with the datagram's source; a record running past
//!   the end drops the rest of the datagram, and a batch header it does not read drops all of
//!   it, counted in [`UdpStats::bad_datagrams`]. A batch of one frame is sent as the frame
//!   alone.
//! - **A fragment** of a frame larger than `mtu`: a datagram that starts with this 20-byte
//!   fragment header (integers little-endian):
//!
//! | offset | size | field |
//! |---|---|---|
//! | 0 | 2 | magic `"HF"` |
//! | 2 | 1 | version, 1 |
//! | 3 | 1 | reserved, 0 |
//! | 4 | 2 | sending system's [`SystemId`] |
//! | 6 | 2 | fragment index, `0..count` |
//! | 8 | 2 | fragment count, ≥ 1 |
//! | 10 | 2 | reserved, 0 |
//! | 12 | 4 | fragmented-message id (u32, per sender, wraps) |
//! | 16 | 4 | total frame length in bytes (u32) |
//!
//! followed by that fragment's piece of the frame. Pieces are cut evenly: with
//! `chunk = ceil(total / count)`, fragment `i` holds bytes `i*chunk .. min((i+1)*chunk, total)`.
//! The receiver derives every piece's position and exact length from `total` and `count`
//! alone, so a fragment whose length is not the expected one is rejected, and fragments can
//! never overlap or leave gaps. A reassembled frame is handed up whole, never split as a batch.
//!
//! A frame that fits one datagram but would be mistaken for something else — it starts with
//! `"HF"` or `"HB"` — is sent as a one-fragment message, so any byte string round-trips
//! unambiguously.
//!
//! # Reassembly
//!
//! Fragments are collected per (source address, sender, message id). A message completes when
//! every fragment arrived; a message still incomplete [`UdpConfig::reassembly_timeout`] after
//! its first fragment is dropped and counted (a single lost piece loses the whole message —
//! the router retries).
//!
//! Memory follows the bytes that arrived, never the total a header announces (see
//! [`Reassembler`]): a message's buffer grows as its pieces arrive, pieces ahead of a gap are
//! kept apart until it fills. Everything held counts against
//! [`UdpConfig::reassembly_limit_bytes`]; over it, the oldest incomplete message of the source
//! address holding the most is dropped (and counted) first, so a flooding source evicts its own
//! messages before anyone else's, and one source holds at most [`MAX_PARTIALS_PER_SOURCE`]
//! messages. [`LinkStats::buffered_bytes`] reports the bytes held.
//!
//! # Handing frames over
//!
//! To a sink that keeps frames ([`FrameSink::takes_frames`], as the runtime's does), a
//! reassembled frame, and a frame of 16 KiB or more that came in one datagram (copied out of
//! the reused receive buffer), is handed over with [`FrameSink::on_frame_owned`]: it becomes
//! the message's payload without another copy. Buffers of 16 KiB and more, for reassembly and
//! for handing over, come from a pool of the link's ([`BufferPool`], up to 8 MiB kept; 1 MiB
//! when the sink does not keep frames) and go back to it when the message is dropped, or when
//! an incomplete message is: a receiver of large frames allocates and frees no memory per
//! frame (fresh 64 KiB buffers per frame cost the allocator's trims of the heap and the page
//! faults that follow: about half the receiver's CPU time at 64 KiB, secured or not). Buffers are only taken
//! for fragments that passed the checks below, in the sizes that [`Reassembler`] would
//! allocate, and charged against the reassembly limit for their capacity.
//!
//! # Bad input
//!
//! A datagram starting with `"HF"` whose header is malformed (truncated, wrong version,
//! non-zero reserved bytes, index ≥ count, total of 0 or above `max_frame`, count larger than
//! the total or inconsistent with it, a piece of the wrong length, or disagreeing with earlier
//! fragments of the same message) is dropped and counted, and so is the malformed tail of a
//! batch. Beyond that the link does not look inside frames (the router's decoder checks them).
//!
//! # Batching
//!
//! [`Link::send_held`] appends a frame's record to its peer's batch (one buffer per peer, of
//! `mtu` bytes, allocated at its first use) instead of sending it. The batch goes
//! out as one datagram when the next frame would not fit (or no further frame could), at the
//! next plain [`Link::send`] to that peer (which joins the batch when it can, so both leave in
//! one datagram), before a frame that cannot be batched, at [`Link::flush`], and when the link
//! is dropped. Frames to one peer thus leave in the order they were given. An error returned by
//! `send` or `send_held` concerns the frame passed in; held frames lost because their batch
//! could not be sent are counted in [`UdpStats::held_frames_dropped`] (and `flush` returns the
//! first such error).
//!
//! # Write-behind
//!
//! A frame given away with [`Link::send_owned`] (the security layer's sealed frames of 16 KiB
//! and more) is sent on the caller's thread, like a `send`, unless the caller streams: it
//! comes back to the same peer within 20 µs of the return of its previous given-away frame.
//! Then the frame goes to the peer's queue and the link's writer thread (one per link, started
//! by the first such frame) sends it, whole or in fragments, while the caller prepares its
//! next frame: for a secured sender, the next seal. Senders that wait for an answer between
//! frames never hand off, so their latency does not change. That is
//! [`UdpConfig::write_behind`]'s default, [`WriteBehind::Streaming`]; `Always` hands every
//! given-away frame to the writer, `Never` none.
//! - Order: while the writer has a peer's frames, a `send`, a `send_held` that sends its batch,
//!   and `flush` wait for it to be done with them before they send, so that nothing overtakes
//!   what was sent first (UDP itself does not promise order; on one host it keeps it).
//! - Room: a peer's queue holds at most 1 MiB (one larger frame when it is empty). A sender
//!   waits up to 2 s for room, or for the writer, then gets [`LinkError::Congested`] and its
//!   frame is not taken.
//! - Failures: a frame the writer cannot send is counted in [`UdpStats::held_frames_dropped`]
//!   (part of [`LinkStats::frames_dropped`]); the caller was told it was taken, as for any
//!   unconfirmed datagram. The frames after it are still sent.
//! - Counting: [`UdpStats::frames_written_behind`] counts the frames the writer sent.
//!   [`Link::stats`]' `buffered_bytes` includes queued bytes and bytes being sent.
//! - Closing: dropping the link lets the writer send its queue first.
//! - What it buys: a sender's thread seals while another thread sends, so with a core to
//!   spare a secured stream of large frames leaves at the unsecured rate. On a machine whose
//!   cores are all busy (the benchmark VM's two, shared with the receiver) it changes nothing:
//!   the same work is done, on two threads instead of one.
//!
//! # Driven receive
//!
//! With [`UdpConfig::driven`] the link starts no receive thread; [`Link::readable`] returns
//! its receive side, whose [`Readable::read_ready`] reads without blocking (`MSG_DONTWAIT`,
//! while the socket itself stays blocking so that sends still wait for buffer space), hands
//! the frames to the sink on the caller's thread and expires incomplete messages. The
//! receive state sits behind a mutex that `read_ready` only tries: a second, concurrent
//! caller reads nothing rather than waiting.
//!
//! # Identity
//!
//! The source address names the sender: a datagram from a fleet endpoint is labelled
//! [`Peer::System`]. A datagram from any other address is still handed up, labelled
//! [`Peer::Unknown`], and counted in [`UdpStats::from_unknown_address`]: a fleet system bound
//! to `0.0.0.0` on a multi-homed robot may send from an address other than the one in the fleet
//! file, and the router checks the frame header's source anyway. A fragment whose sender field
//! disagrees with the fleet system at its source address is dropped, and so is one from an
//! unknown address whose sender field names no fleet system ([`FragmentError::UnknownSender`]).
//!
//! # Datagram size
//!
//! The default payload of 1472 bytes fits an Ethernet MTU of 1500 minus the IPv4 (20) and UDP
//! (8) headers, so no fragment relies on IP fragmentation. On loopback (or a network known to
//! carry jumbo datagrams) [`UdpConfig::loopback`] uses 65000, close to the IPv4 limit of 65507,
//! which cuts a 1 MiB message into 17 datagrams instead of 723. The socket buffers are raised
//! to [`UdpConfig::socket_buffer_bytes`] (the kernel may cap it, e.g. at `net.core.rmem_max`) so
//! a burst of fragments is not dropped by the receiving socket.
//!
//! # Kernel drops
//!
//! Datagrams the kernel drops before the link reads them (the socket's receive buffer was
//! full, a checksum was bad) never reach the link; where the OS reports them they are counted
//! in [`UdpStats::kernel_drops`] and [`LinkStats::kernel_drops`]. On Linux the count is the
//! socket's own drop counter, read with `getsockopt(SO_MEMINFO)` when the stats are asked for,
//! so receiving costs nothing extra. Elsewhere it stays 0. It counts datagrams, not frames (a
//! dropped datagram may have held a batch of frames or one fragment of a frame), and is not
//! part of `frames_dropped`. The kernel's counter is 32 bits wide: a wrap between two reads of
//! the stats is accounted for, as long as fewer than 2³² datagrams are dropped in between.

mod batch;
mod behind;
mod fragment;
mod link;
mod reassembly;
mod receive;
#[cfg(test)]
mod tests;

use parking_lot::{Condvar, Mutex};
use std::collections::BTreeMap;
use std::net::{SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicBool, AtomicU32, AtomicU64};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Duration;

use hetcomm_core::wire::{HEADER_LEN, MAX_PAYLOAD};
use hetcomm_core::SystemId;

use crate::common::{add, lock, WriteBehind, Writer};
use crate::IpOpenError;

// The batch framing is hetcomm-link's (shared with other links); named here as before.
use behind::Behind;
pub use fragment::{parse_fragment, FragmentError, FragmentHeader};
pub use hetcomm_link::batch::{
    batch_records, BatchFrames, BATCH_HEADER_LEN, BATCH_LENGTH_LEN, BATCH_MAGIC, BATCH_VERSION,
};
pub use reassembly::{
    Reassembler, Reassembly, MAX_PARTIALS_PER_SOURCE, MAX_REMEMBERED_COMPLETIONS,
};
use receive::DrivenReceiver;

// Named only by doc links.
#[cfg(doc)]
use hetcomm_core::BufferPool;
#[cfg(doc)]
use hetcomm_link::{FrameSink, Link, LinkCaps, LinkError, LinkStats, Peer, Readable};

/// Magic of a fragment header: `"HF"`.
pub const FRAGMENT_MAGIC: [u8; 2] = *b"HF";
/// Version of the fragment header.
pub const FRAGMENT_VERSION: u8 = 1;
/// Size of the fragment header.
pub const FRAGMENT_HEADER_LEN: usize = 20;
/// The largest UDP payload over IPv4.
pub const MAX_DATAGRAM_PAYLOAD: usize = 65_507;
/// The default datagram payload: an Ethernet MTU of 1500 minus IPv4 and UDP headers.
pub const DEFAULT_DATAGRAM_PAYLOAD: usize = 1472;
/// The datagram payload [`UdpConfig::loopback`] uses.
pub const LOOPBACK_DATAGRAM_PAYLOAD: usize = 65_000;

/// Tunables of a [`UdpLink`].
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct UdpConfig {
    /// Largest datagram payload sent, bytes: the link's `mtu` (default
    /// [`DEFAULT_DATAGRAM_PAYLOAD`]; from `FRAGMENT_HEADER_LEN + 1` up to
    /// [`MAX_DATAGRAM_PAYLOAD`]).
    pub datagram_payload: usize,
    /// Largest message payload accepted, bytes; `None`: the codec's limit. Frames may be this
    /// plus the 48-byte header.
    pub max_message_bytes: Option<usize>,
    /// Most bytes held for incomplete messages at once (default 32 MiB).
    pub reassembly_limit_bytes: usize,
    /// How long after its first fragment an incomplete message is dropped (default 2 s).
    pub reassembly_timeout: Duration,
    /// Send and receive socket buffer size requested from the kernel (default 4 MiB).
    pub socket_buffer_bytes: usize,
    /// Start no receive thread: a thread waiting for messages reads the socket itself through
    /// [`Link::readable`] (see the module docs, "Driven receive"). Nothing is received until
    /// someone calls [`Readable::read_ready`]. Default `false`: the link's own thread receives.
    pub driven: bool,
    /// Which given-away frames the link's writer thread sends behind the sender (see
    /// "Write-behind" above). Default [`WriteBehind::Streaming`].
    pub write_behind: WriteBehind,
}

impl Default for UdpConfig {
    fn default() -> Self {
        UdpConfig {
            datagram_payload: DEFAULT_DATAGRAM_PAYLOAD,
            max_message_bytes: None,
            reassembly_limit_bytes: 32 * 1024 * 1024,
            reassembly_timeout: Duration::from_secs(2),
            socket_buffer_bytes: 4 * 1024 * 1024,
            driven: false,
            write_behind: WriteBehind::default(),
        }
    }
}

impl UdpConfig {
    /// The defaults with [`LOOPBACK_DATAGRAM_PAYLOAD`]-byte datagrams, for systems on one host.
    pub fn loopback() -> Self {
        UdpConfig {
            datagram_payload: LOOPBACK_DATAGRAM_PAYLOAD,
            ..UdpConfig::default()
        }
    }

    /// The largest frame accepted: header plus `max_message_bytes` (capped by the codec's
    /// limit, by what the reassembly buffer can hold and by 65535 fragments).
    pub fn max_frame(&self) -> usize {
        let by_message = HEADER_LEN
            + self
                .max_message_bytes
                .unwrap_or(MAX_PAYLOAD)
                .min(MAX_PAYLOAD);
        let by_fragments =
            usize::from(u16::MAX) * self.datagram_payload.saturating_sub(FRAGMENT_HEADER_LEN);
        by_message
            .min(self.reassembly_limit_bytes)
            .min(by_fragments)
            .max(self.datagram_payload.min(by_message))
    }

    fn check(&self) -> Result<(), IpOpenError> {
        if !(FRAGMENT_HEADER_LEN + 1..=MAX_DATAGRAM_PAYLOAD).contains(&self.datagram_payload) {
            return Err(IpOpenError::BadConfig {
                field: "datagram_payload",
                reason: format!(
                    "{} is outside {}..={MAX_DATAGRAM_PAYLOAD}",
                    self.datagram_payload,
                    FRAGMENT_HEADER_LEN + 1
                ),
            });
        }
        if self.reassembly_timeout.is_zero() {
            return Err(IpOpenError::BadConfig {
                field: "reassembly_timeout",
                reason: "must be longer than zero".into(),
            });
        }
        Ok(())
    }
}

/// Counters of a [`UdpLink`]; [`Link::stats`] reports the subset [`LinkStats`] has.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct UdpStats {
    /// Frames fully handed to the socket, alone, in fragments or in a batch.
    pub frames_sent: u64,
    /// Datagrams handed to the socket: whole frames, batches and fragments.
    pub datagrams_sent: u64,
    /// Batch datagrams sent (each carries one or more held frames).
    pub batches_sent: u64,
    /// Fragment datagrams sent (0 while every frame fits one datagram).
    pub fragments_sent: u64,
    /// Held frames dropped because their batch could not be sent, and frames the writer
    /// thread could not send (see "Write-behind" in the module docs).
    pub held_frames_dropped: u64,
    /// Frames the link's writer thread sent behind a streaming sender (see "Write-behind" in
    /// the module docs).
    pub frames_written_behind: u64,
    /// Frames handed to the sink.
    pub frames_received: u64,
    /// Batch datagrams (`"HB"`) received with at least one frame.
    pub batches_received: u64,
    /// Everything dropped: bad datagrams, incomplete messages given up, held frames whose
    /// batch could not be sent and frames the writer could not send.
    pub frames_dropped: u64,
    /// Malformed fragment datagrams, batch datagrams with a header not read, no record or an
    /// incomplete last record, dropped (in part).
    pub bad_datagrams: u64,
    /// Incomplete messages dropped because their time ran out.
    pub reassembly_timeouts: u64,
    /// Incomplete messages dropped to make room (or refused for being over the limit).
    pub reassembly_evictions: u64,
    /// Fragments dropped as duplicates: of a message still incomplete, or arriving late, after
    /// their message was completed and handed up. Not part of `frames_dropped` (the frame
    /// was delivered, or will be).
    pub duplicate_fragments: u64,
    /// Well-formed fragments of frames larger than this link's `max_frame` (the sender's
    /// `max_message_bytes` is larger than ours), dropped. Each is also one of `bad_datagrams`;
    /// the first is also logged to standard error.
    pub oversize_fragments: u64,
    /// Frames received from an address that is no fleet endpoint (handed up as
    /// [`Peer::Unknown`]).
    pub from_unknown_address: u64,
    /// Bytes held for incomplete messages now, and bytes of frames queued for the writer.
    pub buffered_bytes: u64,
    /// Datagrams the kernel dropped at this link's socket before the link could read them
    /// (see the module docs, "Kernel drops"); 0 where the OS does not report them.
    pub kernel_drops: u64,
}

#[derive(Default)]
struct UdpCounters {
    frames_sent: AtomicU64,
    datagrams_sent: AtomicU64,
    batches_sent: AtomicU64,
    fragments_sent: AtomicU64,
    held_frames_dropped: AtomicU64,
    frames_written_behind: AtomicU64,
    frames_received: AtomicU64,
    batches_received: AtomicU64,
    bad_datagrams: AtomicU64,
    reassembly_timeouts: AtomicU64,
    reassembly_evictions: AtomicU64,
    duplicate_fragments: AtomicU64,
    oversize_fragments: AtomicU64,
    /// The first oversize fragment has been logged.
    oversize_logged: AtomicBool,
    from_unknown_address: AtomicU64,
    buffered_bytes: AtomicU64,
}

struct Shared {
    closing: AtomicBool,
    counters: UdpCounters,
}

/// Frames held for one peer, to go out as one datagram.
#[derive(Default)]
struct Batch {
    /// The batch header, then one record (length, frame) per held frame, at most `mtu` bytes;
    /// empty while nothing is held.
    buf: Vec<u8>,
    /// How many frames `buf` holds.
    frames: u64,
}

/// A peer's address, its batch of held frames and its frames queued for the writer.
struct UdpPeer {
    addr: SocketAddr,
    batch: Mutex<Batch>,
    behind: Mutex<Behind>,
    /// Signalled when the writer takes this peer's queued frames or finishes with them
    /// (senders wait on it for room, or for the writer to be done before they send).
    room: Condvar,
}

/// Who reads the socket.
enum RxSide {
    /// The link's own receive thread (joined on drop).
    Thread(Option<JoinHandle<()>>),
    /// Whichever thread calls [`Readable::read_ready`].
    Driven(Box<DrivenReceiver>),
}

/// A system's UDP endpoint; see the module docs.
pub struct UdpLink {
    tx: Arc<SendSide>,
    local_addr: SocketAddr,
    config: UdpConfig,
    rx: RxSide,
    /// The kernel's drop counter as last read (see "Kernel drops").
    kernel_drops: Mutex<KernelDrops>,
}

/// The sending side of a [`UdpLink`], shared with its writer thread.
struct SendSide {
    local: SystemId,
    socket: Arc<UdpSocket>,
    peers: BTreeMap<SystemId, UdpPeer>,
    /// The datagram payload size.
    mtu: usize,
    max_frame: usize,
    next_message_id: AtomicU32,
    shared: Arc<Shared>,
    /// Sends frames behind a streaming sender (see "Write-behind" in the module docs).
    writer: Arc<Writer>,
    /// Which given-away frames go to the writer.
    write_behind: WriteBehind,
}

/// The kernel's 32-bit drop counter, read now and then, turned into a 64-bit total.
#[derive(Default)]
struct KernelDrops {
    /// The counter as last read.
    last: u32,
    /// Every drop seen.
    total: u64,
}

impl KernelDrops {
    /// Takes the counter's value now (read after the previous one); adds what is new,
    /// wrapping at 2³².
    fn update(&mut self, now: u32) {
        self.total += u64::from(now.wrapping_sub(self.last));
        self.last = now;
    }
}
