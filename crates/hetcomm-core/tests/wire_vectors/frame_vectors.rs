//! The frame vectors of `docs/wire-vectors.json`: valid frames with the header fields and
//! payload each decodes to, and invalid ones with the error each must give.

use super::*;

// ---------------------------------------------------------------------------------------------
// The generator
// ---------------------------------------------------------------------------------------------

#[derive(Serialize)]
pub(crate) struct Wheels {
    pub(crate) left: f64,
    pub(crate) right: f64,
}

#[derive(Serialize)]
pub(crate) enum Mode {
    Explore,
}

#[derive(Serialize)]
pub(crate) enum Goal {
    Waypoint { x: f64, y: f64 },
}

/// A payload that exercises most shapes: string, tuple, vector, options, enums, bytes, map.
#[derive(Serialize)]
pub(crate) struct Status {
    pub(crate) name: String,
    pub(crate) pose: (f64, f64, f32),
    pub(crate) battery: Option<f32>,
    pub(crate) fault: Option<String>,
    pub(crate) mode: Mode,
    pub(crate) goal: Goal,
    pub(crate) tags: Vec<String>,
    #[serde(with = "serde_bytes")]
    pub(crate) raw: Vec<u8>,
    pub(crate) counters: std::collections::BTreeMap<String, u64>,
    pub(crate) uptime_us: u64,
    pub(crate) temperature: i8,
}

/// One valid vector, fields in the order the file shows them.
#[derive(Serialize)]
pub(crate) struct ValidVector {
    pub(crate) name: String,
    pub(crate) description: String,
    pub(crate) frame_hex: String,
    pub(crate) header: HeaderOut,
    pub(crate) payload_hex: String,
    pub(crate) payload_json: Value,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(crate) ack_status: Option<AckStatus>,
    /// An ACK range's first seq (the nine-byte payload; "ACK ranges").
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(crate) ack_first: Option<u64>,
}

/// The header as the file shows it: every field as a plain number.
#[derive(Serialize)]
pub(crate) struct HeaderOut {
    pub(crate) kind: u8,
    pub(crate) flags: u8,
    pub(crate) priority: u8,
    pub(crate) transport: u8,
    pub(crate) source: AddressOut,
    pub(crate) destination: AddressOut,
    pub(crate) incarnation: u32,
    pub(crate) seq: u64,
    pub(crate) message_type: u32,
    pub(crate) timestamp: u64,
    pub(crate) payload_len: usize,
}

#[derive(Serialize)]
pub(crate) struct AddressOut {
    pub(crate) system: u16,
    pub(crate) module: u16,
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
pub(crate) struct InvalidVector {
    pub(crate) name: String,
    pub(crate) description: String,
    pub(crate) frame_hex: String,
    pub(crate) error: String,
}

/// The whole file.
#[derive(Serialize)]
pub(crate) struct VectorFile {
    pub(crate) format: &'static str,
    pub(crate) generated_by: &'static str,
    pub(crate) valid: Vec<ValidVector>,
    pub(crate) invalid: Vec<InvalidVector>,
    pub(crate) udp_datagrams: Vec<DatagramVector>,
    pub(crate) udp_fragmented_frames: Vec<FragmentedVector>,
    pub(crate) udp_reassembly: Vec<ReassemblyVector>,
    pub(crate) udp_fragment_errors: Vec<FragmentErrorVector>,
    pub(crate) stream_hellos: Vec<HelloVector>,
    pub(crate) stream_records: Vec<RecordsVector>,
}

pub(crate) fn valid(name: &str, description: &str, h: Header, payload: &[u8]) -> ValidVector {
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
pub(crate) fn fix_crc(frame: &mut [u8]) {
    let mut h = crc32fast::Hasher::new();
    h.update(&frame[..44]);
    h.update(&[0; 4]);
    h.update(&frame[48..]);
    let crc = h.finalize();
    frame[44..48].copy_from_slice(&crc.to_le_bytes());
}

pub(crate) fn invalid(name: &str, description: &str, frame: &[u8], error: &str) -> InvalidVector {
    InvalidVector {
        name: name.into(),
        description: description.into(),
        frame_hex: hex(frame),
        error: error.into(),
    }
}

/// The data frame of the worked example in `docs/wire-format.md`.
pub(crate) fn wheels_header() -> Header {
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

pub(crate) fn ack_of(data: &Header) -> Header {
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
pub(crate) fn generate() -> VectorFile {
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
