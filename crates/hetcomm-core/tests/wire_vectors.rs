//! The language-neutral wire test vectors in `docs/wire-vectors.json`.
//!
//! * `valid_vectors_decode_and_re_encode`: every valid vector decodes to exactly the header
//!   fields and payload the file states (read from the JSON, not from the generator), and
//!   encoding that header and payload again gives the identical bytes.
//! * `invalid_vectors_are_rejected_with_the_named_error`: every invalid vector is rejected with
//!   the `DecodeError` variant the file names.
//! * `committed_vectors_match_the_generator`: the committed file is byte-for-byte what
//!   `generate()` produces, so the file cannot drift from the code.
//!
//! Regenerate the file after an intended change with
//! `cargo test -p hetcomm-core -- --ignored regenerate_wire_vectors`.

use std::path::PathBuf;

use hetcomm_core::wire::{
    self, AckPayload, FLAG_ACK_REQUESTED, FLAG_BROADCAST, FLAG_BROADCAST_SEQ, FLAG_HEADER_CRC,
    FLAG_TO_ALL, HEADER_LEN, MAX_PAYLOAD, TO_ALL_SYSTEM,
};
use hetcomm_core::{
    payload, AckStatus, Address, DecodeError, FrameKind, Header, MessageType, ModuleId, Priority,
    SystemId, Time,
};
use serde::Serialize;
use serde_json::Value;

fn vectors_path() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../docs/wire-vectors.json")
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

fn unhex(s: &str) -> Vec<u8> {
    s.as_bytes()
        .chunks(2)
        .map(|pair| {
            let digits = std::str::from_utf8(pair).expect("ASCII hex");
            assert_eq!(digits.len(), 2, "odd-length hex string");
            u8::from_str_radix(digits, 16).expect("hex digit")
        })
        .collect()
}

fn addr(system: u16, module: u16) -> Address {
    Address {
        system: SystemId(system),
        module: ModuleId(module),
    }
}

/// The name of a decode error's variant, as the vectors spell it.
fn error_name(e: &DecodeError) -> &'static str {
    match e {
        DecodeError::TooShort { .. } => "TooShort",
        DecodeError::BadMagic { .. } => "BadMagic",
        DecodeError::BadVersion { .. } => "BadVersion",
        DecodeError::BadKind { .. } => "BadKind",
        DecodeError::BadFlags { .. } => "BadFlags",
        DecodeError::TooLong { .. } => "TooLong",
        DecodeError::LengthMismatch { .. } => "LengthMismatch",
        DecodeError::BadChecksum { .. } => "BadChecksum",
        _ => "Unknown",
    }
}

// ---------------------------------------------------------------------------------------------
// The generator
// ---------------------------------------------------------------------------------------------

#[derive(Serialize)]
struct Wheels {
    left: f64,
    right: f64,
}

#[derive(Serialize)]
enum Mode {
    Explore,
}

#[derive(Serialize)]
enum Goal {
    Waypoint { x: f64, y: f64 },
}

/// A payload that exercises most shapes: string, tuple, vector, options, enums, bytes, map.
#[derive(Serialize)]
struct Status {
    name: String,
    pose: (f64, f64, f32),
    battery: Option<f32>,
    fault: Option<String>,
    mode: Mode,
    goal: Goal,
    tags: Vec<String>,
    #[serde(with = "serde_bytes")]
    raw: Vec<u8>,
    counters: std::collections::BTreeMap<String, u64>,
    uptime_us: u64,
    temperature: i8,
}

/// One valid vector, fields in the order the file shows them.
#[derive(Serialize)]
struct ValidVector {
    name: String,
    description: String,
    frame_hex: String,
    header: HeaderOut,
    payload_hex: String,
    payload_json: Value,
    #[serde(skip_serializing_if = "Option::is_none")]
    ack_status: Option<AckStatus>,
    /// An ACK range's first seq (the nine-byte payload; "ACK ranges").
    #[serde(skip_serializing_if = "Option::is_none")]
    ack_first: Option<u64>,
}

/// The header as the file shows it: every field as a plain number.
#[derive(Serialize)]
struct HeaderOut {
    kind: u8,
    flags: u8,
    priority: u8,
    transport: u8,
    source: AddressOut,
    destination: AddressOut,
    incarnation: u32,
    seq: u64,
    message_type: u32,
    timestamp: u64,
    payload_len: usize,
}

#[derive(Serialize)]
struct AddressOut {
    system: u16,
    module: u16,
}

impl From<Address> for AddressOut {
    fn from(a: Address) -> Self {
        AddressOut {
            system: a.system.0,
            module: a.module.0,
        }
    }
}

/// One invalid vector.
#[derive(Serialize)]
struct InvalidVector {
    name: String,
    description: String,
    frame_hex: String,
    error: String,
}

/// The whole file.
#[derive(Serialize)]
struct VectorFile {
    format: &'static str,
    generated_by: &'static str,
    valid: Vec<ValidVector>,
    invalid: Vec<InvalidVector>,
    udp_datagrams: Vec<DatagramVector>,
    udp_fragmented_frames: Vec<FragmentedVector>,
    udp_reassembly: Vec<ReassemblyVector>,
    udp_fragment_errors: Vec<FragmentErrorVector>,
    stream_hellos: Vec<HelloVector>,
    stream_records: Vec<RecordsVector>,
}

/// A UDP datagram that is not a fragment, and what the receiving link hands up.
#[derive(Serialize)]
struct DatagramVector {
    name: String,
    description: String,
    datagram_hex: String,
    /// "whole" (handed up as it is), "batch" (split into frames) or "dropped" (a batch header
    /// the receiver does not read: nothing is handed up).
    handling: &'static str,
    frames_hex: Vec<String>,
    /// The malformed tail of a batch, dropped (and the datagram counted as bad); "" if none.
    dropped_tail_hex: String,
}

/// A frame the UDP sender cuts into fragments, and the datagrams it sends.
#[derive(Serialize)]
struct FragmentedVector {
    name: String,
    description: String,
    datagram_payload: usize,
    sender: u16,
    message_id: u32,
    frame_hex: String,
    fragments_hex: Vec<String>,
}

/// Fragment datagrams arriving (from one address) and what reassembly makes of them.
#[derive(Serialize)]
struct ReassemblyVector {
    name: String,
    description: String,
    max_frame: usize,
    datagrams_hex: Vec<String>,
    frames_hex: Vec<String>,
    rejected: usize,
    duplicates: usize,
    pending: usize,
}

/// A malformed fragment datagram.
#[derive(Serialize)]
struct FragmentErrorVector {
    name: String,
    description: String,
    max_frame: usize,
    datagram_hex: String,
    error: &'static str,
}

/// A stream hello and the system it names (None: the connection is refused).
#[derive(Serialize)]
struct HelloVector {
    name: String,
    description: String,
    hello_hex: String,
    system: Option<u16>,
}

/// The bytes of a stream after the hello, the frames a reader hands up and how it ends.
#[derive(Serialize)]
struct RecordsVector {
    name: String,
    description: String,
    max_frame: usize,
    stream_hex: String,
    frames_hex: Vec<String>,
    /// "clean" (ends between records), "cut" (ends inside a record) or "bad" (a malformed or
    /// oversized record header: the reader drops the connection).
    end: &'static str,
}

fn valid(name: &str, description: &str, h: Header, payload: &[u8]) -> ValidVector {
    let frame = wire::encode(&h, payload);
    let (payload_json, ack_status, ack_first) = match h.kind {
        FrameKind::Ack => {
            let ack = AckPayload::parse(payload, h.seq).expect("ack vectors carry a valid payload");
            let first = (payload.len() == 9).then_some(ack.first);
            (Value::Null, Some(ack.status), first)
        }
        FrameKind::Data => (payload::to_json(payload).unwrap_or(Value::Null), None, None),
    };
    ValidVector {
        name: name.into(),
        description: description.into(),
        frame_hex: hex(&frame),
        header: HeaderOut {
            kind: h.kind as u8,
            flags: h.flags,
            priority: h.priority.0,
            transport: h.transport,
            source: h.source.into(),
            destination: h.destination.into(),
            incarnation: h.incarnation,
            seq: h.seq,
            message_type: h.message_type.0,
            timestamp: h.timestamp.0,
            payload_len: payload.len(),
        },
        payload_hex: hex(payload),
        payload_json,
        ack_status,
        ack_first,
    }
}

