//! The envelope and its byte-exact wire codec. `docs/wire-format.md` is the specification;
//! `docs/wire-vectors.json` holds test vectors every port checks against.
//!
//! A frame is a fixed 48-byte header followed by the payload. All integers are little-endian.
//! The decoder checks magic, version, kind, the declared payload length against the bytes
//! actually present, and a CRC-32 over the whole frame before it hands anything out; it never
//! allocates (the decoded payload borrows from the input). A frame flagged
//! [`FLAG_HEADER_CRC`] carries a CRC of its header only, for links that check the payload's
//! integrity themselves (see [`Header::payload_checked`]).

use serde::{Deserialize, Serialize};

use crate::ids::{Address, MessageId, MessageType, ModuleId, Priority, SystemId};
use crate::time::Time;

/// The two magic bytes that open every frame: `"HC"`.
pub const MAGIC: [u8; 2] = *b"HC";
/// The wire-format version this codec writes and accepts.
pub const VERSION: u8 = 1;
/// Size of the fixed header in bytes.
pub const HEADER_LEN: usize = 48;
/// The largest payload a frame may declare (16 MiB). Larger lengths are rejected before any
/// allocation anywhere downstream.
pub const MAX_PAYLOAD: usize = 16 * 1024 * 1024;

/// Byte offset of the CRC-32 field inside the header.
const CRC_OFFSET: usize = 44;

/// What a frame carries.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FrameKind {
    /// A user message for a module.
    Data = 0,
    /// The receiver's router has handled the data frame named by (origin, incarnation, seq);
    /// the payload is an [`AckStatus`] byte, optionally followed by the first seq of a range
    /// of frames acknowledged with that status ([`AckPayload`]).
    Ack = 1,
}

impl FrameKind {
    fn from_u8(b: u8) -> Option<FrameKind> {
        match b {
            0 => Some(FrameKind::Data),
            1 => Some(FrameKind::Ack),
            _ => None,
        }
    }
}

/// The status carried in an acknowledgement's one-byte payload.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum AckStatus {
    /// Put into the destination module's inbox (or handed to its callback).
    Delivered = 0,
    /// The destination module's inbox was full and its policy refused the message.
    InboxFull = 1,
    /// The destination system has no such module.
    UnknownModule = 2,
}

impl AckStatus {
    /// Decodes a status byte.
    pub fn from_u8(b: u8) -> Option<AckStatus> {
        match b {
            0 => Some(AckStatus::Delivered),
            1 => Some(AckStatus::InboxFull),
            2 => Some(AckStatus::UnknownModule),
            _ => None,
        }
    }
}

/// The most sequence numbers one acknowledgement may cover (its header's `seq` and the
/// numbers below it down to [`AckPayload::first`]): a receiver of an ACK walks the range, so
/// it is bounded; a wider range is malformed.
pub const ACK_RANGE_MAX: u64 = 4096;

/// What an ACK's payload says: one status for the frames `first..=seq` (`seq` from the ACK's
/// header). One byte (the status) acknowledges `seq` alone; nine bytes (the status, then
/// `first` as a little-endian u64, `first < seq`, `seq - first < ACK_RANGE_MAX`) acknowledge
/// the range: a receiver that answers several frames in a row with one status sends one ACK.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct AckPayload {
    /// The status of every frame in the range.
    pub status: AckStatus,
    /// The lowest sequence number acknowledged (equal to the header's `seq` for one frame).
    pub first: u64,
}

impl AckPayload {
    /// Reads an ACK's payload for the ACK whose header says `seq`; None when it is neither
    /// form, or its range is empty, reversed or wider than [`ACK_RANGE_MAX`].
    pub fn parse(payload: &[u8], seq: u64) -> Option<AckPayload> {
        let (status, first) = match payload {
            [b] => (*b, seq),
            [b, rest @ ..] if rest.len() == 8 => {
                let first = u64::from_le_bytes(rest.try_into().ok()?);
                if first >= seq || seq - first >= ACK_RANGE_MAX {
                    return None;
                }
                (*b, first)
            }
            _ => return None,
        };
        Some(AckPayload {
            status: AckStatus::from_u8(status)?,
            first,
        })
    }

    /// The payload's bytes for an ACK whose header says `seq` (one byte when `first == seq`).
    pub fn write(&self, seq: u64, out: &mut [u8; 9]) -> usize {
        out[0] = self.status as u8;
        if self.first == seq {
            return 1;
        }
        out[1..].copy_from_slice(&self.first.to_le_bytes());
        9
    }
}

