//! Batching on the stream links (`send_held` / `flush`), over TCP and Unix stream sockets:
//! held frames leave only at a flush, a plain send or a full batch, always in send order;
//! frames held while the connection is being made follow the connector's rules; large frames
//! pass through intact. Real sockets on 127.0.0.1 (port 0) and in a temporary directory.

mod common;

use std::net::{TcpListener, TcpStream};
use std::sync::Arc;
use std::time::{Duration, Instant};

use common::{wait_until, TcpHarness, UnixHarness, DEADLINE};
use hetcomm_core::SystemId;
use hetcomm_link::conformance::CollectSink;
use hetcomm_link::{FrameSink, Link, LinkError, Peer};
use hetcomm_link_ip::stream::{StreamConfig, StreamStats};
use hetcomm_link_ip::{TcpLink, UnixLink};

const A: SystemId = SystemId(1);
const B: SystemId = SystemId(2);

/// How long a test watches for frames that must *not* arrive yet.
const QUIET: Duration = Duration::from_millis(150);

/// A stream link under test, with its full counters.
trait StreamTestLink: Link {
    fn stream(&self) -> StreamStats;
}

impl StreamTestLink for TcpLink {
    fn stream(&self) -> StreamStats {
        self.stream_stats()
    }
}

impl StreamTestLink for UnixLink {
    fn stream(&self) -> StreamStats {
        self.stream_stats()
    }
}

/// Opens the systems of one transport, so that every test runs on both.
trait Transport {
    fn open(
        &mut self,
        system: SystemId,
        sink: Arc<dyn FrameSink>,
        config: &StreamConfig,
    ) -> Box<dyn StreamTestLink>;

    /// Makes sure nobody listens at `system`'s endpoint (until it is opened).
    fn refuse(&mut self, system: SystemId);
}

impl Transport for TcpHarness {
    fn open(
        &mut self,
        system: SystemId,
        sink: Arc<dyn FrameSink>,
        config: &StreamConfig,
    ) -> Box<dyn StreamTestLink> {
        self.config = config.clone();
        Box::new(self.open_tcp(system, sink))
    }

    fn refuse(&mut self, system: SystemId) {
        // Closing the pre-bound listener frees its port: connects to it are refused.
        self.listeners.remove(&system);
    }
}

impl Transport for UnixHarness {
    fn open(
        &mut self,
        system: SystemId,
        sink: Arc<dyn FrameSink>,
        config: &StreamConfig,
    ) -> Box<dyn StreamTestLink> {
        Box::new(UnixLink::bind(system, &self.paths, sink, config.clone()).expect("open unix link"))
    }

    fn refuse(&mut self, _: SystemId) {
        // The socket file does not exist until the system is opened.
    }
}

/// Runs `test` over TCP, then over Unix sockets.
fn on_both(test: impl Fn(&mut dyn Transport)) {
    test(&mut TcpHarness::new(StreamConfig::default()));
    test(&mut UnixHarness::new(StreamConfig::default()));
}

/// A recognisable frame: its index, then a pattern depending on it; `len` (≥ 4) bytes.
fn frame(index: u32, len: usize) -> Vec<u8> {
    let mut f = index.to_le_bytes().to_vec();
    f.extend((4..len.max(4)).map(|i| (i as u32 ^ index.wrapping_mul(7)) as u8));
    f
}

fn index_of(bytes: &[u8]) -> Option<u32> {
    Some(u32::from_le_bytes(bytes.get(..4)?.try_into().ok()?))
}

/// Asserts that `sink` received exactly `expected`, in order, all from A.
fn assert_received(sink: &CollectSink, expected: &[Vec<u8>]) {
    let n = sink.wait_for(expected.len(), DEADLINE);
    assert_eq!(n, expected.len(), "not everything arrived");
    let got = sink.frames();
    assert_eq!(got.len(), expected.len(), "more frames than sent");
    for (i, (g, e)) in got.iter().zip(expected).enumerate() {
        assert_eq!(g.from, Peer::System(A));
        assert!(
            g.bytes == *e,
            "frame {i}: got #{:?} of {} bytes, expected #{:?} of {} bytes",
            index_of(&g.bytes),
            g.bytes.len(),
            index_of(e),
            e.len()
        );
    }
}

