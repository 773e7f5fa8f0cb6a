//! TCP link behaviour beyond the conformance suite: hostile input, peer restarts, unreachable
//! peers, slow peers and shutdown. Real sockets on 127.0.0.1, port 0 only.

mod common;

use std::io::Write;
use std::net::{TcpListener, TcpStream};
use std::time::{Duration, Instant};

use common::{assert_closed_by_peer, record, wait_until, TcpHarness, DEADLINE};
use hetcomm_core::SystemId;
use hetcomm_link::conformance::CollectSink;
use hetcomm_link::{Link, LinkError, Peer};
use hetcomm_link_ip::stream::{encode_hello, StreamConfig, RECORD_MAGIC, STREAM_VERSION};
use hetcomm_link_ip::TcpLink;

const A: SystemId = SystemId(1);
const B: SystemId = SystemId(2);

#[test]
fn garbage_closes_only_that_connection() {
    let mut h = TcpHarness::new(StreamConfig::default());
    let sink_b = CollectSink::new();
    let a = h.open_tcp(A, CollectSink::new());
    let b = h.open_tcp(B, sink_b.clone());

    // Garbage instead of a hello.
    let mut raw = TcpStream::connect(b.local_addr()).unwrap();
    raw.write_all(b"GET / HTTP/1.1\r\n\r\n").unwrap();
    assert_closed_by_peer(&mut raw);
    wait_until("rejected hello counted", DEADLINE, || {
        b.stream_stats().rejected_connections == 1
    });

    // A valid hello and record, then garbage where the next record header should be.
    let mut raw = TcpStream::connect(b.local_addr()).unwrap();
    raw.write_all(&encode_hello(A)).unwrap();
    raw.write_all(&record(b"fine")).unwrap();
    raw.write_all(b"\xde\xad\xbe\xef garbage").unwrap();
    assert_closed_by_peer(&mut raw);
    assert_eq!(sink_b.wait_for(1, DEADLINE), 1);
    assert_eq!(sink_b.frames()[0].bytes, b"fine");
    assert_eq!(sink_b.frames()[0].from, Peer::System(A));

    // A record announcing more than the limit is refused before anything is allocated.
    let mut raw = TcpStream::connect(b.local_addr()).unwrap();
    raw.write_all(&encode_hello(A)).unwrap();
    let mut huge = RECORD_MAGIC.to_vec();
    huge.extend_from_slice(&[STREAM_VERSION, 0]);
    huge.extend_from_slice(&u32::MAX.to_le_bytes());
    raw.write_all(&huge).unwrap();
    assert_closed_by_peer(&mut raw);
    wait_until("3 drops counted", DEADLINE, || {
        b.stats().frames_dropped == 3
    });

    // The listener still serves well-behaved peers.
    a.send(B, b"after the garbage").unwrap();
    assert_eq!(sink_b.wait_for(2, DEADLINE), 2);
    assert_eq!(sink_b.frames()[1].bytes, b"after the garbage");
    assert_eq!(b.stats().frames_received, 2);
}

#[test]
fn hello_from_a_system_outside_the_fleet_is_refused() {
    let mut h = TcpHarness::new(StreamConfig::default());
    let sink_b = CollectSink::new();
    let b = h.open_tcp(B, sink_b.clone());
    let mut raw = TcpStream::connect(b.local_addr()).unwrap();
    raw.write_all(&encode_hello(SystemId(77))).unwrap();
    // Written before the link has read the hello, so the write itself succeeds.
    let _ = raw.write_all(&record(b"sneaky"));
    assert_closed_by_peer(&mut raw);
    wait_until("rejection counted", DEADLINE, || {
        b.stream_stats().rejected_connections == 1
    });
    assert_eq!(b.stats().frames_dropped, 1);
    assert_eq!(b.stats().frames_received, 0);
    assert!(sink_b.frames().is_empty());
}

