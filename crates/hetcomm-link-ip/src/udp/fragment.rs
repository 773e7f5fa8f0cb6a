//! Fragments (`"HF"`): the header of one piece of a frame too large for one datagram,
//! encoding it and checking a received one (see "Datagram format" in the
//! [module docs](super)).

use hetcomm_core::SystemId;

use super::{FRAGMENT_HEADER_LEN, FRAGMENT_MAGIC, FRAGMENT_VERSION};

/// A parsed fragment header.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FragmentHeader {
    /// The sending system.
    pub sender: SystemId,
    /// This fragment's index.
    pub index: u16,
    /// How many fragments the message has.
    pub count: u16,
    /// The message id, unique per sender until it wraps.
    pub message_id: u32,
    /// The whole frame's length.
    pub total: u32,
}

impl FragmentHeader {
    /// Encodes the header.
    pub fn encode(&self) -> [u8; FRAGMENT_HEADER_LEN] {
        let mut h = [0u8; FRAGMENT_HEADER_LEN];
        h[0..2].copy_from_slice(&FRAGMENT_MAGIC);
        h[2] = FRAGMENT_VERSION;
        h[4..6].copy_from_slice(&self.sender.0.to_le_bytes());
        h[6..8].copy_from_slice(&self.index.to_le_bytes());
        h[8..10].copy_from_slice(&self.count.to_le_bytes());
        h[12..16].copy_from_slice(&self.message_id.to_le_bytes());
        h[16..20].copy_from_slice(&self.total.to_le_bytes());
        h
    }

    /// The byte range of fragment `index` within the frame, derived from `total` and `count`.
    pub(super) fn piece_range(&self) -> std::ops::Range<usize> {
        let (total, count) = (self.total as usize, usize::from(self.count));
        let chunk = total.div_ceil(count);
        let start = usize::from(self.index) * chunk;
        start..(start + chunk).min(total)
    }
}

/// Why a fragment datagram was rejected.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum FragmentError {
    /// Shorter than the fragment header.
    #[error("fragment of {len} bytes is shorter than the {FRAGMENT_HEADER_LEN}-byte header")]
    Truncated {
        /// Bytes received.
        len: usize,
    },
    /// Wrong version or non-zero reserved bytes.
    #[error("fragment header version {version} or reserved bytes not understood")]
    BadHeader {
        /// The version byte found.
        version: u8,
    },
    /// Index, count and total do not fit together.
    #[error("fragment {index} of {count} for a {total}-byte frame is impossible (limit {max})")]
    BadGeometry {
        /// Declared index.
        index: u16,
        /// Declared count.
        count: u16,
        /// Declared total.
        total: u32,
        /// The receiver's `max_frame`.
        max: usize,
    },
    /// The piece is not as long as `total` and `count` say.
    #[error("fragment {index} carries {found} bytes, expected {expected}")]
    BadLength {
        /// Declared index.
        index: u16,
        /// Bytes carried.
        found: usize,
        /// Bytes expected.
        expected: usize,
    },
    /// Count or total differ from earlier fragments of the same message.
    #[error("fragment disagrees with earlier fragments of message {message_id}")]
    Inconsistent {
        /// The message id.
        message_id: u32,
    },
    /// The sender field names another system than the one at the source address.
    #[error("fragment claims sender {claimed} but comes from system {actual}'s address")]
    WrongSender {
        /// The sender field.
        claimed: SystemId,
        /// The system at the source address.
        actual: SystemId,
    },
    /// The sender field names no fleet system (from an address that is no fleet endpoint).
    #[error("fragment claims sender {claimed}, which is no fleet system")]
    UnknownSender {
        /// The sender field.
        claimed: SystemId,
    },
}

/// Parses and checks a fragment datagram (which starts with [`FRAGMENT_MAGIC`]) against
/// `max_frame`; returns the header and the piece.
pub fn parse_fragment(
    datagram: &[u8],
    max_frame: usize,
) -> Result<(FragmentHeader, &[u8]), FragmentError> {
    if datagram.len() < FRAGMENT_HEADER_LEN {
        return Err(FragmentError::Truncated {
            len: datagram.len(),
        });
    }
    let d = datagram;
    let version = d[2];
    if d[0..2] != FRAGMENT_MAGIC || version != FRAGMENT_VERSION || d[3] != 0 || d[10..12] != [0, 0]
    {
        return Err(FragmentError::BadHeader { version });
    }
    let u16_at = |at: usize| u16::from_le_bytes([d[at], d[at + 1]]);
    let h = FragmentHeader {
        sender: SystemId(u16_at(4)),
        index: u16_at(6),
        count: u16_at(8),
        message_id: u32::from_le_bytes([d[12], d[13], d[14], d[15]]),
        total: u32::from_le_bytes([d[16], d[17], d[18], d[19]]),
    };
    let (total, count) = (h.total as usize, usize::from(h.count));
    // Every piece must be non-empty: (count - 1) full chunks must leave bytes for the last.
    let geometry_ok = count >= 1
        && h.index < h.count
        && total >= 1
        && total <= max_frame
        && count <= total
        && (count - 1) * total.div_ceil(count) < total;
    if !geometry_ok {
        return Err(FragmentError::BadGeometry {
            index: h.index,
            count: h.count,
            total: h.total,
            max: max_frame,
        });
    }
    let piece = &d[FRAGMENT_HEADER_LEN..];
    let expected = h.piece_range().len();
    if piece.len() != expected {
        return Err(FragmentError::BadLength {
            index: h.index,
            found: piece.len(),
            expected,
        });
    }
    Ok((h, piece))
}
