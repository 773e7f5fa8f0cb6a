//! The stream link vectors of `docs/wire-vectors.json`: hellos and records as a stream
//! link writes and reads them (docs/wire-format.md, "On the links").

use super::*;

/// A stream hello and the system it names (None: the connection is refused).
#[derive(Serialize)]
pub(crate) struct HelloVector {
    pub(crate) name: String,
    pub(crate) description: String,
    pub(crate) hello_hex: String,
    pub(crate) system: Option<u16>,
}

/// The bytes of a stream after the hello, the frames a reader hands up and how it ends.
#[derive(Serialize)]
pub(crate) struct RecordsVector {
    pub(crate) name: String,
    pub(crate) description: String,
    pub(crate) max_frame: usize,
    pub(crate) stream_hex: String,
    pub(crate) frames_hex: Vec<String>,
    /// "clean" (ends between records), "cut" (ends inside a record) or "bad" (a malformed or
    /// oversized record header: the reader drops the connection).
    pub(crate) end: &'static str,
}

pub(crate) fn hello(system: u16) -> Vec<u8> {
    let mut h = b"HL\x01\x00".to_vec();
    h.extend_from_slice(&system.to_le_bytes());
    h.extend_from_slice(&[0, 0]);
    h
}

pub(crate) fn record(frame: &[u8]) -> Vec<u8> {
    let mut r = b"HR\x01\x00".to_vec();
    r.extend_from_slice(&(frame.len() as u32).to_le_bytes());
    r.extend_from_slice(frame);
    r
}

pub(crate) fn hello_vectors() -> Vec<HelloVector> {
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

pub(crate) fn record_vectors(f: &LinkFrames) -> Vec<RecordsVector> {
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