#[test]
fn traffic_resumes_after_the_peer_restarts_on_the_same_port() {
    let mut h = TcpHarness::new(StreamConfig::default());
    let a = h.open_tcp(A, CollectSink::new());
    let sink_b1 = CollectSink::new();
    let b = h.open_tcp(B, sink_b1.clone());
    a.send(B, b"before").unwrap();
    assert_eq!(sink_b1.wait_for(1, DEADLINE), 1);
    drop(b);

    // During the outage no send blocks; once the reconnect has been refused, sends fail at
    // once as unreachable with the reason (the first ones may still be taken by the kernel
    // before the reset is noticed, or queued for the reconnect).
    let deadline = Instant::now() + DEADLINE;
    loop {
        assert!(
            Instant::now() < deadline,
            "sends to a dead peer kept succeeding"
        );
        let started = Instant::now();
        let result = a.send(B, b"during");
        assert!(
            started.elapsed() < Duration::from_millis(500),
            "send blocked during the outage"
        );
        match result {
            Ok(()) => std::thread::sleep(Duration::from_millis(1)),
            Err(LinkError::Unreachable { peer, reason }) => {
                assert_eq!(peer, B);
                if reason.contains("reconnecting in") {
                    assert!(reason.contains("refused"), "{reason}");
                    break;
                }
            }
            Err(e) => panic!("unexpected error during outage: {e}"),
        }
    }
    assert!(
        a.stream_stats().frames_lost_connecting >= 1,
        "{:?}",
        a.stream_stats()
    );

    let sink_b2 = CollectSink::new();
    let _b2 = h.open_tcp(B, sink_b2.clone());
    let deadline = Instant::now() + DEADLINE;
    while sink_b2.frames().is_empty() {
        assert!(Instant::now() < deadline, "traffic did not resume");
        let _ = a.send(B, b"after");
        sink_b2.wait_for(1, Duration::from_millis(20));
    }
    assert_eq!(sink_b2.frames()[0].bytes, b"after");
    assert_eq!(sink_b2.frames()[0].from, Peer::System(A));
    assert!(a.stats().connects >= 2, "{:?}", a.stats());
}

#[test]
fn connect_to_a_closed_port_fails_fast_and_backs_off() {
    let closed = TcpListener::bind("127.0.0.1:0").unwrap();
    let closed_addr = closed.local_addr().unwrap().to_string();
    drop(closed);
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let endpoints = [
        (A, listener.local_addr().unwrap().to_string()),
        (B, closed_addr),
    ]
    .into();
    let config = StreamConfig {
        backoff_initial: Duration::from_secs(5),
        ..StreamConfig::default()
    };
    let a = TcpLink::with_listener(A, listener, &endpoints, CollectSink::new(), config).unwrap();

    // The send never waits for the connect: it queues the frame and returns at once.
    let started = Instant::now();
    a.send(B, b"x").expect("queued for the connector");
    assert!(
        started.elapsed() < Duration::from_millis(100),
        "send waited for the connect"
    );
    // The connector's refusal drops the queued frame, counted, and starts the backoff.
    let deadline = Instant::now() + DEADLINE;
    while a.stream_stats().frames_lost_connecting < 1 {
        assert!(Instant::now() < deadline, "connect never failed");
        std::thread::sleep(Duration::from_millis(1));
    }
    let err = a.send(B, b"x").unwrap_err();
    let text = err.to_string();
    assert!(
        matches!(err, LinkError::Unreachable { peer: B, .. }),
        "{text}"
    );
    assert!(
        text.contains("unreachable")
            && text.contains("reconnecting in")
            && text.contains("after: ")
            && text.contains("refused"),
        "{text}"
    );
    assert_eq!(a.stats().connects, 0);
}

#[test]
fn a_peer_that_stops_reading_makes_send_fail_within_the_write_timeout() {
    // A "peer" that accepts the connection but never reads from it.
    let stuck = TcpListener::bind("127.0.0.1:0").unwrap();
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let endpoints = [
        (A, listener.local_addr().unwrap().to_string()),
        (B, stuck.local_addr().unwrap().to_string()),
    ]
    .into();
    let config = StreamConfig {
        write_timeout: Duration::from_millis(300),
        ..StreamConfig::default()
    };
    let a = TcpLink::with_listener(A, listener, &endpoints, CollectSink::new(), config).unwrap();
    // Connect first (a send never waits for a connect; it queues behind a connector).
    a.send(B, b"hello").unwrap();
    let deadline = Instant::now() + DEADLINE;
    while a.stream_stats().frames_sent < 1 {
        assert!(Instant::now() < deadline, "never connected");
        std::thread::sleep(Duration::from_millis(1));
    }
    let big = vec![7u8; 16 * 1024 * 1024];
    let started = Instant::now();
    let mut result = Ok(());
    // Kernel buffers take the first frames; within a few the send must hit the timeout.
    for _ in 0..8 {
        result = a.send(B, &big);
        if result.is_err() {
            break;
        }
    }
    let _conn = stuck.accept().unwrap();
    assert!(
        matches!(result, Err(LinkError::Congested { peer: B, .. })),
        "{result:?}"
    );
    assert!(
        started.elapsed() < Duration::from_secs(8),
        "send blocked too long"
    );
    assert_eq!(a.stream_stats().write_failures, 1);
}

#[test]
fn dropping_the_link_closes_accepted_connections_and_returns() {
    let mut h = TcpHarness::new(StreamConfig::default());
    let b = h.open_tcp(B, CollectSink::new());
    let mut raw = TcpStream::connect(b.local_addr()).unwrap();
    raw.write_all(&encode_hello(A)).unwrap();
    wait_until("connection accepted", DEADLINE, || {
        b.stream_stats().accepted == 1
    });
    let started = Instant::now();
    drop(b);
    assert!(started.elapsed() < Duration::from_secs(2), "drop was slow");
    assert_closed_by_peer(&mut raw);
}

