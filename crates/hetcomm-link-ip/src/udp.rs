//! UDP: one socket per system, bound to its endpoint; sends go out with `send_to` on the
//! caller's thread, and a receive thread hands frames to the sink — or, with
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

use std::collections::{BTreeMap, HashMap};
use std::io::{self, IoSlice};
use std::mem::MaybeUninit;
use std::net::{IpAddr, Ipv4Addr, Ipv6Addr, SocketAddr, ToSocketAddrs, UdpSocket};
use std::os::fd::{AsRawFd, RawFd};
use std::sync::atomic::{AtomicBool, AtomicU32, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, TryLockError};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use hetcomm_core::wire::{HEADER_LEN, MAX_PAYLOAD};
use hetcomm_core::SystemId;
use hetcomm_link::{FrameSink, Link, LinkCaps, LinkError, LinkStats, Peer, Readable};

use crate::common::{add, lock};
use crate::OpenError;

/// Magic of a fragment header: `"HF"`.
pub const FRAGMENT_MAGIC: [u8; 2] = *b"HF";
/// Version of the fragment header.
pub const FRAGMENT_VERSION: u8 = 1;
/// Size of the fragment header.
pub const FRAGMENT_HEADER_LEN: usize = 20;
/// Magic of a batch datagram: `"HB"`.
pub const BATCH_MAGIC: [u8; 2] = *b"HB";
/// Version of the batch header.
pub const BATCH_VERSION: u8 = 1;
/// Size of the batch header: magic, version, a reserved byte.
pub const BATCH_HEADER_LEN: usize = 4;
/// Size of the length (u32, little-endian) in front of each frame of a batch.
pub const BATCH_LENGTH_LEN: usize = 4;
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

    fn check(&self) -> Result<(), OpenError> {
        if !(FRAGMENT_HEADER_LEN + 1..=MAX_DATAGRAM_PAYLOAD).contains(&self.datagram_payload) {
            return Err(OpenError::BadConfig {
                field: "datagram_payload",
                reason: format!(
                    "{} is outside {}..={MAX_DATAGRAM_PAYLOAD}",
                    self.datagram_payload,
                    FRAGMENT_HEADER_LEN + 1
                ),
            });
        }
        if self.reassembly_timeout.is_zero() {
            return Err(OpenError::BadConfig {
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
    /// Held frames dropped because their batch could not be sent.
    pub held_frames_dropped: u64,
    /// Frames handed to the sink.
    pub frames_received: u64,
    /// Batch datagrams (`"HB"`) received with at least one frame.
    pub batches_received: u64,
    /// Everything dropped: bad datagrams, incomplete messages given up, and held frames whose
    /// batch could not be sent.
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
    /// Bytes held for incomplete messages now.
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

/// A parsed fragment header.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FragmentHeader {
    /// The sending system.
    pub sender: SystemId,
    /// This fragment's index.
    pub index: u16,
    /// How many fragments the message has.
    pub count: u16,
    /// The message id, unique per sender until it wraps.
    pub message_id: u32,
    /// The whole frame's length.
    pub total: u32,
}

impl FragmentHeader {
    /// Encodes the header.
    pub fn encode(&self) -> [u8; FRAGMENT_HEADER_LEN] {
        let mut h = [0u8; FRAGMENT_HEADER_LEN];
        h[0..2].copy_from_slice(&FRAGMENT_MAGIC);
        h[2] = FRAGMENT_VERSION;
        h[4..6].copy_from_slice(&self.sender.0.to_le_bytes());
        h[6..8].copy_from_slice(&self.index.to_le_bytes());
        h[8..10].copy_from_slice(&self.count.to_le_bytes());
        h[12..16].copy_from_slice(&self.message_id.to_le_bytes());
        h[16..20].copy_from_slice(&self.total.to_le_bytes());
        h
    }

    /// The byte range of fragment `index` within the frame, derived from `total` and `count`.
    fn piece_range(&self) -> std::ops::Range<usize> {
        let (total, count) = (self.total as usize, usize::from(self.count));
        let chunk = total.div_ceil(count);
        let start = usize::from(self.index) * chunk;
        start..(start + chunk).min(total)
    }
}

/// Why a fragment datagram was rejected.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum FragmentError {
    /// Shorter than the fragment header.
    #[error("fragment of {len} bytes is shorter than the {FRAGMENT_HEADER_LEN}-byte header")]
    Truncated {
        /// Bytes received.
        len: usize,
    },
    /// Wrong version or non-zero reserved bytes.
    #[error("fragment header version {version} or reserved bytes not understood")]
    BadHeader {
        /// The version byte found.
        version: u8,
    },
    /// Index, count and total do not fit together.
    #[error("fragment {index} of {count} for a {total}-byte frame is impossible (limit {max})")]
    BadGeometry {
        /// Declared index.
        index: u16,
        /// Declared count.
        count: u16,
        /// Declared total.
        total: u32,
        /// The receiver's `max_frame`.
        max: usize,
    },
    /// The piece is not as long as `total` and `count` say.
    #[error("fragment {index} carries {found} bytes, expected {expected}")]
    BadLength {
        /// Declared index.
        index: u16,
        /// Bytes carried.
        found: usize,
        /// Bytes expected.
        expected: usize,
    },
    /// Count or total differ from earlier fragments of the same message.
    #[error("fragment disagrees with earlier fragments of message {message_id}")]
    Inconsistent {
        /// The message id.
        message_id: u32,
    },
    /// The sender field names another system than the one at the source address.
    #[error("fragment claims sender {claimed} but comes from system {actual}'s address")]
    WrongSender {
        /// The sender field.
        claimed: SystemId,
        /// The system at the source address.
        actual: SystemId,
    },
    /// The sender field names no fleet system (from an address that is no fleet endpoint).
    #[error("fragment claims sender {claimed}, which is no fleet system")]
    UnknownSender {
        /// The sender field.
        claimed: SystemId,
    },
}

/// Parses and checks a fragment datagram (which starts with [`FRAGMENT_MAGIC`]) against
/// `max_frame`; returns the header and the piece.
pub fn parse_fragment(
    datagram: &[u8],
    max_frame: usize,
) -> Result<(FragmentHeader, &[u8]), FragmentError> {
    if datagram.len() < FRAGMENT_HEADER_LEN {
        return Err(FragmentError::Truncated {
            len: datagram.len(),
        });
    }
    let d = datagram;
    let version = d[2];
    if d[0..2] != FRAGMENT_MAGIC || version != FRAGMENT_VERSION || d[3] != 0 || d[10..12] != [0, 0]
    {
        return Err(FragmentError::BadHeader { version });
    }
    let u16_at = |at: usize| u16::from_le_bytes([d[at], d[at + 1]]);
    let h = FragmentHeader {
        sender: SystemId(u16_at(4)),
        index: u16_at(6),
        count: u16_at(8),
        message_id: u32::from_le_bytes([d[12], d[13], d[14], d[15]]),
        total: u32::from_le_bytes([d[16], d[17], d[18], d[19]]),
    };
    let (total, count) = (h.total as usize, usize::from(h.count));
    // Every piece must be non-empty: (count - 1) full chunks must leave bytes for the last.
    let geometry_ok = count >= 1
        && h.index < h.count
        && total >= 1
        && total <= max_frame
        && count <= total
        && (count - 1) * total.div_ceil(count) < total;
    if !geometry_ok {
        return Err(FragmentError::BadGeometry {
            index: h.index,
            count: h.count,
            total: h.total,
            max: max_frame,
        });
    }
    let piece = &d[FRAGMENT_HEADER_LEN..];
    let expected = h.piece_range().len();
    if piece.len() != expected {
        return Err(FragmentError::BadLength {
            index: h.index,
            found: piece.len(),
            expected,
        });
    }
    Ok((h, piece))
}

type MessageKey = (SocketAddr, SystemId, u32);

/// Bytes a partial message is charged for beyond its pieces (its bookkeeping).
const PARTIAL_OVERHEAD: usize = 128;
/// Bytes charged per piece that arrived ahead of its turn (its map entry).
const PIECE_OVERHEAD: usize = 32;
/// The first contiguous buffer of a message holds at most this many pieces: a fragment's
/// header never makes the receiver reserve much more than the bytes it has received.
const FIRST_RESERVE_PIECES: usize = 4;
/// Most incomplete messages from one source address at once; a further one evicts that
/// source's oldest.
pub const MAX_PARTIALS_PER_SOURCE: usize = 64;
/// Most recently completed messages remembered (for [`UdpConfig::reassembly_timeout`]) so
/// that their late duplicate fragments are recognised.
pub const MAX_REMEMBERED_COMPLETIONS: usize = 4096;

struct Partial {
    total: u32,
    count: u16,
    started: Instant,
    /// Pieces `0..next`, in order: the start of the frame. Grows as pieces arrive.
    head: Vec<u8>,
    /// The next piece `head` takes.
    next: u16,
    /// Pieces that arrived ahead of their turn, by index.
    ahead: BTreeMap<u16, Vec<u8>>,
    /// Bytes in `ahead`.
    ahead_bytes: usize,
    /// Bytes this message is charged for in [`Reassembler::held_bytes`].
    charged: usize,
}

impl Partial {
    fn has(&self, index: u16) -> bool {
        index < self.next || self.ahead.contains_key(&index)
    }

    /// What the message costs now: its buffers (by capacity) and bookkeeping.
    fn cost(&self) -> usize {
        PARTIAL_OVERHEAD
            + self.head.capacity()
            + self.ahead_bytes
            + self.ahead.len() * PIECE_OVERHEAD
    }

    /// Takes piece `index` (not held yet).
    fn insert(&mut self, index: u16, piece: &[u8]) {
        if index != self.next {
            self.ahead_bytes += piece.len();
            self.ahead.insert(index, piece.to_vec());
            return;
        }
        self.append(piece);
        while let Some(p) = self.ahead.remove(&self.next) {
            self.ahead_bytes -= p.len();
            self.append(&p);
        }
    }

    /// Appends the next piece to `head`, growing it by at most doubling (and at first by a few
    /// pieces), never past `total`.
    fn append(&mut self, piece: &[u8]) {
        let total = self.total as usize;
        let need = self.head.len() + piece.len();
        if need > self.head.capacity() {
            let chunk = total.div_ceil(usize::from(self.count));
            let target = need
                .max(self.head.capacity() * 2)
                .max(FIRST_RESERVE_PIECES * chunk)
                .min(total);
            self.head.reserve_exact(target - self.head.len());
        }
        self.head.extend_from_slice(piece);
        self.next += 1;
    }
}

/// What one source address holds.
#[derive(Default)]
struct SourceUse {
    bytes: usize,
    partials: usize,
}

/// What [`Reassembler::on_fragment`] made of a fragment.
#[derive(Debug, PartialEq, Eq)]
pub enum Reassembly {
    /// The message is complete: here is the frame.
    Complete(Vec<u8>),
    /// More fragments are needed.
    Pending,
    /// A fragment already taken: of a message still incomplete, or of one completed within
    /// the reassembly timeout (a late duplicate). Dropped; nothing is held for it.
    Duplicate,
    /// The fragment could not be used; `dropped` incomplete messages were given up with it.
    Rejected {
        /// Why.
        error: FragmentError,
        /// Incomplete messages dropped as a consequence (an inconsistent message).
        dropped: usize,
    },
}

/// Bounded, time-limited reassembly of fragmented messages; sans-IO (time is passed in), so it
/// is tested without sockets.
///
/// Memory follows what arrived, not what a header announces: a message's buffer grows as its
/// pieces arrive (the first reservation is at most [`FIRST_RESERVE_PIECES`] pieces, later ones
/// at most double it), and pieces that arrive ahead of their turn are kept apart until the
/// gap before them fills. Everything held, bookkeeping included, is charged against the limit.
/// When a new piece takes the total over the limit, the oldest message of the source address
/// holding the most is dropped, until it fits: a source flooding the receiver loses its own
/// messages first. One source holds at most [`MAX_PARTIALS_PER_SOURCE`] messages.
pub struct Reassembler {
    limit_bytes: usize,
    timeout: Duration,
    max_frame: usize,
    /// Fleet systems a sender field may name (empty: any).
    fleet: Vec<SystemId>,
    partials: HashMap<MessageKey, Partial>,
    sources: HashMap<SocketAddr, SourceUse>,
    held: usize,
    evictions: u64,
    /// Recently completed messages, oldest first, and the same as a set.
    completed: std::collections::VecDeque<(MessageKey, Instant)>,
    completed_set: std::collections::HashSet<MessageKey>,
}

impl Reassembler {
    /// A reassembler holding at most `limit_bytes` for incomplete messages, giving each
    /// `timeout` from its first fragment, accepting frames up to `max_frame`.
    pub fn new(limit_bytes: usize, timeout: Duration, max_frame: usize) -> Reassembler {
        Reassembler {
            limit_bytes,
            timeout,
            max_frame,
            fleet: Vec::new(),
            partials: HashMap::new(),
            sources: HashMap::new(),
            held: 0,
            evictions: 0,
            completed: std::collections::VecDeque::new(),
            completed_set: std::collections::HashSet::new(),
        }
    }

    /// Accepts fragments only from senders named in `fleet` (when it is not empty); others are
    /// rejected with [`FragmentError::UnknownSender`] before anything is held.
    pub fn with_fleet(mut self, fleet: impl IntoIterator<Item = SystemId>) -> Reassembler {
        self.fleet = fleet.into_iter().collect();
        self.fleet.sort_unstable();
        self
    }

    /// Bytes held for incomplete messages (their buffers by capacity, and bookkeeping).
    pub fn held_bytes(&self) -> usize {
        self.held
    }

    /// Incomplete messages held.
    pub fn pending(&self) -> usize {
        self.partials.len()
    }

    /// Incomplete messages dropped (or refused) for lack of room so far.
    pub fn evictions(&self) -> u64 {
        self.evictions
    }

    /// Takes one fragment datagram from `src`, whose fleet system (if known) is `src_system`.
    pub fn on_fragment(
        &mut self,
        datagram: &[u8],
        src: SocketAddr,
        src_system: Option<SystemId>,
        now: Instant,
    ) -> Reassembly {
        let reject = |error| Reassembly::Rejected { error, dropped: 0 };
        let (h, piece) = match parse_fragment(datagram, self.max_frame) {
            Ok(x) => x,
            Err(e) => return reject(e),
        };
        if let Some(actual) = src_system {
            if actual != h.sender {
                return reject(FragmentError::WrongSender {
                    claimed: h.sender,
                    actual,
                });
            }
        } else if !self.fleet.is_empty() && self.fleet.binary_search(&h.sender).is_err() {
            return reject(FragmentError::UnknownSender { claimed: h.sender });
        }
        if h.count == 1 {
            return Reassembly::Complete(piece.to_vec());
        }
        let key = (src, h.sender, h.message_id);
        if let Some(p) = self.partials.get(&key) {
            if p.total != h.total || p.count != h.count {
                self.remove(&key);
                return Reassembly::Rejected {
                    error: FragmentError::Inconsistent {
                        message_id: h.message_id,
                    },
                    dropped: 1,
                };
            }
        } else {
            if self.completed_set.contains(&key) {
                return Reassembly::Duplicate;
            }
            if h.total as usize > self.limit_bytes {
                self.evictions += 1;
                return Reassembly::Pending;
            }
            if self.sources.get(&src).map_or(0, |s| s.partials) >= MAX_PARTIALS_PER_SOURCE {
                if let Some(k) = self.oldest_of(src) {
                    self.remove(&k);
                    self.evictions += 1;
                }
            }
            let p = Partial {
                total: h.total,
                count: h.count,
                started: now,
                head: Vec::new(),
                next: 0,
                ahead: BTreeMap::new(),
                ahead_bytes: 0,
                charged: PARTIAL_OVERHEAD,
            };
            self.held += p.charged;
            let s = self.sources.entry(src).or_default();
            s.bytes += p.charged;
            s.partials += 1;
            self.partials.insert(key, p);
        }
        let Some(p) = self.partials.get_mut(&key) else {
            return Reassembly::Pending;
        };
        if p.has(h.index) {
            return Reassembly::Duplicate;
        }
        p.insert(h.index, piece);
        if p.next == p.count {
            let frame = match self.remove(&key) {
                Some(p) => p.head,
                None => return Reassembly::Pending,
            };
            self.remember(key, now);
            return Reassembly::Complete(frame);
        }
        let (before, after) = (p.charged, p.cost());
        p.charged = after;
        self.held = self.held - before + after;
        if let Some(s) = self.sources.get_mut(&src) {
            s.bytes = s.bytes - before + after;
        }
        while self.held > self.limit_bytes {
            let Some(k) = self.eviction_victim() else {
                break;
            };
            self.remove(&k);
            self.evictions += 1;
        }
        Reassembly::Pending
    }

    /// Drops incomplete messages whose time ran out (returns how many) and forgets completed
    /// messages older than the timeout.
    pub fn expire(&mut self, now: Instant) -> usize {
        let timeout = self.timeout;
        while let Some(&(key, at)) = self.completed.front() {
            if now.saturating_duration_since(at) < timeout {
                break;
            }
            self.completed.pop_front();
            self.completed_set.remove(&key);
        }
        if self.partials.is_empty() {
            return 0;
        }
        let expired: Vec<MessageKey> = self
            .partials
            .iter()
            .filter(|(_, p)| now.saturating_duration_since(p.started) >= timeout)
            .map(|(k, _)| *k)
            .collect();
        for k in &expired {
            self.remove(k);
        }
        expired.len()
    }

    /// Whether [`expire`](Reassembler::expire) has anything to look at.
    fn needs_upkeep(&self) -> bool {
        !self.partials.is_empty() || !self.completed.is_empty()
    }

    fn remember(&mut self, key: MessageKey, now: Instant) {
        if self.completed.len() >= MAX_REMEMBERED_COMPLETIONS {
            if let Some((old, _)) = self.completed.pop_front() {
                self.completed_set.remove(&old);
            }
        }
        if self.completed_set.insert(key) {
            self.completed.push_back((key, now));
        }
    }

    /// The oldest incomplete message from `src`.
    fn oldest_of(&self, src: SocketAddr) -> Option<MessageKey> {
        self.partials
            .iter()
            .filter(|(k, _)| k.0 == src)
            .min_by_key(|(_, p)| p.started)
            .map(|(k, _)| *k)
    }

    /// The message to drop for room: the oldest of the source holding the most bytes.
    fn eviction_victim(&self) -> Option<MessageKey> {
        let (&src, _) = self.sources.iter().max_by_key(|(_, s)| s.bytes)?;
        self.oldest_of(src)
    }

    fn remove(&mut self, key: &MessageKey) -> Option<Partial> {
        let p = self.partials.remove(key)?;
        self.held -= p.charged;
        if let Some(s) = self.sources.get_mut(&key.0) {
            s.bytes -= p.charged;
            s.partials -= 1;
            if s.partials == 0 {
                self.sources.remove(&key.0);
            }
        }
        Some(p)
    }
}

struct Shared {
    closing: AtomicBool,
    counters: UdpCounters,
}

/// Appends `frame` as a record to batch `b` (starting the batch with its header if it is
/// empty); the caller has checked that it fits.
fn push_record(b: &mut Batch, frame: &[u8]) {
    if b.buf.is_empty() {
        b.buf.extend_from_slice(&batch_header());
    }
    // A frame that fits a datagram is far below 4 GiB.
    b.buf.extend_from_slice(&(frame.len() as u32).to_le_bytes());
    b.buf.extend_from_slice(frame);
    b.frames += 1;
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

/// A peer's address and its batch of held frames.
struct UdpPeer {
    addr: SocketAddr,
    batch: Mutex<Batch>,
}

/// Who reads the socket.
enum RxSide {
    /// The link's own receive thread (joined on drop).
    Thread(Option<JoinHandle<()>>),
    /// Whichever thread calls [`Readable::read_ready`].
    Driven(Box<DrivenReceiver>),
}

/// Whether `frame` may travel in a batch: its record fits one datagram with the batch header.
/// Any bytes may: the link never looks inside a frame.
fn batchable(frame: &[u8], mtu: usize) -> bool {
    BATCH_HEADER_LEN + BATCH_LENGTH_LEN + frame.len() <= mtu
}

/// Whether a frame that fits one datagram must nevertheless be sent as a one-fragment message,
/// because a receiver would take the bare datagram for a fragment or a batch.
fn misread_alone(frame: &[u8]) -> bool {
    frame.starts_with(&FRAGMENT_MAGIC) || frame.starts_with(&BATCH_MAGIC)
}

/// The batch header every batch datagram starts with.
fn batch_header() -> [u8; BATCH_HEADER_LEN] {
    [BATCH_MAGIC[0], BATCH_MAGIC[1], BATCH_VERSION, 0]
}

/// Checks the batch header of datagram `d` (which starts with [`BATCH_MAGIC`]); returns the
/// records behind it, or `None` if the header is not one this version reads.
pub fn batch_records(d: &[u8]) -> Option<BatchFrames<'_>> {
    (d.len() >= BATCH_HEADER_LEN && d[..BATCH_HEADER_LEN] == batch_header()).then(|| BatchFrames {
        rest: &d[BATCH_HEADER_LEN..],
    })
}

/// The frames of a batch datagram's records, front to back. Stops at the first record that
/// does not fit in what is left (or a length cut short) and leaves it, with everything after
/// it, in [`BatchFrames::rest`].
#[derive(Clone, Debug)]
pub struct BatchFrames<'a> {
    rest: &'a [u8],
}

impl<'a> BatchFrames<'a> {
    /// What the walk has not taken: empty after a well-formed batch, else its malformed tail.
    pub fn rest(&self) -> &'a [u8] {
        self.rest
    }
}

