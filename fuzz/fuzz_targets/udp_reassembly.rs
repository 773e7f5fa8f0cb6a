//! A sequence of datagrams into the UDP fragment parser and reassembler
//! (`udp::parse_fragment`, `udp::Reassembler`), with time passing and expiry in between.
//!
//! Checked after every step:
//! - no panic;
//! - `on_fragment` rejects exactly what `parse_fragment` rejects, with the same error, and
//!   otherwise only for a wrong sender, a sender outside the fleet (`with_fleet`, used by
//!   half of the inputs) or a disagreeing message; a `Duplicate` is a fragment whose message
//!   and index were fed before;
//! - a one-fragment message comes back as its piece; any other reassembled frame has the
//!   declared length and is made of pieces that were actually fed (same source, sender,
//!   message id, count and total, each piece at its index);
//! - `held_bytes()` never exceeds the configured limit, and the heap the reassembler really
//!   holds stays within twice the bytes held plus a per-message allowance and the remembered
//!   completions; one datagram never makes it allocate more than 8 times its size plus 64 KiB
//!   (memory follows the bytes received, not what a header announces);
//! - expiry at the timeout gives up everything, and dropping the reassembler frees exactly
//!   the heap its calls took.
//!
//! Input: one configuration byte (and its parameters), a byte whose bit 0 selects
//! `with_fleet`, then operations; see `run`.
#![no_main]

#[path = "common/mod.rs"]
mod common;

#[global_allocator]
static ALLOC: common::Counting = common::Counting;

use std::collections::{HashMap, HashSet};
use std::net::{IpAddr, Ipv4Addr, SocketAddr};
use std::time::{Duration, Instant};

use common::Cursor;
use hetcomm_core::SystemId;
use hetcomm_link_ip::udp::{
    parse_fragment, FragmentError, FragmentHeader, Reassembler, Reassembly, UdpConfig,
    FRAGMENT_HEADER_LEN, MAX_DATAGRAM_PAYLOAD, MAX_REMEMBERED_COMPLETIONS,
};
use libfuzzer_sys::fuzz_target;

/// Heap allowed per incomplete message beyond its buffer and index table (hash-map slot,
/// bookkeeping), and for the map's spare capacity.
const PER_MESSAGE: usize = 512;
const SLACK: usize = 64 * 1024;

/// Most heap one datagram may make the reassembler allocate, as a multiple of its size (plus
/// `SLACK`): the first reservation of a message is at most 4 pieces, a piece ahead of its turn
/// is copied once. `HETCOMM_FUZZ_MAX_AMPLIFICATION=N` overrides it (0: no check).
fn max_amplification() -> Option<usize> {
    static F: std::sync::OnceLock<Option<usize>> = std::sync::OnceLock::new();
    *F.get_or_init(|| match std::env::var("HETCOMM_FUZZ_MAX_AMPLIFICATION") {
        Ok(v) => v.parse().ok().filter(|&n| n > 0),
        Err(_) => Some(8),
    })
}

/// The fleet the reassembler is told about in `with_fleet` inputs.
const FLEET: [SystemId; 2] = [SystemId(1), SystemId(2)];
/// Heap per remembered completed message (key, time, set entry), up to
/// `MAX_REMEMBERED_COMPLETIONS`.
const PER_COMPLETION: usize = 192;

/// (source, sender, message id, count, total): what makes fragments belong together.
type Key = (SocketAddr, SystemId, u32, u16, u32);

struct Cfg {
    limit: usize,
    max_frame: usize,
    timeout: Duration,
    /// Operations whose first fragment may make the reassembler zero a buffer of up to
    /// `max_frame` bytes are capped in the default configuration (16 MiB each), for speed.
    max_big_ops: usize,
}

