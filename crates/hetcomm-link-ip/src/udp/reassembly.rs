//! [`Reassembler`]: putting fragmented frames back together with bounded memory, eviction of
//! the largest holder, a timeout, and recognition of late duplicates.

use std::collections::{BTreeMap, BTreeSet, HashMap, HashSet, VecDeque};
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::{Duration, Instant};

use hetcomm_core::{BufferPool, SystemId};

use super::fragment::{parse_fragment, FragmentError};
// Named only by doc links.
#[cfg(doc)]
use super::UdpConfig;

type MessageKey = (SocketAddr, SystemId, u32);

/// When an incomplete message began (its first fragment's time), then the order in which
/// messages began: ties go to the earlier, never to a hash map's order.
type Age = (Instant, u64);

/// Bytes a partial message is charged for beyond its pieces (its bookkeeping).
pub(super) const PARTIAL_OVERHEAD: usize = 128;
/// Bytes charged per piece that arrived ahead of its turn (its map entry).
pub(super) const PIECE_OVERHEAD: usize = 32;
/// The first contiguous buffer of a message holds at most this many pieces: a fragment's
/// header never makes the receiver reserve much more than the bytes it has received.
const FIRST_RESERVE_PIECES: usize = 4;
/// Most incomplete messages from one source address at once; a further one evicts that
/// source's oldest.
pub const MAX_PARTIALS_PER_SOURCE: usize = 64;
/// Most recently completed messages remembered (for [`UdpConfig::reassembly_timeout`]) so
/// that their late duplicate fragments are recognised.
pub const MAX_REMEMBERED_COMPLETIONS: usize = 4096;
/// Buffers of at least this many bytes come from the pool (when there is one) and go back to
/// it; smaller ones are left to the allocator, which serves them cheaply.
pub(super) const POOLED_MIN: usize = 16 * 1024;
/// Pooled buffers are asked for in multiples of this many bytes, so that frames of similar
/// sizes reuse each other's buffers.
const POOLED_STEP: usize = 4096;

/// An empty buffer from `pool` with room for `len` bytes (rounded up to [`POOLED_STEP`]), and
/// never more than a quarter beyond that: whoever holds it is charged (or holds memory) for its
/// capacity.
pub(super) fn pooled(pool: &BufferPool, len: usize) -> Vec<u8> {
    let len = len.next_multiple_of(POOLED_STEP);
    pool.take_within(len, len + len / 4)
}

/// Gives `buf` back to `pool` (if any) when it is large enough to be worth keeping; frees it
/// otherwise.
pub(super) fn recycle(pool: Option<&Arc<BufferPool>>, buf: Vec<u8>) {
    if let Some(pool) = pool.filter(|_| buf.capacity() >= POOLED_MIN) {
        pool.give(buf);
    }
}

struct Partial {
    total: u32,
    count: u16,
    age: Age,
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
    fn insert(&mut self, index: u16, piece: &[u8], pool: Option<&Arc<BufferPool>>) {
        if index != self.next {
            self.ahead_bytes += piece.len();
            self.ahead.insert(index, piece.to_vec());
            return;
        }
        self.append(piece, pool);
        while let Some(p) = self.ahead.remove(&self.next) {
            self.ahead_bytes -= p.len();
            self.append(&p, pool);
        }
    }