/// Rewrites the CRC field so that the frame's only defect is the one the caller made.
fn fix_crc(frame: &mut [u8]) {
    let mut h = crc32fast::Hasher::new();
    h.update(&frame[..44]);
    h.update(&[0; 4]);
    h.update(&frame[48..]);
    let crc = h.finalize();
    frame[44..48].copy_from_slice(&crc.to_le_bytes());
}

fn invalid(name: &str, description: &str, frame: &[u8], error: &str) -> InvalidVector {
    InvalidVector {
        name: name.into(),
        description: description.into(),
        frame_hex: hex(frame),
        error: error.into(),
    }
}

/// The data frame of the worked example in `docs/wire-format.md`.
fn wheels_header() -> Header {
    Header {
        kind: FrameKind::Data,
        flags: FLAG_ACK_REQUESTED,
        priority: Priority::NORMAL,
        transport: b'R',
        source: addr(1, 2),
        destination: addr(3, 4),
        incarnation: 0x1234_5678,
        seq: 1,
        message_type: MessageType(1),
        timestamp: Time(1_700_000_000_000_000),
    }
}

fn ack_of(data: &Header) -> Header {
    Header {
        kind: FrameKind::Ack,
        flags: 0,
        priority: data.priority,
        transport: data.transport,
        source: data.destination,
        destination: data.source,
        incarnation: data.incarnation,
        seq: data.seq,
        message_type: data.message_type,
        timestamp: data.timestamp,
    }
}