fn config(c: &mut Cursor) -> Cfg {
    let kind = c.u8();
    if kind.is_multiple_of(4) {
        let d = UdpConfig::default();
        return Cfg {
            limit: d.reassembly_limit_bytes,
            max_frame: d.max_frame(),
            timeout: d.reassembly_timeout,
            max_big_ops: 3,
        };
    }
    // Small configurations, built the way a link builds its reassembler from a `UdpConfig`.
    let shift = 2 * u32::from(kind % 4 - 1);
    let payload = FRAGMENT_HEADER_LEN + 1 + usize::from(c.u16()) % (MAX_DATAGRAM_PAYLOAD - 20);
    let cfg = UdpConfig {
        datagram_payload: payload,
        max_message_bytes: Some(usize::from(c.u16()) << shift),
        reassembly_limit_bytes: usize::from(c.u16()) << shift,
        reassembly_timeout: Duration::from_millis(1 + u64::from(c.u8())),
        ..UdpConfig::default()
    };
    Cfg {
        limit: cfg.reassembly_limit_bytes,
        max_frame: cfg.max_frame(),
        timeout: cfg.reassembly_timeout,
        max_big_ops: usize::MAX,
    }
}

fn source(n: u8) -> SocketAddr {
    SocketAddr::new(IpAddr::V4(Ipv4Addr::new(10, 0, 0, 1 + (n & 3))), 9000)
}

/// Byte range of fragment `index` of a `total`-byte frame cut into `count` pieces, as
/// documented in the udp module ("pieces are cut evenly"); `None` if the geometry is invalid.
fn piece_range(total: usize, count: usize, index: usize) -> Option<std::ops::Range<usize>> {
    if count == 0 || total == 0 || count > total || index >= count {
        return None;
    }
    let chunk = total.div_ceil(count);
    if (count - 1) * chunk >= total {
        return None;
    }
    let start = index * chunk;
    Some(start..(start + chunk).min(total))
}

struct Harness {
    cfg: Cfg,
    r: Reassembler,
    now: Instant,
    /// Every piece accepted so far, by message and index.
    fed: HashMap<(Key, u16), HashSet<Vec<u8>>>,
    /// Heap taken by the reassembler's calls and not handed back in a `Complete`.
    held_heap: isize,
    pending_high: usize,
    frames: [Vec<u8>; 4],
    big_ops: usize,
    /// (source, sender, id) of every message a fragment was taken for.
    fed_ids: HashSet<(SocketAddr, SystemId, u32)>,
    /// Whether the reassembler was built `with_fleet(FLEET)`.
    fleet: bool,
    /// Messages completed from more than one fragment (remembered by the reassembler).
    completions: usize,
}

impl Harness {
    fn feed(&mut self, d: &[u8], src: SocketAddr, src_system: Option<SystemId>) {
        let expected = parse_fragment(d, self.cfg.max_frame).map(|(h, p)| (h, p.to_vec()));
        let before = common::reset_peak();
        let out = self.r.on_fragment(d, src, src_system, self.now);
        let peak = common::peak() - before;
        if let Some(factor) = max_amplification() {
            assert!(
                peak <= factor * d.len() + SLACK,
                "a {}-byte datagram made the reassembler allocate {peak} bytes ({}x)",
                d.len(),
                peak / d.len().max(1)
            );
        }
        let mut delta = common::live() as isize - before as isize;
        if let Reassembly::Complete(v) = &out {
            delta -= v.capacity() as isize;
        }
        self.held_heap += delta;
        match expected {
            Err(e) => assert_eq!(
                out,
                Reassembly::Rejected {
                    error: e,
                    dropped: 0
                },
                "on_fragment and parse_fragment disagree"
            ),
            Ok((h, piece)) => self.check_accepted(h, piece, src, src_system, out),
        }
        self.check_bounds();
    }