/// Flag bit: the sender wants an acknowledgement.
pub const FLAG_ACK_REQUESTED: u8 = 0b0000_0001;
/// Flag bit: this message is one copy of a broadcast.
pub const FLAG_BROADCAST: u8 = 0b0000_0010;
/// Flag bit: the CRC covers the 48 header bytes only, not the payload. A sender sets it only
/// on links that protect the bytes themselves (a checksummed, reliable byte stream such as
/// TCP); it saves a pass over the payload on both sides. Decoders still check the header's
/// CRC, the magic, the version and the lengths. Receivers should accept such frames only from
/// links that protect the payload themselves (the router does so).
pub const FLAG_HEADER_CRC: u8 = 0b0000_0100;
/// Flag bit: the sequence number counts in the sender's *broadcast* sequence space (one
/// counter per sender incarnation for its native broadcasts) instead of the space of the
/// sender and the destination system. Set on every frame of a native broadcast: the one frame
/// for every system ([`FLAG_TO_ALL`]), the copies the sender retransmits to the systems that
/// did not acknowledge it, and the acknowledgements of either. Receivers suppress duplicates
/// per (sender, incarnation, space).
pub const FLAG_BROADCAST_SEQ: u8 = 0b0000_1000;
/// Flag bit: this one data frame is for every system that receives it (a native broadcast,
/// one put on a transport that reaches every system at once); `destination.system` carries no
/// meaning and is written as [`TO_ALL_SYSTEM`]. Only with [`FLAG_BROADCAST`] and
/// [`FLAG_BROADCAST_SEQ`] on a data frame; receivers drop other combinations as malformed,
/// and accept the frame only when the communication table allows its sender to send them
/// on the transport it came by.
pub const FLAG_TO_ALL: u8 = 0b0001_0000;
/// What a native broadcast frame ([`FLAG_TO_ALL`]) writes as its destination system.
pub const TO_ALL_SYSTEM: SystemId = SystemId(u16::MAX);
/// Flags this version defines; a frame with other bits set is rejected.
pub const KNOWN_FLAGS: u8 =
    FLAG_ACK_REQUESTED | FLAG_BROADCAST | FLAG_HEADER_CRC | FLAG_BROADCAST_SEQ | FLAG_TO_ALL;

/// The envelope header: the thesis's Fig. 9 fields plus version, kind, flags, priority,
/// incarnation, timestamp and an integrity check.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct Header {
    /// Data or acknowledgement.
    pub kind: FrameKind,
    /// [`FLAG_ACK_REQUESTED`], [`FLAG_BROADCAST`], [`FLAG_HEADER_CRC`],
    /// [`FLAG_BROADCAST_SEQ`], [`FLAG_TO_ALL`].
    pub flags: u8,
    /// Receive priority at the destination inbox.
    pub priority: Priority,
    /// The thesis's "communication type": a one-byte tag of the transport that carried the
    /// frame (by convention the table letter, e.g. `b'R'`; 0 when unknown).
    pub transport: u8,
    /// Where the message comes from. Its system is also the message id's origin.
    pub source: Address,
    /// Where the message goes.
    pub destination: Address,
    /// A number the sender picks anew each time its process starts, so that a restarted
    /// sender's sequence numbers are not mistaken for duplicates.
    pub incarnation: u32,
    /// Sequence number within (origin, incarnation, destination system); starts at 1. One
    /// counter per destination lets a receiver see a gap-free stream from each sender (for
    /// in-order delivery) while (origin, seq) still names a message uniquely at its receiver.
    /// An acknowledgement echoes the acknowledged frame's sequence number.
    pub seq: u64,
    /// The user message type.
    pub message_type: MessageType,
    /// When the sender created the message, in microseconds on the sender's wall clock (since
    /// the UNIX epoch; virtual time under simulation). Informational: no timer or deadline
    /// is computed from it, so a sender whose clock is stepped only stamps differently.
    pub timestamp: Time,
}

impl Header {
    /// A data header with default priority, no flags, sequence 0 and timestamp zero; the
    /// router fills in the rest.
    pub fn data(source: Address, destination: Address, message_type: MessageType) -> Header {
        Header {
            kind: FrameKind::Data,
            flags: 0,
            priority: Priority::NORMAL,
            transport: 0,
            source,
            destination,
            incarnation: 0,
            seq: 0,
            message_type,
            timestamp: Time::ZERO,
        }
    }