/// Builds the whole vector file.
fn generate() -> VectorFile {
    let wheels = payload::encode(&Wheels {
        left: -10.0,
        right: 10.0,
    })
    .expect("encodes");
    let wheels_h = wheels_header();

    let status = Status {
        name: "scout-1".into(),
        pose: (1.5, -2.25, 0.5),
        battery: Some(0.75),
        fault: None,
        mode: Mode::Explore,
        goal: Goal::Waypoint { x: 10.0, y: -3.5 },
        tags: vec!["lidar".into(), "gps".into()],
        raw: vec![0x00, 0x7f, 0x80, 0xff],
        counters: [("rx".to_string(), 300u64), ("tx".to_string(), 70_000)].into(),
        uptime_us: 5_000_000_000,
        temperature: -12,
    };
    let status_payload = payload::encode(&status).expect("encodes");

    let broadcast_h = Header {
        kind: FrameKind::Data,
        flags: FLAG_ACK_REQUESTED | FLAG_BROADCAST,
        priority: Priority(150),
        transport: b'U',
        source: addr(2, 1),
        destination: addr(5, 3),
        incarnation: 7,
        seq: 42,
        message_type: MessageType(20),
        timestamp: Time(123_456_789),
    };
    // A native broadcast: one frame for every system, numbered in the sender's broadcast space.
    let to_all_h = Header {
        flags: FLAG_ACK_REQUESTED | FLAG_BROADCAST | FLAG_BROADCAST_SEQ | FLAG_TO_ALL,
        transport: b'Z',
        destination: Address {
            system: TO_ALL_SYSTEM,
            module: ModuleId(3),
        },
        seq: 1,
        ..broadcast_h
    };
    // Its retransmission to system 5 alone, and system 5's acknowledgement.
    let to_all_copy_h = Header {
        flags: FLAG_ACK_REQUESTED | FLAG_BROADCAST | FLAG_BROADCAST_SEQ,
        destination: addr(5, 3),
        ..to_all_h
    };
    let to_all_ack_h = Header {
        flags: FLAG_BROADCAST_SEQ,
        ..ack_of(&to_all_copy_h)
    };
    let empty_h = Header {
        kind: FrameKind::Data,
        flags: 0,
        priority: Priority::LOWEST,
        transport: 0,
        source: addr(0, 0),
        destination: addr(1, 0),
        incarnation: 0,
        seq: 1,
        message_type: MessageType(0),
        timestamp: Time::ZERO,
    };
    let max_priority_h = Header {
        priority: Priority::HIGHEST,
        flags: FLAG_ACK_REQUESTED,
        transport: b'W',
        seq: 2,
        timestamp: Time(1_700_000_000_250_000),
        ..wheels_h
    };
    let large_h = Header {
        kind: FrameKind::Data,
        flags: 0,
        priority: Priority(254),
        transport: 0xff,
        source: addr(u16::MAX, u16::MAX - 1),
        destination: addr(u16::MAX - 2, u16::MAX - 3),
        incarnation: u32::MAX,
        seq: u64::MAX,
        message_type: MessageType(u32::MAX),
        timestamp: Time(u64::MAX),
    };
    let large_payload = payload::encode(&(u64::MAX, i64::MIN, u32::MAX)).expect("encodes");
    let header_crc_h = Header {
        flags: FLAG_ACK_REQUESTED | FLAG_HEADER_CRC,
        ..wheels_h
    };

    let mut valid_vectors = vec![
        valid(
            "data_struct_wheels",
            "The worked example of docs/wire-format.md: Wheels { left: -10.0, right: 10.0 }, \
             message type 1, from (1, 2) to (3, 4), acknowledgement requested.",
            wheels_h,
            &wheels,
        ),
        valid(
            "data_struct_many_shapes",
            "A struct payload using string, tuple, Option (Some and None), unit and struct enum \
             variants, Vec<String>, serde_bytes (bin), a map, a large u64 and a negative i8.",
            Header {
                seq: 3,
                message_type: MessageType(2),
                ..wheels_h
            },
            &status_payload,
        ),
        valid(
            "data_broadcast_ack_requested",
            "One copy of a broadcast with an acknowledgement requested (flags 0x03). The \
             payload is the string \"hello\".",
            broadcast_h,
            &payload::encode("hello").expect("encodes"),
        ),
    ];
    for (status, name) in [
        (AckStatus::Delivered, "ack_delivered"),
        (AckStatus::InboxFull, "ack_inbox_full"),
        (AckStatus::UnknownModule, "ack_unknown_module"),
    ] {
        valid_vectors.push(valid(
            name,
            &format!(
                "An acknowledgement of data_struct_wheels with status {} ({status:?}): source \
                 and destination swapped, incarnation and seq echoed (priority, transport, \
                 message type and timestamp too, as the router does); the one-byte payload is \
                 the status.",
                status as u8
            ),
            ack_of(&wheels_h),
            &[status as u8],
        ));
    }
    // An ACK range: data_struct_wheels's sender's frames 2 to 5 all delivered, in one ACK.
    let mut range_payload = vec![AckStatus::Delivered as u8];
    range_payload.extend_from_slice(&2u64.to_le_bytes());
    valid_vectors.push(valid(
        "ack_range_delivered",
        "An ACK range (\"ACK ranges\"): the acknowledgement of data_struct_wheels's sender's \
         frames 2, 3, 4 and 5, all delivered, in one frame. The header is the ACK of the \
         last (seq 5); the nine-byte payload is the status (0, delivered) and then first = 2 \
         (u64 little-endian).",
        Header {
            seq: 5,
            ..ack_of(&wheels_h)
        },
        &range_payload,
    ));
    valid_vectors.extend([
        valid(
            "ack_of_broadcast",
            "An acknowledgement (delivered) of data_broadcast_ack_requested's copy.",
            ack_of(&broadcast_h),
            &[AckStatus::Delivered as u8],
        ),
        valid(
            "data_broadcast_to_all",
            "A native broadcast: one frame that every system on the transport receives (one \
             Zenoh put on `<prefix>/all`). Flags 0x1b: acknowledgement requested, broadcast, \
             FLAG_BROADCAST_SEQ (seq 1 counts in system 2's broadcast space) and FLAG_TO_ALL \
             (destination.system is written 65535 and means every system; the module is \
             used). The payload is the string \"hello\".",
            to_all_h,
            &payload::encode("hello").expect("encodes"),
        ),
        valid(
            "data_broadcast_copy",
            "The retransmission of data_broadcast_to_all to system 5 alone, which did not \
             acknowledge it: FLAG_TO_ALL cleared and destination.system 5; still \
             FLAG_BROADCAST_SEQ and seq 1, so a receiver that had the original after all \
             suppresses it as a duplicate (flags 0x0b).",
            to_all_copy_h,
            &payload::encode("hello").expect("encodes"),
        ),
        valid(
            "ack_of_broadcast_to_all",
            "System 5's acknowledgement (delivered) of data_broadcast_to_all or of its copy: \
             flags 0x08 (FLAG_BROADCAST_SEQ: the seq is in the sender's broadcast space), \
             source the acknowledging system (never 65535), destination the broadcast's \
             sender.",
            to_all_ack_h,
            &[AckStatus::Delivered as u8],
        ),
        valid(
            "data_empty_payload",
            "A data frame with no payload bytes at all (payload_len 0): all-zero ids, lowest \
             priority, no flags. payload_json is null because zero bytes are not a \
             MessagePack value.",
            empty_h,
            &[],
        ),
        valid(
            "data_nil_payload",
            "A data frame whose payload is the single MessagePack nil (a unit value or None).",
            Header { seq: 2, ..empty_h },
            &payload::encode(&()).expect("encodes"),
        ),
        valid(
            "data_max_priority",
            "Priority 255 (the highest), transport tag 'W'.",
            max_priority_h,
            &payload::encode(&Wheels {
                left: 0.0,
                right: 0.0,
            })
            .expect("encodes"),
        ),
        valid(
            "data_large_ids",
            "Every id field near or at its maximum: systems and modules 65532..65535, \
             incarnation, seq, message type and timestamp all-ones. The payload is the array \
             [u64::MAX, i64::MIN, u32::MAX]. (JavaScript readers need a big-integer JSON \
             parser for this vector.)",
            large_h,
            &large_payload,
        ),
        valid(
            "data_header_crc",
            "data_struct_wheels as a sender writes it on a link that checks the payload itself \
             (TCP): flags 0x05 (acknowledgement requested, FLAG_HEADER_CRC), so the CRC covers \
             the 48 header bytes only (with the CRC field as zero), not the payload.",
            header_crc_h,
            &wheels,
        ),
    ]);

    let good = wire::encode(&wheels_h, &wheels);
    let mut invalid_vectors = vec![
        invalid("empty", "No bytes at all.", &[], "TooShort"),
        invalid(
            "truncated_header",
            "The first 47 bytes of data_struct_wheels: one byte short of a header.",
            &good[..HEADER_LEN - 1],
            "TooShort",
        ),
    ];
    let mut truncated = good[..good.len() - 1].to_vec();
    fix_crc(&mut truncated);
    invalid_vectors.push(invalid(
        "truncated_payload",
        "data_struct_wheels without its last payload byte (CRC recomputed): the header \
         declares 30 payload bytes, 29 are present.",
        &truncated,
        "LengthMismatch",
    ));
    let mut trailing = good.clone();
    trailing.push(0xc0);
    fix_crc(&mut trailing);
    invalid_vectors.push(invalid(
        "trailing_byte",
        "data_struct_wheels followed by one extra byte (CRC recomputed over all of it): a \
         frame is exactly header plus declared payload.",
        &trailing,
        "LengthMismatch",
    ));
    let mutations: [(&str, &str, usize, u8, &str); 8] = [
        (
            "bad_magic",
            "Magic \"hC\" instead of \"HC\".",
            0,
            b'h',
            "BadMagic",
        ),
        (
            "bad_magic_second_byte",
            "Magic \"HX\".",
            1,
            b'X',
            "BadMagic",
        ),
        ("bad_version_0", "Version 0.", 2, 0, "BadVersion"),
        (
            "bad_version_2",
            "Version 2, from a future codec.",
            2,
            2,
            "BadVersion",
        ),
        (
            "bad_kind",
            "Frame kind 2, which version 1 does not define.",
            3,
            2,
            "BadKind",
        ),
        ("bad_kind_high", "Frame kind 255.", 3, 0xff, "BadKind"),
        (
            "unknown_flag_bit",
            "Flags 0x21: bit 5 is not defined.",
            4,
            0x21,
            "BadFlags",
        ),
        ("unknown_flag_high_bit", "Flags 0x80.", 4, 0x80, "BadFlags"),
    ];
    for (name, description, offset, byte, error) in mutations {
        let mut frame = good.clone();
        frame[offset] = byte;
        fix_crc(&mut frame);
        invalid_vectors.push(invalid(
            name,
            &format!(
                "data_struct_wheels with byte {offset} changed (CRC recomputed). {description}"
            ),
            &frame,
            error,
        ));
    }
    let mut oversized = good[..HEADER_LEN].to_vec();
    oversized[40..44].copy_from_slice(&((MAX_PAYLOAD + 1) as u32).to_le_bytes());
    fix_crc(&mut oversized);
    invalid_vectors.push(invalid(
        "oversized_length",
        "A lone header declaring MAX_PAYLOAD + 1 = 16777217 payload bytes (CRC recomputed): \
         rejected from the header alone, before waiting for or allocating the payload.",
        &oversized,
        "TooLong",
    ));
    let mut max_len = good[..HEADER_LEN].to_vec();
    max_len[40..44].copy_from_slice(&u32::MAX.to_le_bytes());
    fix_crc(&mut max_len);
    invalid_vectors.push(invalid(
        "length_all_ones",
        "A lone header declaring 0xffffffff payload bytes (CRC recomputed).",
        &max_len,
        "TooLong",
    ));
    let mut mismatch = good.clone();
    mismatch[40..44].copy_from_slice(&31u32.to_le_bytes());
    fix_crc(&mut mismatch);
    invalid_vectors.push(invalid(
        "length_mismatch",
        "data_struct_wheels with its payload length field raised from 30 to 31 (CRC \
         recomputed).",
        &mismatch,
        "LengthMismatch",
    ));
    let mut bad_crc = good.clone();
    bad_crc[44] ^= 0x01;
    invalid_vectors.push(invalid(
        "bad_checksum",
        "data_struct_wheels with the lowest bit of its CRC field flipped.",
        &bad_crc,
        "BadChecksum",
    ));
    let mut flipped = good.clone();
    flipped[HEADER_LEN + 5] ^= 0x80;
    invalid_vectors.push(invalid(
        "payload_bit_flip",
        "data_struct_wheels with one payload bit flipped and the CRC left alone.",
        &flipped,
        "BadChecksum",
    ));
    let mut zero_crc = good.clone();
    zero_crc[44..48].copy_from_slice(&[0; 4]);
    invalid_vectors.push(invalid(
        "checksum_zero",
        "data_struct_wheels with a zero CRC field: the CRC is never optional.",
        &zero_crc,
        "BadChecksum",
    ));
    let mut reserved = good.clone();
    reserved[7] = 1;
    invalid_vectors.push(invalid(
        "reserved_byte_set_without_crc_fix",
        "data_struct_wheels with reserved byte 7 set to 1 and the CRC left alone. (Version 1 \
         decoders ignore the reserved byte's value, so this is caught only by the CRC.)",
        &reserved,
        "BadChecksum",
    ));
    let header_crc = wire::encode(&header_crc_h, &wheels);
    let mut corrupted = header_crc.clone();
    corrupted[20] ^= 0x01;
    invalid_vectors.push(invalid(
        "header_crc_header_corrupted",
        "data_header_crc with the lowest bit of its seq field flipped and the CRC left alone: \
         with FLAG_HEADER_CRC the header is still checksummed.",
        &corrupted,
        "BadChecksum",
    ));
    let mut cleared = header_crc.clone();
    cleared[4] &= !FLAG_HEADER_CRC;
    invalid_vectors.push(invalid(
        "header_crc_flag_cleared",
        "data_header_crc with FLAG_HEADER_CRC cleared (flags 0x01) and the CRC left alone: the \
         decoder now checks a CRC over the whole frame, which the sender did not compute.",
        &cleared,
        "BadChecksum",
    ));
    let mut short = header_crc.clone();
    short.pop();
    invalid_vectors.push(invalid(
        "header_crc_truncated_payload",
        "data_header_crc without its last payload byte (the header and its CRC are intact): \
         lengths are checked whatever the flags.",
        &short,
        "LengthMismatch",
    ));
    // Order of checks: two defects, the earlier check wins.
    let mut two = good.clone();
    two[2] = 9;
    two[44] ^= 0xff;
    invalid_vectors.push(invalid(
        "order_version_before_checksum",
        "Version 9 and a wrong CRC: the version check comes first.",
        &two,
        "BadVersion",
    ));
    let mut two = good[..HEADER_LEN].to_vec();
    two[0] = b'X';
    two[40..44].copy_from_slice(&u32::MAX.to_le_bytes());
    invalid_vectors.push(invalid(
        "order_magic_before_length",
        "Bad magic and an oversized length: the magic check comes first.",
        &two,
        "BadMagic",
    ));
    let mut two = good.clone();
    two[3] = 7;
    two.push(0);
    invalid_vectors.push(invalid(
        "order_length_before_kind",
        "Kind 7 and a trailing byte: the length check comes before the kind check.",
        &two,
        "LengthMismatch",
    ));
    let mut two = good.clone();
    two[3] = 7;
    two[4] = 0x10;
    invalid_vectors.push(invalid(
        "order_kind_before_flags",
        "Kind 7 and flags 0x10 (CRC not fixed): the kind check comes before the flags check, \
         both before the CRC.",
        &two,
        "BadKind",
    ));

    let ack = wire::encode(&ack_of(&wheels_h), &[AckStatus::Delivered as u8]);
    let broadcast = wire::encode(&broadcast_h, &payload::encode("hello").expect("encodes"));
    let frames = LinkFrames {
        wheels: good,
        ack,
        broadcast,
        header_crc,
    };
    VectorFile {
        format: "hetcomm wire format version 1; see docs/wire-format.md",
        generated_by: "cargo test -p hetcomm-core -- --ignored regenerate_wire_vectors",
        valid: valid_vectors,
        invalid: invalid_vectors,
        udp_datagrams: udp_datagram_vectors(&frames),
        udp_fragmented_frames: fragmented_vectors(&frames),
        udp_reassembly: reassembly_vectors(&frames),
        udp_fragment_errors: fragment_error_vectors(&frames),
        stream_hellos: hello_vectors(),
        stream_records: record_vectors(&frames),
    }
}

