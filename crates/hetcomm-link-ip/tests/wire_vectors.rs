//! The link sections of `docs/wire-vectors.json` (UDP datagrams and batches, fragments,
//! reassembly, fragment errors, stream hellos and records) against this crate's real encoders
//! and decoders. The vectors are generated from the document by hetcomm-core's vector test,
//! which cannot use this crate; here they meet the code that puts the bytes on the wire:
//!
//! * the public parsers (`parse_fragment`, `Reassembler`, `decode_hello`,
//!   `decode_record_header`, `encode_hello`, `FragmentHeader::encode`) directly;
//! * the private encoders and receive paths (batching, fragmenting, record framing, the
//!   stream reader) through real sockets on 127.0.0.1: a raw socket captures what a link
//!   sends, or sends the vector's bytes to a link and the sink shows what it hands up.

mod common;

use std::io::{Read, Write};
use std::net::{IpAddr, Ipv4Addr, Shutdown, SocketAddr, TcpListener, TcpStream, UdpSocket};
use std::sync::Arc;
use std::time::{Duration, Instant};

use common::{tcp_listeners, udp_sockets, wait_until, DEADLINE};
use hetcomm_core::wire::HEADER_LEN;
use hetcomm_core::SystemId;
use hetcomm_link::conformance::CollectSink;
use hetcomm_link::{Link, Peer};
use hetcomm_link_ip::stream::{
    decode_hello, decode_record_header, encode_hello, StreamConfig, HELLO_LEN, RECORD_HEADER_LEN,
};
use hetcomm_link_ip::udp::{
    parse_fragment, FragmentError, Reassembler, Reassembly, FRAGMENT_HEADER_LEN,
};
use hetcomm_link_ip::{TcpLink, UdpConfig, UdpLink};
use serde_json::Value;

fn load() -> Value {
    let path =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../docs/wire-vectors.json");
    let text = std::fs::read_to_string(&path)
        .unwrap_or_else(|e| panic!("cannot read {}: {e}", path.display()));
    serde_json::from_str(&text).expect("wire-vectors.json is valid JSON")
}

fn unhex(s: &str) -> Vec<u8> {
    assert!(s.len().is_multiple_of(2), "odd-length hex string");
    (0..s.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&s[i..i + 2], 16).expect("hex digit"))
        .collect()
}

fn section<'a>(file: &'a Value, key: &str) -> &'a [Value] {
    let v = file[key]
        .as_array()
        .unwrap_or_else(|| panic!("{key} is not an array"));
    assert!(!v.is_empty(), "{key} is empty");
    v
}

fn text<'a>(v: &'a Value, key: &str) -> &'a str {
    v[key]
        .as_str()
        .unwrap_or_else(|| panic!("{key} is not a string in {v}"))
}

fn num(v: &Value, key: &str) -> u64 {
    v[key]
        .as_u64()
        .unwrap_or_else(|| panic!("{key} is not an unsigned integer in {v}"))
}

fn bytes(v: &Value, key: &str) -> Vec<u8> {
    unhex(text(v, key))
}

fn byte_list(v: &Value, key: &str) -> Vec<Vec<u8>> {
    v[key]
        .as_array()
        .unwrap_or_else(|| panic!("{key} is not an array in {v}"))
        .iter()
        .map(|h| unhex(h.as_str().expect("hex string")))
        .collect()
}

const A: SystemId = SystemId(1);
const B: SystemId = SystemId(2);

/// Receives `n` datagrams on `raw`.
fn recv_datagrams(raw: &UdpSocket, n: usize) -> Vec<Vec<u8>> {
    let mut buf = vec![0u8; 65_536];
    (0..n)
        .map(|i| {
            let len = raw
                .recv(&mut buf)
                .unwrap_or_else(|e| panic!("datagram {i} of {n}: {e}"));
            buf[..len].to_vec()
        })
        .collect()
}

/// System `sender`'s UDP link with `config`, towards a raw socket at B's endpoint.
fn udp_sender(sender: SystemId, config: UdpConfig) -> (UdpLink, UdpSocket) {
    let (endpoints, mut sockets) = udp_sockets(&[sender, B]);
    let link = UdpLink::with_socket(
        sender,
        sockets.remove(&sender).unwrap(),
        &endpoints,
        CollectSink::new(),
        config,
    )
    .expect("open udp link");
    let raw = sockets.remove(&B).unwrap();
    raw.set_read_timeout(Some(DEADLINE)).unwrap();
    (link, raw)
}