/// Asserts that `sink` still has exactly `n` frames after a quiet while.
fn assert_still(sink: &CollectSink, n: usize, what: &str) {
    std::thread::sleep(QUIET);
    assert_eq!(sink.frames().len(), n, "{what}");
}

/// A and B with A's connection to B up.
struct Connected {
    a: Box<dyn StreamTestLink>,
    _b: Box<dyn StreamTestLink>,
    /// B's sink.
    sink: Arc<CollectSink>,
    /// The frames B has received so far: the one that made the connection.
    expected: Vec<Vec<u8>>,
}

fn connected(t: &mut dyn Transport, config: &StreamConfig) -> Connected {
    let sink = CollectSink::new();
    let b = t.open(B, sink.clone(), config);
    let a = t.open(A, CollectSink::new(), config);
    let first = frame(u32::MAX, 16);
    a.send(B, &first).unwrap();
    assert_eq!(sink.wait_for(1, DEADLINE), 1);
    // A's connector thread counts the frame after its write returns, which may be after B
    // has read it: tests compare A's counter with this starting point.
    wait_until("A counts the first frame", DEADLINE, || {
        a.stream().frames_sent == 1
    });
    Connected {
        a,
        _b: b,
        sink,
        expected: vec![first],
    }
}

#[test]
fn stream_links_batch_unless_the_batch_size_is_zero() {
    on_both(|t| {
        let c = connected(t, &StreamConfig::default());
        assert!(c.a.batches());
    });
    let off = StreamConfig {
        batch_bytes: 0,
        ..StreamConfig::default()
    };
    on_both(|t| {
        // Without a batch, send_held writes at once.
        let Connected {
            a,
            _b,
            sink,
            mut expected,
        } = connected(t, &off);
        assert!(!a.batches());
        expected.push(frame(0, 64));
        a.send_held(B, &expected[1]).unwrap();
        assert_received(&sink, &expected);
    });
}

#[test]
fn held_frames_arrive_in_order_only_after_flush() {
    on_both(|t| {
        let Connected {
            a,
            _b,
            sink,
            mut expected,
        } = connected(t, &StreamConfig::default());
        let sent_before = a.stream().frames_sent;
        for i in 0..100 {
            expected.push(frame(i, 4 + i as usize));
            a.send_held(B, expected.last().unwrap()).unwrap();
        }
        assert_still(&sink, 1, "held frames went out before the flush");
        assert_eq!(a.stream().frames_sent, sent_before);
        assert!(a.stats().buffered_bytes > 0);
        a.flush().unwrap();
        assert_received(&sink, &expected);
        assert_eq!(a.stream().frames_sent, sent_before + 100);
        assert_eq!(a.stats().buffered_bytes, 0);
    });
}

#[test]
fn a_plain_send_carries_the_held_frames_before_it() {
    on_both(|t| {
        let Connected {
            a,
            _b,
            sink,
            mut expected,
        } = connected(t, &StreamConfig::default());
        for i in 0..3 {
            expected.push(frame(i, 40));
            a.send_held(B, expected.last().unwrap()).unwrap();
        }
        expected.push(frame(3, 2000));
        a.send(B, expected.last().unwrap()).unwrap();
        assert_received(&sink, &expected);
        // Nothing is left for a flush to write.
        let sent = a.stream().frames_sent;
        a.flush().unwrap();
        assert_eq!(a.stream().frames_sent, sent);
    });
}

#[test]
fn a_full_batch_goes_out_without_a_flush() {
    // Ten 100-byte frames (108 bytes with their record headers) fill a 1100-byte batch.
    let config = StreamConfig {
        batch_bytes: 1100,
        ..StreamConfig::default()
    };
    on_both(|t| {
        let Connected {
            a,
            _b,
            sink,
            mut expected,
        } = connected(t, &config);
        for i in 0..10 {
            expected.push(frame(i, 100));
            a.send_held(B, expected.last().unwrap()).unwrap();
        }
        assert_still(&sink, 1, "a batch that fits went out");
        // The eleventh does not fit: the ten go out, it is held.
        expected.push(frame(10, 100));
        a.send_held(B, expected.last().unwrap()).unwrap();
        assert_received(&sink, &expected[..11]);
        assert_still(&sink, 11, "the frame that started the new batch went out");
        // A frame larger than a whole batch follows the held one at once.
        expected.push(frame(11, 5000));
        a.send_held(B, expected.last().unwrap()).unwrap();
        assert_received(&sink, &expected);
        assert_eq!(a.stats().buffered_bytes, 0);
    });
}