// ---------------------------------------------------------------------------------------------
// Link framing (docs/wire-format.md, "On the links"), encoded here from the spec
// ---------------------------------------------------------------------------------------------
//
// hetcomm-core cannot use hetcomm-link-ip (which depends on it), so these bytes are built from
// the document alone; crates/hetcomm-link-ip/tests/wire_vectors.rs checks the real UDP and
// stream encoders and decoders against the committed file.

/// The default largest frame of a UDP or stream link: the 48-byte header plus MAX_PAYLOAD.
const DEFAULT_MAX_FRAME: usize = HEADER_LEN + MAX_PAYLOAD;
const FRAGMENT_HEADER_LEN: usize = 20;
const RECORD_HEADER_LEN: usize = 8;

/// Frames the link vectors carry.
struct LinkFrames {
    /// data_struct_wheels.
    wheels: Vec<u8>,
    /// ack_delivered.
    ack: Vec<u8>,
    /// data_broadcast_ack_requested.
    broadcast: Vec<u8>,
    /// data_header_crc.
    header_crc: Vec<u8>,
}

/// A data frame from (1, 2) to (3, 4) whose payload is `payload`.
fn frame_with_payload(seq: u64, payload: &[u8]) -> Vec<u8> {
    wire::encode(
        &Header {
            seq,
            message_type: MessageType(9),
            ..wheels_header()
        },
        payload,
    )
}

/// A 100-byte data frame: its payload is a 50-character MessagePack string (str 8).
fn hundred_byte_frame() -> Vec<u8> {
    let mut payload = vec![0xd9, 50];
    payload.extend((0..50u8).map(|i| b'a' + i % 26));
    let f = frame_with_payload(4, &payload);
    assert_eq!(f.len(), 100);
    f
}

/// One fragment datagram: the 20-byte fragment header and the piece.
fn fragment(
    sender: u16,
    index: u16,
    count: u16,
    message_id: u32,
    total: u32,
    piece: &[u8],
) -> Vec<u8> {
    let mut d = Vec::with_capacity(FRAGMENT_HEADER_LEN + piece.len());
    d.extend_from_slice(b"HF");
    d.extend_from_slice(&[1, 0]);
    d.extend_from_slice(&sender.to_le_bytes());
    d.extend_from_slice(&index.to_le_bytes());
    d.extend_from_slice(&count.to_le_bytes());
    d.extend_from_slice(&[0, 0]);
    d.extend_from_slice(&message_id.to_le_bytes());
    d.extend_from_slice(&total.to_le_bytes());
    d.extend_from_slice(piece);
    d
}

/// The fragments a sender with `datagram_payload`-byte datagrams cuts `frame` into: as few as
/// fit, pieces cut evenly.
fn fragments(frame: &[u8], datagram_payload: usize, sender: u16, message_id: u32) -> Vec<Vec<u8>> {
    let total = frame.len();
    let count = total
        .div_ceil(datagram_payload - FRAGMENT_HEADER_LEN)
        .max(1);
    let chunk = total.div_ceil(count);
    (0..count)
        .map(|i| {
            let piece = &frame[i * chunk..((i + 1) * chunk).min(total)];
            fragment(
                sender,
                i as u16,
                count as u16,
                message_id,
                total as u32,
                piece,
            )
        })
        .collect()
}

fn hello(system: u16) -> Vec<u8> {
    let mut h = b"HL\x01\x00".to_vec();
    h.extend_from_slice(&system.to_le_bytes());
    h.extend_from_slice(&[0, 0]);
    h
}

fn record(frame: &[u8]) -> Vec<u8> {
    let mut r = b"HR\x01\x00".to_vec();
    r.extend_from_slice(&(frame.len() as u32).to_le_bytes());
    r.extend_from_slice(frame);
    r
}

fn hexes(frames: &[&[u8]]) -> Vec<String> {
    frames.iter().map(|f| hex(f)).collect()
}

/// A batch datagram holding `frames` as records, as the sender writes it.
fn udp_batch(frames: &[&[u8]]) -> Vec<u8> {
    let mut d = b"HB\x01\x00".to_vec();
    for f in frames {
        d.extend_from_slice(&(f.len() as u32).to_le_bytes());
        d.extend_from_slice(f);
    }
    d
}

fn datagram(
    name: &str,
    description: &str,
    datagram: &[u8],
    frames: &[&[u8]],
    dropped_tail: &[u8],
) -> DatagramVector {
    let handling = if !datagram.starts_with(b"HB") {
        "whole"
    } else if frames.is_empty() && dropped_tail.is_empty() {
        "dropped"
    } else {
        "batch"
    };
    DatagramVector {
        name: name.into(),
        description: description.into(),
        datagram_hex: hex(datagram),
        handling,
        frames_hex: hexes(frames),
        dropped_tail_hex: hex(dropped_tail),
    }
}

