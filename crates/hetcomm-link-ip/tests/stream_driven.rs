//! Driven receive on the stream links (`StreamConfig::driven`): accepted connections are read
//! by whoever calls `Readable::read_ready`, as the runtime's waiting modules do. Real sockets
//! on 127.0.0.1 (port 0) and in a temporary directory.

mod common;

use parking_lot::Mutex;
use std::io::Write;
use std::net::TcpStream;
use std::sync::Arc;
use std::time::{Duration, Instant};

use common::driven::{poll_readable, Driver};
use common::{assert_closed_by_peer, record, wait_until, TcpHarness, UnixHarness, DEADLINE};
use hetcomm_core::{FrameBuf, SystemId};
use hetcomm_link::conformance::{self, CollectSink, Layered};
use hetcomm_link::{FrameSink, Link, Peer};
use hetcomm_link_ip::stream::{encode_hello, StreamConfig};

const A: SystemId = SystemId(1);
const B: SystemId = SystemId(2);

fn driven() -> StreamConfig {
    StreamConfig {
        driven: true,
        ..StreamConfig::default()
    }
}

// The suite reads driven links itself, through `Link::readable` (as the runtime's waiting
// threads do): the plain harnesses with a driven configuration are all it needs.

#[test]
fn driven_tcp_passes_conformance() {
    conformance::run_all(&mut TcpHarness::new(driven()));
}

#[test]
fn driven_unix_passes_conformance() {
    conformance::run_all(&mut UnixHarness::new(driven()));
}

/// As the runtime opens an `emulated` transport over TCP: the driven link inside an emulation
/// layer, read through the wrapper.
#[test]
fn driven_tcp_wrapped_in_emulation_passes_conformance() {
    conformance::run_all(&mut Layered::emulated(TcpHarness::new(driven())));
}

#[test]
fn driven_unix_wrapped_in_emulation_passes_conformance() {
    conformance::run_all(&mut Layered::emulated(UnixHarness::new(driven())));
}

/// Records each frame and whether it came as an owned (pooled) buffer.
#[derive(Default)]
struct OwningSink {
    frames: Mutex<Vec<(Vec<u8>, bool)>>,
}

impl FrameSink for OwningSink {
    fn on_frame(&self, frame: &[u8], _from: Peer) {
        self.frames.lock().push((frame.to_vec(), false));
    }
    fn on_frame_owned(&self, frame: FrameBuf, _from: Peer) {
        let pooled = frame.is_pooled();
        self.frames.lock().push((frame.into_vec(), pooled));
    }
    fn takes_frames(&self) -> bool {
        true
    }
}

fn frame(index: u8, len: usize) -> Vec<u8> {
    (0..len)
        .map(|i| (i as u8).wrapping_mul(31) ^ index)
        .collect()
}

#[test]
fn frames_wait_for_read_ready_then_arrive_whole_and_in_order() {
    let mut h = TcpHarness::new(driven());
    let sink = Arc::new(OwningSink::default());
    let b = h.open_tcp(B, sink.clone());
    let a = h.open_tcp(A, CollectSink::new());
    let rx = b.readable().expect("a driven link is readable");
    let sizes = [10, 20_000, 1 << 20, 0, 64, 70_000, 3, 16 * 1024 + 1];
    let frames: Vec<_> = (0..40u8)
        .map(|i| frame(i, sizes[usize::from(i) % sizes.len()]))
        .collect();
    // From a thread: more bytes than the socket buffers hold, so the sender waits for B.
    let sender = {
        let frames = frames.clone();
        std::thread::spawn(move || {
            for f in &frames {
                a.send(B, f).unwrap();
            }
            a
        })
    };
    // Nobody drives B: the bytes wait in its socket.
    assert!(poll_readable(rx, 10_000), "epoll never reported data");
    std::thread::sleep(Duration::from_millis(100));
    assert!(sink.frames.lock().is_empty());
    assert_eq!(b.stats().frames_received, 0);
    // Driving it hands them over, a budget's worth per connection and call.
    let mut handed = 0;
    let deadline = Instant::now() + DEADLINE;
    while handed < frames.len() {
        assert!(
            Instant::now() < deadline,
            "only {handed} frames arrived; B: {:?}, readable now: {}",
            b.stream_stats(),
            poll_readable(rx, 0)
        );
        poll_readable(rx, 100);
        let n = rx.read_ready(4).unwrap();
        assert!(n <= 4 + 64, "budget ignored: {n}");
        handed += n;
    }
    assert_eq!(handed, frames.len());
    let got = sink.frames.lock();
    for (i, ((g, pooled), f)) in got.iter().zip(&frames).enumerate() {
        assert!(g == f, "frame {i}");
        // Large frames are read into pooled buffers of their own.
        assert_eq!(*pooled, f.len() > 16 * 1024 && *pooled, "frame {i}");
    }
    assert!(got.iter().any(|(_, pooled)| *pooled), "no pooled frame");
    assert_eq!(b.stats().frames_received, frames.len() as u64);
    assert_eq!(rx.read_ready(64).unwrap(), 0);
    let a = sender.join().unwrap();
    // Frames queued while A was still connecting are written (and counted) by A's connector
    // thread, which may finish its write after B has read the last byte.
    wait_until("A counts every frame sent", DEADLINE, || {
        a.stats().frames_sent == frames.len() as u64
    });
}

#[test]
fn bad_and_cut_streams_close_only_their_connection_and_are_counted() {
    let mut h = TcpHarness::new(driven());
    let sink = CollectSink::new();
    let b = Arc::new(h.open_tcp(B, sink.clone()));
    let a = h.open_tcp(A, CollectSink::new());
    let addr = b.local_addr();
    let _driver = Driver::start(b.clone());

    // A good record, then garbage where the next header should be.
    let mut raw = TcpStream::connect(addr).unwrap();
    raw.write_all(&encode_hello(A)).unwrap();
    raw.write_all(&record(b"fine")).unwrap();
    raw.write_all(b"\xde\xad\xbe\xef garbage").unwrap();
    assert_closed_by_peer(&mut raw);
    assert_eq!(sink.wait_for(1, DEADLINE), 1);
    wait_until("the bad record counted", DEADLINE, || {
        b.stats().frames_dropped == 1
    });

    // Half of a large frame, then the connection closes: the frame is lost and counted.
    let mut raw = TcpStream::connect(addr).unwrap();
    raw.write_all(&encode_hello(A)).unwrap();
    let big = record(&frame(7, 300_000));
    raw.write_all(&big[..150_000]).unwrap();
    drop(raw);
    wait_until("the cut frame counted", DEADLINE, || {
        b.stats().frames_dropped == 2
    });

    // A peer that closes between records costs nothing.
    let mut raw = TcpStream::connect(addr).unwrap();
    raw.write_all(&encode_hello(A)).unwrap();
    raw.write_all(&record(b"bye")).unwrap();
    drop(raw);
    assert_eq!(sink.wait_for(2, DEADLINE), 2);

    // The link still serves well-behaved peers.
    a.send(B, b"after").unwrap();
    assert_eq!(sink.wait_for(3, DEADLINE), 3);
    let bytes: Vec<_> = sink.frames().into_iter().map(|f| f.bytes).collect();
    assert_eq!(bytes, [&b"fine"[..], b"bye", b"after"]);
    std::thread::sleep(Duration::from_millis(50));
    let s = b.stream_stats();
    assert_eq!((s.frames_received, s.frames_dropped), (3, 2), "{s:?}");
}
