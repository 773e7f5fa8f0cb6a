//! Inputs found by (or probed with) the fuzz targets in `fuzz/` (see `fuzz/README.md`), fed to
//! the public API as plain tests.
//!
//! The tests marked `#[ignore]` state the behaviour wanted for a known, not yet fixed issue
//! and fail today; run them with `cargo test -p hetcomm-link-ip --test fuzz_regressions --
//! --ignored --nocapture`, which also prints what was measured.

use std::alloc::{GlobalAlloc, Layout, System};
use std::net::{IpAddr, Ipv4Addr, SocketAddr};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;
use std::time::{Duration, Instant};

use hetcomm_core::SystemId;
use hetcomm_link_ip::udp::{FragmentHeader, Reassembler, Reassembly, UdpConfig};

/// Counts live heap bytes and their peak, so that a test can see what one call allocates.
struct Counting;

static LIVE: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);

fn grew(n: usize) {
    let now = LIVE.fetch_add(n, Ordering::Relaxed) + n;
    PEAK.fetch_max(now, Ordering::Relaxed);
}

// SAFETY: forwards every call unchanged to `System`; only counters are updated.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let p = System.alloc(layout);
        if !p.is_null() {
            grew(layout.size());
        }
        p
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        let p = System.alloc_zeroed(layout);
        if !p.is_null() {
            grew(layout.size());
        }
        p
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        System.dealloc(ptr, layout);
        LIVE.fetch_sub(layout.size(), Ordering::Relaxed);
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        let p = System.realloc(ptr, layout, new_size);
        if !p.is_null() {
            if new_size >= layout.size() {
                grew(new_size - layout.size());
            } else {
                LIVE.fetch_sub(layout.size() - new_size, Ordering::Relaxed);
            }
        }
        p
    }
}

#[global_allocator]
static ALLOC: Counting = Counting;

/// Heap measurements are global: one measuring test at a time.
static MEASURING: Mutex<()> = Mutex::new(());

/// Runs `f`; returns its result, the most heap it had live beyond what was live before, and
/// the heap it left live.
fn measure<T>(f: impl FnOnce() -> T) -> (T, usize, isize) {
    let before = LIVE.load(Ordering::Relaxed);
    PEAK.store(before, Ordering::Relaxed);
    let out = f();
    let peak = PEAK.load(Ordering::Relaxed) - before;
    let kept = LIVE.load(Ordering::Relaxed) as isize - before as isize;
    (out, peak, kept)
}

const SRC: SocketAddr = SocketAddr::new(IpAddr::V4(Ipv4Addr::LOCALHOST), 9);

fn fragment(h: FragmentHeader, piece_len: usize) -> Vec<u8> {
    let mut d = h.encode().to_vec();
    d.resize(d.len() + piece_len, 0xA5);
    d
}

fn default_reassembler() -> Reassembler {
    let c = UdpConfig::default();
    Reassembler::new(
        c.reassembly_limit_bytes,
        c.reassembly_timeout,
        c.max_frame(),
    )
}

/// The 276-byte first fragment of a message claiming 65535 fragments of 256 bytes
/// (16 776 960 bytes): `parse_fragment` accepts it, and the reassembler allocates (and
/// zeroes) the whole message buffer plus a 65535-entry index at once, and counts all of it
/// against `reassembly_limit_bytes`: two such datagrams (552 bytes) fill the default 32 MiB
/// limit, and every further one evicts a pending message. Found probing the `udp_reassembly`
/// target with `HETCOMM_FUZZ_MAX_AMPLIFICATION=16` (corpus seed
/// `vec_amplification_first_fragment`).
fn amplifying_first_fragment(message_id: u32) -> Vec<u8> {
    fragment(
        FragmentHeader {
            sender: SystemId(1),
            index: 0,
            count: 65535,
            message_id,
            total: 65535 * 256,
        },
        256,
    )
}

#[test]
fn amplifying_first_fragment_is_accepted_and_accounted_within_the_limit() {
    // What holds today: no panic, pending, within the limit, freed at the timeout.
    let _g = MEASURING.lock().unwrap_or_else(|e| e.into_inner());
    let mut r = default_reassembler();
    let d = amplifying_first_fragment(1);
    assert_eq!(d.len(), 276);
    let t0 = Instant::now();
    let (out, peak, _) = measure(|| r.on_fragment(&d, SRC, Some(SystemId(1)), t0));
    assert_eq!(out, Reassembly::Pending);
    assert_eq!(r.held_bytes(), 65535 * 256);
    assert!(r.held_bytes() <= UdpConfig::default().reassembly_limit_bytes);
    println!(
        "first fragment: {} bytes in, {peak} heap bytes allocated ({}x), {} bytes held",
        d.len(),
        peak / d.len(),
        r.held_bytes()
    );
    assert_eq!(r.expire(t0 + UdpConfig::default().reassembly_timeout), 1);
    assert_eq!(r.held_bytes(), 0);
}

