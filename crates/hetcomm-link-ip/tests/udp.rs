//! UDP link behaviour beyond the conformance suite: large-message reassembly, missing
//! fragments, hostile datagrams. Crafted datagrams come from a raw `UdpSocket` that stands in
//! for a fleet system. Real sockets on 127.0.0.1, port 0 only.

mod common;

use std::net::UdpSocket;
use std::time::{Duration, Instant};

use common::{udp_sockets, wait_until, DEADLINE};
use hetcomm_core::SystemId;
use hetcomm_link::conformance::CollectSink;
use hetcomm_link::{Link, LinkError, Peer};
use hetcomm_link_ip::udp::{FragmentHeader, UdpStats};
use hetcomm_link_ip::{UdpConfig, UdpLink};

const A: SystemId = SystemId(1);
const B: SystemId = SystemId(2);

fn pattern(len: usize, seed: u8) -> Vec<u8> {
    (0..len).map(|i| (i % 251) as u8 ^ seed).collect()
}

/// B's link, plus a raw socket bound at A's fleet endpoint to craft datagrams from.
fn b_and_raw_a(config: UdpConfig) -> (UdpLink, UdpSocket, std::sync::Arc<CollectSink>) {
    let (endpoints, mut sockets) = udp_sockets(&[A, B]);
    let sink = CollectSink::new();
    let b = UdpLink::with_socket(
        B,
        sockets.remove(&B).unwrap(),
        &endpoints,
        sink.clone(),
        config,
    )
    .unwrap();
    let raw = sockets.remove(&A).unwrap();
    raw.connect(b.local_addr()).unwrap();
    (b, raw, sink)
}

/// The fragments of `frame` as the link cuts them, `count` pieces.
fn fragments(frame: &[u8], count: u16, message_id: u32) -> Vec<Vec<u8>> {
    let chunk = frame.len().div_ceil(count as usize);
    (0..count)
        .map(|index| {
            let h = FragmentHeader {
                sender: A,
                index,
                count,
                message_id,
                total: frame.len() as u32,
            };
            let mut d = h.encode().to_vec();
            let start = index as usize * chunk;
            d.extend_from_slice(&frame[start..(start + chunk).min(frame.len())]);
            d
        })
        .collect()
}

#[test]
fn a_one_mebibyte_frame_reassembles() {
    let (endpoints, mut sockets) = udp_sockets(&[A, B]);
    let sink_b = CollectSink::new();
    let config = UdpConfig::loopback();
    let a = UdpLink::with_socket(
        A,
        sockets.remove(&A).unwrap(),
        &endpoints,
        CollectSink::new(),
        config.clone(),
    )
    .unwrap();
    let b = UdpLink::with_socket(
        B,
        sockets.remove(&B).unwrap(),
        &endpoints,
        sink_b.clone(),
        config,
    )
    .unwrap();
    let frame = pattern(1024 * 1024 + 1, 0x5a);
    // UDP may lose a fragment even on loopback; the link is unreliable, so resend until one
    // copy arrives, as the router would.
    let deadline = Instant::now() + DEADLINE;
    while sink_b.frames().is_empty() {
        assert!(Instant::now() < deadline, "1 MiB frame never reassembled");
        a.send(B, &frame).unwrap();
        sink_b.wait_for(1, Duration::from_millis(500));
    }
    let got = &sink_b.frames()[0];
    assert!(got.bytes == frame, "reassembled frame differs");
    assert_eq!(got.from, Peer::System(A));
    assert_eq!(a.udp_stats().fragments_sent % 17, 0, "{:?}", a.udp_stats());
    assert_eq!(a.caps().mtu, 65_000);
    // Copies that lost a fragment are given up after the reassembly timeout.
    wait_until("reassembly memory released", DEADLINE, || {
        b.stats().buffered_bytes == 0
    });
    assert!(!a.caps().reliable && !a.caps().ordered);
}