impl<'a> Iterator for BatchFrames<'a> {
    type Item = &'a [u8];

    fn next(&mut self) -> Option<&'a [u8]> {
        // Every record takes at least its 4-byte length, so every step makes progress.
        let (len, body) = self.rest.split_first_chunk::<BATCH_LENGTH_LEN>()?;
        let n = u32::from_le_bytes(*len) as usize;
        if n > body.len() {
            return None;
        }
        let (frame, rest) = body.split_at(n);
        self.rest = rest;
        Some(frame)
    }
}

/// A system's UDP endpoint; see the module docs.
pub struct UdpLink {
    local: SystemId,
    socket: Arc<UdpSocket>,
    local_addr: SocketAddr,
    peers: BTreeMap<SystemId, UdpPeer>,
    config: UdpConfig,
    max_frame: usize,
    next_message_id: AtomicU32,
    shared: Arc<Shared>,
    rx: RxSide,
    /// The kernel's drop counter as last read (see "Kernel drops").
    kernel_drops: Mutex<KernelDrops>,
}

impl UdpLink {
    /// Binds `local`'s endpoint from `endpoints` (port 0 picks a free port; see
    /// [`UdpLink::local_addr`]) and starts the receive thread (unless [`UdpConfig::driven`]).
    /// The other entries are the peers; they are resolved now, since their addresses also
    /// identify senders.
    pub fn bind(
        local: SystemId,
        endpoints: &BTreeMap<SystemId, String>,
        sink: Arc<dyn FrameSink>,
        config: UdpConfig,
    ) -> Result<UdpLink, OpenError> {
        let endpoint = endpoints
            .get(&local)
            .ok_or(OpenError::NoLocalEndpoint { system: local })?;
        let socket = UdpSocket::bind(endpoint.as_str()).map_err(|source| OpenError::Bind {
            endpoint: endpoint.clone(),
            source,
        })?;
        UdpLink::with_socket(local, socket, endpoints, sink, config)
    }

