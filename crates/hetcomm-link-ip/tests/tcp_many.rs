//! Many inbound connections to one TCP listener (issue 20): threads do not grow with
//! connections, descriptors close as soon as the peers do, and connections over
//! `max_connections` are refused and counted. Real sockets on 127.0.0.1, port 0.
//!
//! The scenarios measure the whole process (`/proc/self/task`, `/proc/self/fd`), so they run
//! one after the other in a single test: nothing else in this process opens sockets or
//! starts threads meanwhile (not even the test harness, which runs each test on a thread).

mod common;

use std::io::Write;
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::sync::Arc;
use std::time::{Duration, Instant};

use common::driven::Driver;
use common::{assert_closed_by_peer, record, wait_until, TcpHarness, DEADLINE};
use hetcomm_core::SystemId;
use hetcomm_link::conformance::CollectSink;
use hetcomm_link::{Link, Peer};
use hetcomm_link_ip::stream::{
    encode_hello, StreamConfig, StreamLink, StreamListener, StreamTransport,
};
use hetcomm_link_ip::tcp::TcpTransport;

const A: SystemId = SystemId(1);
const B: SystemId = SystemId(2);
/// Connections each test opens.
const CONNECTIONS: usize = 2000;
/// Descriptors and threads the process may open or start besides the ones counted, e.g. the
/// directory handle that counting descriptors opens.
const SLACK: usize = 8;

fn threads() -> usize {
    std::fs::read_dir("/proc/self/task").unwrap().count()
}

fn fds() -> usize {
    std::fs::read_dir("/proc/self/fd").unwrap().count()
}

/// Raises the soft descriptor limit to at least `need`, as far as the hard limit allows.
fn allow_descriptors(need: usize) {
    let mut lim = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: `lim` is a valid rlimit for the call to fill in.
    assert_eq!(unsafe { libc::getrlimit(libc::RLIMIT_NOFILE, &mut lim) }, 0);
    let need = need as libc::rlim_t;
    if lim.rlim_cur < need {
        assert!(
            lim.rlim_max >= need,
            "this test needs {need} descriptors; the hard limit is {}",
            lim.rlim_max
        );
        lim.rlim_cur = need;
        // SAFETY: as above; raising the soft limit up to the hard one is always allowed.
        assert_eq!(unsafe { libc::setrlimit(libc::RLIMIT_NOFILE, &lim) }, 0);
    }
}

/// Opens `n` connections to `addr`; those with an even index send `hello` first.
fn connect_many(addr: SocketAddr, n: usize, hello: Option<SystemId>) -> Vec<TcpStream> {
    (0..n)
        .map(|i| {
            let mut s = TcpStream::connect(addr).unwrap_or_else(|e| panic!("connect {i}: {e}"));
            if let (Some(id), true) = (hello, i % 2 == 0) {
                s.write_all(&encode_hello(id)).unwrap();
            }
            s
        })
        .collect()
}

/// A frame sent on a fresh connection arrives: the link still serves peers.
fn still_served(addr: SocketAddr, sink: &CollectSink, text: &[u8]) {
    let before = sink.frames().len();
    let mut s = TcpStream::connect(addr).unwrap();
    s.write_all(&encode_hello(A)).unwrap();
    s.write_all(&record(text)).unwrap();
    assert_eq!(sink.wait_for(before + 1, DEADLINE), before + 1);
    let got = &sink.frames()[before];
    assert_eq!((&got.bytes[..], got.from), (text, Peer::System(A)));
}

#[test]
fn many_connections() {
    two_thousand_connections_add_no_thread_and_close_with_their_peers();
    connections_over_the_limit_are_refused_and_counted_on_a_driven_link();
    reader_threads_are_bounded_too_and_close_with_their_peers();
}