#[test]
fn a_missing_fragment_drops_the_message_and_frees_its_memory() {
    let config = UdpConfig {
        reassembly_timeout: Duration::from_millis(200),
        ..UdpConfig::default()
    };
    let (b, raw, sink) = b_and_raw_a(config);
    let frame = pattern(5000, 1);
    let frags = fragments(&frame, 4, 42);
    for (i, f) in frags.iter().enumerate() {
        if i != 2 {
            raw.send(f).unwrap();
        }
    }
    // Three pieces of 1250 bytes arrived (and the bookkeeping is charged too).
    wait_until("partial message held", DEADLINE, || {
        b.stats().buffered_bytes >= 3 * 1250
    });
    wait_until("partial message dropped", DEADLINE, || {
        b.udp_stats().reassembly_timeouts == 1
    });
    wait_until("memory released", DEADLINE, || {
        b.stats().buffered_bytes == 0
    });
    assert_eq!(b.stats().frames_dropped, 1);
    assert!(sink.frames().is_empty());

    // The same link still reassembles a complete message afterwards, in any order.
    for f in fragments(&frame, 4, 43).iter().rev() {
        raw.send(f).unwrap();
    }
    assert_eq!(sink.wait_for(1, DEADLINE), 1);
    assert_eq!(sink.frames()[0].bytes, frame);
    assert_eq!(sink.frames()[0].from, Peer::System(A));
}

#[test]
fn bad_datagrams_are_counted_and_dropped() {
    let (b, raw, sink) = b_and_raw_a(UdpConfig::default());
    let good = &fragments(&pattern(3000, 2), 3, 7)[0];
    let mut bad: Vec<Vec<u8>> = vec![
        b"HF garbage that is not a fragment header".to_vec(),
        b"HF\x01\x00trunc".to_vec(), // shorter than the header
    ];
    let mut d = good.clone();
    d[8..10].copy_from_slice(&u16::MAX.to_le_bytes()); // absurd count
    bad.push(d);
    let mut d = good.clone();
    d[16..20].copy_from_slice(&u32::MAX.to_le_bytes()); // absurd total
    bad.push(d);
    let mut d = good.clone();
    d[6..8].copy_from_slice(&9u16.to_le_bytes()); // index beyond count
    bad.push(d);
    let mut d = good.clone();
    d[4..6].copy_from_slice(&B.0.to_le_bytes()); // claims another sender than its address
    bad.push(d);
    let mut d = good.clone();
    d.truncate(d.len() - 1); // piece one byte short
    bad.push(d);
    for d in &bad {
        raw.send(d).unwrap();
    }
    let n = bad.len() as u64;
    wait_until("bad datagrams counted", DEADLINE, || {
        b.udp_stats().bad_datagrams == n
    });
    assert_eq!(b.stats().frames_dropped, n);
    assert_eq!(b.stats().buffered_bytes, 0);
    // Still alive: an ordinary frame goes through.
    raw.send(b"HC a plain frame").unwrap();
    assert_eq!(sink.wait_for(1, DEADLINE), 1);
    assert_eq!(sink.frames()[0].bytes, b"HC a plain frame");
    assert_eq!(b.stats().frames_received, 1);
}

#[test]
fn datagrams_from_outside_the_fleet_are_handed_up_as_unknown() {
    let (b, _raw, sink) = b_and_raw_a(UdpConfig::default());
    let stranger = UdpSocket::bind("127.0.0.1:0").unwrap();
    stranger.send_to(b"who am I", b.local_addr()).unwrap();
    assert_eq!(sink.wait_for(1, DEADLINE), 1);
    assert_eq!(sink.frames()[0].from, Peer::Unknown);
    assert_eq!(b.udp_stats().from_unknown_address, 1);
}

#[test]
fn small_frames_that_look_like_fragments_round_trip() {
    let (endpoints, mut sockets) = udp_sockets(&[A, B]);
    let sink_b = CollectSink::new();
    let a = UdpLink::with_socket(
        A,
        sockets.remove(&A).unwrap(),
        &endpoints,
        CollectSink::new(),
        UdpConfig::default(),
    )
    .unwrap();
    let _b = UdpLink::with_socket(
        B,
        sockets.remove(&B).unwrap(),
        &endpoints,
        sink_b.clone(),
        UdpConfig::default(),
    )
    .unwrap();
    let deadline = Instant::now() + DEADLINE;
    while sink_b.frames().is_empty() {
        assert!(Instant::now() < deadline, "frame never arrived");
        a.send(B, b"HF but a frame").unwrap();
        sink_b.wait_for(1, Duration::from_millis(100));
    }
    assert_eq!(sink_b.frames()[0].bytes, b"HF but a frame");
    assert!(a.udp_stats().fragments_sent >= 1);
}