    /// Starts the link on an already-bound `socket` (tests bind port 0 for every system first).
    /// `local`'s own entry in `endpoints`, if any, is not used.
    pub fn with_socket(
        local: SystemId,
        socket: UdpSocket,
        endpoints: &BTreeMap<SystemId, String>,
        sink: Arc<dyn FrameSink>,
        config: UdpConfig,
    ) -> Result<UdpLink, OpenError> {
        config.check()?;
        let local_addr = socket.local_addr()?;
        let mut peer_addrs = BTreeMap::new();
        for (&id, endpoint) in endpoints.iter().filter(|(id, _)| **id != local) {
            peer_addrs.insert(id, resolve(id, endpoint, local_addr.is_ipv4())?);
        }
        // Best effort: the kernel may cap these (net.core.rmem_max / wmem_max).
        let sock = socket2::SockRef::from(&socket);
        let _ = sock.set_recv_buffer_size(config.socket_buffer_bytes);
        let _ = sock.set_send_buffer_size(config.socket_buffer_bytes);
        if !config.driven {
            // The receive thread wakes at least this often to expire incomplete messages and
            // to notice shutdown should the wake-up datagram be lost.
            let tick = (config.reassembly_timeout / 4)
                .clamp(Duration::from_millis(10), Duration::from_millis(250));
            socket.set_read_timeout(Some(tick))?;
        }
        let socket = Arc::new(socket);
        let shared = Arc::new(Shared {
            closing: AtomicBool::new(false),
            counters: UdpCounters::default(),
        });
        let max_frame = config.max_frame();
        let receiver = Receiver {
            socket: socket.clone(),
            buf: vec![0; RECV_BUF_LEN],
            state: RxState {
                shared: shared.clone(),
                sink,
                senders: peer_addrs.iter().map(|(id, addr)| (*addr, *id)).collect(),
                reassembler: Reassembler::new(
                    config.reassembly_limit_bytes,
                    config.reassembly_timeout,
                    max_frame,
                )
                .with_fleet(peer_addrs.keys().copied()),
            },
        };
        let rx = if config.driven {
            RxSide::Driven(Box::new(DrivenReceiver {
                fd: socket.as_raw_fd(),
                receiver: Mutex::new(receiver),
            }))
        } else {
            let thread = std::thread::Builder::new()
                .name(format!("hetcomm-udp-rx-{local}"))
                .spawn(move || receiver.run())?;
            RxSide::Thread(Some(thread))
        };
        let peers = peer_addrs
            .into_iter()
            .map(|(id, addr)| {
                let batch = Mutex::new(Batch::default());
                (id, UdpPeer { addr, batch })
            })
            .collect();
        Ok(UdpLink {
            local,
            socket,
            local_addr,
            peers,
            config,
            max_frame,
            // Start from a value tied to the clock so that a restarted sender is unlikely to
            // reuse the ids of its previous incarnation's half-delivered messages.
            next_message_id: AtomicU32::new(clock_seed()),
            shared,
            rx,
            kernel_drops: Mutex::new(KernelDrops::default()),
        })
    }