    /// The thesis's message id: (origin system, sequence).
    pub fn message_id(&self) -> MessageId {
        MessageId {
            origin: self.source.system,
            seq: self.seq,
        }
    }

    /// Whether the sender asked for an acknowledgement.
    pub fn ack_requested(&self) -> bool {
        self.flags & FLAG_ACK_REQUESTED != 0
    }

    /// Whether this message is one copy of a broadcast.
    pub fn is_broadcast(&self) -> bool {
        self.flags & FLAG_BROADCAST != 0
    }

    /// Whether the frame's CRC covers its payload too (no [`FLAG_HEADER_CRC`]). When false,
    /// only the transport vouches for the payload's bytes.
    pub fn payload_checked(&self) -> bool {
        self.flags & FLAG_HEADER_CRC == 0
    }

    /// Whether the sequence number counts in the sender's broadcast space
    /// ([`FLAG_BROADCAST_SEQ`]).
    pub fn broadcast_seq(&self) -> bool {
        self.flags & FLAG_BROADCAST_SEQ != 0
    }

    /// Whether this one frame is for every system that receives it ([`FLAG_TO_ALL`]).
    pub fn to_all(&self) -> bool {
        self.flags & FLAG_TO_ALL != 0
    }
}

/// A decoded frame borrowing its payload from the input buffer.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Frame<'a> {
    /// The header.
    pub header: Header,
    /// The payload bytes (length already checked against the header).
    pub payload: &'a [u8],
}

/// Why a frame was rejected. Offsets are byte offsets into the frame.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum DecodeError {
    /// Fewer bytes than a header.
    #[error("truncated frame: {len} bytes, a header needs {HEADER_LEN}")]
    TooShort {
        /// Bytes received.
        len: usize,
    },
    /// The first two bytes are not `HC`.
    #[error("bad magic {found:02x?} at offset 0, expected \"HC\"")]
    BadMagic {
        /// The two bytes found.
        found: [u8; 2],
    },
    /// A version this codec does not speak.
    #[error("unsupported wire version {found} at offset 2, this build speaks version {VERSION}")]
    BadVersion {
        /// The version byte found.
        found: u8,
    },
    /// An unknown frame kind.
    #[error("unknown frame kind {found} at offset 3")]
    BadKind {
        /// The kind byte found.
        found: u8,
    },
    /// Flag bits this version does not define.
    #[error("unknown flag bits {found:#04x} at offset 4")]
    BadFlags {
        /// The flags byte found.
        found: u8,
    },
    /// The declared payload length exceeds [`MAX_PAYLOAD`].
    #[error("payload length {declared} at offset 40 exceeds the limit of {MAX_PAYLOAD} bytes")]
    TooLong {
        /// Declared payload length.
        declared: u64,
    },
    /// The declared payload length disagrees with the bytes present.
    #[error("payload length {declared} at offset 40, but {present} payload bytes present")]
    LengthMismatch {
        /// Declared payload length.
        declared: usize,
        /// Payload bytes actually present.
        present: usize,
    },
    /// The CRC-32 does not match: the frame (or, with [`FLAG_HEADER_CRC`], its header) was
    /// corrupted.
    #[error(
        "checksum mismatch at offset 44: frame says {declared:#010x}, computed {computed:#010x}"
    )]
    BadChecksum {
        /// The checksum in the frame.
        declared: u32,
        /// The checksum of the bytes received.
        computed: u32,
    },
}

/// Writes `header` and `payload` into `out` (appending). Use [`encode`] for a fresh buffer.
/// The CRC covers the whole frame, or only the header when `header.flags` has
/// [`FLAG_HEADER_CRC`].
///
/// # Panics
/// If `payload` is longer than [`MAX_PAYLOAD`]: callers check sizes first (the router refuses
/// such sends with an error).
pub fn encode_into(header: &Header, payload: &[u8], out: &mut Vec<u8>) {
    out.reserve(HEADER_LEN + payload.len());
    encode_header_into(header, payload, out);
    out.extend_from_slice(payload);
}