fn udp_datagram_vectors(f: &LinkFrames) -> Vec<DatagramVector> {
    let (wheels, ack) = (&f.wheels[..], &f.ack[..]);
    let mut bad_crc = f.wheels.clone();
    bad_crc[44] ^= 0x01;
    let second = frame_with_payload(2, &payload::encode(&7u8).expect("encodes"));
    let cat = |parts: &[&[u8]]| parts.concat();
    let b = |frames: &[&[u8]]| udp_batch(frames);
    let mut other_version = b(&[wheels]);
    other_version[2] = 2;
    let sealed: &[u8] = b"\x8f\x02 sealed bytes, no wire frame";
    vec![
        datagram(
            "whole_data_frame",
            "data_struct_wheels alone in a datagram: the usual case for a frame that fits.",
            wheels,
            &[wheels],
            &[],
        ),
        datagram(
            "whole_ack_frame",
            "ack_delivered alone in a datagram.",
            ack,
            &[ack],
            &[],
        ),
        datagram(
            "batch_data_and_ack",
            "A batch: the header \"HB\" 01 00, then data_struct_wheels and ack_delivered as \
             records (a u32 length, then the frame). This is how an acknowledgement rides \
             along with data going the same way (the runtime holds both for the peer and they \
             leave in one datagram); each is an ordinary frame.",
            &b(&[wheels, ack]),
            &[wheels, ack],
            &[],
        ),
        datagram(
            "batch_of_three",
            "A batch of ack_delivered, data_broadcast_ack_requested and a data frame whose \
             payload is 7.",
            &b(&[ack, &f.broadcast, &second]),
            &[ack, &f.broadcast, &second],
            &[],
        ),
        datagram(
            "batch_with_a_corrupt_frame",
            "A batch whose middle frame has a wrong CRC: the link splits records by their \
             lengths only and hands all three up; the router's decoder then drops the middle \
             one (BadChecksum).",
            &b(&[wheels, &bad_crc, ack]),
            &[wheels, &bad_crc, ack],
            &[],
        ),
        datagram(
            "batch_of_bytes_that_are_no_frames",
            "A batch of a record of 30 opaque bytes (what a layer sealing frames would hand \
             the link), an empty record and data_struct_wheels: records carry any bytes, and \
             the link never looks inside them.",
            &b(&[sealed, &[], wheels]),
            &[sealed, &[], wheels],
            &[],
        ),
        datagram(
            "batch_trailing_byte",
            "A batch of data_struct_wheels followed by one stray byte, too few for a record \
             length: the frame is handed up, the byte is dropped and the datagram counted as \
             bad.",
            &cat(&[&b(&[wheels]), &[0xc0]]),
            &[wheels],
            &[0xc0],
        ),
        datagram(
            "batch_truncated_last_frame",
            "A batch of data_struct_wheels and a record announcing 78 bytes of which only 60 \
             follow: that record is dropped.",
            &b(&[wheels, wheels])[..4 + 82 + 4 + 60],
            &[wheels],
            &cat(&[&78u32.to_le_bytes(), &wheels[..60]]),
        ),
        datagram(
            "batch_huge_length",
            "A batch of ack_delivered and a record whose length is 0xffffffff: dropped (no \
             receiver allocates for it; the datagram holds all there is).",
            &cat(&[&b(&[ack]), &[0xff; 4], b"rest"]),
            &[ack],
            &cat(&[&[0xff; 4], b"rest"]),
        ),
        datagram(
            "batch_bad_version",
            "A batch header with version 2: this version reads none of it; the datagram is \
             dropped and counted as bad.",
            &other_version,
            &[],
            &[],
        ),
        datagram(
            "whole_frames_back_to_back",
            "data_struct_wheels and ack_delivered back to back without a batch header (how \
             batches looked before \"HB\"): not a batch, handed up whole as one frame, which \
             the router's decoder rejects (LengthMismatch).",
            &cat(&[wheels, ack]),
            &[&cat(&[wheels, ack])],
            &[],
        ),
        datagram(
            "whole_frame_with_trailing_byte",
            "data_struct_wheels plus one stray byte: handed up whole (the link reads no frame \
             header); the decoder rejects it (LengthMismatch).",
            &cat(&[wheels, &[0xc0]]),
            &[&cat(&[wheels, &[0xc0]])],
            &[],
        ),
        datagram(
            "whole_truncated_frame",
            "data_struct_wheels without its last byte: handed up whole; the router's decoder \
             rejects it (LengthMismatch).",
            &wheels[..wheels.len() - 1],
            &[&wheels[..wheels.len() - 1]],
            &[],
        ),
        datagram(
            "whole_not_a_frame",
            "Twelve ASCII bytes: not a fragment, not a batch, handed up whole (the decoder \
             rejects it: BadMagic).",
            b"hello, world",
            &[b"hello, world"],
            &[],
        ),
        datagram(
            "whole_empty",
            "An empty datagram: handed up as a zero-byte frame (the decoder rejects it: \
             TooShort).",
            &[],
            &[&[]],
            &[],
        ),
    ]
}

fn fragmented(
    name: &str,
    description: &str,
    frame: &[u8],
    datagram_payload: usize,
    message_id: u32,
) -> FragmentedVector {
    FragmentedVector {
        name: name.into(),
        description: description.into(),
        datagram_payload,
        sender: 1,
        message_id,
        frame_hex: hex(frame),
        fragments_hex: fragments(frame, datagram_payload, 1, message_id)
            .iter()
            .map(|d| hex(d))
            .collect(),
    }
}

fn big_frame() -> Vec<u8> {
    // bin 16 of 2949 bytes: a 2952-byte payload, a 3000-byte frame.
    let mut payload = vec![0xc5, 0x0b, 0x85];
    payload.extend((0..2949u32).map(|i| (i * 7 % 251) as u8));
    let f = frame_with_payload(5, &payload);
    assert_eq!(f.len(), 3000);
    f
}

fn fragmented_vectors(f: &LinkFrames) -> Vec<FragmentedVector> {
    vec![
        fragmented(
            "wheels_in_three",
            "data_struct_wheels (78 bytes) from system 1 over a link with 50-byte datagrams: \
             pieces of at most 30 bytes, so 3 fragments; cut evenly, 26 bytes each.",
            &f.wheels,
            50,
            0x0102_0304,
        ),
        fragmented(
            "uneven_pieces",
            "A 100-byte frame over 60-byte datagrams: pieces of at most 40 bytes, so 3 \
             fragments of ceil(100 / 3) = 34, 34 and 32 bytes.",
            &hundred_byte_frame(),
            60,
            7,
        ),
        fragmented(
            "default_datagrams",
            "A 3000-byte frame over the default 1472-byte datagrams (1452-byte pieces): 3 \
             fragments of 1000 bytes. The message id is near the top of its range; ids wrap.",
            &big_frame(),
            1472,
            0xffff_fffe,
        ),
        fragmented(
            "one_fragment_hb_bytes",
            "Bytes starting with \"HB\" (no frame; links carry any bytes). They fit a \
             datagram, but a datagram of their own would be read as a batch, so the sender \
             sends them as a message of one fragment, which the receiver hands up whole.",
            b"HB is not a batch",
            1472,
            42,
        ),
        fragmented(
            "one_fragment_hf_bytes",
            "Bytes starting with \"HF\" (no frame; links carry any bytes): sent as a message \
             of one fragment so that the receiver does not take them for a fragment header.",
            b"HF is not a fragment",
            1472,
            43,
        ),
    ]
}

/// The counts after the frames: `rejected`, `duplicates`, `pending`, in the JSON's order.
#[allow(clippy::too_many_arguments)]
fn reassembly(
    name: &str,
    description: &str,
    max_frame: usize,
    datagrams: &[&[u8]],
    frames: &[&[u8]],
    rejected: usize,
    duplicates: usize,
    pending: usize,
) -> ReassemblyVector {
    ReassemblyVector {
        name: name.into(),
        description: description.into(),
        max_frame,
        datagrams_hex: hexes(datagrams),
        frames_hex: hexes(frames),
        rejected,
        duplicates,
        pending,
    }
}