    /// The address the socket is bound to (with the real port when the endpoint said 0).
    pub fn local_addr(&self) -> SocketAddr {
        self.local_addr
    }

    /// All counters, including those [`LinkStats`] has no field for.
    pub fn udp_stats(&self) -> UdpStats {
        let c = &self.shared.counters;
        let get = |a: &AtomicU64| a.load(Ordering::Relaxed);
        let bad = get(&c.bad_datagrams);
        let timeouts = get(&c.reassembly_timeouts);
        let evictions = get(&c.reassembly_evictions);
        let held_dropped = get(&c.held_frames_dropped);
        UdpStats {
            frames_sent: get(&c.frames_sent),
            datagrams_sent: get(&c.datagrams_sent),
            batches_sent: get(&c.batches_sent),
            fragments_sent: get(&c.fragments_sent),
            held_frames_dropped: held_dropped,
            frames_received: get(&c.frames_received),
            batches_received: get(&c.batches_received),
            frames_dropped: bad + timeouts + evictions + held_dropped,
            bad_datagrams: bad,
            reassembly_timeouts: timeouts,
            reassembly_evictions: evictions,
            duplicate_fragments: get(&c.duplicate_fragments),
            oversize_fragments: get(&c.oversize_fragments),
            from_unknown_address: get(&c.from_unknown_address),
            buffered_bytes: get(&c.buffered_bytes),
            kernel_drops: self.kernel_drops(),
        }
    }

    /// Datagrams the kernel dropped at the socket so far (0 where the OS does not say).
    fn kernel_drops(&self) -> u64 {
        // Read under the lock, so that the reads are in order and each adds what is new.
        let mut drops = lock(&self.kernel_drops);
        if let Some(now) = socket_drops(&self.socket) {
            drops.update(now);
        }
        drops.total
    }

    fn check_size(&self, frame: &[u8]) -> Result<(), LinkError> {
        if frame.len() > self.max_frame {
            return Err(LinkError::TooLarge {
                len: frame.len(),
                max: self.max_frame,
            });
        }
        Ok(())
    }

    fn peer(&self, to: SystemId) -> Result<&UdpPeer, LinkError> {
        self.peers.get(&to).ok_or_else(|| {
            let reason = if to == self.local {
                "it is this system itself".to_string()
            } else {
                format!("system {to} has no endpoint on this udp link")
            };
            LinkError::Unreachable { peer: to, reason }
        })
    }

    /// Sends `frame` on its own: as one datagram, or as fragments.
    fn send_now(&self, to: SystemId, addr: SocketAddr, frame: &[u8]) -> Result<(), LinkError> {
        let counters = &self.shared.counters;
        let mtu = self.config.datagram_payload;
        if frame.len() <= mtu && !misread_alone(frame) {
            self.socket
                .send_to(frame, addr)
                .map_err(|e| self.send_error(to, addr, e))?;
            add(&counters.datagrams_sent, 1);
            add(&counters.frames_sent, 1);
            return Ok(());
        }
        let too_large = || LinkError::TooLarge {
            len: frame.len(),
            max: self.max_frame,
        };
        let piece_max = mtu - FRAGMENT_HEADER_LEN;
        let count = frame.len().div_ceil(piece_max).max(1);
        let count = u16::try_from(count).map_err(|_| too_large())?;
        let total = u32::try_from(frame.len()).map_err(|_| too_large())?;
        let message_id = self.next_message_id.fetch_add(1, Ordering::Relaxed);
        let dest = socket2::SockAddr::from(addr);
        let sock = socket2::SockRef::from(&*self.socket);
        for index in 0..count {
            let h = FragmentHeader {
                sender: self.local,
                index,
                count,
                message_id,
                total,
            };
            let head = h.encode();
            let piece = &frame[h.piece_range()];
            sock.send_to_vectored(&[IoSlice::new(&head), IoSlice::new(piece)], &dest)
                .map_err(|e| self.send_error(to, addr, e))?;
            add(&counters.fragments_sent, 1);
            add(&counters.datagrams_sent, 1);
        }
        add(&counters.frames_sent, 1);
        Ok(())
    }

