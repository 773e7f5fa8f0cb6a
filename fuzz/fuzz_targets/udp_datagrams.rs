//! Datagrams, sent over 127.0.0.1, into the receive side of a real `UdpLink` (driven, so that
//! the target reads on its own thread with `Readable::read_ready`): the datagram
//! classification (whole frame / batch / fragment), the batch walk and the link's own
//! reassembler, which are private (`RxState::on_datagram`, `looks_like_batch`,
//! `BatchFrames`).
//!
//! Each datagram is followed by a sentinel datagram (a whole frame no datagram kind can be
//! mistaken for) from the same socket; the target reads until the sentinel is handed up, so it
//! knows the datagram has been handled. What the sink got and the link's counters must then
//! agree with a model of the "Datagram format" section of the udp module docs, written here:
//! whole frames handed up as they are; `"HB"` batches checked (magic, version 1, reserved 0)
//! and their records (u32 length, frame) walked, a malformed tail or unread header counted;
//! fragments fed to a public `Reassembler` configured as the link's (same limit, timeout,
//! `max_frame` and fleet), whose completions, duplicates, rejections (oversize ones too),
//! evictions and held bytes the link's must match. Also: labels (`Peer::System` for the fleet socket,
//! `Peer::Unknown` and `from_unknown_address` for the other), and no panic.
//!
//! Input: a configuration byte (and parameters), a byte ignored (`udp_reassembly`'s fleet
//! byte, so that the two share seeds), then operations; see `run`.
#![no_main]

#[path = "common/mod.rs"]
mod common;

use std::collections::BTreeMap;
use std::net::{SocketAddr, UdpSocket};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use common::Cursor;
use hetcomm_core::{BufferPool, SystemId};
use hetcomm_link::{FrameSink, Link, Peer};
use hetcomm_link_ip::udp::{
    FragmentError, FragmentHeader, Reassembler, Reassembly, UdpConfig, UdpStats,
    FRAGMENT_HEADER_LEN, FRAGMENT_MAGIC, MAX_DATAGRAM_PAYLOAD,
};
use hetcomm_link_ip::UdpLink;
use libfuzzer_sys::fuzz_target;

const FLEET_SYSTEM: SystemId = SystemId(1);
const LOCAL: SystemId = SystemId(2);
const SENTINEL: &[u8] = b"ZZ sentinel: neither a fragment nor a batch";

#[derive(Default)]
struct Sink(Mutex<Vec<(Vec<u8>, Peer)>>);

impl FrameSink for Sink {
    fn on_frame(&self, frame: &[u8], from: Peer) {
        self.0.lock().unwrap().push((frame.to_vec(), from));
    }
}

fn config(c: &mut Cursor) -> UdpConfig {
    let kind = c.u8();
    // Long enough that nothing expires during one input: the model does not follow the clock.
    let reassembly_timeout = Duration::from_secs(120);
    if kind.is_multiple_of(4) {
        return UdpConfig {
            reassembly_timeout,
            driven: true,
            ..UdpConfig::default()
        };
    }
    // The same layout as udp_reassembly's configuration (so seeds work for both); its
    // timeout byte is read and ignored.
    let shift = 2 * u32::from(kind % 4 - 1);
    let config = UdpConfig {
        datagram_payload: FRAGMENT_HEADER_LEN
            + 1
            + usize::from(c.u16()) % (MAX_DATAGRAM_PAYLOAD - 20),
        max_message_bytes: Some(usize::from(c.u16()) << shift),
        // At least 4 MiB, more than an input's fragments can fill, so that the link never
        // evicts for room: the victim is the oldest message of the source holding the most,
        // which this harness's model does not follow (`udp_reassembly` covers eviction; the
        // per-source cap still evicts here, deterministically).
        reassembly_limit_bytes: (usize::from(c.u16()) << shift).max(4 << 20),
        reassembly_timeout,
        socket_buffer_bytes: 1 << 20,
        driven: true,
        write_behind: Default::default(),
    };
    c.u8();
    config
}

/// What the link must do with one datagram, from the module docs.
#[derive(Default, Debug, Clone, PartialEq, Eq)]
struct Expect {
    frames: Vec<Vec<u8>>,
    batches: u64,
    bad: u64,
    evictions: u64,
    duplicates: u64,
    oversize: u64,
}