#[test]
fn bind_reports_the_real_port_and_oversize_is_refused() {
    let endpoints = [(A, "127.0.0.1:0".to_string())].into();
    let config = StreamConfig {
        max_message_bytes: Some(100),
        ..StreamConfig::default()
    };
    let a = TcpLink::bind(A, &endpoints, CollectSink::new(), config).unwrap();
    assert_ne!(a.local_addr().port(), 0);
    assert_eq!(a.caps().max_frame, 148);
    assert!(matches!(
        a.send(B, &[0; 149]),
        Err(LinkError::TooLarge { len: 149, max: 148 })
    ));
    assert!(matches!(
        a.send(B, &[0; 148]),
        Err(LinkError::Unreachable { .. })
    ));
    assert!(matches!(
        a.send(A, b"me"),
        Err(LinkError::Unreachable { .. })
    ));
    assert!(matches!(
        TcpLink::bind(B, &endpoints, CollectSink::new(), StreamConfig::default()),
        Err(hetcomm_link_ip::IpOpenError::NoLocalEndpoint { system: B })
    ));
}

#[test]
fn a_hello_may_come_in_pieces_but_not_late() {
    const HELLO_TIMEOUT: Duration = Duration::from_millis(300);
    let mut h = TcpHarness::new(StreamConfig {
        hello_timeout: HELLO_TIMEOUT,
        ..StreamConfig::default()
    });
    let sink = CollectSink::new();
    let b = h.open_tcp(B, sink.clone());
    let addr = b.local_addr();
    let started = Instant::now();
    // Silent, and three bytes of a hello: both closed once the timeout has passed.
    let mut silent = TcpStream::connect(addr).unwrap();
    let mut partial = TcpStream::connect(addr).unwrap();
    partial.write_all(&encode_hello(A)[..3]).unwrap();
    // A hello and a record one byte per write: read as they come, then served.
    let mut slow = TcpStream::connect(addr).unwrap();
    slow.set_nodelay(true).unwrap();
    let mut bytes = encode_hello(A).to_vec();
    bytes.extend_from_slice(&record(b"byte by byte"));
    for byte in &bytes {
        slow.write_all(std::slice::from_ref(byte)).unwrap();
    }
    assert_eq!(sink.wait_for(1, DEADLINE), 1);
    assert_eq!(sink.frames()[0].bytes, b"byte by byte");
    assert_closed_by_peer(&mut silent);
    assert_closed_by_peer(&mut partial);
    assert!(
        started.elapsed() >= HELLO_TIMEOUT,
        "closed before the timeout"
    );
    // Counted, then closed (which gives its slot back): two updates to wait for.
    wait_until("both late hellos counted and closed", DEADLINE, || {
        let s = b.stream_stats();
        (s.rejected_connections, s.open_connections) == (2, 1)
    });
    assert_eq!(b.stats().frames_dropped, 2);
}

#[test]
fn a_record_over_the_receivers_max_message_bytes_is_counted_as_oversize() {
    let (endpoints, mut listeners) = common::tcp_listeners(&[A, B]);
    let big = StreamConfig {
        max_message_bytes: Some(100_000),
        ..StreamConfig::default()
    };
    let small = StreamConfig {
        max_message_bytes: Some(1000),
        ..StreamConfig::default()
    };
    let a = TcpLink::with_listener(
        A,
        listeners.remove(&A).unwrap(),
        &endpoints,
        CollectSink::new(),
        big,
    )
    .unwrap();
    let sink = CollectSink::new();
    let b = TcpLink::with_listener(
        B,
        listeners.remove(&B).unwrap(),
        &endpoints,
        sink.clone(),
        small,
    )
    .unwrap();
    a.send(B, &[7; 1048]).unwrap(); // exactly B's largest frame: delivered
    assert_eq!(sink.wait_for(1, DEADLINE), 1);
    // Over it: B closes the connection and counts it, in two counters updated one after
    // the other, so wait for both.
    a.send(B, &[7; 2000]).unwrap();
    wait_until("the oversize record counted", DEADLINE, || {
        let s = b.stream_stats();
        (s.oversize_records, s.frames_dropped) == (1, 1)
    });
    let s = b.stream_stats();
    assert_eq!(s.frames_dropped, 1, "{s:?}");
    assert_eq!(b.stats().frames_dropped, 1);
    // A reconnects once it notices; later frames arrive again.
    let deadline = Instant::now() + DEADLINE;
    while sink.frames().len() < 2 {
        assert!(Instant::now() < deadline, "no frame after the oversize one");
        let _ = a.send(B, b"after");
        sink.wait_for(2, Duration::from_millis(100));
    }
    assert_eq!(sink.frames()[1].bytes, b"after");
}
