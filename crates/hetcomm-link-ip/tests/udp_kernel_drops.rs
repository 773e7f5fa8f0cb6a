//! Datagrams the kernel drops at a full receive buffer are counted (`SO_MEMINFO` on Linux):
//! a driven UDP link that nobody reads, with the smallest receive buffer the kernel allows,
//! gets a burst from a plain socket; then everything is read and every datagram is accounted
//! for, received or counted as dropped. Real sockets on 127.0.0.1, port 0 only.

#![cfg(target_os = "linux")]

mod common;

use std::net::UdpSocket;

use common::driven::poll_readable;
use common::{udp_sockets, DEADLINE};
use hetcomm_core::SystemId;
use hetcomm_link::conformance::CollectSink;
use hetcomm_link::{Link, Peer};
use hetcomm_link_ip::{UdpConfig, UdpLink};

const A: SystemId = SystemId(1);
const B: SystemId = SystemId(2);

/// Datagrams in the burst: far more than the smallest receive buffer holds.
const BURST: u64 = 500;

/// A datagram the link hands up whole (neither a fragment nor a batch).
fn datagram(i: u64) -> Vec<u8> {
    let mut d = vec![b'x'; 200];
    d[..8].copy_from_slice(&i.to_le_bytes());
    d
}

#[test]
fn a_full_receive_buffer_counts_every_dropped_datagram() {
    let (endpoints, mut sockets) = udp_sockets(&[A, B]);
    let sink = CollectSink::new();
    let config = UdpConfig {
        // The kernel raises this to its minimum (a few KiB): room for a handful of datagrams.
        socket_buffer_bytes: 1,
        driven: true,
        ..UdpConfig::default()
    };
    let b = UdpLink::with_socket(
        B,
        sockets.remove(&B).unwrap(),
        &endpoints,
        sink.clone(),
        config,
    )
    .unwrap();
    let raw: UdpSocket = sockets.remove(&A).unwrap();
    raw.connect(b.local_addr()).unwrap();
    let rx = b.readable().expect("driven link is readable");

    // Nobody reads while the burst arrives: the receive buffer fills and the kernel drops
    // the rest.
    for i in 0..BURST {
        raw.send(&datagram(i)).unwrap();
    }
    let sent = BURST;

    // Read everything there is until every datagram sent is either received or counted as
    // dropped (more than one round only if loopback delivery lags behind the sends).
    let deadline = std::time::Instant::now() + DEADLINE;
    loop {
        while rx.read_ready(64).unwrap() > 0 {}
        let s = b.stats();
        if s.frames_received + s.kernel_drops == sent {
            break;
        }
        assert!(
            s.frames_received + s.kernel_drops < sent,
            "more accounted for than sent: {s:?}, sent {sent}"
        );
        assert!(
            std::time::Instant::now() < deadline,
            "datagrams unaccounted for: {s:?}, sent {sent}"
        );
        poll_readable(rx, 100);
    }

    let s = b.stats();
    let u = b.udp_stats();
    println!(
        "sent {sent}: received {}, kernel drops {}",
        s.frames_received, s.kernel_drops
    );
    assert!(s.kernel_drops > 0, "the burst overflowed nothing: {s:?}");
    assert!(s.frames_received > 0, "{s:?}");
    assert_eq!(s.frames_received + s.kernel_drops, sent, "{s:?}");
    assert_eq!(u.kernel_drops, s.kernel_drops);
    // Read again: the count is a total, not what is new since the last read.
    assert_eq!(b.stats().kernel_drops, s.kernel_drops);
    assert_eq!(
        s.frames_dropped, 0,
        "kernel drops are not frames the link dropped"
    );
    let frames = sink.frames();
    assert_eq!(frames.len() as u64, s.frames_received);
    assert!(frames.iter().all(|f| f.from == Peer::System(A)));
    // What arrived came in order, each datagram once.
    let seqs: Vec<u64> = frames
        .iter()
        .map(|f| u64::from_le_bytes(f.bytes[..8].try_into().unwrap()))
        .collect();
    assert!(seqs.windows(2).all(|w| w[0] < w[1]), "{seqs:?}");
}