#[test]
#[ignore = "known issue: one 276-byte datagram makes the reassembler allocate 16.8 MB"]
fn a_first_fragment_allocates_little_more_than_itself() {
    let _g = MEASURING.lock().unwrap_or_else(|e| e.into_inner());
    let mut r = default_reassembler();
    let d = amplifying_first_fragment(1);
    let (_, peak, _) = measure(|| r.on_fragment(&d, SRC, Some(SystemId(1)), Instant::now()));
    println!("{} bytes in, {peak} heap bytes allocated", d.len());
    assert!(
        peak <= 64 * 1024,
        "{peak} bytes allocated for a {}-byte datagram",
        d.len()
    );
}

#[test]
#[ignore = "known issue: two 276-byte datagrams evict a legitimate pending message"]
fn a_few_tiny_datagrams_do_not_evict_a_pending_message() {
    let _g = MEASURING.lock().unwrap_or_else(|e| e.into_inner());
    let mut r = default_reassembler();
    let t0 = Instant::now();
    // A legitimate 1 MiB message, half received.
    let total = 1 << 20;
    let count = 1024u16;
    let good = |index| {
        fragment(
            FragmentHeader {
                sender: SystemId(2),
                index,
                count,
                message_id: 7,
                total,
            },
            1024,
        )
    };
    let other = SocketAddr::new(IpAddr::V4(Ipv4Addr::LOCALHOST), 10);
    for i in 0..512 {
        assert_eq!(
            r.on_fragment(&good(i), other, None, t0),
            Reassembly::Pending
        );
    }
    for id in 0..2 {
        r.on_fragment(&amplifying_first_fragment(id), SRC, None, t0);
    }
    println!(
        "after 2 x 276 bytes: {} pending, {} evictions, {} bytes held",
        r.pending(),
        r.evictions(),
        r.held_bytes()
    );
    assert_eq!(r.evictions(), 0, "552 bytes of datagrams evicted a message");
}

/// Incomplete messages of 2 bytes each (a 21-byte first fragment, count 2, total 2) count 2
/// bytes each against `reassembly_limit_bytes`, but each also takes a hash-map entry, a
/// 2-byte buffer and a 2-entry index: the heap held is far more than the limit says.
#[test]
#[ignore = "known issue: per-message bookkeeping is not counted against the limit"]
fn tiny_messages_stay_within_a_small_multiple_of_the_limit() {
    let _g = MEASURING.lock().unwrap_or_else(|e| e.into_inner());
    let limit = 1 << 20;
    let mut r = Reassembler::new(limit, Duration::from_secs(2), 1 << 20);
    let t0 = Instant::now();
    let n = limit / 2;
    let frags: Vec<Vec<u8>> = (0..n as u32)
        .map(|id| {
            fragment(
                FragmentHeader {
                    sender: SystemId(1),
                    index: 0,
                    count: 2,
                    message_id: id,
                    total: 2,
                },
                1,
            )
        })
        .collect();
    let (_, _, kept) = measure(|| {
        for f in &frags {
            r.on_fragment(f, SRC, None, t0);
        }
    });
    // One more new message now has to evict: time the scan for the oldest.
    let extra = fragment(
        FragmentHeader {
            sender: SystemId(1),
            index: 0,
            count: 2,
            message_id: u32::MAX,
            total: 2,
        },
        1,
    );
    let started = Instant::now();
    let evicting = 100;
    for i in 0..evicting {
        let mut d = extra.clone();
        d[12..16].copy_from_slice(&(u32::MAX - i).to_le_bytes());
        r.on_fragment(&d, SRC, None, t0 + Duration::from_millis(1));
    }
    let per_eviction = started.elapsed() / evicting;
    println!(
        "{} pending messages, {} bytes held (limit {limit}), {kept} heap bytes ({}x the limit); \
         a new message then takes {per_eviction:?} to evict the oldest",
        r.pending(),
        r.held_bytes(),
        kept / limit as isize
    );
    assert!(
        kept <= 4 * limit as isize,
        "{kept} heap bytes for a {limit}-byte limit"
    );
}