    fn check_accepted(
        &mut self,
        h: FragmentHeader,
        piece: Vec<u8>,
        src: SocketAddr,
        src_system: Option<SystemId>,
        out: Reassembly,
    ) {
        if let Some(actual) = src_system.filter(|s| *s != h.sender) {
            assert_eq!(
                out,
                Reassembly::Rejected {
                    error: FragmentError::WrongSender {
                        claimed: h.sender,
                        actual
                    },
                    dropped: 0
                }
            );
            return;
        }
        if src_system.is_none() && self.fleet && !FLEET.contains(&h.sender) {
            assert_eq!(
                out,
                Reassembly::Rejected {
                    error: FragmentError::UnknownSender { claimed: h.sender },
                    dropped: 0
                }
            );
            return;
        }
        let total = h.total as usize;
        let range = piece_range(total, usize::from(h.count), usize::from(h.index))
            .expect("parse_fragment accepted an invalid geometry");
        assert_eq!(range.len(), piece.len(), "piece length");
        if h.count == 1 {
            assert_eq!(out, Reassembly::Complete(piece), "one-fragment message");
            return;
        }
        let key = (src, h.sender, h.message_id, h.count, h.total);
        match out {
            Reassembly::Pending => {
                self.fed_ids.insert((src, h.sender, h.message_id));
                self.fed.entry((key, h.index)).or_default().insert(piece);
            }
            Reassembly::Duplicate => {
                // Of a pending message: that index was taken. Of a message completed within
                // the timeout: the reassembler remembers only (source, sender, id).
                assert!(
                    self.fed_ids.contains(&(src, h.sender, h.message_id)),
                    "fragment {} of message {} called a duplicate, but no fragment of that \
                     message was taken before",
                    h.index,
                    h.message_id
                );
            }
            Reassembly::Complete(frame) => {
                self.completions += 1;
                self.fed_ids.insert((src, h.sender, h.message_id));
                self.fed.entry((key, h.index)).or_default().insert(piece);
                assert_eq!(frame.len(), total, "reassembled frame length");
                for i in 0..h.count {
                    let r = piece_range(total, usize::from(h.count), usize::from(i)).unwrap();
                    let ok = self
                        .fed
                        .get(&(key, i))
                        .is_some_and(|s| s.contains(&frame[r.clone()]));
                    assert!(ok, "piece {i} ({r:?}) of a reassembled frame was never fed");
                }
            }
            Reassembly::Rejected { error, dropped } => {
                assert_eq!(
                    (error, dropped),
                    (
                        FragmentError::Inconsistent {
                            message_id: h.message_id
                        },
                        1
                    ),
                    "an accepted fragment was rejected"
                );
            }
        }
    }

    fn check_bounds(&mut self) {
        let held = self.r.held_bytes();
        assert!(
            held <= self.cfg.limit,
            "{held} bytes held over the {}-byte limit",
            self.cfg.limit
        );
        self.pending_high = self.pending_high.max(self.r.pending());
        let bound = 2 * held
            + PER_MESSAGE * self.pending_high
            + PER_COMPLETION * self.completions.min(MAX_REMEMBERED_COMPLETIONS)
            + SLACK;
        assert!(
            self.held_heap <= bound as isize,
            "the reassembler holds {} heap bytes for {held} bytes held in {} messages",
            self.held_heap,
            self.r.pending()
        );
    }

    fn expire(&mut self) -> usize {
        let before = common::live();
        let n = self.r.expire(self.now);
        self.held_heap += common::live() as isize - before as isize;
        self.check_bounds();
        n
    }
}

