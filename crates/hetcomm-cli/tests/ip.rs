//! Acceptance tests of the UDP and TCP transports with one system per process: `hetcomm
//! listen` and `hetcomm send` run as separate OS processes (or a `Comm` in this test process
//! talks to them), raw sockets play peers that misbehave.
//!
//! Every port is on 127.0.0.1 and picked free at run time (see `support::free_udp_port`);
//! every wait is bounded by the test's deadline; children are killed on drop.

mod support;

use std::io::{Read, Write};
use std::net::{Shutdown, TcpStream, UdpSocket};
use std::time::Duration;

use hetcomm::wire::{self, FrameKind, Header};
use hetcomm::{Address, Comm, FailReason, MessageType, ModuleId, Outcome, SystemId, Time};
use serde_json::{json, Value};
use support::*;

/// The message every send test uses (type 7 to Act).
const HELLO: &str = r#"{"code":1,"text":"hello"}"#;

fn delivery_across_processes(kind: &str) {
    let deadline = Deadline::after(30);
    let (_dir, fleet, _) = loopback_fleet(kind, &[("Alpha", 0), ("Bravo", 1)]);
    let mut bravo = listen(&fleet, "Bravo", &["--count", "1"], deadline);
    let sent = send(&fleet, "Alpha", "Bravo", HELLO, deadline);
    assert_eq!(sent.stdout.len(), 1, "{sent:?}");
    assert!(
        sent.stdout[0].starts_with("Bravo: delivered to the inbox (attempts: 1, "),
        "{sent:?}"
    );
    assert_eq!(sent.status.code(), Some(0), "{sent:?}");

    let line = bravo.next_stdout(deadline);
    assert!(
        message_text(&line).starts_with("Alpha.Plan -> Act  type=7 prio=100 "),
        "{line}"
    );
    assert!(line.ends_with(r#"{"code":1,"text":"hello"}"#), "{line}");
    let status = bravo.wait_exit(deadline);
    assert_eq!(status.code(), Some(0));
    assert_eq!(
        counters_line(&bravo),
        "received 1 message; router: 1 received, 0 duplicates, 0 too old, 0 malformed, 0 unknown origin, 0 misrouted, 0 unknown module; inboxes dropped 0; links dropped 0; security: rejected_auth 0, rejected_replay 0, rejected_table 0, rejected_unknown_sender 0, rejected_no_session 0, handshake_timeouts 0, handshakes 1"
    );
}

#[test]
fn udp_delivery_across_processes() {
    delivery_across_processes("udp");
}

#[test]
fn tcp_delivery_across_processes() {
    delivery_across_processes("tcp");
}

#[test]
fn broadcast_to_all_reaches_two_listeners() {
    let deadline = Deadline::after(30);
    let (_dir, fleet, _) = loopback_fleet("udp", &[("Alpha", 0), ("Bravo", 1), ("Charlie", 2)]);
    let mut bravo = listen(&fleet, "Bravo", &["--count", "1"], deadline);
    let mut charlie = listen(&fleet, "Charlie", &["--count", "1"], deadline);
    let sent = send(&fleet, "Alpha", "All", HELLO, deadline);
    assert_eq!(sent.status.code(), Some(0), "{sent:?}");
    let mut lines = sent.stdout.clone();
    lines.sort();
    assert_eq!(lines.len(), 2, "{sent:?}");
    assert!(
        lines[0].starts_with("Bravo: delivered to the inbox (attempts: 1, "),
        "{sent:?}"
    );
    assert!(
        lines[1].starts_with("Charlie: delivered to the inbox (attempts: 1, "),
        "{sent:?}"
    );
    for listener in [&mut bravo, &mut charlie] {
        let line = listener.next_stdout(deadline);
        assert!(
            message_text(&line).starts_with("Alpha.Plan -> Act  type=7 "),
            "{line}"
        );
        assert!(line.contains(" broadcast "), "{line}");
        assert!(line.ends_with(HELLO), "{line}");
        assert_eq!(listener.wait_exit(deadline).code(), Some(0));
    }
}

/// A data frame from `from` (module Plan) to Bravo.Act, acknowledgement requested.
fn data_frame(from: u16, to: u16, incarnation: u32, seq: u64, json: &Value) -> Vec<u8> {
    let mut h = Header::data(
        Address {
            system: SystemId(from),
            module: ModuleId(0),
        },
        Address {
            system: SystemId(to),
            module: ModuleId(1),
        },
        MessageType(7),
    );
    h.flags = wire::FLAG_ACK_REQUESTED;
    h.incarnation = incarnation;
    h.seq = seq;
    h.timestamp = Time::from_micros(1_000_000);
    wire::encode(&h, &hetcomm::payload::from_json(json).unwrap())
}

/// Reads one datagram on `sock` within the deadline and decodes it as an acknowledgement.
fn read_ack(sock: &UdpSocket, deadline: Deadline) -> Header {
    let mut buf = vec![0u8; 70_000];
    sock.set_read_timeout(Some(deadline.left().max(Duration::from_millis(1))))
        .unwrap();
    let (n, _) = sock
        .recv_from(&mut buf)
        .expect("an acknowledgement in time");
    let frame = wire::decode(&buf[..n]).expect("the acknowledgement decodes");
    assert_eq!(frame.header.kind, FrameKind::Ack);
    assert_eq!(frame.payload, [wire::AckStatus::Delivered as u8]);
    frame.header
}

#[test]
fn udp_duplicates_are_suppressed_and_reacknowledged() {
    let deadline = Deadline::after(30);
    // Charlie is a fleet system that is not running: the raw socket sits at its endpoint, so
    // Bravo's acknowledgements come back to it.
    let raw = UdpSocket::bind("127.0.0.1:0").unwrap();
    let charlie = raw.local_addr().unwrap().to_string();
    let bravo_ep = format!("127.0.0.1:{}", free_udp_port());
    let alpha_ep = format!("127.0.0.1:{}", free_udp_port());
    let dir = TempDir::new("dup");
    let fleet = dir.write(
        "fleet.toml",
        &unsecured(&fleet_text(
            "udp",
            &[
                ("Alpha", 0, alpha_ep),
                ("Bravo", 1, bravo_ep.clone()),
                ("Charlie", 2, charlie),
            ],
        )),
    );
    let mut bravo = listen(&fleet, "Bravo", &["--count", "2", "--json"], deadline);

    let first = data_frame(2, 1, 0xAAAA_0001, 1, &json!({"n": 1}));
    // Each copy waits for its acknowledgement before the next goes out, as a retransmission
    // would (a copy arriving while the first is still being delivered is not re-acknowledged:
    // the pending acknowledgement covers it).
    for copy in 0..3 {
        raw.send_to(&first, &bravo_ep).unwrap();
        let ack = read_ack(&raw, deadline);
        assert_eq!(ack.seq, 1, "ack of copy {copy}");
        assert_eq!(ack.incarnation, 0xAAAA_0001, "ack of copy {copy}");
        assert_eq!(ack.source.system, SystemId(1));
        assert_eq!(ack.destination.system, SystemId(2));
    }
    // Same (origin, seq), another incarnation: Charlie restarted, this is a new message.
    let restarted = data_frame(2, 1, 0xBBBB_0002, 1, &json!({"n": 2}));
    raw.send_to(&restarted, &bravo_ep).unwrap();
    let ack = read_ack(&raw, deadline);
    assert_eq!((ack.seq, ack.incarnation), (1, 0xBBBB_0002));

    assert_eq!(bravo.wait_exit(deadline).code(), Some(0));
    let printed: Vec<Value> = bravo
        .stdout_lines()
        .iter()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(printed.len(), 2, "{printed:?}");
    // Two messages, two ids: the restarted sender's incarnation tells them apart.
    for (p, (n, incarnation)) in printed.iter().zip([(1, 0xAAAA_0001u32), (2, 0xBBBB_0002)]) {
        assert_eq!(p["from_system"], "Charlie");
        assert_eq!(p["to_module"], "Act");
        assert_eq!(
            p["id"],
            json!({"origin": 2, "incarnation": incarnation, "seq": 1, "broadcast_space": false})
        );
        assert_eq!(p["payload"], json!({ "n": n }));
    }
    assert_eq!(
        counters_line(&bravo),
        "received 2 messages; router: 2 received, 2 duplicates, 0 too old, 0 malformed, 0 unknown origin, 0 misrouted, 0 unknown module; inboxes dropped 0; links dropped 0"
    );
    // Nothing else came back (e.g. a fourth acknowledgement for the first incarnation).
    raw.set_nonblocking(true).unwrap();
    let mut buf = [0u8; 2048];
    assert!(
        raw.recv_from(&mut buf).is_err(),
        "an extra datagram came back"
    );
}

#[test]
fn udp_message_over_one_mebibyte_is_reassembled() {
    let deadline = Deadline::after(40);
    let (_dir, fleet, _) = loopback_fleet("udp", &[("Alpha", 0), ("Bravo", 1)]);
    let mut bravo = listen(&fleet, "Bravo", &["--count", "1", "--json"], deadline);

    // ~1.1 MiB of text with a pattern whose period (73) does not divide a fragment's size, so
    // a misplaced fragment would show.
    let text: String = (0..1_150_000u32)
        .map(|i| char::from(b'0' + (i % 73) as u8))
        .collect();
    let payload = hetcomm::payload::from_json(&json!({ "blob": text })).unwrap();
    assert!(payload.len() >= 1024 * 1024);

    let alpha = Comm::open(&fleet, "Alpha").unwrap();
    let plan = alpha.module("Plan").unwrap();
    let ticket = plan
        .send_raw("Bravo", "Act", MessageType(7), &payload, Default::default())
        .unwrap();
    let outcome = ticket
        .wait_timeout(deadline.left())
        .expect("an outcome in time");
    assert!(matches!(outcome, Outcome::Delivered { .. }), "{outcome}");

    let line = bravo.next_stdout(deadline);
    let got: Value = serde_json::from_str(&line).unwrap();
    assert_eq!(got["size"], json!(payload.len()));
    assert_eq!(got["from_system"], "Alpha");
    assert!(got["payload"]["blob"] == json!(text), "payload differs");
    assert_eq!(bravo.wait_exit(deadline).code(), Some(0));
    eprintln!("1 MiB over UDP: {outcome}");
}

#[test]
fn tcp_peer_killed_and_restarted() {
    let deadline = Deadline::after(50);
    let (_dir, fleet, _) = loopback_fleet("tcp", &[("Alpha", 0), ("Bravo", 1)]);
    let mut bravo = listen(&fleet, "Bravo", &[], deadline);

    let alpha = Comm::open(&fleet, "Alpha").unwrap();
    let plan = alpha.module("Plan").unwrap();
    let send = |n: u32| {
        let payload = hetcomm::payload::from_json(&json!({ "n": n })).unwrap();
        plan.send_raw("Bravo", "Act", MessageType(7), &payload, Default::default())
            .unwrap()
            .wait_timeout(deadline.left())
            .expect("an outcome in time")
    };

    let first = send(1);
    assert!(matches!(first, Outcome::Delivered { .. }), "{first}");
    assert!(bravo.next_stdout(deadline).ends_with(r#"{"n":1}"#));

    bravo.kill();
    let mut unreachable = 0;
    for n in 2..5 {
        let outcome = send(n);
        eprintln!("during the outage: message {n} {outcome}");
        match outcome {
            Outcome::Failed {
                reason: FailReason::Unreachable(_),
                ..
            } => unreachable += 1,
            // A frame the link took before it noticed the peer was gone: the sender cannot
            // know it was lost, so it says so instead of claiming a failure.
            Outcome::Unconfirmed { .. } => {}
            other => panic!("send {n} during the outage: {other}"),
        }
    }
    // Whether a send meets the link in its reconnect backoff (Unreachable at once: failed) or
    // is taken by a connection attempt that then fails (unconfirmed) depends on how fast the
    // kernel tears the dead peer down; either way no outage send claimed success.
    eprintln!("{unreachable} of 3 outage sends were refused as unreachable");

    // A new Bravo on the same port.
    let mut bravo = listen(&fleet, "Bravo", &[], deadline);
    let redelivery_deadline = deadline.within(Duration::from_secs(15));
    let mut n = 10;
    let delivered = loop {
        let outcome = send(n);
        if let Outcome::Delivered { .. } = outcome {
            break outcome;
        }
        eprintln!("after the restart: message {n} {outcome}");
        assert!(
            !redelivery_deadline.passed(),
            "not delivered after the restart: {outcome}"
        );
        n += 1;
        // Pace the retries (the link's reconnect backoff is at most a second).
        std::thread::sleep(Duration::from_millis(50));
    };
    let line = bravo.wait_stdout(&format!(r#"{{"n":{n}}}"#), deadline);
    assert!(
        message_text(&line).starts_with("Alpha.Plan -> Act  type=7 "),
        "{line}"
    );
    eprintln!("after the restart: message {n} {delivered}");
}

#[test]
fn udp_receiver_that_never_acknowledges() {
    let deadline = Deadline::after(30);
    let sink = UdpSocket::bind("127.0.0.1:0").unwrap();
    let bravo_ep = sink.local_addr().unwrap().to_string();
    let alpha_ep = format!("127.0.0.1:{}", free_udp_port());
    let dir = TempDir::new("noack");
    let fleet = dir.write(
        "fleet.toml",
        &unsecured(&fleet_text(
            "udp",
            &[("Alpha", 0, alpha_ep), ("Bravo", 1, bravo_ep)],
        )),
    );
    let sent = send(&fleet, "Alpha", "Bravo", HELLO, deadline);
    // The frames did arrive (the sink holds them below) but nothing acknowledged them: the
    // sender must not call that a failure.
    assert_eq!(
        sent.stdout,
        ["Bravo: unconfirmed: no acknowledgement; it may or may not have arrived (attempts: 3)"],
        "{sent:?}"
    );
    assert_eq!(sent.status.code(), Some(3), "{sent:?}");

    // The sender has exited: everything it sent is already in the socket's queue.
    sink.set_nonblocking(true).unwrap();
    let mut buf = vec![0u8; 70_000];
    let mut copies = Vec::new();
    while let Ok((n, _)) = sink.recv_from(&mut buf) {
        copies.push(buf[..n].to_vec());
    }
    assert_eq!(copies.len(), 3, "datagrams seen: {}", copies.len());
    let headers: Vec<Header> = copies
        .iter()
        .map(|c| wire::decode(c).expect("a valid frame").header)
        .collect();
    for h in &headers {
        assert_eq!(h.kind, FrameKind::Data);
        assert!(h.ack_requested());
        assert_eq!(h.seq, headers[0].seq);
        assert_eq!(h.incarnation, headers[0].incarnation);
        assert_eq!(
            (h.source.system, h.destination.system),
            (SystemId(0), SystemId(1))
        );
    }
    assert_eq!(copies[0], copies[1]);
    assert_eq!(copies[1], copies[2]);
}

#[test]
fn udp_bad_frames_are_counted_and_the_system_keeps_serving() {
    let deadline = Deadline::after(30);
    let (_dir, fleet, ports) = loopback_fleet_unsecured("udp", &[("Alpha", 0), ("Bravo", 1)]);
    let bravo_ep = format!("127.0.0.1:{}", ports[1]);
    let mut bravo = listen(&fleet, "Bravo", &["--count", "1"], deadline);

    let good = data_frame(0, 1, 77, 1, &json!({"bad": false}));
    let mut wrong_version = good.clone();
    wrong_version[2] = 9;
    let mut oversized = good.clone();
    oversized[40..44].copy_from_slice(&u32::MAX.to_le_bytes());
    let mut bad_crc = good.clone();
    let last = bad_crc.len() - 1;
    bad_crc[last] ^= 0xff;
    let garbage: Vec<u8> = (0..300u32).map(|i| (i * 37 + 11) as u8).collect();
    let malformed: Vec<(&str, Vec<u8>)> = vec![
        ("truncated", good[..30].to_vec()),
        ("truncated payload", good[..good.len() - 2].to_vec()),
        ("wrong version", wrong_version),
        ("oversized length", oversized),
        ("bad checksum", bad_crc),
        ("garbage", garbage),
        ("short garbage", b"hello?".to_vec()),
    ];
    let unknown_origin = data_frame(999, 1, 77, 1, &json!({"bad": true}));
    let misrouted = data_frame(0, 5, 77, 2, &json!({"bad": true}));

    let raw = UdpSocket::bind("127.0.0.1:0").unwrap();
    for (what, bytes) in &malformed {
        raw.send_to(bytes, &bravo_ep)
            .unwrap_or_else(|e| panic!("{what}: {e}"));
    }
    raw.send_to(&unknown_origin, &bravo_ep).unwrap();
    raw.send_to(&misrouted, &bravo_ep).unwrap();

    // Bravo's one receive thread handles datagrams in arrival order: the bad ones are counted
    // before this one arrives.
    let sent = send(&fleet, "Alpha", "Bravo", HELLO, deadline);
    assert!(
        sent.stdout[0].starts_with("Bravo: delivered to the inbox (attempts: 1, "),
        "{sent:?}"
    );
    let line = bravo.next_stdout(deadline);
    assert!(
        message_text(&line).starts_with("Alpha.Plan -> Act  type=7 "),
        "{line}"
    );
    assert!(line.ends_with(HELLO), "{line}");
    assert_eq!(bravo.wait_exit(deadline).code(), Some(0));
    assert_eq!(
        counters_line(&bravo),
        format!(
            "received 1 message; router: 1 received, 0 duplicates, 0 too old, {} malformed, 1 unknown origin, 1 misrouted, 0 unknown module; inboxes dropped 0; links dropped 0",
            malformed.len()
        )
    );
    // None of the bad frames was acknowledged.
    raw.set_nonblocking(true).unwrap();
    let mut buf = [0u8; 2048];
    assert!(
        raw.recv_from(&mut buf).is_err(),
        "a bad frame got an answer"
    );
}

/// Waits until the peer closes `s` (EOF or reset), within the deadline.
fn wait_closed(s: &mut TcpStream, deadline: Deadline) {
    s.set_read_timeout(Some(deadline.left().max(Duration::from_millis(1))))
        .unwrap();
    let mut buf = [0u8; 64];
    loop {
        match s.read(&mut buf) {
            Ok(0) => return,
            Ok(_) => {}
            Err(e)
                if e.kind() == std::io::ErrorKind::WouldBlock
                    || e.kind() == std::io::ErrorKind::TimedOut =>
            {
                panic!("the listener did not close the connection in time")
            }
            Err(_) => return, // reset
        }
    }
}

#[test]
fn tcp_garbage_is_dropped_and_the_system_keeps_serving() {
    let deadline = Deadline::after(30);
    let (_dir, fleet, ports) = loopback_fleet_unsecured("tcp", &[("Alpha", 0), ("Bravo", 1)]);
    let bravo_ep = format!("127.0.0.1:{}", ports[1]);
    let mut bravo = listen(&fleet, "Bravo", &["--count", "1"], deadline);

    // 1. No hello, just noise: the connection is rejected.
    let mut c = TcpStream::connect(&bravo_ep).unwrap();
    let noise: Vec<u8> = (0..200u32).map(|i| (i * 91 + 3) as u8).collect();
    c.write_all(&noise).unwrap();
    wait_closed(&mut c, deadline);

    // 2. A proper hello (as Alpha) and record carrying a garbage frame (the router counts it
    //    malformed), then a record with a bad magic (the link drops it and closes).
    let mut c = TcpStream::connect(&bravo_ep).unwrap();
    let mut bytes = vec![b'H', b'L', 1, 0, 0, 0, 0, 0];
    let junk = b"definitely not a frame".to_vec();
    bytes.extend_from_slice(&[b'H', b'R', 1, 0]);
    bytes.extend_from_slice(&(junk.len() as u32).to_le_bytes());
    bytes.extend_from_slice(&junk);
    bytes.extend_from_slice(&[b'X', b'R', 1, 0, 4, 0, 0, 0, 1, 2, 3, 4]);
    c.write_all(&bytes).unwrap();
    wait_closed(&mut c, deadline);
    let _ = c.shutdown(Shutdown::Both);

    let sent = send(&fleet, "Alpha", "Bravo", HELLO, deadline);
    assert!(
        sent.stdout[0].starts_with("Bravo: delivered to the inbox (attempts: 1, "),
        "{sent:?}"
    );
    assert_eq!(sent.status.code(), Some(0));
    let line = bravo.next_stdout(deadline);
    assert!(line.ends_with(HELLO), "{line}");
    assert_eq!(bravo.wait_exit(deadline).code(), Some(0));
    assert_eq!(
        counters_line(&bravo),
        "received 1 message; router: 1 received, 0 duplicates, 0 too old, 1 malformed, 0 unknown origin, 0 misrouted, 0 unknown module; inboxes dropped 0; links dropped 2"
    );
}