fn reassembly_vectors(f: &LinkFrames) -> Vec<ReassemblyVector> {
    let w = fragments(&f.wheels, 50, 1, 1);
    let hundred = hundred_byte_frame();
    let h = fragments(&hundred, 60, 1, 2);
    let mut trailing = f.wheels.clone();
    trailing.push(0xc0);
    let one = fragments(&trailing, 1472, 1, 3);
    // Same message id as `w`, another total: the message is inconsistent.
    let other = fragments(&hundred, 60, 1, 1);
    let mut long_piece = w[1].clone();
    long_piece.push(0);
    let m = DEFAULT_MAX_FRAME;
    vec![
        reassembly(
            "in_order",
            "The fragments of wheels_in_three (message id 1) in order.",
            m,
            &[&w[0], &w[1], &w[2]],
            &[&f.wheels],
            0,
            0,
            0,
        ),
        reassembly(
            "reversed",
            "The same fragments, last first: order does not matter.",
            m,
            &[&w[2], &w[1], &w[0]],
            &[&f.wheels],
            0,
            0,
            0,
        ),
        reassembly(
            "duplicate_fragment",
            "Fragment 0 twice: the copy is ignored.",
            m,
            &[&w[0], &w[0], &w[1], &w[2]],
            &[&f.wheels],
            0,
            1,
            0,
        ),
        reassembly(
            "interleaved_messages",
            "Two messages from one sender (ids 1 and 2, the second the 100-byte frame of \
             uneven_pieces) interleaved: each completes with its own last fragment.",
            m,
            &[&w[0], &h[0], &w[1], &h[1], &w[2], &h[2]],
            &[&f.wheels, &hundred],
            0,
            0,
            0,
        ),
        reassembly(
            "one_fragment_message",
            "A message of one fragment (data_struct_wheels plus a stray byte) is complete at \
             once and handed up whole: a reassembled frame is never split as a batch.",
            m,
            &[&one[0]],
            &[&trailing],
            0,
            0,
            0,
        ),
        reassembly(
            "missing_fragment",
            "Fragments 0 and 2 only: nothing is handed up; the incomplete message is held \
             until its reassembly timeout.",
            m,
            &[&w[0], &w[2]],
            &[],
            0,
            0,
            1,
        ),
        reassembly(
            "inconsistent_message",
            "Fragment 0 of message 1 (78 bytes in 3), then a fragment of message 1 claiming \
             100 bytes in 3: the second is rejected and the incomplete message dropped with \
             it. Fragments 1 and 2 of the first then start a new message that can never \
             complete (fragment 0 is gone).",
            m,
            &[&w[0], &other[1], &w[1], &w[2]],
            &[],
            1,
            0,
            1,
        ),
        reassembly(
            "malformed_fragment_among_good_ones",
            "A copy of fragment 1 with one byte too many is rejected; the good fragments still \
             complete the message.",
            m,
            &[&w[0], &long_piece, &w[1], &w[2]],
            &[&f.wheels],
            1,
            0,
            0,
        ),
        reassembly(
            "late_duplicate_after_completion",
            "Fragment 1 again after the message completed: the receiver remembers the \
             message for its reassembly timeout and drops the copy as a duplicate; nothing is \
             held.",
            m,
            &[&w[0], &w[1], &w[2], &w[1]],
            &[&f.wheels],
            0,
            1,
            0,
        ),
        reassembly(
            "over_the_receivers_max_frame",
            "wheels_in_three at a receiver whose largest frame is 77 bytes: every fragment is \
             rejected (BadGeometry).",
            77,
            &[&w[0], &w[1], &w[2]],
            &[],
            3,
            0,
            0,
        ),
    ]
}

fn fragment_error_vectors(f: &LinkFrames) -> Vec<FragmentErrorVector> {
    let w = fragments(&f.wheels, 50, 1, 1);
    let h = fragments(&hundred_byte_frame(), 60, 1, 2);
    let base = &w[0];
    let with = |at: usize, bytes: &[u8]| {
        let mut d = base.clone();
        d[at..at + bytes.len()].copy_from_slice(bytes);
        d
    };
    let e =
        |name: &str, description: &str, max_frame: usize, d: &[u8], error| FragmentErrorVector {
            name: name.into(),
            description: description.into(),
            max_frame,
            datagram_hex: hex(d),
            error,
        };
    let m = 1000;
    let mut long = base.clone();
    long.push(0);
    let mut last_long = h[2].clone();
    last_long.extend_from_slice(&[0, 0]);
    vec![
        e(
            "truncated",
            "The first 19 bytes of a fragment header.",
            m,
            &base[..19],
            "Truncated",
        ),
        e("magic_only", "Just \"HF\".", m, b"HF", "Truncated"),
        e(
            "bad_version",
            "Fragment 0 of wheels_in_three with version 2.",
            m,
            &with(2, &[2]),
            "BadHeader",
        ),
        e(
            "reserved_byte_3",
            "Byte 3 (reserved) set to 1.",
            m,
            &with(3, &[1]),
            "BadHeader",
        ),
        e(
            "reserved_bytes_10",
            "Byte 11 (reserved) set to 1.",
            m,
            &with(10, &[0, 1]),
            "BadHeader",
        ),
        e(
            "count_zero",
            "Fragment count 0.",
            m,
            &with(8, &[0, 0]),
            "BadGeometry",
        ),
        e(
            "index_not_below_count",
            "Index 3 of 3.",
            m,
            &with(6, &[3, 0]),
            "BadGeometry",
        ),
        e(
            "total_zero",
            "A one-fragment message of total length 0 with no piece.",
            m,
            &fragment(1, 0, 1, 1, 0, &[]),
            "BadGeometry",
        ),
        e(
            "total_over_max_frame",
            "Fragment 0 of wheels_in_three (total 78) at a receiver whose largest frame is 77.",
            77,
            base,
            "BadGeometry",
        ),
        e(
            "count_over_total",
            "3 fragments for a 2-byte frame.",
            m,
            &fragment(1, 0, 3, 1, 2, &[0]),
            "BadGeometry",
        ),
        e(
            "empty_last_piece",
            "4 fragments for 5 bytes: pieces of ceil(5 / 4) = 2 bytes leave nothing for the \
             fourth, so that count is impossible.",
            m,
            &fragment(1, 0, 4, 1, 5, &[0, 0]),
            "BadGeometry",
        ),
        e(
            "piece_too_long",
            "Fragment 0 of wheels_in_three with one byte appended (27, expected 26).",
            m,
            &long,
            "BadLength",
        ),
        e(
            "piece_too_short",
            "Fragment 0 of wheels_in_three without its last byte.",
            m,
            &base[..base.len() - 1],
            "BadLength",
        ),
        e(
            "last_piece_too_long",
            "The last fragment of uneven_pieces carrying 34 bytes instead of 32.",
            m,
            &last_long,
            "BadLength",
        ),
    ]
}

fn hello_vectors() -> Vec<HelloVector> {
    let v = |name: &str, description: &str, bytes: Vec<u8>, system: Option<u16>| HelloVector {
        name: name.into(),
        description: description.into(),
        hello_hex: hex(&bytes),
        system,
    };
    let with = |at: usize, byte: u8| {
        let mut h = hello(1);
        h[at] = byte;
        h
    };
    vec![
        v("system_1", "The hello of system 1.", hello(1), Some(1)),
        v(
            "system_513",
            "System 513 (0x0201): little-endian.",
            hello(513),
            Some(513),
        ),
        v(
            "system_65535",
            "The largest system id.",
            hello(u16::MAX),
            Some(u16::MAX),
        ),
        v(
            "bad_magic",
            "\"HX\" instead of \"HL\".",
            with(1, b'X'),
            None,
        ),
        v(
            "record_instead_of_hello",
            "A record header where the hello belongs.",
            record(&[])[..8].to_vec(),
            None,
        ),
        v("bad_version", "Version 2.", with(2, 2), None),
        v(
            "reserved_byte_3",
            "Byte 3 (reserved) set to 1.",
            with(3, 1),
            None,
        ),
        v(
            "reserved_byte_7",
            "Byte 7 (reserved) set to 1.",
            with(7, 1),
            None,
        ),
    ]
}