#[test]
fn interleaved_held_and_plain_sends_keep_their_order() {
    let config = StreamConfig {
        batch_bytes: 4096,
        ..StreamConfig::default()
    };
    on_both(|t| {
        let Connected {
            a,
            _b,
            sink,
            mut expected,
        } = connected(t, &config);
        // A fixed pseudo-random mix of sizes (some larger than the batch) and of send_held,
        // send and flush.
        let mut x = 0x2545_f491_u32;
        for i in 0..2000 {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            let len = match x % 16 {
                0 => 4096 + (x as usize >> 8) % 70_000,
                1..=4 => 200 + (x as usize >> 8) % 3000,
                _ => 4 + (x as usize >> 8) % 120,
            };
            let f = frame(i, len);
            match (x >> 4) % 8 {
                0 => a.send(B, &f).unwrap(),
                1 => {
                    a.send_held(B, &f).unwrap();
                    a.flush().unwrap();
                }
                _ => a.send_held(B, &f).unwrap(),
            }
            expected.push(f);
        }
        a.flush().unwrap();
        assert_received(&sink, &expected);
        assert_eq!(a.stream().frames_sent, expected.len() as u64);
        assert_eq!(a.stats().frames_dropped, 0);
    });
}

#[test]
fn megabyte_frames_arrive_intact_between_held_frames() {
    on_both(|t| {
        let Connected {
            a,
            _b,
            sink,
            mut expected,
        } = connected(t, &StreamConfig::default());
        for i in 0..12 {
            let big = frame(1000 + i, (1 << 20) + i as usize * 4099);
            let small = frame(i, 60);
            a.send_held(B, &small).unwrap();
            if i % 2 == 0 {
                a.send(B, &big).unwrap();
            } else {
                a.send_held(B, &big).unwrap();
            }
            expected.push(small);
            expected.push(big);
        }
        a.flush().unwrap();
        assert_received(&sink, &expected);
    });
}

#[test]
fn frames_sent_in_two_pieces_arrive_whole_and_in_order() {
    // Before the connection is up (queued for the connector), after it, and behind held
    // frames: each `send_parts` arrives as the one frame `head` + `body`.
    let mut h = TcpHarness::new(StreamConfig::default());
    let a = h.open_tcp(A, CollectSink::new());
    let mut expected = Vec::new();
    let send = |expected: &mut Vec<Vec<u8>>, f: Vec<u8>, split: usize| {
        a.send_parts(B, &f[..split], &f[split..]).unwrap();
        expected.push(f);
    };
    send(&mut expected, frame(0, 70_000), 48);
    send(&mut expected, frame(1, 100), 100);
    let sink_b = CollectSink::new();
    let _b = h.open_tcp(B, sink_b.clone());
    wait_until("A connected", DEADLINE, || a.stream_stats().connects == 1);
    send(&mut expected, frame(2, 1 << 20), 48);
    let held = frame(3, 40);
    a.send_held(B, &held).unwrap();
    expected.push(held);
    send(&mut expected, frame(4, 30_000), 4);
    let max = StreamConfig::default().max_frame();
    match a.send_parts(B, &[0; 48], &vec![0; max]) {
        Err(LinkError::TooLarge { len, .. }) => assert_eq!(len, max + 48),
        other => panic!("expected TooLarge, got {other:?}"),
    }
    assert_received(&sink_b, &expected);
    assert_eq!(a.stream_stats().frames_sent, expected.len() as u64);
}