#[test]
fn max_message_bytes_limits_sends() {
    let (endpoints, mut sockets) = udp_sockets(&[A, B]);
    let config = UdpConfig {
        max_message_bytes: Some(4000),
        ..UdpConfig::default()
    };
    let a = UdpLink::with_socket(
        A,
        sockets.remove(&A).unwrap(),
        &endpoints,
        CollectSink::new(),
        config,
    )
    .unwrap();
    assert_eq!(a.caps().max_frame, 4048);
    assert_eq!(a.caps().mtu, 1472);
    let err = a.send(B, &[0; 4049]).unwrap_err();
    assert!(
        matches!(
            err,
            LinkError::TooLarge {
                len: 4049,
                max: 4048
            }
        ),
        "{err}"
    );
    assert!(err.to_string().contains("exceeds"), "{err}");
    a.send(B, &[0; 4048]).unwrap();
    assert!(matches!(
        a.send(SystemId(9), b"x"),
        Err(LinkError::Unreachable { .. })
    ));
}

#[test]
fn bind_reports_the_real_port_and_bad_config_is_named() {
    let endpoints = [(A, "127.0.0.1:0".to_string())].into();
    let a = UdpLink::bind(A, &endpoints, CollectSink::new(), UdpConfig::default()).unwrap();
    assert_ne!(a.local_addr().port(), 0);
    let config = UdpConfig {
        datagram_payload: 70_000,
        ..UdpConfig::default()
    };
    let err = UdpLink::bind(
        B,
        &[(B, "127.0.0.1:0".to_string())].into(),
        CollectSink::new(),
        config,
    )
    .err()
    .unwrap();
    assert!(err.to_string().contains("datagram_payload"), "{err}");
}

/// One 276-byte datagram announcing a 16 776 960-byte message in 65535 pieces of 256 bytes.
fn hostile(sender: SystemId, index: u16, message_id: u32) -> Vec<u8> {
    let h = FragmentHeader {
        sender,
        index,
        count: u16::MAX,
        message_id,
        total: 256 * u32::from(u16::MAX),
    };
    let mut d = h.encode().to_vec();
    d.extend_from_slice(&[0xEE; 256]);
    d
}

#[test]
fn hostile_fragment_headers_hold_almost_nothing_and_legitimate_messages_still_arrive() {
    let (endpoints, mut sockets) = udp_sockets(&[A, B]);
    let sink_b = CollectSink::new();
    let config = UdpConfig::loopback();
    let a = UdpLink::with_socket(
        A,
        sockets.remove(&A).unwrap(),
        &endpoints,
        CollectSink::new(),
        config.clone(),
    )
    .unwrap();
    let b = UdpLink::with_socket(
        B,
        sockets.remove(&B).unwrap(),
        &endpoints,
        sink_b.clone(),
        config,
    )
    .unwrap();
    // From an address that is no fleet endpoint, claiming a fleet sender (accepted, but held
    // by what arrived) and claiming a stranger (refused before anything is held).
    let attacker = UdpSocket::bind("127.0.0.1:0").unwrap();
    attacker.connect(b.local_addr()).unwrap();
    let frame = pattern(1024 * 1024, 0x33);
    let deadline = Instant::now() + DEADLINE;
    let mut round = 0u32;
    while sink_b.frames().is_empty() {
        assert!(Instant::now() < deadline, "1 MiB frame never reassembled");
        for (i, index) in [0u16, 65_534, 17].into_iter().enumerate() {
            attacker
                .send(&hostile(A, index, round * 8 + i as u32))
                .unwrap();
        }
        attacker.send(&hostile(SystemId(99), 0, round)).unwrap();
        a.send(B, &frame).unwrap();
        for index in [1u16, 2] {
            attacker.send(&hostile(A, index, round * 8)).unwrap();
        }
        sink_b.wait_for(1, Duration::from_millis(300));
        round += 1;
    }
    assert!(
        sink_b.frames()[0].bytes == frame,
        "reassembled frame differs"
    );
    assert_eq!(sink_b.frames()[0].from, Peer::System(A));
    // Every hostile datagram sent so far has been read once the stranger's last is counted.
    wait_until("hostile datagrams read", DEADLINE, || {
        b.udp_stats().bad_datagrams >= u64::from(round)
    });
    // Each hostile message holds its few pieces and bookkeeping, not its 16 MiB. (A copy of the
    // legitimate frame that lost a fragment in an earlier round may be held too: at most its
    // buffer of twice a mebibyte. The receive thread may still be finishing the accounting of
    // the frame it just handed on, hence the wait.)
    let per_round = 3 * (256 * 4 + 1024);
    let lost_copies = u64::from(round - 1) * (2 << 20);
    let bound = u64::from(round) * per_round + lost_copies;
    let held_within_bound = |s: &UdpStats| s.buffered_bytes <= bound;
    let settled = Instant::now() + Duration::from_secs(2);
    while !held_within_bound(&b.udp_stats()) && Instant::now() < settled {
        std::thread::sleep(Duration::from_millis(5));
    }
    let s = b.udp_stats();
    assert!(
        held_within_bound(&s),
        "{} bytes held after {round} rounds: {s:?}",
        s.buffered_bytes
    );
    assert_eq!(s.reassembly_evictions, 0, "{s:?}");
    assert!(
        s.frames_dropped >= u64::from(round),
        "refusals counted: {s:?}"
    );
    // The hostile messages never complete: they time out and are counted.
    wait_until("hostile messages given up", DEADLINE, || {
        b.stats().buffered_bytes == 0
    });
    assert!(b.udp_stats().reassembly_timeouts >= 3 * u64::from(round));
}