fn record_vectors(f: &LinkFrames) -> Vec<RecordsVector> {
    let v = |name: &str,
             description: &str,
             max_frame: usize,
             stream: Vec<u8>,
             frames: &[&[u8]],
             end: &'static str| RecordsVector {
        name: name.into(),
        description: description.into(),
        max_frame,
        stream_hex: hex(&stream),
        frames_hex: hexes(frames),
        end,
    };
    let m = DEFAULT_MAX_FRAME;
    let (wheels, ack) = (&f.wheels[..], &f.ack[..]);
    let cat = |parts: &[&[u8]]| parts.concat();
    let mut bad_version = record(ack);
    bad_version[2] = 2;
    let mut reserved = record(ack);
    reserved[3] = 1;
    let mut all_ones = record(&[]);
    all_ones[4..8].copy_from_slice(&u32::MAX.to_le_bytes());
    vec![
        v(
            "one_record",
            "data_struct_wheels in one record.",
            m,
            record(wheels),
            &[wheels],
            "clean",
        ),
        v(
            "data_and_ack",
            "What a TCP connection carries: data_header_crc (FLAG_HEADER_CRC, as senders write \
             data on TCP) and then ack_delivered, one record each.",
            m,
            cat(&[&record(&f.header_crc), &record(ack)]),
            &[&f.header_crc, ack],
            "clean",
        ),
        v(
            "empty_record",
            "A record of length 0 between two others: a zero-byte frame is handed up (and \
             rejected by the decoder).",
            m,
            cat(&[&record(ack), &record(&[]), &record(ack)]),
            &[ack, &[], ack],
            "clean",
        ),
        v(
            "any_bytes",
            "The link does not look inside records: bytes that are no frame are handed up.",
            m,
            record(b"not a frame"),
            &[b"not a frame"],
            "clean",
        ),
        v(
            "nothing",
            "A connection that ends right after its hello.",
            m,
            Vec::new(),
            &[],
            "clean",
        ),
        v(
            "at_max_frame",
            "data_struct_wheels (78 bytes) at a reader whose largest frame is 78.",
            78,
            record(wheels),
            &[wheels],
            "clean",
        ),
        v(
            "cut_in_record_header",
            "One record, then the first 5 bytes of another header, then the end of the \
             stream.",
            m,
            cat(&[&record(wheels), &record(ack)[..5]]),
            &[wheels],
            "cut",
        ),
        v(
            "cut_in_frame",
            "The first 50 bytes of the record of data_struct_wheels, then the end of the \
             stream.",
            m,
            record(wheels)[..50].to_vec(),
            &[],
            "cut",
        ),
        v(
            "bad_magic_after_one_record",
            "A good record, then a header with magic \"HX\": the reader drops the connection; \
             nothing after the bad header is read.",
            m,
            cat(&[&record(wheels), b"HX\x01\x00\x01\x00\x00\x00\x00"]),
            &[wheels],
            "bad",
        ),
        v(
            "frame_without_record",
            "data_struct_wheels written straight onto the stream without a record header: \
             \"HC\" is not \"HR\".",
            m,
            wheels.to_vec(),
            &[],
            "bad",
        ),
        v(
            "bad_version",
            "A record header with version 2.",
            m,
            bad_version,
            &[],
            "bad",
        ),
        v(
            "reserved_byte",
            "A record header with byte 3 (reserved) set to 1.",
            m,
            reserved,
            &[],
            "bad",
        ),
        v(
            "over_max_frame",
            "data_struct_wheels (78 bytes) at a reader whose largest frame is 77: refused from \
             the header, before the frame is read.",
            77,
            record(wheels),
            &[],
            "bad",
        ),
        v(
            "length_all_ones",
            "A record header announcing 0xffffffff bytes.",
            m,
            all_ones,
            &[],
            "bad",
        ),
    ]
}

/// What introduces the `secured_frames` section, the file's last key. That section is
/// generated by `crates/hetcomm-security/tests/wire_vectors.rs` (this crate cannot use
/// hetcomm-security), which checks it against the real code; here it is copied through as
/// committed.
const SECURED_MARKER: &str = ",\n  \"secured_frames\": ";

fn generate_text() -> String {
    let mut text = serde_json::to_string_pretty(&generate()).expect("json serializes");
    text.push('\n');
    let committed = std::fs::read_to_string(vectors_path()).unwrap_or_default();
    if let Some(at) = committed.find(SECURED_MARKER) {
        text.truncate(text.len() - "\n}\n".len());
        text.push_str(&committed[at..]);
    }
    text
}

fn load() -> Value {
    let path = vectors_path();
    let text = std::fs::read_to_string(&path)
        .unwrap_or_else(|e| panic!("cannot read {}: {e}", path.display()));
    serde_json::from_str(&text).expect("wire-vectors.json is valid JSON")
}

// ---------------------------------------------------------------------------------------------
// The checks
// ---------------------------------------------------------------------------------------------

fn num(v: &Value, key: &str) -> u64 {
    v[key]
        .as_u64()
        .unwrap_or_else(|| panic!("field {key} is not an unsigned integer in {v}"))
}

fn json_addr(v: &Value) -> Address {
    addr(num(v, "system") as u16, num(v, "module") as u16)
}

#[test]
fn valid_vectors_decode_and_re_encode() {
    let file = load();
    let vectors = file["valid"].as_array().expect("valid is an array");
    assert!(vectors.len() >= 10, "expected at least 10 valid vectors");
    for v in vectors {
        let name = v["name"].as_str().expect("name");
        let bytes = unhex(v["frame_hex"].as_str().expect("frame_hex"));
        let frame = wire::decode(&bytes).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(
            wire::peek_frame_len(&bytes),
            Ok(bytes.len()),
            "{name}: peek_frame_len"
        );

        let j = &v["header"];
        let h = frame.header;
        assert_eq!(h.kind as u64, num(j, "kind"), "{name}: kind");
        assert_eq!(h.flags as u64, num(j, "flags"), "{name}: flags");
        assert_eq!(h.priority.0 as u64, num(j, "priority"), "{name}: priority");
        assert_eq!(h.transport as u64, num(j, "transport"), "{name}: transport");
        assert_eq!(h.source, json_addr(&j["source"]), "{name}: source");
        assert_eq!(
            h.destination,
            json_addr(&j["destination"]),
            "{name}: destination"
        );
        assert_eq!(
            h.incarnation as u64,
            num(j, "incarnation"),
            "{name}: incarnation"
        );
        assert_eq!(h.seq, num(j, "seq"), "{name}: seq");
        assert_eq!(
            h.message_type.0 as u64,
            num(j, "message_type"),
            "{name}: message_type"
        );
        assert_eq!(h.timestamp.0, num(j, "timestamp"), "{name}: timestamp");
        assert_eq!(
            frame.payload.len() as u64,
            num(j, "payload_len"),
            "{name}: payload_len"
        );

        assert_eq!(
            hex(frame.payload),
            v["payload_hex"].as_str().expect("payload_hex"),
            "{name}: payload bytes"
        );
        match h.kind {
            FrameKind::Ack => {
                let ack = AckPayload::parse(frame.payload, h.seq)
                    .unwrap_or_else(|| panic!("{name}: an ack carries a status or a range"));
                let first = (frame.payload.len() == 9).then_some(ack.first);
                assert_eq!(first, v["ack_first"].as_u64(), "{name}: ack_first");
                let status = ack.status;
                assert_eq!(
                    serde_json::to_value(status).unwrap(),
                    v["ack_status"],
                    "{name}"
                );
                assert_eq!(v["payload_json"], Value::Null, "{name}: payload_json");
            }
            FrameKind::Data => {
                let json = payload::to_json(frame.payload).unwrap_or(Value::Null);
                assert_eq!(json, v["payload_json"], "{name}: payload_json");
            }
        }

        let again = wire::encode(&h, frame.payload);
        assert_eq!(hex(&again), hex(&bytes), "{name}: re-encoding differs");
    }
}

#[test]
fn invalid_vectors_are_rejected_with_the_named_error() {
    let file = load();
    let vectors = file["invalid"].as_array().expect("invalid is an array");
    assert!(vectors.len() >= 8, "expected at least 8 invalid vectors");
    for v in vectors {
        let name = v["name"].as_str().expect("name");
        let bytes = unhex(v["frame_hex"].as_str().expect("frame_hex"));
        let expected = v["error"].as_str().expect("error");
        match wire::decode(&bytes) {
            Ok(_) => panic!("{name}: decoded, expected {expected}"),
            Err(e) => assert_eq!(error_name(&e), expected, "{name}: {e}"),
        }
        // What the header alone tells a stream reader must agree with the full decode.
        if let Err(e) = wire::peek_frame_len(&bytes) {
            assert_eq!(error_name(&e), expected, "{name}: peek_frame_len said {e}");
        }
    }
}