#[test]
fn frames_held_while_connecting_wait_for_the_flush_then_follow_the_queue() {
    // TCP only: a bound listener that nobody accepts on yet completes connections in its
    // backlog, so A's connector succeeds before B's link exists.
    let mut h = TcpHarness::new(StreamConfig::default());
    let a = h.open_tcp(A, CollectSink::new());
    let mut expected = Vec::new();
    for i in 0..5 {
        expected.push(frame(i, 30));
        a.send_held(B, expected.last().unwrap()).unwrap();
    }
    wait_until("A connected", DEADLINE, || a.stream_stats().connects == 1);
    let sink_b = CollectSink::new();
    let _b = h.open_tcp(B, sink_b.clone());
    assert_still(
        &sink_b,
        0,
        "frames held while connecting went out unflushed",
    );
    a.flush().unwrap();
    assert_received(&sink_b, &expected);

    // Before the connection is up, a plain send releases the held frames before it, and the
    // connector writes them all in order; what is held after it waits for the flush.
    let mut h = TcpHarness::new(StreamConfig::default());
    let a = h.open_tcp(A, CollectSink::new());
    let mut expected = Vec::new();
    for i in 0..7 {
        expected.push(frame(i, 30 + i as usize));
        if i == 4 {
            a.send(B, expected.last().unwrap()).unwrap();
        } else {
            a.send_held(B, expected.last().unwrap()).unwrap();
        }
    }
    let sink_b = CollectSink::new();
    let _b = h.open_tcp(B, sink_b.clone());
    assert_received(&sink_b, &expected[..5]);
    assert_still(&sink_b, 5, "frames held after the send went out unflushed");
    a.flush().unwrap();
    assert_received(&sink_b, &expected);
    assert_eq!(a.stream_stats().frames_lost_connecting, 0);
}

#[test]
fn a_flush_before_the_connection_is_up_hands_the_frames_to_the_connector() {
    let mut h = TcpHarness::new(StreamConfig::default());
    let a = h.open_tcp(A, CollectSink::new());
    let expected: Vec<_> = (0..20).map(|i| frame(i, 50)).collect();
    for f in &expected {
        a.send_held(B, f).unwrap();
    }
    // Most likely still connecting: then the connector writes them once connected.
    a.flush().unwrap();
    let sink_b = CollectSink::new();
    let _b = h.open_tcp(B, sink_b.clone());
    assert_received(&sink_b, &expected);
}

#[test]
fn frames_held_for_a_peer_that_refuses_are_counted_lost() {
    on_both(|t| {
        // B is never opened: TCP refuses the connection, the Unix path does not exist.
        t.refuse(B);
        let config = StreamConfig {
            backoff_initial: Duration::from_secs(5),
            ..StreamConfig::default()
        };
        let a = t.open(A, CollectSink::new(), &config);
        // The connector may be refused (and start its backoff) before all three are held:
        // from then on they are refused at once, as below.
        let mut held = 0;
        for i in 0..3 {
            match a.send_held(B, &frame(i, 10)) {
                Ok(()) => held += 1,
                Err(LinkError::Unreachable { .. }) if held > 0 => {}
                Err(e) => panic!("frame {i}: {e}"),
            }
        }
        a.flush().unwrap();
        wait_until("the connect failed", DEADLINE, || {
            a.stream().frames_lost_connecting == held
        });
        assert_eq!(a.stats().buffered_bytes, 0);
        // The backoff refuses held frames like sent ones, and a flush has nothing to do.
        let err = a.send_held(B, &frame(3, 10)).unwrap_err();
        assert!(
            matches!(&err, LinkError::Unreachable { peer: B, reason } if reason.contains("reconnecting in")),
            "{err}"
        );
        a.flush().unwrap();
        assert_eq!(a.stream().frames_sent, 0);
        assert_eq!(a.stream().connects, 0);
    });
}

#[test]
fn dropping_the_link_writes_what_is_held() {
    on_both(|t| {
        let Connected {
            a,
            _b,
            sink,
            mut expected,
        } = connected(t, &StreamConfig::default());
        for i in 0..10 {
            expected.push(frame(i, 30));
            a.send_held(B, expected.last().unwrap()).unwrap();
        }
        drop(a);
        assert_received(&sink, &expected);
    });
}

#[test]
fn flush_with_nothing_held_is_a_no_op() {
    on_both(|t| {
        // Before any traffic: no connection is made, nothing is counted.
        let a = t.open(A, CollectSink::new(), &StreamConfig::default());
        for _ in 0..1000 {
            a.flush().unwrap();
        }
        assert_eq!(a.stream(), StreamStats::default());
        drop(a);
        // After traffic, with everything written already.
        let Connected {
            a,
            _b,
            sink,
            mut expected,
        } = connected(t, &StreamConfig::default());
        expected.push(frame(0, 20));
        a.send_held(B, &expected[1]).unwrap();
        a.flush().unwrap();
        assert_received(&sink, &expected);
        let stats = a.stream();
        let started = Instant::now();
        for _ in 0..100_000 {
            a.flush().unwrap();
        }
        // Only an atomic load each: far below a microsecond even in a debug build.
        assert!(started.elapsed() < Duration::from_secs(1), "flush is slow");
        assert_eq!(a.stream(), stats);
    });
}