    /// Sends the held frames `b` towards `to` as one datagram and empties the batch. `own` of
    /// them (0 or 1, the last) are the caller's, who gets the error; should the send fail, the
    /// others are counted as dropped.
    fn send_batch(
        &self,
        to: SystemId,
        addr: SocketAddr,
        b: &mut Batch,
        own: u64,
    ) -> Result<(), LinkError> {
        if b.frames == 0 {
            return Ok(());
        }
        // One frame goes out bare, as `send` would send it (readable by receivers that predate
        // batch records, and 8 bytes shorter), unless it would be misread alone.
        let first = BATCH_HEADER_LEN + BATCH_LENGTH_LEN;
        let alone = b.frames == 1 && !misread_alone(&b.buf[first..]);
        let datagram = if alone { &b.buf[first..] } else { &b.buf[..] };
        let result = self.socket.send_to(datagram, addr);
        let frames = b.frames;
        b.buf.clear();
        b.frames = 0;
        let c = &self.shared.counters;
        match result {
            Ok(_) => {
                add(&c.frames_sent, frames);
                add(&c.datagrams_sent, 1);
                add(&c.batches_sent, u64::from(!alone));
                Ok(())
            }
            Err(e) => {
                add(&c.held_frames_dropped, frames.saturating_sub(own));
                Err(self.send_error(to, addr, e))
            }
        }
    }

    fn send_error(&self, to: SystemId, addr: SocketAddr, e: io::Error) -> LinkError {
        if e.kind() == io::ErrorKind::WouldBlock || e.raw_os_error() == Some(libc::ENOBUFS) {
            return LinkError::Congested {
                peer: to,
                reason: format!("socket send buffer full sending to {addr}: {e}"),
            };
        }
        match e.kind() {
            io::ErrorKind::ConnectionRefused
            | io::ErrorKind::HostUnreachable
            | io::ErrorKind::NetworkUnreachable
            | io::ErrorKind::AddrNotAvailable
            | io::ErrorKind::NetworkDown => LinkError::Unreachable {
                peer: to,
                reason: format!("send_to {addr} failed: {e}"),
            },
            _ => LinkError::Io(e),
        }
    }
}

/// The kernel's count of datagrams dropped at `socket` since it was opened (`SO_MEMINFO`,
/// Linux 4.12 and later), a 32-bit counter that wraps; `None` where it is not reported.
#[cfg(target_os = "linux")]
fn socket_drops(socket: &UdpSocket) -> Option<u32> {
    /// `SO_MEMINFO` (`asm-generic/socket.h`; sparc numbers it differently). The libc crate
    /// does not export it for every target.
    const SO_MEMINFO: libc::c_int = if cfg!(any(target_arch = "sparc", target_arch = "sparc64")) {
        0x39
    } else {
        55
    };
    let drops = libc::SK_MEMINFO_DROPS as usize;
    // The kernel fills as much of its `SK_MEMINFO_VARS` counters (9 today) as fits.
    let mut info = [0u32; 16];
    let mut len = std::mem::size_of_val(&info) as libc::socklen_t;
    // SAFETY: `socket` is open for the whole call; `info` is a live, writable buffer of `len`
    // bytes, and the kernel writes at most `len` bytes into it and the length into `len`.
    let r = unsafe {
        libc::getsockopt(
            socket.as_raw_fd(),
            libc::SOL_SOCKET,
            SO_MEMINFO,
            info.as_mut_ptr().cast(),
            &mut len,
        )
    };
    let filled = (len as usize) / std::mem::size_of::<u32>();
    (r == 0 && filled > drops).then(|| info[drops])
}

/// Not reported on this OS.
#[cfg(not(target_os = "linux"))]
fn socket_drops(_socket: &UdpSocket) -> Option<u32> {
    None
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

fn clock_seed() -> u32 {
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.subsec_nanos() ^ (d.as_secs() as u32).rotate_left(16))
        .unwrap_or(0);
    nanos ^ std::process::id().rotate_left(8)
}

fn resolve(id: SystemId, endpoint: &str, prefer_v4: bool) -> Result<SocketAddr, OpenError> {
    let bad = |reason: String| OpenError::BadEndpoint {
        system: id,
        endpoint: endpoint.to_string(),
        reason,
    };
    let addrs: Vec<SocketAddr> = endpoint
        .to_socket_addrs()
        .map_err(|e| bad(e.to_string()))?
        .collect();
    addrs
        .iter()
        .find(|a| a.is_ipv4() == prefer_v4)
        .or(addrs.first())
        .copied()
        .ok_or_else(|| bad("resolves to no address".into()))
}

impl Link for UdpLink {
    fn caps(&self) -> LinkCaps {
        LinkCaps {
            max_frame: self.max_frame,
            mtu: self.config.datagram_payload,
            reliable: false,
            ordered: false,
            broadcast: false,
        }
    }

    fn send(&self, to: SystemId, frame: &[u8]) -> Result<(), LinkError> {
        self.check_size(frame)?;
        let peer = self.peer(to)?;
        let mtu = self.config.datagram_payload;
        {
            let mut b = lock(&peer.batch);
            if b.frames > 0 {
                if b.buf.len() + BATCH_LENGTH_LEN + frame.len() <= mtu {
                    // Joins the held frames: one datagram for all of them.
                    push_record(&mut b, frame);
                    return self.send_batch(to, peer.addr, &mut b, 1);
                }
                // Held frames go first. Their failure is counted; the result is this frame's.
                let _ = self.send_batch(to, peer.addr, &mut b, 0);
            }
        }
        self.send_now(to, peer.addr, frame)
    }

    fn stats(&self) -> LinkStats {
        let s = self.udp_stats();
        LinkStats {
            frames_sent: s.frames_sent,
            frames_received: s.frames_received,
            frames_dropped: s.frames_dropped,
            connects: 0,
            buffered_bytes: s.buffered_bytes,
            kernel_drops: s.kernel_drops,
            security: Default::default(),
        }
    }

    fn send_held(&self, to: SystemId, frame: &[u8]) -> Result<(), LinkError> {
        self.check_size(frame)?;
        let peer = self.peer(to)?;
        let mtu = self.config.datagram_payload;
        let mut b = lock(&peer.batch);
        if !batchable(frame, mtu) {
            // Held frames go first. Their failure is counted; the result is this frame's.
            let _ = self.send_batch(to, peer.addr, &mut b, 0);
            drop(b);
            return self.send_now(to, peer.addr, frame);
        }
        if b.buf.len() + BATCH_LENGTH_LEN + frame.len() > mtu {
            let _ = self.send_batch(to, peer.addr, &mut b, 0);
        }
        if b.buf.capacity() < mtu {
            // Once per peer: afterwards holding a frame never allocates.
            b.buf.reserve_exact(mtu);
        }
        push_record(&mut b, frame);
        if mtu - b.buf.len() < BATCH_LENGTH_LEN + HEADER_LEN {
            // No further frame can fit: holding these longer would only add latency.
            return self.send_batch(to, peer.addr, &mut b, 1);
        }
        Ok(())
    }

    fn flush(&self) -> Result<(), LinkError> {
        let mut first = Ok(());
        for (&to, peer) in &self.peers {
            let mut b = lock(&peer.batch);
            if let Err(e) = self.send_batch(to, peer.addr, &mut b, 0) {
                if first.is_ok() {
                    first = Err(e);
                }
            }
        }
        first
    }