    /// Appends the next piece to `head`, growing it by at most doubling (and at first by a few
    /// pieces), never past `total` (but for the rounding of a pooled buffer, under 4 KiB).
    fn append(&mut self, piece: &[u8], pool: Option<&Arc<BufferPool>>) {
        let total = self.total as usize;
        let need = self.head.len() + piece.len();
        if need > self.head.capacity() {
            let chunk = total.div_ceil(usize::from(self.count));
            let target = need
                .max(self.head.capacity() * 2)
                .max(FIRST_RESERVE_PIECES * chunk)
                .min(total);
            match pool.filter(|_| target >= POOLED_MIN) {
                // A buffer that comes back to the pool when the frame is dropped: large frames
                // arriving one after another then reuse the same memory instead of a fresh
                // allocation each, which the allocator faults in page by page.
                Some(pool) => {
                    let mut grown = pooled(pool, target);
                    grown.extend_from_slice(&self.head);
                    recycle(Some(pool), std::mem::replace(&mut self.head, grown));
                }
                None => self.head.reserve_exact(target - self.head.len()),
            }
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
/// pieces arrive (the first reservation is at most `FIRST_RESERVE_PIECES` (4) pieces, later ones
/// at most double it), and pieces that arrive ahead of their turn are kept apart until the
/// gap before them fills. Everything held, bookkeeping included, is charged against the limit.
/// When a new piece takes the total over the limit, the oldest message of the source address
/// holding the most is dropped, until it fits: a source flooding the receiver loses its own
/// messages first. One source holds at most [`MAX_PARTIALS_PER_SOURCE`] messages.
///
/// Each datagram costs the same however many messages are pending: the victim of an eviction
/// and the messages whose time ran out are found through ordered indexes (sources by bytes
/// held, messages by age), never by a scan of everything held, so a flood of forged sources
/// filling the limit does not slow the receiver down.
pub struct Reassembler {
    limit_bytes: usize,
    timeout: Duration,
    max_frame: usize,
    /// Where large reassembly buffers come from and go back to (see
    /// [`with_pool`](Reassembler::with_pool)).
    pool: Option<Arc<BufferPool>>,
    /// Fleet systems a sender field may name (empty: any).
    fleet: Vec<SystemId>,
    partials: HashMap<MessageKey, Partial>,
    sources: HashMap<SocketAddr, SourceUse>,
    /// Every source in `sources` by the bytes it holds: the last holds the most.
    by_bytes: BTreeSet<(usize, SocketAddr)>,
    /// Every incomplete message by age, oldest first: expiry looks at the front only.
    by_age: BTreeMap<Age, MessageKey>,
    /// Every incomplete message by source address, then in the order they began: a source's
    /// oldest is the first of its range. (One map for all sources: a map per source would
    /// cost a node's worth of memory for each forged address.)
    by_source: BTreeMap<(SocketAddr, u64), (SystemId, u32)>,
    /// The order number the next message to begin gets (see [`Age`]).
    next_order: u64,
    held: usize,
    evictions: u64,
    /// Recently completed messages, oldest first, and the same as a set.
    completed: VecDeque<(MessageKey, Instant)>,
    completed_set: HashSet<MessageKey>,
}

impl Reassembler {
    /// A reassembler holding at most `limit_bytes` for incomplete messages, giving each
    /// `timeout` from its first fragment, accepting frames up to `max_frame`.
    pub fn new(limit_bytes: usize, timeout: Duration, max_frame: usize) -> Reassembler {
        Reassembler {
            limit_bytes,
            timeout,
            max_frame,
            pool: None,
            fleet: Vec::new(),
            partials: HashMap::new(),
            sources: HashMap::new(),
            by_bytes: BTreeSet::new(),
            by_age: BTreeMap::new(),
            by_source: BTreeMap::new(),
            next_order: 0,
            held: 0,
            evictions: 0,
            completed: VecDeque::new(),
            completed_set: HashSet::new(),
        }
    }

    /// Accepts fragments only from senders named in `fleet` (when it is not empty); others are
    /// rejected with [`FragmentError::UnknownSender`] before anything is held.
    pub fn with_fleet(mut self, fleet: impl IntoIterator<Item = SystemId>) -> Reassembler {
        self.fleet = fleet.into_iter().collect();
        self.fleet.sort_unstable();
        self
    }

    /// Takes the buffers of large messages (16 KiB and more) from `pool`, and gives those of
    /// messages dropped incomplete back to it: a completed frame's buffer goes back when
    /// whoever it is handed to drops it (see [`BufferPool::wrap`]). A message's buffer grows
    /// in the same steps as without a pool, each rounded up to 4 KiB; a pooled buffer may have
    /// up to a quarter more room than that, and is charged for all of it.
    pub fn with_pool(mut self, pool: Arc<BufferPool>) -> Reassembler {
        self.pool = Some(pool);
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
            let frame = match self.pool.as_ref().filter(|_| piece.len() >= POOLED_MIN) {
                Some(pool) => {
                    let mut buf = pooled(pool, piece.len());
                    buf.extend_from_slice(piece);
                    buf
                }
                None => piece.to_vec(),
            };
            return Reassembly::Complete(frame);
        }
        let key = (src, h.sender, h.message_id);
        if let Some(p) = self.partials.get(&key) {
            if p.total != h.total || p.count != h.count {
                self.discard(&key);
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
                    self.discard(&k);
                    self.evictions += 1;
                }
            }
            let age = (now, self.next_order);
            self.next_order += 1;
            let p = Partial {
                total: h.total,
                count: h.count,
                age,
                head: Vec::new(),
                next: 0,
                ahead: BTreeMap::new(),
                ahead_bytes: 0,
                charged: PARTIAL_OVERHEAD,
            };
            self.held += p.charged;
            self.recharge(src, |s| {
                s.bytes += PARTIAL_OVERHEAD;
                s.partials += 1;
            });
            self.by_age.insert(age, key);
            self.by_source
                .insert((src, age.1), (h.sender, h.message_id));
            self.partials.insert(key, p);
        }
        let Some(p) = self.partials.get_mut(&key) else {
            return Reassembly::Pending;
        };
        if p.has(h.index) {
            return Reassembly::Duplicate;
        }
        p.insert(h.index, piece, self.pool.as_ref());
        if p.next == p.count {
            let frame = match self.remove(&key) {
                Some(p) => p.head,
                None => return Reassembly::Pending,
            };
            self.remember(key, now);
            return Reassembly::Complete(frame);
        }
        let (before, after) = (p.charged, p.cost());
        if after != before {
            // Most pieces land in room the head already has: no index to move then.
            p.charged = after;
            self.held = self.held - before + after;
            self.recharge(src, |s| s.bytes = s.bytes - before + after);
        }
        while self.held > self.limit_bytes {
            let Some(k) = self.eviction_victim() else {
                break;
            };
            self.discard(&k);
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
        // Oldest first: the first message whose time has not run out ends the look.
        let mut expired = 0;
        while let Some((&(started, _), &key)) = self.by_age.first_key_value() {
            if now.saturating_duration_since(started) < timeout {
                break;
            }
            self.discard(&key);
            expired += 1;
        }
        expired
    }

    /// Whether [`expire`](Reassembler::expire) has anything to look at.
    pub(super) fn needs_upkeep(&self) -> bool {
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
        let (&(addr, _), &(sender, message_id)) = self.by_source.range((src, 0)..).next()?;
        (addr == src).then_some((src, sender, message_id))
    }

    /// The message to drop for room: the oldest of the source holding the most bytes (of two
    /// holding as much, the one with the higher address).
    fn eviction_victim(&self) -> Option<MessageKey> {
        let &(_, src) = self.by_bytes.last()?;
        self.oldest_of(src)
    }

    /// Changes what `src` holds with `change` (creating its entry if need be), keeping
    /// `by_bytes` in step, and forgets the source once it holds no message.
    fn recharge(&mut self, src: SocketAddr, change: impl FnOnce(&mut SourceUse)) {
        let s = self.sources.entry(src).or_default();
        self.by_bytes.remove(&(s.bytes, src));
        change(s);
        if s.partials == 0 {
            self.sources.remove(&src);
        } else {
            self.by_bytes.insert((s.bytes, src));
        }
    }

    /// Drops an incomplete message; its buffer goes back to the pool.
    fn discard(&mut self, key: &MessageKey) {
        if let Some(p) = self.remove(key) {
            recycle(self.pool.as_ref(), p.head);
        }
    }

    fn remove(&mut self, key: &MessageKey) -> Option<Partial> {
        let p = self.partials.remove(key)?;
        self.held -= p.charged;
        self.by_age.remove(&p.age);
        self.by_source.remove(&(key.0, p.age.1));
        self.recharge(key.0, |s| {
            s.bytes -= p.charged;
            s.partials -= 1;
        });
        Some(p)
    }
}