/// B's UDP link, and a raw socket at A's endpoint sending to it.
fn udp_receiver() -> (UdpLink, UdpSocket, Arc<CollectSink>) {
    let (endpoints, mut sockets) = udp_sockets(&[A, B]);
    let sink = CollectSink::new();
    let link = UdpLink::with_socket(
        B,
        sockets.remove(&B).unwrap(),
        &endpoints,
        sink.clone(),
        UdpConfig::loopback(),
    )
    .expect("open udp link");
    let raw = sockets.remove(&A).unwrap();
    raw.connect(link.local_addr()).unwrap();
    (link, raw, sink)
}

#[test]
fn udp_datagrams_are_handed_up_as_the_vectors_say() {
    let file = load();
    for v in section(&file, "udp_datagrams") {
        let name = text(v, "name");
        let datagram = bytes(v, "datagram_hex");
        let frames = byte_list(v, "frames_hex");
        let tail = bytes(v, "dropped_tail_hex");
        let (link, raw, sink) = udp_receiver();
        raw.send(&datagram).unwrap();
        assert_eq!(
            sink.wait_for(frames.len(), DEADLINE),
            frames.len(),
            "{name}"
        );
        let got: Vec<Vec<u8>> = sink.frames().into_iter().map(|r| r.bytes).collect();
        assert_eq!(got, frames, "{name}: frames handed up");
        assert!(
            sink.frames().iter().all(|r| r.from == Peer::System(A)),
            "{name}: labelled with the sender's system"
        );
        let handling = text(v, "handling");
        let bad = !tail.is_empty() || handling == "dropped";
        wait_until("the datagram counted", DEADLINE, || {
            let s = link.udp_stats();
            s.bad_datagrams == u64::from(bad) && s.frames_received == frames.len() as u64
        });
        let s = link.udp_stats();
        let batch = handling == "batch";
        assert_eq!(s.batches_received, u64::from(batch), "{name}: batch?");
        assert_eq!(s.bad_datagrams, u64::from(bad), "{name}: bad tail");
        assert_eq!(s.frames_received, frames.len() as u64, "{name}");
    }
}

#[test]
fn udp_sender_writes_the_vector_datagrams() {
    let file = load();
    let mut checked = 0;
    for v in section(&file, "udp_datagrams") {
        let name = text(v, "name");
        if !text(v, "dropped_tail_hex").is_empty() || text(v, "handling") == "dropped" {
            continue; // malformed: no sender writes it
        }
        let datagram = bytes(v, "datagram_hex");
        let frames = byte_list(v, "frames_hex");
        let (link, raw) = udp_sender(A, UdpConfig::default());
        if text(v, "handling") == "whole" {
            link.send(B, &frames[0])
                .unwrap_or_else(|e| panic!("{name}: {e}"));
        } else {
            for f in &frames {
                link.send_held(B, f)
                    .unwrap_or_else(|e| panic!("{name}: {e}"));
            }
            link.flush().unwrap_or_else(|e| panic!("{name}: {e}"));
        }
        assert_eq!(recv_datagrams(&raw, 1), vec![datagram], "{name}");
        checked += 1;
    }
    assert!(checked >= 8);
}

/// A fragment with its message id replaced by `id`.
fn with_message_id(d: &[u8], id: u32) -> Vec<u8> {
    let mut d = d.to_vec();
    d[12..16].copy_from_slice(&id.to_le_bytes());
    d
}

#[test]
fn udp_sender_cuts_frames_into_the_vector_fragments() {
    let file = load();
    for v in section(&file, "udp_fragmented_frames") {
        let name = text(v, "name");
        let frame = bytes(v, "frame_hex");
        let expected = byte_list(v, "fragments_hex");
        let sender = SystemId(num(v, "sender") as u16);
        let config = UdpConfig {
            datagram_payload: num(v, "datagram_payload") as usize,
            ..UdpConfig::default()
        };
        let (link, raw) = udp_sender(sender, config);
        link.send(B, &frame)
            .unwrap_or_else(|e| panic!("{name}: {e}"));
        let got = recv_datagrams(&raw, expected.len());
        // The message id is the sender's own counter (seeded from the clock): the vector's
        // stands for it. All fragments of one message carry the same one.
        let id = u32::from_le_bytes(got[0][12..16].try_into().unwrap());
        let got: Vec<Vec<u8>> = got
            .iter()
            .map(|d| with_message_id(d, num(v, "message_id") as u32))
            .collect();
        assert_eq!(
            got, expected,
            "{name}: fragments (sent with message id {id})"
        );
        assert_eq!(
            link.udp_stats().fragments_sent,
            expected.len() as u64,
            "{name}"
        );

        // The public header encoder and parser agree with every fragment.
        for (i, d) in expected.iter().enumerate() {
            let (h, piece) =
                parse_fragment(d, usize::MAX).unwrap_or_else(|e| panic!("{name}: {e}"));
            assert_eq!((h.sender, usize::from(h.index)), (sender, i), "{name}");
            assert_eq!(h.total as usize, frame.len(), "{name}");
            assert_eq!(
                h.encode(),
                d[..FRAGMENT_HEADER_LEN],
                "{name}: header encoding"
            );
            assert_eq!(piece, &d[FRAGMENT_HEADER_LEN..], "{name}");
        }
    }
}

