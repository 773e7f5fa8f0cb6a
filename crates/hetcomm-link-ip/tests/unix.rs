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