#[test]
fn late_duplicate_fragments_are_counted_as_duplicates_not_drops() {
    let config = UdpConfig {
        reassembly_timeout: Duration::from_millis(300),
        ..UdpConfig::default()
    };
    let (b, raw, sink) = b_and_raw_a(config);
    let frame = pattern(3000, 5);
    let frags = fragments(&frame, 3, 77);
    for f in &frags {
        raw.send(f).unwrap();
    }
    assert_eq!(sink.wait_for(1, DEADLINE), 1);
    // Duplicates after completion: one of each piece, then a marker frame behind them.
    for f in &frags {
        raw.send(f).unwrap();
    }
    raw.send(b"marker").unwrap();
    assert_eq!(sink.wait_for(2, DEADLINE), 2);
    wait_until("duplicates counted", DEADLINE, || {
        b.udp_stats().duplicate_fragments == 3
    });
    assert_eq!(b.stats().buffered_bytes, 0);
    // Past the reassembly timeout nothing is given up: the message was delivered.
    std::thread::sleep(Duration::from_millis(700));
    raw.send(b"marker").unwrap();
    assert_eq!(sink.wait_for(3, DEADLINE), 3);
    let s = b.udp_stats();
    assert_eq!((s.reassembly_timeouts, s.frames_dropped), (0, 0), "{s:?}");
    assert_eq!(s.frames_received, 3);
}

#[test]
fn fragments_over_the_receivers_max_message_bytes_are_counted_as_oversize() {
    let config = UdpConfig {
        max_message_bytes: Some(2000),
        ..UdpConfig::default()
    };
    let (b, raw, sink) = b_and_raw_a(config);
    let frame = pattern(5000, 9);
    let frags = fragments(&frame, 4, 5);
    for f in &frags {
        raw.send(f).unwrap();
    }
    wait_until("oversize fragments counted", DEADLINE, || {
        b.udp_stats().oversize_fragments == 4
    });
    let s = b.udp_stats();
    assert_eq!((s.bad_datagrams, s.frames_dropped), (4, 4), "{s:?}");
    assert_eq!(s.buffered_bytes, 0);
    assert!(sink.frames().is_empty());
    // A malformed fragment is bad but not oversize.
    raw.send(&frags[0][..10]).unwrap();
    wait_until("bad fragment counted", DEADLINE, || {
        b.udp_stats().bad_datagrams == 5
    });
    assert_eq!(b.udp_stats().oversize_fragments, 4);
}