    fn batches(&self) -> bool {
        true
    }

    fn readable(&self) -> Option<&dyn Readable> {
        match &self.rx {
            RxSide::Driven(d) => Some(&**d),
            RxSide::Thread(_) => None,
        }
    }
}

impl Drop for UdpLink {
    fn drop(&mut self) {
        // Best effort: held frames would otherwise be lost without a trace.
        let _ = self.flush();
        self.shared.closing.store(true, Ordering::SeqCst);
        let RxSide::Thread(thread) = &mut self.rx else {
            return; // driven: no thread to stop
        };
        // Wake the receive thread with an empty datagram to ourselves; the read timeout is the
        // fallback should it be lost.
        let mut me = self.local_addr;
        if me.ip().is_unspecified() {
            me.set_ip(match me.ip() {
                IpAddr::V4(_) => Ipv4Addr::LOCALHOST.into(),
                IpAddr::V6(_) => Ipv6Addr::LOCALHOST.into(),
            });
        }
        let _ = self.socket.send_to(&[], me);
        if let Some(t) = thread.take() {
            let _ = t.join();
        }
    }
}

/// Large enough for any UDP datagram, so nothing is silently truncated.
const RECV_BUF_LEN: usize = 65_536;

/// The receive side: the socket, one receive buffer reused for every datagram, and what the
/// datagrams are made into.
struct Receiver {
    socket: Arc<UdpSocket>,
    buf: Vec<u8>,
    state: RxState,
}

/// Receive errors after which reading simply goes on: timeouts, signals, and an earlier
/// send's ICMP error, which some platforms report on the next receive.
fn is_transient(e: &io::Error) -> bool {
    matches!(
        e.kind(),
        io::ErrorKind::WouldBlock
            | io::ErrorKind::TimedOut
            | io::ErrorKind::Interrupted
            | io::ErrorKind::ConnectionRefused
            | io::ErrorKind::ConnectionReset
    )
}

/// Receives one datagram if one is waiting, without blocking (the socket itself stays
/// blocking, for the sends).
fn recv_dontwait(socket: &UdpSocket, buf: &mut [u8]) -> io::Result<(usize, Option<SocketAddr>)> {
    // SAFETY: `[u8]` and `[MaybeUninit<u8>]` have the same layout, and socket2 promises never
    // to write uninitialised bytes into the buffer (it passes it straight to recvfrom(2)), so
    // `buf` stays initialised.
    let uninit = unsafe { &mut *(buf as *mut [u8] as *mut [MaybeUninit<u8>]) };
    let (n, from) =
        socket2::SockRef::from(socket).recv_from_with_flags(uninit, libc::MSG_DONTWAIT)?;
    Ok((n, from.as_socket()))
}

impl Receiver {
    /// The receive thread's loop.
    fn run(mut self) {
        let mut consecutive_errors = 0u32;
        while !self.state.shared.closing.load(Ordering::SeqCst) {
            match self.socket.recv_from(&mut self.buf) {
                Ok((n, src)) => {
                    consecutive_errors = 0;
                    if self.state.shared.closing.load(Ordering::SeqCst) {
                        break;
                    }
                    self.state.on_datagram(&self.buf[..n], src);
                }
                Err(e) if is_transient(&e) => {}
                Err(_) => {
                    // An unexpected, possibly persistent error: pause a little so it cannot
                    // spin a core, and keep serving.
                    consecutive_errors = consecutive_errors.saturating_add(1);
                    if consecutive_errors > 3 {
                        std::thread::sleep(Duration::from_millis(10));
                    }
                }
            }
            self.state.upkeep();
        }
    }

    /// Reads at most `budget` datagrams that have arrived, without blocking; returns the
    /// number of frames handed to the sink. An unexpected error is returned only when no frame
    /// was handed on (a persistent one shows again at the next call).
    fn read_ready(&mut self, budget: usize) -> io::Result<usize> {
        let mut frames = 0;
        let mut failure = None;
        for _ in 0..budget {
            match recv_dontwait(&self.socket, &mut self.buf) {
                Ok((n, Some(src))) => frames += self.state.on_datagram(&self.buf[..n], src),
                // Not an IP source: cannot happen on a UDP/IP socket; nothing to attribute.
                Ok((_, None)) => {}
                Err(e) if e.kind() == io::ErrorKind::WouldBlock => break,
                Err(e) if is_transient(&e) => {}
                Err(e) => {
                    failure = Some(e);
                    break;
                }
            }
        }
        self.state.upkeep();
        match failure {
            Some(e) if frames == 0 => Err(e),
            _ => Ok(frames),
        }
    }
}

/// What received datagrams are made into, and where they go.
struct RxState {
    shared: Arc<Shared>,
    sink: Arc<dyn FrameSink>,
    senders: HashMap<SocketAddr, SystemId>,
    reassembler: Reassembler,
}

impl RxState {
    /// Takes one datagram from `src`; returns the number of frames handed to the sink.
    fn on_datagram(&mut self, d: &[u8], src: SocketAddr) -> usize {
        let c = &self.shared.counters;
        let system = self.senders.get(&src).copied();
        let from = match system {
            Some(id) => Peer::System(id),
            None => Peer::Unknown,
        };
        if d.starts_with(&BATCH_MAGIC) {
            return self.deliver_batch(d, from);
        }
        if !d.starts_with(&FRAGMENT_MAGIC) {
            self.deliver(d, from);
            return 1;
        }
        let evictions_before = self.reassembler.evictions();
        let outcome = self.reassembler.on_fragment(d, src, system, Instant::now());
        add(
            &c.reassembly_evictions,
            self.reassembler.evictions() - evictions_before,
        );
        match outcome {
            Reassembly::Complete(frame) => {
                self.deliver(&frame, from);
                1
            }
            Reassembly::Pending => 0,
            Reassembly::Duplicate => {
                add(&c.duplicate_fragments, 1);
                0
            }
            Reassembly::Rejected { dropped, error } => {
                add(&c.bad_datagrams, 1);
                add(&c.reassembly_evictions, dropped as u64);
                if let FragmentError::BadGeometry { total, max, .. } = error {
                    if total as usize > max {
                        self.on_oversize(total, max, src);
                    }
                }
                0
            }
        }
    }

    /// A well-formed fragment of a message larger than this link's `max_frame`: the sender's
    /// `max_message_bytes` is larger than ours. Counted; the first one is logged.
    fn on_oversize(&self, total: u32, max: usize, src: SocketAddr) {
        let c = &self.shared.counters;
        add(&c.oversize_fragments, 1);
        if !c.oversize_logged.swap(true, Ordering::Relaxed) {
            eprintln!(
                "hetcomm udp link: dropped a fragment from {src} of a {total}-byte frame, more \
                 than this link's largest frame of {max} bytes: the sender's max_message_bytes \
                 is larger than ours (further such fragments are only counted in \
                 oversize_fragments)"
            );
        }
    }

    fn deliver(&self, frame: &[u8], from: Peer) {
        let c = &self.shared.counters;
        if from == Peer::Unknown {
            add(&c.from_unknown_address, 1);
        }
        // Counted first so that whoever the sink wakes sees the counter already updated.
        add(&c.frames_received, 1);
        self.sink.on_frame(frame, from);
    }

