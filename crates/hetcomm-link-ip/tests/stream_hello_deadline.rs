//! `StreamConfig::hello_timeout` is a deadline for the whole hello, not a bound per read, on
//! both receive paths: the poller (TCP) and a thread per connection (a listener that cannot be
//! polled, like RFCOMM's; here TCP sockets that do not offer their descriptors). Real sockets
//! on 127.0.0.1.

mod common;

use std::collections::BTreeMap;
use std::io::{self, Read, Write};
use std::net::{Shutdown, SocketAddr, TcpListener, TcpStream};
use std::time::{Duration, Instant};

use common::{wait_until, DEADLINE};
use hetcomm_core::SystemId;
use hetcomm_link::conformance::CollectSink;
use hetcomm_link_ip::stream::{
    encode_hello, StreamConfig, StreamLink, StreamListener, StreamSocket, StreamTransport,
};
use hetcomm_link_ip::TcpLink;

const A: SystemId = SystemId(1);
const B: SystemId = SystemId(2);
const HELLO_TIMEOUT: Duration = Duration::from_millis(400);

/// A TCP stream that keeps its descriptor to itself, so the link reads it on a thread.
struct Opaque(TcpStream);

impl Read for Opaque {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        self.0.read(buf)
    }
}

impl Write for Opaque {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        self.0.write(buf)
    }
    fn flush(&mut self) -> io::Result<()> {
        self.0.flush()
    }
}

impl StreamSocket for Opaque {
    fn try_clone(&self) -> io::Result<Self> {
        self.0.try_clone().map(Opaque)
    }
    fn shutdown_both(&self) -> io::Result<()> {
        self.0.shutdown(Shutdown::Both)
    }
    fn set_write_timeout(&self, timeout: Option<Duration>) -> io::Result<()> {
        self.0.set_write_timeout(timeout)
    }
    fn set_read_timeout(&self, timeout: Option<Duration>) -> io::Result<()> {
        self.0.set_read_timeout(timeout)
    }
}

/// A TCP listener that cannot be polled: an accept thread and a reader thread per connection.
struct OpaqueListener(TcpListener);

impl StreamListener for OpaqueListener {
    type Socket = Opaque;
    type PeerAddr = SocketAddr;
    fn accept(&self) -> io::Result<(Opaque, SocketAddr)> {
        self.0.accept().map(|(s, a)| (Opaque(s), a))
    }
    fn wake(&self) {
        if let Ok(addr) = self.0.local_addr() {
            let _ = TcpStream::connect_timeout(&addr, Duration::from_millis(500));
        }
    }
}

struct OpaqueTcp;

impl StreamTransport for OpaqueTcp {
    type Socket = Opaque;
    type Listener = OpaqueListener;
    type Addr = String;
    const NAME: &'static str = "opaque-tcp";
    fn connect(&self, addr: &String, timeout: Duration) -> io::Result<Opaque> {
        let addr: SocketAddr = addr.parse().map_err(io::Error::other)?;
        TcpStream::connect_timeout(&addr, timeout).map(Opaque)
    }
}

fn config() -> StreamConfig {
    StreamConfig {
        hello_timeout: HELLO_TIMEOUT,
        ..StreamConfig::default()
    }
}

/// Writes a hello one byte at a time, each write a little under the hello timeout apart, so
/// that every single read is well within the timeout but the whole hello is not; returns once
/// the receiver has closed the connection (or all bytes were written).
fn dribble_hello(addr: SocketAddr) -> (Duration, bool) {
    let started = Instant::now();
    let mut s = TcpStream::connect(addr).unwrap();
    s.set_nodelay(true).unwrap();
    let gap = HELLO_TIMEOUT / 2;
    for byte in encode_hello(A) {
        if s.write_all(&[byte]).is_err() {
            break;
        }
        std::thread::sleep(gap);
    }
    // The receiver never writes: a read returns 0 (or an error) once it has closed.
    s.set_read_timeout(Some(DEADLINE)).unwrap();
    let closed = matches!(s.read(&mut [0u8; 1]), Ok(0) | Err(_));
    (started.elapsed(), closed)
}

fn check_rejected(rejected: impl Fn() -> u64, elapsed: Duration, closed: bool) {
    assert!(closed, "the connection was closed");
    wait_until("the slow hello rejected", DEADLINE, || rejected() == 1);
    // 8 bytes at HELLO_TIMEOUT / 2 apart would take 4 × HELLO_TIMEOUT: per read it would pass.
    assert!(
        elapsed < HELLO_TIMEOUT * 3,
        "closed after {elapsed:?}, not near the {HELLO_TIMEOUT:?} deadline"
    );
}

#[test]
fn a_hello_one_byte_at_a_time_is_cut_off_at_the_deadline_on_a_reader_thread() {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = listener.local_addr().unwrap();
    let endpoints = BTreeMap::from([(A, "127.0.0.1:9".to_string()), (B, addr.to_string())]);
    let sink = CollectSink::new();
    let b = StreamLink::new(
        OpaqueTcp,
        B,
        OpaqueListener(listener),
        endpoints,
        sink.clone(),
        config(),
    )
    .unwrap();
    let (elapsed, closed) = dribble_hello(addr);
    check_rejected(|| b.stream_stats().rejected_connections, elapsed, closed);
    assert!(sink.frames().is_empty());
    // A prompt hello is still accepted on the same link.
    let mut ok = TcpStream::connect(addr).unwrap();
    ok.write_all(&encode_hello(A)).unwrap();
    ok.write_all(b"HR\x01\x00\x02\x00\x00\x00hi").unwrap();
    assert_eq!(sink.wait_for(1, DEADLINE), 1);
    assert_eq!(sink.frames()[0].bytes, b"hi");
}

#[test]
fn a_hello_one_byte_at_a_time_is_cut_off_at_the_deadline_by_the_poller() {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = listener.local_addr().unwrap();
    let endpoints = BTreeMap::from([(A, "127.0.0.1:9".to_string()), (B, addr.to_string())]);
    let b = TcpLink::with_listener(B, listener, &endpoints, CollectSink::new(), config()).unwrap();
    let (elapsed, closed) = dribble_hello(addr);
    check_rejected(|| b.stream_stats().rejected_connections, elapsed, closed);
}