struct Model {
    reassembler: Reassembler,
    /// A pool like the link's: its reassembler takes large messages' buffers from it,
    /// rounded up to 4 KiB and charged by capacity, so `buffered_bytes` agrees only if the
    /// model's buffers come and go as the link's do.
    pool: Arc<BufferPool>,
    now: Instant,
}

/// Bytes the link's pool keeps when its sink does not keep frames (the udp module's
/// `REASSEMBLY_POOL_BYTES`).
const LINK_POOL_BYTES: usize = 1 << 20;
/// Buffers of at least this many bytes go back to the pool (the reassembler's `POOLED_MIN`).
const POOLED_MIN: usize = 16 * 1024;

impl Model {
    fn datagram(&mut self, d: &[u8], src: SocketAddr, system: Option<SystemId>) -> Expect {
        let mut e = Expect::default();
        if d.starts_with(b"HB") {
            // A batch: header "HB", version 1, reserved 0, then records (u32 length, frame)
            // until one runs past the end. An unread header drops the datagram; so does a
            // batch without a single complete record.
            if d.len() < 4 || d[2] != 1 || d[3] != 0 {
                e.bad = 1;
                return e;
            }
            let mut rest = &d[4..];
            while rest.len() >= 4 {
                let n = u32::from_le_bytes(rest[..4].try_into().unwrap()) as usize;
                if n > rest.len() - 4 {
                    break;
                }
                e.frames.push(rest[4..4 + n].to_vec());
                rest = &rest[4 + n..];
            }
            e.batches = u64::from(!e.frames.is_empty());
            e.bad = u64::from(!rest.is_empty() || e.frames.is_empty());
            return e;
        }
        if !d.starts_with(&FRAGMENT_MAGIC) {
            e.frames.push(d.to_vec());
            return e;
        }
        // Strictly increasing, like the link's clock, so that "the oldest" is the same message.
        self.now += Duration::from_micros(1);
        let before = self.reassembler.evictions();
        match self.reassembler.on_fragment(d, src, system, self.now) {
            Reassembly::Complete(f) => {
                e.frames.push(f.clone());
                // As the link does once its sink (which keeps no frames) has returned.
                if f.capacity() >= POOLED_MIN {
                    self.pool.give(f);
                }
            }
            Reassembly::Pending => {}
            Reassembly::Duplicate => e.duplicates = 1,
            Reassembly::Rejected { dropped, error } => {
                e.bad = 1;
                e.evictions += dropped as u64;
                if let FragmentError::BadGeometry { total, max, .. } = error {
                    e.oversize = u64::from(total as usize > max);
                }
            }
        }
        e.evictions += self.reassembler.evictions() - before;
        e
    }
}

struct Rig {
    link: UdpLink,
    link_addr: SocketAddr,
    fleet: UdpSocket,
    stranger: UdpSocket,
    sink: Arc<Sink>,
    model: Model,
    stats: UdpStats,
}

impl Rig {
    fn new(config: UdpConfig) -> Rig {
        let local = UdpSocket::bind("127.0.0.1:0").unwrap();
        let link_addr = local.local_addr().unwrap();
        let fleet = UdpSocket::bind("127.0.0.1:0").unwrap();
        let stranger = UdpSocket::bind("127.0.0.1:0").unwrap();
        let endpoints = BTreeMap::from([
            (LOCAL, link_addr.to_string()),
            (FLEET_SYSTEM, fleet.local_addr().unwrap().to_string()),
        ]);
        let sink = Arc::new(Sink::default());
        let pool = BufferPool::new(LINK_POOL_BYTES);
        let model = Model {
            reassembler: Reassembler::new(
                config.reassembly_limit_bytes,
                config.reassembly_timeout,
                config.max_frame(),
            )
            .with_fleet([FLEET_SYSTEM])
            .with_pool(pool.clone()),
            pool,
            now: Instant::now(),
        };
        let link = UdpLink::with_socket(LOCAL, local, &endpoints, sink.clone(), config)
            .expect("link opens");
        Rig {
            link,
            link_addr,
            fleet,
            stranger,
            sink,
            model,
            stats: UdpStats::default(),
        }
    }