#[test]
fn udp_receiver_reassembles_the_vector_fragments() {
    let file = load();
    for v in section(&file, "udp_fragmented_frames") {
        let name = text(v, "name");
        let frame = bytes(v, "frame_hex");
        let mut datagrams = byte_list(v, "fragments_hex");
        datagrams.reverse(); // any order will do
        let (endpoints, mut sockets) = udp_sockets(&[SystemId(num(v, "sender") as u16), B]);
        let sink = CollectSink::new();
        let link = UdpLink::with_socket(
            B,
            sockets.remove(&B).unwrap(),
            &endpoints,
            sink.clone(),
            UdpConfig::default(),
        )
        .expect("open");
        let raw = sockets.into_values().next().unwrap();
        for d in &datagrams {
            raw.send_to(d, link.local_addr()).unwrap();
        }
        assert_eq!(sink.wait_for(1, DEADLINE), 1, "{name}");
        assert_eq!(sink.frames()[0].bytes, frame, "{name}");
        wait_until("nothing held", DEADLINE, || {
            link.udp_stats().buffered_bytes == 0
        });
    }
}

#[test]
fn reassembler_follows_the_vectors() {
    let file = load();
    let src = SocketAddr::new(IpAddr::V4(Ipv4Addr::LOCALHOST), 9);
    for v in section(&file, "udp_reassembly") {
        let name = text(v, "name");
        let max_frame = num(v, "max_frame") as usize;
        let mut r = Reassembler::new(32 << 20, Duration::from_secs(2), max_frame);
        let now = Instant::now();
        let (mut frames, mut rejected, mut duplicates) = (Vec::new(), 0, 0);
        for d in byte_list(v, "datagrams_hex") {
            match r.on_fragment(&d, src, Some(A), now) {
                Reassembly::Complete(f) => frames.push(f),
                Reassembly::Pending => {}
                Reassembly::Duplicate => duplicates += 1,
                Reassembly::Rejected { .. } => rejected += 1,
            }
        }
        assert_eq!(frames, byte_list(v, "frames_hex"), "{name}: frames");
        assert_eq!(rejected, num(v, "rejected") as usize, "{name}: rejected");
        assert_eq!(
            duplicates,
            num(v, "duplicates") as usize,
            "{name}: duplicates"
        );
        assert_eq!(r.pending(), num(v, "pending") as usize, "{name}: pending");
        // Whatever is still incomplete goes at the timeout, and its memory with it.
        assert_eq!(
            r.expire(now + Duration::from_secs(2)),
            r.pending().max(num(v, "pending") as usize)
        );
        assert_eq!(r.held_bytes(), 0, "{name}");
    }
}

fn fragment_error_name(e: &FragmentError) -> &'static str {
    match e {
        FragmentError::Truncated { .. } => "Truncated",
        FragmentError::BadHeader { .. } => "BadHeader",
        FragmentError::BadGeometry { .. } => "BadGeometry",
        FragmentError::BadLength { .. } => "BadLength",
        FragmentError::Inconsistent { .. } => "Inconsistent",
        FragmentError::WrongSender { .. } => "WrongSender",
        FragmentError::UnknownSender { .. } => "UnknownSender",
        _ => "Unknown",
    }
}