/// Appends only the [`HEADER_LEN`]-byte header of the frame that carries `payload` (its
/// length and CRC included); the frame is that header followed by `payload`. A sender can
/// then write the two pieces with one vectored write instead of copying the payload.
///
/// # Panics
///
/// If `payload` is longer than [`MAX_PAYLOAD`].
pub fn encode_header_into(header: &Header, payload: &[u8], out: &mut Vec<u8>) {
    assert!(payload.len() <= MAX_PAYLOAD, "payload over MAX_PAYLOAD");
    let start = out.len();
    out.extend_from_slice(&MAGIC);
    out.push(VERSION);
    out.push(header.kind as u8);
    out.push(header.flags);
    out.push(header.priority.0);
    out.push(header.transport);
    out.push(0); // reserved
    out.extend_from_slice(&header.source.system.0.to_le_bytes());
    out.extend_from_slice(&header.source.module.0.to_le_bytes());
    out.extend_from_slice(&header.destination.system.0.to_le_bytes());
    out.extend_from_slice(&header.destination.module.0.to_le_bytes());
    out.extend_from_slice(&header.incarnation.to_le_bytes());
    out.extend_from_slice(&header.seq.to_le_bytes());
    out.extend_from_slice(&header.message_type.0.to_le_bytes());
    out.extend_from_slice(&header.timestamp.0.to_le_bytes());
    out.extend_from_slice(&(payload.len() as u32).to_le_bytes());
    out.extend_from_slice(&[0; 4]); // CRC placeholder
    let crc = checksum_parts(&out[start..], payload, header.flags & FLAG_HEADER_CRC != 0);
    out[start + CRC_OFFSET..start + CRC_OFFSET + 4].copy_from_slice(&crc.to_le_bytes());
}

/// Encodes a frame into a new buffer.
pub fn encode(header: &Header, payload: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(HEADER_LEN + payload.len());
    encode_into(header, payload, &mut out);
    out
}

/// CRC-32 (IEEE) of a whole frame, or of its header only (`header_only`), with its CRC field
/// taken as zero.
fn checksum(frame: &[u8], header_only: bool) -> u32 {
    checksum_parts(&frame[..HEADER_LEN], &frame[HEADER_LEN..], header_only)
}

/// [`checksum`] of the frame `header` (exactly [`HEADER_LEN`] bytes) followed by `payload`.
fn checksum_parts(header: &[u8], payload: &[u8], header_only: bool) -> u32 {
    let mut h = crc32fast::Hasher::new();
    h.update(&header[..CRC_OFFSET]);
    h.update(&[0; 4]);
    h.update(&header[CRC_OFFSET + 4..HEADER_LEN]);
    if !header_only {
        h.update(payload);
    }
    h.finalize()
}

fn u16_at(b: &[u8], at: usize) -> u16 {
    u16::from_le_bytes([b[at], b[at + 1]])
}
fn u32_at(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]])
}
fn u64_at(b: &[u8], at: usize) -> u64 {
    let mut a = [0; 8];
    a.copy_from_slice(&b[at..at + 8]);
    u64::from_le_bytes(a)
}

/// Reads only the declared total frame length (header + payload) from the first
/// [`HEADER_LEN`] bytes, after checking magic, version and the length limit. Stream links use
/// it to know how many bytes to wait for before they allocate.
pub fn peek_frame_len(head: &[u8]) -> Result<usize, DecodeError> {
    if head.len() < HEADER_LEN {
        return Err(DecodeError::TooShort { len: head.len() });
    }
    check_prefix(head)?;
    let declared = u32_at(head, 40) as usize;
    if declared > MAX_PAYLOAD {
        return Err(DecodeError::TooLong {
            declared: declared as u64,
        });
    }
    Ok(HEADER_LEN + declared)
}

fn check_prefix(b: &[u8]) -> Result<(), DecodeError> {
    if b[0..2] != MAGIC {
        return Err(DecodeError::BadMagic {
            found: [b[0], b[1]],
        });
    }
    if b[2] != VERSION {
        return Err(DecodeError::BadVersion { found: b[2] });
    }
    Ok(())
}