    /// Hands up the complete frames of batch datagram `d`; returns how many.
    fn deliver_batch(&self, d: &[u8], from: Peer) -> usize {
        let c = &self.shared.counters;
        let Some(records) = batch_records(d) else {
            // A batch header this version does not read: nothing in it can be trusted.
            add(&c.bad_datagrams, 1);
            return 0;
        };
        // Walked once to count, so that the counters are updated (once per datagram) before
        // the sink wakes anyone; the walk only reads the records' lengths.
        let mut walk = records.clone();
        let n = walk.by_ref().count();
        if !walk.rest.is_empty() || n == 0 {
            add(&c.bad_datagrams, 1);
        }
        if n == 0 {
            return 0;
        }
        add(&c.batches_received, 1);
        if from == Peer::Unknown {
            add(&c.from_unknown_address, n as u64);
        }
        add(&c.frames_received, n as u64);
        // Every frame of the batch carries the peer the datagram came from.
        self.sink.on_frames(&mut records.clone(), from);
        n
    }

    /// Expires incomplete messages whose time ran out and publishes the bytes held.
    fn upkeep(&mut self) {
        let c = &self.shared.counters;
        if self.reassembler.needs_upkeep() {
            let expired = self.reassembler.expire(Instant::now());
            add(&c.reassembly_timeouts, expired as u64);
        }
        c.buffered_bytes
            .store(self.reassembler.held_bytes() as u64, Ordering::Relaxed);
    }
}

/// The receive side of a driven link, read by whichever thread calls
/// [`Readable::read_ready`].
struct DrivenReceiver {
    fd: RawFd,
    receiver: Mutex<Receiver>,
}

impl Readable for DrivenReceiver {
    fn fd(&self) -> RawFd {
        self.fd
    }