#[test]
fn malformed_fragments_are_rejected_with_the_named_error() {
    let file = load();
    for v in section(&file, "udp_fragment_errors") {
        let name = text(v, "name");
        let d = bytes(v, "datagram_hex");
        let max_frame = num(v, "max_frame") as usize;
        match parse_fragment(&d, max_frame) {
            Ok(h) => panic!("{name}: parsed as {h:?}"),
            Err(e) => assert_eq!(fragment_error_name(&e), text(v, "error"), "{name}: {e}"),
        }
    }
}

#[test]
fn malformed_fragments_are_dropped_and_counted_by_a_link() {
    let file = load();
    let (link, raw, sink) = udp_receiver();
    let vectors = section(&file, "udp_fragment_errors");
    // All of them at a link with the default largest frame.
    for v in vectors {
        raw.send(&bytes(v, "datagram_hex")).unwrap();
    }
    let n = vectors.len() as u64;
    wait_until("bad fragments counted", DEADLINE, || {
        link.udp_stats().bad_datagrams >= n - 1
    });
    // total_over_max_frame is within this link's (larger) limit: a well-formed first
    // fragment, held as an incomplete message.
    assert_eq!(link.udp_stats().bad_datagrams, n - 1);
    assert!(sink.frames().is_empty());
    // Its 78-byte buffer at most, and bookkeeping.
    let held = link.udp_stats().buffered_bytes;
    assert!((26..1024).contains(&held), "{held} bytes held");
}

#[test]
fn a_fragment_naming_another_sender_is_dropped() {
    let file = load();
    let v = &section(&file, "udp_fragmented_frames")[0];
    let (link, raw, sink) = udp_receiver();
    let first = byte_list(v, "fragments_hex").remove(0);
    let (mut h, piece) = parse_fragment(&first, usize::MAX).unwrap();
    assert_eq!(h.sender, A, "sent from A's address");
    h.sender = SystemId(7);
    let d = [&h.encode()[..], piece].concat();
    raw.send(&d).unwrap();
    wait_until("the fragment rejected", DEADLINE, || {
        link.udp_stats().bad_datagrams == 1
    });
    assert!(sink.frames().is_empty());
}

#[test]
fn hellos_decode_and_encode_as_the_vectors_say() {
    let file = load();
    for v in section(&file, "stream_hellos") {
        let name = text(v, "name");
        let h: [u8; HELLO_LEN] = bytes(v, "hello_hex").try_into().expect("8 bytes");
        let system = v["system"].as_u64().map(|s| SystemId(s as u16));
        assert_eq!(decode_hello(&h), system, "{name}");
        if let Some(s) = system {
            assert_eq!(encode_hello(s), h, "{name}: encoding");
        }
    }
}

/// B's TCP link with `max_frame`, and where it listens.
fn tcp_receiver(max_frame: usize) -> (TcpLink, SocketAddr, Arc<CollectSink>) {
    let (endpoints, mut listeners) = tcp_listeners(&[A, B]);
    let sink = CollectSink::new();
    let config = StreamConfig {
        max_message_bytes: Some(max_frame - HEADER_LEN),
        ..StreamConfig::default()
    };
    let link = TcpLink::with_listener(
        B,
        listeners.remove(&B).unwrap(),
        &endpoints,
        sink.clone(),
        config,
    )
    .expect("open tcp link");
    let addr = link.local_addr();
    (link, addr, sink)
}

#[test]
fn stream_readers_hand_up_the_vector_records() {
    let file = load();
    for v in section(&file, "stream_records") {
        let name = text(v, "name");
        let stream = bytes(v, "stream_hex");
        let frames = byte_list(v, "frames_hex");
        let max_frame = num(v, "max_frame") as usize;
        let end = text(v, "end");

        // The public record-header check agrees with the vector, record by record.
        let mut rest = &stream[..];
        let mut seen = 0;
        while rest.len() >= RECORD_HEADER_LEN {
            let head: [u8; RECORD_HEADER_LEN] = rest[..RECORD_HEADER_LEN].try_into().unwrap();
            let Some(len) = decode_record_header(&head, max_frame) else {
                assert_eq!(end, "bad", "{name}: a header the reader refuses");
                break;
            };
            if rest.len() < RECORD_HEADER_LEN + len {
                break;
            }
            assert_eq!(
                rest[RECORD_HEADER_LEN..RECORD_HEADER_LEN + len],
                frames[seen],
                "{name}"
            );
            seen += 1;
            rest = &rest[RECORD_HEADER_LEN + len..];
        }
        assert_eq!(seen, frames.len(), "{name}");

        // A real reader: A's hello, the vector's bytes, the end of the stream.
        let (link, addr, sink) = tcp_receiver(max_frame);
        let mut conn = TcpStream::connect(addr).unwrap();
        conn.write_all(&encode_hello(A)).unwrap();
        conn.write_all(&stream).unwrap();
        conn.shutdown(Shutdown::Write).unwrap();
        // The reader closes its side when the stream ends, however it ends; the acceptor
        // never writes, so this read sees only that.
        conn.set_read_timeout(Some(DEADLINE)).unwrap();
        let mut none = Vec::new();
        conn.read_to_end(&mut none)
            .expect("the reader closes the connection");
        assert!(none.is_empty(), "{name}: the acceptor wrote");
        assert_eq!(
            sink.wait_for(frames.len(), DEADLINE),
            frames.len(),
            "{name}"
        );
        let got: Vec<Vec<u8>> = sink.frames().into_iter().map(|r| r.bytes).collect();
        assert_eq!(got, frames, "{name}: frames handed up");
        assert!(
            sink.frames().iter().all(|r| r.from == Peer::System(A)),
            "{name}"
        );
        let dropped = u64::from(end != "clean");
        wait_until("the end counted", DEADLINE, || {
            link.stream_stats().frames_dropped == dropped
        });
        assert_eq!(link.stream_stats().rejected_connections, 0, "{name}");
    }
}