fn two_thousand_connections_add_no_thread_and_close_with_their_peers() {
    allow_descriptors(3 * CONNECTIONS + 256);
    let mut h = TcpHarness::new(StreamConfig {
        max_connections: 4096,
        ..StreamConfig::default()
    });
    let sink = CollectSink::new();
    let b = h.open_tcp(B, sink.clone());
    let addr = b.local_addr();
    let (threads_before, fds_before) = (threads(), fds());

    // Half identify themselves and then idle, half idle before their hello.
    let started = Instant::now();
    let clients = connect_many(addr, CONNECTIONS, Some(A));
    wait_until("every connection accepted", DEADLINE, || {
        b.stream_stats().open_connections == CONNECTIONS as u64
    });
    let connect_time = started.elapsed();
    let (threads_during, fds_during) = (threads(), fds());
    assert!(
        threads_during <= threads_before,
        "threads grew with connections: {threads_before} -> {threads_during}"
    );
    // One descriptor per connection on each side, nothing more.
    assert!(
        fds_during <= fds_before + 2 * CONNECTIONS + SLACK,
        "descriptors: {fds_before} -> {fds_during} for {CONNECTIONS} connections"
    );
    still_served(addr, &sink, b"among many");

    let closed = Instant::now();
    drop(clients);
    wait_until("descriptors back to the baseline", DEADLINE, || {
        fds() <= fds_before
    });
    let close_time = closed.elapsed();
    let (threads_after, fds_after) = (threads(), fds());
    assert!(threads_after <= threads_before);
    let s = b.stream_stats();
    assert_eq!(s.open_connections, 0, "{s:?}");
    // The ones that never sent their hello count as rejected, one dropped frame each.
    assert_eq!(s.accepted, CONNECTIONS as u64 + 1, "{s:?}");
    assert_eq!(s.rejected_connections, CONNECTIONS as u64 / 2, "{s:?}");
    assert_eq!(s.frames_dropped, CONNECTIONS as u64 / 2, "{s:?}");
    assert_eq!(s.refused_connections, 0, "{s:?}");
    still_served(addr, &sink, b"after many");
    eprintln!(
        "{CONNECTIONS} connections: threads {threads_before}/{threads_during}/{threads_after}, \
         descriptors {fds_before}/{fds_during}/{fds_after} (before/during/after); \
         accepted in {connect_time:?}, closed in {close_time:?}"
    );
}

fn connections_over_the_limit_are_refused_and_counted_on_a_driven_link() {
    allow_descriptors(3 * CONNECTIONS + 256);
    const LIMIT: usize = 300;
    let mut h = TcpHarness::new(StreamConfig {
        driven: true,
        max_connections: LIMIT,
        // What is counted here is refusals over the limit. On a loaded machine opening the
        // 2000 connections has taken more than the default 5 s hello timeout (the backlog
        // fills and connects wait for SYN retransmissions), and the kept connections that
        // send no hello then timed out and were replaced from the backlog: 150 rejected,
        // 1550 refused instead of 1700. Their timeout is the other scenario's subject.
        hello_timeout: 3 * DEADLINE,
        ..StreamConfig::default()
    });
    let sink = CollectSink::new();
    let b = Arc::new(h.open_tcp(B, sink.clone()));
    let addr = b.local_addr();
    // Read as the runtime reads it: by a thread waiting on the link's descriptor.
    let driver = Driver::start(b.clone());
    let (threads_before, fds_before) = (threads(), fds());

    let mut clients = connect_many(addr, CONNECTIONS, Some(A));
    let refused = (CONNECTIONS - LIMIT) as u64;
    wait_until("every connection accepted or refused", DEADLINE, || {
        b.stream_stats().accepted == CONNECTIONS as u64
    });
    let (threads_during, fds_during) = (threads(), fds());
    let s = b.stream_stats();
    assert_eq!(
        (s.open_connections, s.refused_connections),
        (LIMIT as u64, refused),
        "{s:?}"
    );
    // Refused connections are part of what the runtime reports as dropped.
    assert_eq!(b.stats().frames_dropped, refused);
    assert!(
        threads_during <= threads_before,
        "threads grew with connections: {threads_before} -> {threads_during}"
    );
    // The test's 2000 ends, and the link's at most LIMIT.
    assert!(
        fds_during <= fds_before + CONNECTIONS + LIMIT + SLACK,
        "descriptors: {fds_before} -> {fds_during} for {CONNECTIONS} connections"
    );
    // The last one was refused: closed by the link.
    assert_closed_by_peer(clients.last_mut().unwrap());

    let closed = Instant::now();
    drop(clients);
    wait_until("descriptors back to the baseline", DEADLINE, || {
        fds() <= fds_before
    });
    let close_time = closed.elapsed();
    let (threads_after, fds_after) = (threads(), fds());
    assert_eq!(b.stream_stats().open_connections, 0);
    assert!(threads_after <= threads_before);
    eprintln!(
        "{CONNECTIONS} connections, limit {LIMIT}: threads \
         {threads_before}/{threads_during}/{threads_after}, descriptors \
         {fds_before}/{fds_during}/{fds_after} (before/during/after); closed in {close_time:?}"
    );
    // The slots are free again.
    still_served(addr, &sink, b"after the crowd");
    drop(driver);
}

