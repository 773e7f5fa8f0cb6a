//! Unit tests of the UDP link: the kernel drop counter, the batch walk, what is batched,
//! fragment headers and the [`Reassembler`] (ordering, limits, eviction, timeouts,
//! duplicates and inconsistent fragments).

use std::net::{IpAddr, Ipv4Addr};
use std::time::Instant;

use super::batch::{batchable, misread_alone, push_record};
use super::reassembly::{PARTIAL_OVERHEAD, PIECE_OVERHEAD};
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
    // All began at the same instant: the first five to begin were the ones evicted, whatever
    // a hash map's order, and every later one completes without evicting another.
    for id in 5..MAX_PARTIALS_PER_SOURCE as u32 + 5 {
        let f = fragments(&[4u8; 300], 100, id);
        assert_eq!(r.on_fragment(&f[1], SRC, None, t0), Reassembly::Pending);
        assert_eq!(
            r.on_fragment(&f[2], SRC, None, t0),
            Reassembly::Complete(vec![4u8; 300]),
            "message {id}"
        );
    }
    assert_eq!((r.evictions(), r.pending(), r.held_bytes()), (5, 0, 0));
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

#[test]
fn a_pooled_reassembler_reuses_its_buffers_and_is_charged_for_them() {
    let pool = hetcomm_core::BufferPool::new(1 << 20);
    let mut r = Reassembler::new(1 << 20, Duration::from_secs(2), 1 << 20).with_pool(pool.clone());
    let t0 = Instant::now();
    let frame: Vec<u8> = (0..40_000u32).map(|i| i as u8).collect();
    let frags = fragments(&frame, 20_000, 1);
    assert_eq!(r.on_fragment(&frags[0], SRC, None, t0), Reassembly::Pending);
    // A pooled buffer for the whole frame (4 KiB steps), charged for its capacity.
    let charged = r.held_bytes() - PARTIAL_OVERHEAD;
    assert!((40_000..40_000 + 4096).contains(&charged), "{charged}");
    // Given up at the timeout: the buffer goes back to the pool.
    assert_eq!(r.expire(t0 + Duration::from_secs(2)), 1);
    assert_eq!((r.held_bytes(), pool.kept_bytes()), (0, charged));
    // The next message of that size is reassembled in it, and the frame's buffer returns to
    // the pool when whoever it was handed to drops it.
    let again = fragments(&frame, 20_000, 2);
    assert_eq!(r.on_fragment(&again[0], SRC, None, t0), Reassembly::Pending);
    assert_eq!(pool.kept_bytes(), 0);
    let Reassembly::Complete(got) = r.on_fragment(&again[1], SRC, None, t0) else {
        panic!("not complete");
    };
    assert_eq!(got, frame);
    drop(pool.wrap(got));
    assert_eq!(pool.kept_bytes(), charged);
    // Small messages are left to the allocator.
    let small = fragments(&frame[..3000], 1000, 3);
    r.on_fragment(&small[0], SRC, None, t0);
    assert_eq!(pool.kept_bytes(), charged);
}