#[test]
fn a_failed_flush_counts_the_held_frames_as_dropped() {
    // B is a raw listener that accepts A's connection and closes it.
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let own = TcpListener::bind("127.0.0.1:0").unwrap();
    let endpoints = [
        (A, own.local_addr().unwrap().to_string()),
        (B, listener.local_addr().unwrap().to_string()),
    ]
    .into();
    let a =
        TcpLink::with_listener(A, own, &endpoints, CollectSink::new(), Default::default()).unwrap();
    a.send(B, b"hello").unwrap();
    let (conn, _): (TcpStream, _) = listener.accept().unwrap();
    wait_until("A connected", DEADLINE, || {
        a.stream_stats().frames_sent == 1
    });
    drop(conn);
    drop(listener);
    // The first batches may still be taken by the kernel before the reset is noticed.
    let deadline = Instant::now() + DEADLINE;
    let mut held = 0u64;
    let err = loop {
        assert!(Instant::now() < deadline, "flush never failed");
        for i in 0..3 {
            a.send_held(B, &frame(i, 100)).unwrap();
        }
        held += 3;
        match a.flush() {
            Ok(()) => std::thread::sleep(Duration::from_millis(5)),
            Err(e) => break e,
        }
    };
    assert!(
        matches!(&err, LinkError::Unreachable { peer: B, .. }),
        "{err}"
    );
    let s = a.stream_stats();
    assert_eq!(s.held_frames_dropped, 3, "{s:?}");
    assert_eq!(s.frames_sent, 1 + held - 3, "{s:?}");
    assert_eq!(s.write_failures, 1);
    assert_eq!(a.stats().frames_dropped, 3);
    assert_eq!(a.stats().buffered_bytes, 0);
    // The failed batch is gone; a later flush has nothing to write.
    a.flush().unwrap();
}

/// Records how frames arrive: each `on_frame` call as a group of one, each `on_frames` call
/// as one group.
#[derive(Default)]
struct GroupSink(std::sync::Mutex<Vec<Vec<Vec<u8>>>>);

impl GroupSink {
    fn frames(&self) -> usize {
        self.0.lock().unwrap().iter().map(Vec::len).sum()
    }
}

impl FrameSink for GroupSink {
    fn on_frame(&self, frame: &[u8], _from: Peer) {
        self.0.lock().unwrap().push(vec![frame.to_vec()]);
    }

    fn on_frames(&self, frames: &mut dyn Iterator<Item = &[u8]>, from: Peer) {
        assert_eq!(from, Peer::System(A));
        let group: Vec<Vec<u8>> = frames.map(<[u8]>::to_vec).collect();
        self.0.lock().unwrap().push(group);
    }
}

#[test]
fn records_read_together_reach_the_sink_in_runs() {
    on_both(|t| {
        let sink = Arc::new(GroupSink::default());
        let _b = t.open(B, sink.clone(), &StreamConfig::default());
        let a = t.open(A, CollectSink::new(), &StreamConfig::default());
        let expected: Vec<Vec<u8>> = (0..200).map(|i| frame(i, 40)).collect();
        a.send(B, &expected[0]).unwrap();
        wait_until("the first frame", DEADLINE, || sink.frames() == 1);
        // The other 199 in one write: read in one go, they go up in runs of at most 64.
        for f in &expected[1..] {
            a.send_held(B, f).unwrap();
        }
        a.flush().unwrap();
        wait_until("every frame", DEADLINE, || sink.frames() == expected.len());
        let groups = sink.0.lock().unwrap().clone();
        assert_eq!(groups.concat(), expected, "in order, each once");
        assert!(groups.iter().all(|g| g.len() <= 64), "runs of at most 64");
        assert!(groups.len() < 20, "{} calls for 200 frames", groups.len());
    });
}