fn run(data: &[u8]) {
    let mut c = Cursor::new(data);
    let cfg = config(&mut c);
    let fleet = c.u8() & 1 == 1;
    let before = common::live();
    let r = Reassembler::new(cfg.limit, cfg.timeout, cfg.max_frame);
    let r = if fleet { r.with_fleet(FLEET) } else { r };
    let mut h = Harness {
        held_heap: common::live() as isize - before as isize,
        cfg,
        r,
        now: Instant::now(),
        fed: HashMap::new(),
        pending_high: 0,
        frames: Default::default(),
        big_ops: 0,
        fleet,
        completions: 0,
        fed_ids: HashSet::new(),
    };
    while !c.is_empty() {
        let op = c.u8();
        let src = source(op >> 4);
        // Which fleet system the source address belongs to, if any.
        let system_mode = op >> 6;
        match op & 15 {
            // A raw datagram.
            0..=3 => {
                let len = usize::from(c.u16()) % 4096;
                let d = c.bytes(len).to_vec();
                let sys = match system_mode {
                    1 | 2 => Some(SystemId(u16::from(system_mode))),
                    _ => None,
                };
                h.feed(&d, src, sys);
            }
            // A well-formed header with arbitrary fields and a piece of the length its
            // geometry implies (or of an arbitrary length if it has none).
            4..=6 => {
                let hdr = FragmentHeader {
                    sender: SystemId(c.u16() % 4),
                    index: c.u16(),
                    count: c.u16(),
                    message_id: u32::from(c.u8() % 4),
                    total: c.u32(),
                };
                let fill = c.u8();
                let len = match piece_range(
                    hdr.total as usize,
                    usize::from(hdr.count),
                    usize::from(hdr.index),
                ) {
                    Some(r) => r.len(),
                    None => usize::from(fill),
                };
                if len > MAX_DATAGRAM_PAYLOAD || hdr.total as usize > 1 << 20 {
                    if h.big_ops >= h.cfg.max_big_ops {
                        continue;
                    }
                    h.big_ops += 1;
                }
                let mut d = hdr.encode().to_vec();
                d.resize(FRAGMENT_HEADER_LEN + len.min(MAX_DATAGRAM_PAYLOAD), fill);
                let sys = match system_mode {
                    1 => Some(hdr.sender),
                    2 => Some(SystemId(hdr.sender.0 ^ 1)),
                    _ => None,
                };
                h.feed(&d, src, sys);
            }
            // Sets frame slot `s`.
            7 => {
                let s = usize::from(c.u8() % 4);
                let len = usize::from(c.u16()) % 8192;
                let seed = c.bytes(len.min(64)).to_vec();
                h.frames[s] = (0..len)
                    .map(|i| seed.get(i % seed.len().max(1)).copied().unwrap_or(0) ^ (i / 64) as u8)
                    .collect();
            }
            // Fragments `from..from + n` of frame slot `s`, cut into `count` pieces.
            8..=11 => {
                let s = usize::from(c.u8() % 4);
                let count = c.u16() % 512;
                let message_id = u32::from(c.u8() % 4);
                let sender = SystemId(u16::from(c.u8() % 4));
                let from = c.u16();
                let n = c.u8();
                let reverse = op & 1 == 1;
                let frame = h.frames[s].clone();
                let total = frame.len();
                if total == 0 {
                    continue;
                }
                // Make the geometry valid: chunk from the wished count, then the count that
                // chunk really gives.
                let chunk = total.div_ceil(usize::from(count.max(1)).min(total));
                let count = total.div_ceil(chunk) as u16;
                let from = from % count;
                let to = from.saturating_add(u16::from(n).max(1)).min(count);
                let mut order: Vec<u16> = (from..to).collect();
                if reverse {
                    order.reverse();
                }
                let sys = match system_mode {
                    1 => Some(sender),
                    2 => Some(SystemId(sender.0 ^ 1)),
                    _ => None,
                };
                for index in order {
                    let hdr = FragmentHeader {
                        sender,
                        index,
                        count,
                        message_id,
                        total: total as u32,
                    };
                    let r = piece_range(total, usize::from(count), usize::from(index)).unwrap();
                    let mut d = hdr.encode().to_vec();
                    d.extend_from_slice(&frame[r]);
                    h.feed(&d, src, sys);
                }
            }
            // Time passes.
            12 | 13 => h.now += Duration::from_micros(u64::from(c.u16()) * 64),
            14 => {
                h.expire();
            }
            // The timeout passes: everything incomplete is given up.
            _ => {
                h.now += h.cfg.timeout;
                let pending = h.r.pending();
                assert_eq!(h.expire(), pending);
                assert_eq!((h.r.pending(), h.r.held_bytes()), (0, 0));
            }
        }
    }
    h.now += h.cfg.timeout;
    let pending = h.r.pending();
    assert_eq!(h.expire(), pending, "expiry at the timeout");
    assert_eq!((h.r.pending(), h.r.held_bytes()), (0, 0));
    // Dropping the reassembler frees exactly what its calls took.
    let before = common::live();
    drop(h.r);
    let freed = before as isize - common::live() as isize;
    assert_eq!(freed, h.held_heap, "heap accounting of the reassembler");
}

fuzz_target!(|data: &[u8]| run(data));