#[test]
fn every_error_variant_has_a_vector() {
    let file = load();
    let named: Vec<&str> = file["invalid"]
        .as_array()
        .expect("invalid is an array")
        .iter()
        .map(|v| v["error"].as_str().expect("error"))
        .collect();
    for variant in [
        "TooShort",
        "BadMagic",
        "BadVersion",
        "BadKind",
        "BadFlags",
        "TooLong",
        "LengthMismatch",
        "BadChecksum",
    ] {
        assert!(named.contains(&variant), "no invalid vector for {variant}");
    }
}

#[test]
fn committed_vectors_match_the_generator() {
    let path = vectors_path();
    let committed = std::fs::read_to_string(&path)
        .unwrap_or_else(|e| panic!("cannot read {}: {e}", path.display()));
    assert!(
        committed == generate_text(),
        "{} differs from what the generator produces: if the change is intended, run \
         `cargo test -p hetcomm-core -- --ignored regenerate_wire_vectors` and review the diff",
        path.display()
    );
}

/// Writes `docs/wire-vectors.json` from [`generate`].
#[test]
#[ignore = "writes docs/wire-vectors.json; run on purpose after an intended change"]
fn regenerate_wire_vectors() {
    let path = vectors_path();
    std::fs::write(&path, generate_text())
        .unwrap_or_else(|e| panic!("cannot write {}: {e}", path.display()));
    println!("wrote {}", path.display());
}

// ---------------------------------------------------------------------------------------------
// The link framing vectors, checked against the document's rules with the frame codec alone
// (the real UDP and stream code is checked in crates/hetcomm-link-ip/tests/wire_vectors.rs)
// ---------------------------------------------------------------------------------------------

fn str_of<'a>(v: &'a Value, key: &str) -> &'a str {
    v[key]
        .as_str()
        .unwrap_or_else(|| panic!("field {key} is not a string in {v}"))
}

fn hex_list(v: &Value, key: &str) -> Vec<Vec<u8>> {
    v[key]
        .as_array()
        .unwrap_or_else(|| panic!("field {key} is not an array in {v}"))
        .iter()
        .map(|h| unhex(h.as_str().expect("hex string")))
        .collect()
}

fn section<'a>(file: &'a Value, key: &str) -> &'a Vec<Value> {
    let vectors = file[key]
        .as_array()
        .unwrap_or_else(|| panic!("{key} is not an array"));
    assert!(!vectors.is_empty(), "{key} is empty");
    vectors
}

#[test]
fn udp_datagrams_split_as_documented() {
    let file = load();
    let (mut batches, mut tails, mut dropped) = (0, 0, 0);
    for v in section(&file, "udp_datagrams") {
        let name = str_of(v, "name");
        let d = unhex(str_of(v, "datagram_hex"));
        assert!(!d.starts_with(b"HF"), "{name}: fragments are elsewhere");
        // A batch starts with "HB"; its header is "HB", version 1, a zero byte; then records.
        let (handling, frames, rest) = if !d.starts_with(b"HB") {
            ("whole", vec![d.clone()], Vec::new())
        } else if d.len() < 4 || d[2] != 1 || d[3] != 0 {
            ("dropped", Vec::new(), Vec::new())
        } else {
            let mut rest = &d[4..];
            let mut frames = Vec::new();
            while rest.len() >= 4 {
                let n = u32::from_le_bytes(rest[..4].try_into().unwrap()) as usize;
                if n > rest.len() - 4 {
                    break;
                }
                frames.push(rest[4..4 + n].to_vec());
                rest = &rest[4 + n..];
            }
            ("batch", frames, rest.to_vec())
        };
        assert_eq!(handling, str_of(v, "handling"), "{name}");
        assert_eq!(frames, hex_list(v, "frames_hex"), "{name}: frames");
        assert_eq!(hex(&rest), str_of(v, "dropped_tail_hex"), "{name}: tail");
        batches += usize::from(handling == "batch");
        dropped += usize::from(handling == "dropped");
        tails += usize::from(!rest.is_empty());
    }
    assert!(
        batches >= 3 && tails >= 3 && dropped >= 1,
        "too few batch vectors"
    );
}

#[test]
fn udp_fragments_cut_frames_as_documented() {
    let file = load();
    for v in section(&file, "udp_fragmented_frames") {
        let name = str_of(v, "name");
        let frame = unhex(str_of(v, "frame_hex"));
        let mtu = num(v, "datagram_payload") as usize;
        let datagrams = hex_list(v, "fragments_hex");
        let count = frame.len().div_ceil(mtu - FRAGMENT_HEADER_LEN);
        assert_eq!(datagrams.len(), count.max(1), "{name}: fragment count");
        let chunk = frame.len().div_ceil(datagrams.len());
        let mut joined = Vec::new();
        for (i, d) in datagrams.iter().enumerate() {
            assert!(
                d.len() <= mtu,
                "{name}: fragment {i} exceeds the datagram size"
            );
            let u16_at = |at: usize| u16::from_le_bytes([d[at], d[at + 1]]);
            let u32_at = |at: usize| u32::from_le_bytes(d[at..at + 4].try_into().unwrap());
            assert_eq!(&d[..4], b"HF\x01\x00", "{name}: magic, version, reserved");
            assert_eq!(u16_at(4) as u64, num(v, "sender"), "{name}: sender");
            assert_eq!(usize::from(u16_at(6)), i, "{name}: index");
            assert_eq!(usize::from(u16_at(8)), datagrams.len(), "{name}: count");
            assert_eq!(&d[10..12], &[0, 0], "{name}: reserved");
            assert_eq!(
                u32_at(12) as u64,
                num(v, "message_id"),
                "{name}: message id"
            );
            assert_eq!(u32_at(16) as usize, frame.len(), "{name}: total");
            let piece = &d[FRAGMENT_HEADER_LEN..];
            assert_eq!(
                piece.len(),
                chunk.min(frame.len() - i * chunk),
                "{name}: piece {i}"
            );
            joined.extend_from_slice(piece);
        }
        assert_eq!(joined, frame, "{name}: the pieces are the frame");
    }
}

#[test]
fn stream_records_parse_as_documented() {
    let file = load();
    for v in section(&file, "stream_hellos") {
        let name = str_of(v, "name");
        let h = unhex(str_of(v, "hello_hex"));
        assert_eq!(h.len(), 8, "{name}");
        let ok = h[..4] == *b"HL\x01\x00" && h[6..8] == [0, 0];
        let system = ok.then(|| u64::from(u16::from_le_bytes([h[4], h[5]])));
        assert_eq!(system, v["system"].as_u64(), "{name}");
    }
    for v in section(&file, "stream_records") {
        let name = str_of(v, "name");
        let stream = unhex(str_of(v, "stream_hex"));
        let max_frame = num(v, "max_frame") as usize;
        let mut rest = &stream[..];
        let mut frames = Vec::new();
        let end = loop {
            if rest.is_empty() {
                break "clean";
            }
            if rest.len() < RECORD_HEADER_LEN {
                break "cut";
            }
            let len = u32::from_le_bytes(rest[4..8].try_into().unwrap()) as usize;
            if rest[..4] != *b"HR\x01\x00" || len > max_frame {
                break "bad";
            }
            if rest.len() < RECORD_HEADER_LEN + len {
                break "cut";
            }
            frames.push(rest[RECORD_HEADER_LEN..RECORD_HEADER_LEN + len].to_vec());
            rest = &rest[RECORD_HEADER_LEN + len..];
        };
        assert_eq!(end, str_of(v, "end"), "{name}: end");
        assert_eq!(frames, hex_list(v, "frames_hex"), "{name}: frames");
    }
}