#[test]
fn stream_readers_refuse_bad_hellos() {
    let file = load();
    for v in section(&file, "stream_hellos") {
        let name = text(v, "name");
        // A well-formed hello of a system outside the fleet is refused as well.
        let refused = v["system"].as_u64().is_none_or(|s| s != u64::from(A.0));
        let (link, addr, sink) = tcp_receiver(HEADER_LEN + 1024);
        let mut conn = TcpStream::connect(addr).unwrap();
        // The hello and a record of one byte, in one write: a refused connection may be
        // reset under a later write.
        let bytes = [
            bytes(v, "hello_hex"),
            b"HR\x01\x00\x01\x00\x00\x00x".to_vec(),
        ]
        .concat();
        let written = conn.write_all(&bytes);
        if refused {
            conn.set_read_timeout(Some(DEADLINE)).unwrap();
            let mut none = Vec::new();
            let _ = conn.read_to_end(&mut none);
            wait_until("the connection refused", DEADLINE, || {
                link.stream_stats().rejected_connections == 1
            });
            assert!(sink.frames().is_empty(), "{name}");
        } else {
            written.unwrap_or_else(|e| panic!("{name}: {e}"));
            assert_eq!(sink.wait_for(1, DEADLINE), 1, "{name}");
            assert_eq!(sink.frames()[0].bytes, b"x", "{name}");
        }
    }
}

#[test]
fn stream_senders_write_the_vector_hello_and_records() {
    let file = load();
    let hello_a = section(&file, "stream_hellos")
        .iter()
        .find(|v| v["system"].as_u64() == Some(u64::from(A.0)))
        .map(|v| bytes(v, "hello_hex"))
        .expect("a hello of system 1");
    let mut checked = 0;
    for v in section(&file, "stream_records") {
        let name = text(v, "name");
        if text(v, "end") != "clean" {
            continue; // no sender writes these
        }
        let frames = byte_list(v, "frames_hex");
        let (endpoints, mut listeners) = tcp_listeners(&[A, B]);
        let raw: TcpListener = listeners.remove(&B).unwrap();
        let config = StreamConfig {
            max_message_bytes: Some(num(v, "max_frame") as usize - HEADER_LEN),
            ..StreamConfig::default()
        };
        let link = TcpLink::with_listener(
            A,
            listeners.remove(&A).unwrap(),
            &endpoints,
            CollectSink::new(),
            config,
        )
        .expect("open tcp link");
        for f in &frames {
            link.send(B, f).unwrap_or_else(|e| panic!("{name}: {e}"));
        }
        if frames.is_empty() {
            // Nothing sent: no connection either. (The vector's stream is empty.)
            assert!(text(v, "stream_hex").is_empty());
            continue;
        }
        let (mut conn, _) = raw.accept().unwrap();
        conn.set_read_timeout(Some(DEADLINE)).unwrap();
        let expected = [hello_a.clone(), bytes(v, "stream_hex")].concat();
        let mut got = vec![0u8; expected.len()];
        conn.read_exact(&mut got)
            .unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(got, expected, "{name}: hello and records");
        checked += 1;
    }
    assert!(checked >= 4);
}