    fn read_ready(&self, budget: usize) -> io::Result<usize> {
        let mut rx = match self.receiver.try_lock() {
            Ok(rx) => rx,
            Err(TryLockError::Poisoned(e)) => e.into_inner(),
            // Another thread is reading (or a sink called back in): this call must not block,
            // and that reader hands on whatever has arrived.
            Err(TryLockError::WouldBlock) => return Ok(0),
        };
        rx.read_ready(budget)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use hetcomm_core::wire;

    const SRC: SocketAddr = SocketAddr::new(IpAddr::V4(Ipv4Addr::LOCALHOST), 9);

    fn fragments(frame: &[u8], piece_max: usize, id: u32) -> Vec<Vec<u8>> {
        let count = frame.len().div_ceil(piece_max) as u16;
        (0..count)
            .map(|index| {
                let h = FragmentHeader {
                    sender: SystemId(1),
                    index,
                    count,
                    message_id: id,
                    total: frame.len() as u32,
                };
                let mut d = h.encode().to_vec();
                d.extend_from_slice(&frame[h.piece_range()]);
                d
            })
            .collect()
    }

    fn wire_frame(seq: u64, payload_len: usize) -> Vec<u8> {
        use hetcomm_core::{Address, MessageType, ModuleId};
        let at = |s| Address {
            system: SystemId(s),
            module: ModuleId(1),
        };
        let mut h = wire::Header::data(at(1), at(2), MessageType(7));
        h.seq = seq;
        wire::encode(&h, &vec![seq as u8; payload_len])
    }

    #[test]
    fn the_kernel_drop_counter_wraps_into_a_64_bit_total() {
        let mut d = KernelDrops::default();
        d.update(0);
        assert_eq!(d.total, 0);
        d.update(10);
        d.update(10);
        assert_eq!(d.total, 10);
        d.update(u32::MAX - 1);
        assert_eq!(d.total, u64::from(u32::MAX) - 1);
        d.update(3); // wrapped
        assert_eq!(d.total, u64::from(u32::MAX) + 4);
    }

    fn batch_of(frames: &[&[u8]]) -> Vec<u8> {
        let mut b = Batch::default();
        for f in frames {
            push_record(&mut b, f);
        }
        assert_eq!(b.frames, frames.len() as u64);
        b.buf
    }

    #[test]
    fn batch_walk_stops_at_the_first_incomplete_record() {
        let frames: Vec<Vec<u8>> = (0..3).map(|i| wire_frame(i, 10 * i as usize)).collect();
        let refs: Vec<&[u8]> = frames.iter().map(|f| &f[..]).collect();
        let batch = batch_of(&refs);
        assert!(batch.starts_with(b"HB\x01\x00"));
        let mut walk = batch_records(&batch).unwrap();
        assert_eq!(walk.by_ref().collect::<Vec<_>>(), frames);
        assert!(walk.rest().is_empty());

        // A record announcing more than is left, and a length cut short.
        let mut tail = batch.clone();
        tail.extend_from_slice(&100u32.to_le_bytes());
        tail.extend_from_slice(&[1; 99]);
        let mut walk = batch_records(&tail).unwrap();
        assert_eq!(walk.by_ref().count(), 3);
        assert_eq!(walk.rest().len(), 103);
        let mut short = batch.clone();
        short.extend_from_slice(&[0, 0]);
        let mut walk = batch_records(&short).unwrap();
        assert_eq!(walk.by_ref().count(), 3);
        assert_eq!(walk.rest(), &[0, 0]);

        // Any bytes travel, empty ones included: the link never reads a frame.
        let odd = batch_of(&[b"", b"HF", b"not a frame"]);
        let got: Vec<&[u8]> = batch_records(&odd).unwrap().collect();
        assert_eq!(got, [&b""[..], b"HF", b"not a frame"]);

        let mut bad = batch.clone();
        bad[2] = 2;
        assert!(batch_records(&bad).is_none(), "another version");
        bad[2] = 1;
        bad[3] = 1;
        assert!(batch_records(&bad).is_none(), "reserved byte set");
        assert!(batch_records(b"HB\x01").is_none(), "truncated header");
    }

    #[test]
    fn any_frame_that_fits_is_batched_and_only_magics_are_misread() {
        let f = wire_frame(1, 64);
        assert!(batchable(&f, 1472));
        assert!(batchable(&f, f.len() + 8));
        assert!(!batchable(&f, f.len() + 7), "record and header must fit");
        assert!(
            batchable(&[0u8; 100], 1472),
            "not a wire frame: batched all the same"
        );
        assert!(batchable(b"HC short", 1472));
        assert!(!misread_alone(&f));
        let mut longer = f.clone();
        longer.push(0);
        assert!(
            !misread_alone(&longer),
            "trailing bytes are the frame's own business"
        );
        assert!(misread_alone(b"HF...") && misread_alone(b"HB..."));
    }

    fn reassembler() -> Reassembler {
        Reassembler::new(1000, Duration::from_secs(2), 10_000)
    }

    #[test]
    fn out_of_order_fragments_reassemble() {
        let frame: Vec<u8> = (0..=255).cycle().take(1001).collect();
        let mut frags = fragments(&frame, 100, 7);
        frags.reverse();
        let mut r = Reassembler::new(1 << 20, Duration::from_secs(2), 10_000);
        let now = Instant::now();
        let mut out = None;
        for f in &frags {
            match r.on_fragment(f, SRC, Some(SystemId(1)), now) {
                Reassembly::Complete(v) => out = Some(v),
                Reassembly::Pending => {}
                other => panic!("{other:?}"),
            }
        }
        assert_eq!(out.as_deref(), Some(&frame[..]));
        assert_eq!(r.held_bytes(), 0);
    }

    #[test]
    fn pieces_are_even_and_never_empty() {
        for total in 1..300u32 {
            for count in 1..=total.min(40) as u16 {
                let h = FragmentHeader {
                    sender: SystemId(0),
                    index: 0,
                    count,
                    message_id: 0,
                    total,
                };
                let chunk = (total as usize).div_ceil(count as usize);
                let valid = (count as usize - 1) * chunk < total as usize;
                let mut d = h.encode().to_vec();
                d.extend(std::iter::repeat_n(0, h.piece_range().len()));
                assert_eq!(
                    parse_fragment(&d, 1 << 20).is_ok(),
                    valid,
                    "{total}/{count}"
                );
            }
        }
    }

    #[test]
    fn absurd_headers_are_rejected() {
        let good = &fragments(&[1u8; 300], 100, 1)[0];
        assert!(parse_fragment(good, 1000).is_ok());
        assert!(matches!(
            parse_fragment(&good[..10], 1000),
            Err(FragmentError::Truncated { .. })
        ));
        let mut d = good.clone();
        d[2] = 2;
        assert!(matches!(
            parse_fragment(&d, 1000),
            Err(FragmentError::BadHeader { .. })
        ));
        let mut d = good.clone();
        d[8..10].copy_from_slice(&0u16.to_le_bytes());
        assert!(matches!(
            parse_fragment(&d, 1000),
            Err(FragmentError::BadGeometry { .. })
        ));
        let mut d = good.clone();
        d[16..20].copy_from_slice(&u32::MAX.to_le_bytes());
        assert!(matches!(
            parse_fragment(&d, 1000),
            Err(FragmentError::BadGeometry { .. })
        ));
        let mut d = good.clone();
        d[6..8].copy_from_slice(&3u16.to_le_bytes());
        assert!(matches!(
            parse_fragment(&d, 1000),
            Err(FragmentError::BadGeometry { .. })
        ));
        let mut d = good.clone();
        d.push(0);
        assert!(matches!(
            parse_fragment(&d, 1000),
            Err(FragmentError::BadLength { .. })
        ));
    }

    #[test]
    fn missing_fragment_times_out_and_frees_memory() {
        let mut r = reassembler();
        let frags = fragments(&[5u8; 500], 100, 3);
        let t0 = Instant::now();
        for f in &frags[1..] {
            assert_eq!(r.on_fragment(f, SRC, None, t0), Reassembly::Pending);
        }
        // Four pieces held ahead of the missing first one, and the bookkeeping.
        let held = r.held_bytes();
        assert!((400..=400 + PARTIAL_OVERHEAD + 4 * PIECE_OVERHEAD).contains(&held));
        assert_eq!(r.expire(t0 + Duration::from_secs(1)), 0);
        assert_eq!(r.expire(t0 + Duration::from_secs(2)), 1);
        assert_eq!(r.held_bytes(), 0);
        // The late first fragment starts a new, hopeless message rather than resurrecting it.
        assert_eq!(r.on_fragment(&frags[0], SRC, None, t0), Reassembly::Pending);
    }

    #[test]
    fn memory_follows_the_bytes_received_not_the_declared_total() {
        let mut r = Reassembler::new(32 << 20, Duration::from_secs(2), 16 << 20);
        let t0 = Instant::now();
        // One 276-byte datagram announcing 16 776 960 bytes in 65535 pieces of 256.
        let h = |index| FragmentHeader {
            sender: SystemId(1),
            index,
            count: u16::MAX,
            message_id: 9,
            total: 256 * u32::from(u16::MAX),
        };
        for index in [0, 65_534] {
            let mut d = h(index).encode().to_vec();
            d.extend_from_slice(&[0xAA; 256]);
            assert_eq!(r.on_fragment(&d, SRC, None, t0), Reassembly::Pending);
        }
        assert!(r.held_bytes() < 8 * 1024, "{} bytes held", r.held_bytes());
    }

    #[test]
    fn the_largest_holder_is_evicted_first() {
        let mut r = Reassembler::new(4000, Duration::from_secs(2), 10_000);
        let t0 = Instant::now();
        let other: SocketAddr = "127.0.0.1:10".parse().unwrap();
        let legit = fragments(&[1u8; 1000], 100, 1);
        // The legitimate message starts first (older), then a flood from another source.
        assert_eq!(r.on_fragment(&legit[0], SRC, None, t0), Reassembly::Pending);
        let mut flood_evictions = 0;
        for id in 0..20 {
            let f = fragments(&[2u8; 1000], 100, 100 + id);
            for piece in &f[..9] {
                r.on_fragment(piece, other, None, t0 + Duration::from_millis(1));
            }
            flood_evictions = r.evictions();
        }
        assert!(flood_evictions > 0);
        assert!(r.held_bytes() <= 4000);
        let mut out = None;
        for piece in &legit[1..] {
            if let Reassembly::Complete(v) = r.on_fragment(piece, SRC, None, t0) {
                out = Some(v);
            }
        }
        assert_eq!(
            out.as_deref(),
            Some(&[1u8; 1000][..]),
            "the flood evicted itself"
        );
    }

    #[test]
    fn limit_refuses_messages_larger_than_itself_and_bounds_messages_per_source() {
        let mut r = reassembler();
        let t0 = Instant::now();
        let big = fragments(&[3u8; 1500], 100, 3);
        assert_eq!(r.on_fragment(&big[0], SRC, None, t0), Reassembly::Pending);
        assert_eq!(r.evictions(), 1);
        assert_eq!(r.pending(), 0);
        let mut r = Reassembler::new(1 << 20, Duration::from_secs(2), 10_000);
        for id in 0..MAX_PARTIALS_PER_SOURCE as u32 + 5 {
            r.on_fragment(&fragments(&[4u8; 300], 100, id)[0], SRC, None, t0);
        }
        assert_eq!(r.pending(), MAX_PARTIALS_PER_SOURCE);
        assert_eq!(r.evictions(), 5);
    }

    #[test]
    fn unknown_senders_are_refused_and_duplicates_recognised() {
        let mut r = reassembler().with_fleet([SystemId(1), SystemId(2)]);
        let t0 = Instant::now();
        let mut stranger = fragments(&[1u8; 300], 100, 1)[0].clone();
        stranger[4..6].copy_from_slice(&7u16.to_le_bytes());
        assert!(matches!(
            r.on_fragment(&stranger, SRC, None, t0),
            Reassembly::Rejected {
                error: FragmentError::UnknownSender { .. },
                ..
            }
        ));
        let f = fragments(&[1u8; 300], 100, 2);
        assert_eq!(r.on_fragment(&f[0], SRC, None, t0), Reassembly::Pending);
        assert_eq!(r.on_fragment(&f[0], SRC, None, t0), Reassembly::Duplicate);
        assert_eq!(r.on_fragment(&f[1], SRC, None, t0), Reassembly::Pending);
        assert!(matches!(
            r.on_fragment(&f[2], SRC, None, t0),
            Reassembly::Complete(_)
        ));
        // A late duplicate of the completed message holds nothing and never times out.
        assert_eq!(r.on_fragment(&f[1], SRC, None, t0), Reassembly::Duplicate);
        assert_eq!((r.pending(), r.held_bytes()), (0, 0));
        assert_eq!(r.expire(t0 + Duration::from_secs(3)), 0);
        // Once the timeout has passed the message is forgotten.
        assert_eq!(r.on_fragment(&f[1], SRC, None, t0), Reassembly::Pending);
    }

    #[test]
    fn inconsistent_and_misattributed_fragments_are_rejected() {
        let mut r = reassembler();
        let t0 = Instant::now();
        let a = fragments(&[1u8; 300], 100, 1);
        let b = fragments(&[1u8; 400], 100, 1); // same id, different total
        assert_eq!(r.on_fragment(&a[0], SRC, None, t0), Reassembly::Pending);
        assert!(matches!(
            r.on_fragment(&b[1], SRC, None, t0),
            Reassembly::Rejected { dropped: 1, .. }
        ));
        assert_eq!(r.held_bytes(), 0);
        assert!(matches!(
            r.on_fragment(&a[0], SRC, Some(SystemId(2)), t0),
            Reassembly::Rejected {
                error: FragmentError::WrongSender { .. },
                ..
            }
        ));
    }
}