    fn send(&mut self, d: &[u8], from_fleet: bool) {
        let (socket, label) = if from_fleet {
            (&self.fleet, Peer::System(FLEET_SYSTEM))
        } else {
            (&self.stranger, Peer::Unknown)
        };
        let src = socket.local_addr().unwrap();
        let expect = self
            .model
            .datagram(d, src, from_fleet.then_some(FLEET_SYSTEM));
        socket.send_to(d, self.link_addr).unwrap();
        socket.send_to(SENTINEL, self.link_addr).unwrap();
        let readable = self.link.readable().expect("a driven link is readable");
        let deadline = Instant::now() + Duration::from_secs(10);
        let got = loop {
            readable.read_ready(16).expect("read_ready");
            let mut g = self.sink.0.lock().unwrap();
            if g.last().is_some_and(|(f, _)| f == SENTINEL) {
                g.pop();
                break std::mem::take(&mut *g);
            }
            drop(g);
            assert!(
                Instant::now() < deadline,
                "datagram or sentinel never handed up"
            );
            std::thread::yield_now();
        };
        let frames: Vec<Vec<u8>> = got
            .into_iter()
            .map(|(f, from)| {
                assert_eq!(from, label, "label of a frame from {src}");
                f
            })
            .collect();
        assert_eq!(
            frames,
            expect.frames,
            "frames handed up for {}-byte datagram",
            d.len()
        );
        // Counters: the datagram's effect plus the sentinel (one whole frame).
        let s = self.link.udp_stats();
        let n = expect.frames.len() as u64 + 1;
        let p = &self.stats;
        assert_eq!(s.frames_received - p.frames_received, n, "frames_received");
        assert_eq!(
            s.batches_received - p.batches_received,
            expect.batches,
            "batches"
        );
        assert_eq!(
            s.bad_datagrams - p.bad_datagrams,
            expect.bad,
            "bad_datagrams"
        );
        assert_eq!(
            s.reassembly_evictions - p.reassembly_evictions,
            expect.evictions,
            "reassembly_evictions"
        );
        let unknown = if from_fleet { 0 } else { n };
        assert_eq!(
            s.from_unknown_address - p.from_unknown_address,
            unknown,
            "from_unknown_address"
        );
        assert_eq!(
            s.duplicate_fragments - p.duplicate_fragments,
            expect.duplicates,
            "duplicate_fragments"
        );
        assert_eq!(
            s.oversize_fragments - p.oversize_fragments,
            expect.oversize,
            "oversize_fragments"
        );
        assert_eq!(s.reassembly_timeouts, 0);
        assert_eq!(
            s.buffered_bytes,
            self.model.reassembler.held_bytes() as u64,
            "buffered_bytes"
        );
        self.stats = s;
    }
}

fn run(data: &[u8]) {
    let mut c = Cursor::new(data);
    let config = config(&mut c);
    // The fleet byte of udp_reassembly's layout: the link always knows its fleet.
    c.u8();
    let mut rig = Rig::new(config);
    while !c.is_empty() {
        let op = c.u8();
        let from_fleet = op & 0x80 == 0;
        let d = match op & 3 {
            // Raw bytes.
            0 | 1 => {
                let len = usize::from(c.u16()) % 4096;
                c.bytes(len).to_vec()
            }
            // A batch: its header (as sent, or with a byte changed), records of the lengths
            // the input gives, then some other bytes.
            2 => {
                let mut d = b"HB\x01\x00".to_vec();
                let (at, to) = (c.u8(), c.u8());
                if at < 4 {
                    d[usize::from(at)] = to;
                }
                for i in 0..c.u8() % 8 {
                    let n = usize::from(c.u8());
                    d.extend_from_slice(&(n as u32).to_le_bytes());
                    d.resize(d.len() + n, i);
                }
                let tail = usize::from(c.u8() % 64);
                d.extend_from_slice(c.bytes(tail));
                d
            }
            // A fragment with a well-formed header, and a piece of the length it claims (or
            // not, per bit 2).
            _ => {
                let h = FragmentHeader {
                    sender: SystemId(c.u16() % 3),
                    index: c.u16(),
                    count: c.u16(),
                    message_id: u32::from(c.u8() % 4),
                    total: c.u32() % (1 << 20),
                };
                let fill = c.u8();
                let chunk = (h.total as usize).div_ceil(usize::from(h.count.max(1)));
                let start = usize::from(h.index) * chunk;
                let mut len = (start + chunk).min(h.total as usize).saturating_sub(start);
                if op & 4 != 0 {
                    len = usize::from(fill);
                }
                let mut d = h.encode().to_vec();
                d.resize(
                    FRAGMENT_HEADER_LEN + len.min(MAX_DATAGRAM_PAYLOAD - 20),
                    fill,
                );
                d
            }
        };
        rig.send(&d, from_fleet);
    }
}

fuzz_target!(|data: &[u8]| run(data));