/// A TCP listener the link cannot poll (as an RFCOMM one): the link falls back to an accept
/// thread and a reader thread per connection.
struct Unpolled(TcpListener);

impl StreamListener for Unpolled {
    type Socket = TcpStream;
    type PeerAddr = SocketAddr;
    fn accept(&self) -> std::io::Result<(TcpStream, SocketAddr)> {
        self.0.accept()
    }
    fn wake(&self) {
        StreamListener::wake(&self.0)
    }
}

struct UnpolledTcp;

impl StreamTransport for UnpolledTcp {
    type Socket = TcpStream;
    type Listener = Unpolled;
    type Addr = String;
    const NAME: &'static str = "unpolled";
    fn connect(&self, addr: &String, timeout: Duration) -> std::io::Result<TcpStream> {
        TcpTransport.connect(addr, timeout)
    }
}

fn reader_threads_are_bounded_too_and_close_with_their_peers() {
    const N: usize = 200;
    const LIMIT: usize = 50;
    allow_descriptors(3 * N + 256);
    let (endpoints, mut listeners) = common::tcp_listeners(&[A, B]);
    let sink = CollectSink::new();
    let config = StreamConfig {
        max_connections: LIMIT,
        ..StreamConfig::default()
    };
    let listener = Unpolled(listeners.remove(&B).unwrap());
    let addr = listener.0.local_addr().unwrap();
    let b = StreamLink::new(UnpolledTcp, B, listener, endpoints, sink.clone(), config).unwrap();
    let (threads_before, fds_before) = (threads(), fds());

    let clients = connect_many(addr, N, Some(A));
    wait_until("every connection accepted or refused", DEADLINE, || {
        b.stream_stats().accepted == N as u64
    });
    let s = b.stream_stats();
    assert_eq!(
        (s.open_connections, s.refused_connections),
        (LIMIT as u64, (N - LIMIT) as u64),
        "{s:?}"
    );
    let (threads_during, fds_during) = (threads(), fds());
    assert!(
        threads_during <= threads_before + LIMIT,
        "threads: {threads_before} -> {threads_during}"
    );
    // A reader keeps a second handle to its connection to shut it down at close.
    assert!(
        fds_during <= fds_before + N + 2 * LIMIT + SLACK,
        "descriptors: {fds_before} -> {fds_during}"
    );

    drop(clients);
    wait_until("descriptors back to the baseline", DEADLINE, || {
        fds() <= fds_before
    });
    wait_until("reader threads gone", DEADLINE, || {
        threads() <= threads_before
    });
    assert_eq!(b.stream_stats().open_connections, 0);
    still_served(addr, &sink, b"served by a thread");
    eprintln!(
        "{N} connections, limit {LIMIT}, a thread each: threads {threads_before}/{threads_during}, \
         descriptors {fds_before}/{fds_during} (before/during)"
    );
}
