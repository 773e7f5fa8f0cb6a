//! The UDP link vectors of `docs/wire-vectors.json` (datagrams, fragments and their
//! reassembly) and the frames and framing helpers every link vector uses, built from
//! docs/wire-format.md ("On the links").

use super::*;

/// A UDP datagram that is not a fragment, and what the receiving link hands up.
#[derive(Serialize)]
pub(crate) struct DatagramVector {
    pub(crate) name: String,
    pub(crate) description: String,
    pub(crate) datagram_hex: String,
    /// "whole" (handed up as it is), "batch" (split into frames) or "dropped" (a batch header
    /// the receiver does not read: nothing is handed up).
    pub(crate) handling: &'static str,
    pub(crate) frames_hex: Vec<String>,
    /// The malformed tail of a batch, dropped (and the datagram counted as bad); "" if none.
    pub(crate) dropped_tail_hex: String,
}

/// A frame the UDP sender cuts into fragments, and the datagrams it sends.
#[derive(Serialize)]
pub(crate) struct FragmentedVector {
    pub(crate) name: String,
    pub(crate) description: String,
    pub(crate) datagram_payload: usize,
    pub(crate) sender: u16,
    pub(crate) message_id: u32,
    pub(crate) frame_hex: String,
    pub(crate) fragments_hex: Vec<String>,
}

/// Fragment datagrams arriving (from one address) and what reassembly makes of them.
#[derive(Serialize)]
pub(crate) struct ReassemblyVector {
    pub(crate) name: String,
    pub(crate) description: String,
    pub(crate) max_frame: usize,
    pub(crate) datagrams_hex: Vec<String>,
    pub(crate) frames_hex: Vec<String>,
    pub(crate) rejected: usize,
    pub(crate) duplicates: usize,
    pub(crate) pending: usize,
}

/// A malformed fragment datagram.
#[derive(Serialize)]
pub(crate) struct FragmentErrorVector {
    pub(crate) name: String,
    pub(crate) description: String,
    pub(crate) max_frame: usize,
    pub(crate) datagram_hex: String,
    pub(crate) error: &'static str,
}

// ---------------------------------------------------------------------------------------------
// Link framing (docs/wire-format.md, "On the links"), encoded here from the spec
// ---------------------------------------------------------------------------------------------
//
// hetcomm-core cannot use hetcomm-link-ip (which depends on it), so these bytes are built from
// the document alone; crates/hetcomm-link-ip/tests/wire_vectors.rs checks the real UDP and
// stream encoders and decoders against the committed file.

/// The default largest frame of a UDP or stream link: the 48-byte header plus MAX_PAYLOAD.
pub(crate) const DEFAULT_MAX_FRAME: usize = HEADER_LEN + MAX_PAYLOAD;
pub(crate) const FRAGMENT_HEADER_LEN: usize = 20;
pub(crate) const RECORD_HEADER_LEN: usize = 8;

/// Frames the link vectors carry.
pub(crate) struct LinkFrames {
    /// data_struct_wheels.
    pub(crate) wheels: Vec<u8>,
    /// ack_delivered.
    pub(crate) ack: Vec<u8>,
    /// data_broadcast_ack_requested.
    pub(crate) broadcast: Vec<u8>,
    /// data_header_crc.
    pub(crate) header_crc: Vec<u8>,
}

/// A data frame from (1, 2) to (3, 4) whose payload is `payload`.
pub(crate) fn frame_with_payload(seq: u64, payload: &[u8]) -> Vec<u8> {
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
pub(crate) fn hundred_byte_frame() -> Vec<u8> {
    let mut payload = vec![0xd9, 50];
    payload.extend((0..50u8).map(|i| b'a' + i % 26));
    let f = frame_with_payload(4, &payload);
    assert_eq!(f.len(), 100);
    f
}

/// One fragment datagram: the 20-byte fragment header and the piece.
pub(crate) fn fragment(
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
pub(crate) fn fragments(
    frame: &[u8],
    datagram_payload: usize,
    sender: u16,
    message_id: u32,
) -> Vec<Vec<u8>> {
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

pub(crate) fn hexes(frames: &[&[u8]]) -> Vec<String> {
    frames.iter().map(|f| hex(f)).collect()
}

/// A batch datagram holding `frames` as records, as the sender writes it.
pub(crate) fn udp_batch(frames: &[&[u8]]) -> Vec<u8> {
    let mut d = b"HB\x01\x00".to_vec();
    for f in frames {
        d.extend_from_slice(&(f.len() as u32).to_le_bytes());
        d.extend_from_slice(f);
    }
    d
}

pub(crate) fn datagram(
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

pub(crate) fn udp_datagram_vectors(f: &LinkFrames) -> Vec<DatagramVector> {
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

pub(crate) fn fragmented(
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

pub(crate) fn big_frame() -> Vec<u8> {
    // bin 16 of 2949 bytes: a 2952-byte payload, a 3000-byte frame.
    let mut payload = vec![0xc5, 0x0b, 0x85];
    payload.extend((0..2949u32).map(|i| (i * 7 % 251) as u8));
    let f = frame_with_payload(5, &payload);
    assert_eq!(f.len(), 3000);
    f
}

pub(crate) fn fragmented_vectors(f: &LinkFrames) -> Vec<FragmentedVector> {
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
pub(crate) fn reassembly(
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

pub(crate) fn reassembly_vectors(f: &LinkFrames) -> Vec<ReassemblyVector> {
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

pub(crate) fn fragment_error_vectors(f: &LinkFrames) -> Vec<FragmentErrorVector> {
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