/// Decodes exactly one frame: `bytes` must hold the header and exactly the declared payload
/// (trailing bytes are an error). With [`FLAG_HEADER_CRC`] set only the header is checksummed:
/// a corrupted payload of the right length is not detected here (by design: the link vouches
/// for it, see [`Header::payload_checked`]).
pub fn decode(bytes: &[u8]) -> Result<Frame<'_>, DecodeError> {
    let total = peek_frame_len(bytes)?;
    let declared = total - HEADER_LEN;
    let present = bytes.len() - HEADER_LEN;
    if declared != present {
        return Err(DecodeError::LengthMismatch { declared, present });
    }
    let kind = FrameKind::from_u8(bytes[3]).ok_or(DecodeError::BadKind { found: bytes[3] })?;
    let flags = bytes[4];
    if flags & !KNOWN_FLAGS != 0 {
        return Err(DecodeError::BadFlags { found: flags });
    }
    let declared_crc = u32_at(bytes, CRC_OFFSET);
    let computed = checksum(bytes, flags & FLAG_HEADER_CRC != 0);
    if declared_crc != computed {
        return Err(DecodeError::BadChecksum {
            declared: declared_crc,
            computed,
        });
    }
    let header = Header {
        kind,
        flags,
        priority: Priority(bytes[5]),
        transport: bytes[6],
        source: Address {
            system: SystemId(u16_at(bytes, 8)),
            module: ModuleId(u16_at(bytes, 10)),
        },
        destination: Address {
            system: SystemId(u16_at(bytes, 12)),
            module: ModuleId(u16_at(bytes, 14)),
        },
        incarnation: u32_at(bytes, 16),
        seq: u64_at(bytes, 20),
        message_type: MessageType(u32_at(bytes, 28)),
        timestamp: Time(u64_at(bytes, 32)),
    };
    Ok(Frame {
        header,
        payload: &bytes[HEADER_LEN..],
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn arb_header() -> impl Strategy<Value = Header> {
        (
            prop_oneof![Just(FrameKind::Data), Just(FrameKind::Ack)],
            0u8..=KNOWN_FLAGS,
            any::<u8>(),
            any::<u8>(),
            any::<(u16, u16, u16, u16)>(),
            any::<u32>(),
            any::<u64>(),
            any::<u32>(),
            any::<u64>(),
        )
            .prop_map(
                |(kind, flags, prio, transport, (ss, sm, ds, dm), inc, seq, ty, ts)| Header {
                    kind,
                    flags,
                    priority: Priority(prio),
                    transport,
                    source: (SystemId(ss), ModuleId(sm)).into(),
                    destination: (SystemId(ds), ModuleId(dm)).into(),
                    incarnation: inc,
                    seq,
                    message_type: MessageType(ty),
                    timestamp: Time(ts),
                },
            )
    }

    proptest! {
        #[test]
        fn round_trip(header in arb_header(), payload in proptest::collection::vec(any::<u8>(), 0..2048)) {
            let frame = encode(&header, &payload);
            prop_assert_eq!(frame.len(), HEADER_LEN + payload.len());
            let decoded = decode(&frame).unwrap();
            prop_assert_eq!(decoded.header, header);
            prop_assert_eq!(decoded.payload, &payload[..]);
        }

        #[test]
        fn header_alone_then_payload_is_the_same_frame(header in arb_header(), payload in proptest::collection::vec(any::<u8>(), 0..2048)) {
            // Whole-frame and header-only CRC (arb_header sets either flag).
            let mut split = vec![9u8];
            encode_header_into(&header, &payload, &mut split);
            prop_assert_eq!(split.len(), 1 + HEADER_LEN);
            split.extend_from_slice(&payload);
            prop_assert_eq!(&split[1..], &encode(&header, &payload)[..]);
        }

        #[test]
        fn arbitrary_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..256)) {
            let _ = decode(&bytes);
            let _ = peek_frame_len(&bytes);
        }

        #[test]
        fn any_single_bit_flip_is_rejected(mut header in arb_header(),
                                           payload in proptest::collection::vec(any::<u8>(), 0..64),
                                           bit in any::<prop::sample::Index>()) {
            header.flags &= !FLAG_HEADER_CRC;
            let mut frame = encode(&header, &payload);
            let i = bit.index(frame.len() * 8);
            frame[i / 8] ^= 1 << (i % 8);
            prop_assert!(decode(&frame).is_err());
        }

        #[test]
        fn header_crc_frames_reject_any_header_bit_flip(mut header in arb_header(),
                                                        payload in proptest::collection::vec(any::<u8>(), 0..64),
                                                        bit in any::<prop::sample::Index>()) {
            header.flags |= FLAG_HEADER_CRC;
            let mut frame = encode(&header, &payload);
            let i = bit.index(HEADER_LEN * 8);
            frame[i / 8] ^= 1 << (i % 8);
            prop_assert!(decode(&frame).is_err());
        }

        #[test]
        fn header_crc_frames_do_not_check_the_payload(mut header in arb_header(),
                                                      payload in proptest::collection::vec(any::<u8>(), 1..64),
                                                      bit in any::<prop::sample::Index>()) {
            header.flags |= FLAG_HEADER_CRC;
            let mut frame = encode(&header, &payload);
            let i = bit.index(payload.len() * 8);
            frame[HEADER_LEN + i / 8] ^= 1 << (i % 8);
            // By design: the header is intact, the payload is the link's business.
            let decoded = decode(&frame).unwrap();
            prop_assert_eq!(decoded.header, header);
            prop_assert!(!decoded.header.payload_checked());
            prop_assert_eq!(decoded.payload, &frame[HEADER_LEN..]);
        }

        #[test]
        fn truncation_and_trailing_bytes_are_rejected(header in arb_header(),
                                                      payload in proptest::collection::vec(any::<u8>(), 1..64),
                                                      cut in any::<prop::sample::Index>()) {
            let frame = encode(&header, &payload);
            let short = &frame[..cut.index(frame.len())];
            prop_assert!(decode(short).is_err());
            let mut long = frame.clone();
            long.push(0);
            prop_assert!(decode(&long).is_err());
        }
    }

    #[test]
    fn oversized_length_is_rejected_before_allocation() {
        let mut frame = encode(
            &Header::data(
                Address::from((SystemId(0), ModuleId(0))),
                Address::from((SystemId(1), ModuleId(0))),
                MessageType(1),
            ),
            b"",
        );
        frame[40..44].copy_from_slice(&u32::MAX.to_le_bytes());
        assert_eq!(
            peek_frame_len(&frame),
            Err(DecodeError::TooLong {
                declared: u32::MAX as u64
            })
        );
    }

    fn sample_header(flags: u8) -> Header {
        let mut h = Header::data(
            Address::from((SystemId(1), ModuleId(2))),
            Address::from((SystemId(3), ModuleId(4))),
            MessageType(1),
        );
        h.flags = flags;
        h.seq = 7;
        h
    }

    #[test]
    fn header_crc_covers_exactly_the_header() {
        let payload = vec![0xa5u8; 1000];
        let frame = encode(&sample_header(FLAG_HEADER_CRC), &payload);
        let mut head = frame[..HEADER_LEN].to_vec();
        head[CRC_OFFSET..CRC_OFFSET + 4].fill(0);
        let stored = u32_at(&frame, CRC_OFFSET);
        assert_eq!(stored, crc32fast::hash(&head));
        let decoded = decode(&frame).unwrap();
        assert!(!decoded.header.payload_checked());
        assert_eq!(decoded.payload, &payload[..]);
        // The same frame without the flag is checksummed over everything.
        let full = encode(&sample_header(0), &payload);
        assert!(decode(&full).unwrap().header.payload_checked());
        assert_ne!(u32_at(&full, CRC_OFFSET), crc32fast::hash(&head));
    }

    #[test]
    fn header_crc_frames_still_check_header_and_lengths() {
        let frame = encode(&sample_header(FLAG_HEADER_CRC), b"payload");
        // A corrupted header field (the sequence number).
        let mut bad = frame.clone();
        bad[20] ^= 0x01;
        assert!(matches!(decode(&bad), Err(DecodeError::BadChecksum { .. })));
        // Clearing the flag makes the CRC cover the payload, which it was not computed over.
        let mut cleared = frame.clone();
        cleared[4] &= !FLAG_HEADER_CRC;
        assert!(matches!(
            decode(&cleared),
            Err(DecodeError::BadChecksum { .. })
        ));
        // Lengths: a byte missing, a byte too many.
        assert!(matches!(
            decode(&frame[..frame.len() - 1]),
            Err(DecodeError::LengthMismatch { .. })
        ));
        let mut long = frame.clone();
        long.push(0);
        assert!(matches!(
            decode(&long),
            Err(DecodeError::LengthMismatch { .. })
        ));
        // Magic and version are checked first, as always.
        let mut magic = frame.clone();
        magic[0] = b'X';
        assert!(matches!(decode(&magic), Err(DecodeError::BadMagic { .. })));
        // A payload byte changed: accepted, by design.
        let mut payload = frame.clone();
        *payload.last_mut().unwrap() ^= 0xff;
        assert_eq!(decode(&payload).unwrap().payload, b"payloa\x9b");
    }

    #[test]
    fn wrong_version_is_named() {
        let mut frame = encode(
            &Header::data(
                Address::from((SystemId(0), ModuleId(0))),
                Address::from((SystemId(1), ModuleId(0))),
                MessageType(1),
            ),
            b"x",
        );
        frame[2] = 9;
        assert_eq!(decode(&frame), Err(DecodeError::BadVersion { found: 9 }));
    }
}
