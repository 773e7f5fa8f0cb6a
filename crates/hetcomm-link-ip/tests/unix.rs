//! The stream layer over Unix stream sockets, beyond the conformance suite.

mod common;

use std::io::Write;
use std::os::unix::net::{UnixListener, UnixStream};

use common::{wait_until, TempDir, DEADLINE};
use hetcomm_core::SystemId;
use hetcomm_link::conformance::CollectSink;
use hetcomm_link::{Link, Peer};
use hetcomm_link_ip::stream::StreamConfig;
use hetcomm_link_ip::UnixLink;

const A: SystemId = SystemId(1);
const B: SystemId = SystemId(2);

#[test]
fn stale_socket_file_is_replaced_and_removed_on_drop() {
    let dir = TempDir::new("unix-stale");
    let paths = [(A, dir.0.join("a.sock")), (B, dir.0.join("b.sock"))].into();
    // A socket file nobody accepts on, as a crashed process leaves behind.
    drop(UnixListener::bind(dir.0.join("b.sock")).unwrap());
    assert!(dir.0.join("b.sock").exists());
    let sink_b = CollectSink::new();
    let b = UnixLink::bind(B, &paths, sink_b.clone(), StreamConfig::default()).unwrap();
    // A live one is not stolen.
    assert!(UnixLink::bind(B, &paths, CollectSink::new(), StreamConfig::default()).is_err());
    let a = UnixLink::bind(A, &paths, CollectSink::new(), StreamConfig::default()).unwrap();
    a.send(B, b"over a unix socket").unwrap();
    assert_eq!(sink_b.wait_for(1, DEADLINE), 1);
    assert_eq!(sink_b.frames()[0].from, Peer::System(A));
    drop(b);
    assert!(!dir.0.join("b.sock").exists());
}

#[test]
fn garbage_on_a_unix_connection_is_dropped() {
    let dir = TempDir::new("unix-garbage");
    let paths = [(A, dir.0.join("a.sock")), (B, dir.0.join("b.sock"))].into();
    let b = UnixLink::bind(B, &paths, CollectSink::new(), StreamConfig::default()).unwrap();
    let mut raw = UnixStream::connect(b.path()).unwrap();
    raw.write_all(b"not a hello").unwrap();
    wait_until("rejection counted", DEADLINE, || {
        b.stats().frames_dropped == 1
    });
    assert_eq!(b.stream_stats().rejected_connections, 1);
}

#[test]
fn unix_connections_over_the_limit_are_refused_until_a_slot_frees() {
    let dir = TempDir::new("unix-limit");
    let paths = [(A, dir.0.join("a.sock")), (B, dir.0.join("b.sock"))].into();
    let config = StreamConfig {
        max_connections: 2,
        ..StreamConfig::default()
    };
    let sink = CollectSink::new();
    let b = UnixLink::bind(B, &paths, sink.clone(), config).unwrap();
    let hello = hetcomm_link_ip::stream::encode_hello(A);
    let mut held: Vec<UnixStream> = (0..2)
        .map(|_| {
            let mut s = UnixStream::connect(b.path()).unwrap();
            s.write_all(&hello).unwrap();
            s
        })
        .collect();
    wait_until("two connections open", DEADLINE, || {
        b.stream_stats().open_connections == 2
    });
    // The third is closed at once, and counted where the runtime reports drops.
    let mut third = UnixStream::connect(b.path()).unwrap();
    third.set_read_timeout(Some(DEADLINE)).unwrap();
    let mut byte = [0u8; 1];
    assert!(matches!(
        std::io::Read::read(&mut third, &mut byte),
        Ok(0) | Err(_)
    ));
    wait_until("refusal counted", DEADLINE, || {
        b.stream_stats().refused_connections == 1
    });
    assert_eq!(b.stats().frames_dropped, 1);
    // A peer that leaves frees its slot for the next.
    held.pop();
    wait_until("a slot freed", DEADLINE, || {
        b.stream_stats().open_connections == 1
    });
    let mut next = UnixStream::connect(b.path()).unwrap();
    next.write_all(&hello).unwrap();
    next.write_all(&common::record(b"in the freed slot"))
        .unwrap();
    assert_eq!(sink.wait_for(1, DEADLINE), 1);
    assert_eq!(sink.frames()[0].bytes, b"in the freed slot");
    assert_eq!(b.stream_stats().refused_connections, 1);
}
