//! A frame as a serialized `std_msgs/msg/UInt8MultiArray` sample (encapsulation header and
//! CDR body), written and read by hand: the Cyclone DDS backend hands DDS raw samples, so it
//! needs the same bytes rustdds's serde writes for [`crate::msg::FrameMessage`], without a
//! copy of the frame on the way out (the header goes in its own I/O vector).

/// Encapsulation header of little-endian plain CDR (`CDR_LE`), as ROS 2 writes it.
const CDR_LE: [u8; 2] = [0x00, 0x01];

/// The bytes that come before a `len`-byte frame: the encapsulation header (with the count
/// of padding bytes at the end of the sample in its options, as Cyclone DDS writes it), an
/// empty `layout` (no dimensions, `data_offset` 0) and the length of `data`; and how many
/// zero bytes must follow the frame to pad the sample to a multiple of 4.
pub fn header(len: usize) -> ([u8; 16], usize) {
    let pad = (4 - len % 4) % 4;
    let mut h = [0u8; 16];
    h[..2].copy_from_slice(&CDR_LE);
    h[3] = pad as u8;
    // h[4..8]: `layout.dim` is an empty sequence; h[8..12]: `layout.data_offset` = 0.
    h[12..16].copy_from_slice(&(len as u32).to_le_bytes());
    (h, pad)
}

/// Zero bytes to pad a sample with (at most 3 are used).
pub const PADDING: [u8; 3] = [0; 3];

/// Why a sample is not a frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum Malformed {
    /// The sample ends before the message does.
    #[error("the sample is truncated")]
    Truncated,
    /// The encapsulation is not plain CDR (XCDR1 or XCDR2, either byte order).
    #[error("unsupported encapsulation {0:#06x}")]
    Encoding(u16),
    /// The `data` field is empty: a hetcomm frame never is.
    #[error("the message carries no data")]
    Empty,
}

/// A cursor over a CDR body; alignment is relative to the body's start.
struct Reader<'a> {
    body: &'a [u8],
    at: usize,
    little: bool,
}

impl<'a> Reader<'a> {
    fn take(&mut self, n: usize) -> Result<&'a [u8], Malformed> {
        let end = self.at.checked_add(n).ok_or(Malformed::Truncated)?;
        let out = self.body.get(self.at..end).ok_or(Malformed::Truncated)?;
        self.at = end;
        Ok(out)
    }

    fn u32(&mut self) -> Result<u32, Malformed> {
        self.at = self.at.next_multiple_of(4);
        let b: [u8; 4] = self.take(4)?.try_into().expect("4 bytes");
        Ok(match self.little {
            true => u32::from_le_bytes(b),
            false => u32::from_be_bytes(b),
        })
    }
}

/// The `data` of a serialized `std_msgs/msg/UInt8MultiArray` sample (header included), in
/// either byte order, XCDR1 or plain XCDR2 (where this type's fields align alike). A
/// non-empty `layout` (another ROS 2 program's) is skipped over.
pub fn frame(sample: &[u8]) -> Result<&[u8], Malformed> {
    let head = sample.get(..4).ok_or(Malformed::Truncated)?;
    let id = u16::from_be_bytes([head[0], head[1]]);
    // CDR_BE 0, CDR_LE 1, PLAIN_CDR2_BE 6, PLAIN_CDR2_LE 7.
    if !matches!(id, 0 | 1 | 6 | 7) {
        return Err(Malformed::Encoding(id));
    }
    let mut r = Reader {
        body: &sample[4..],
        at: 0,
        little: id & 1 == 1,
    };
    let dims = r.u32()?;
    for _ in 0..dims {
        let label = r.u32()? as usize;
        r.take(label)?;
        r.u32()?; // size
        r.u32()?; // stride
    }
    r.u32()?; // data_offset
    let len = r.u32()? as usize;
    match r.take(len)? {
        [] => Err(Malformed::Empty),
        data => Ok(data),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(frame: &[u8]) -> Vec<u8> {
        let (h, pad) = header(frame.len());
        [&h[..], frame, &PADDING[..pad]].concat()
    }

    #[test]
    fn frames_round_trip_padded_to_four() {
        for n in 1..9 {
            let f: Vec<u8> = (0..n as u8).collect();
            let s = sample(&f);
            assert_eq!(s.len() % 4, 0);
            assert_eq!(s[3] as usize, s.len() - 16 - n);
            assert_eq!(frame(&s), Ok(&f[..]));
        }
    }

    #[test]
    fn foreign_layouts_and_big_endian_are_read() {
        // Big endian, one dimension labelled "xy" (length 3 with its NUL), then 2 data bytes.
        let mut s = vec![0, 0, 0, 0];
        s.extend_from_slice(&1u32.to_be_bytes());
        s.extend_from_slice(&3u32.to_be_bytes());
        s.extend_from_slice(b"xy\0\0"); // label and one byte of alignment
        s.extend_from_slice(&2u32.to_be_bytes()); // size
        s.extend_from_slice(&1u32.to_be_bytes()); // stride
        s.extend_from_slice(&0u32.to_be_bytes()); // data_offset
        s.extend_from_slice(&2u32.to_be_bytes());
        s.extend_from_slice(&[9, 8]);
        assert_eq!(frame(&s), Ok(&[9u8, 8][..]));
    }

    #[test]
    fn what_is_not_a_frame_is_refused() {
        assert_eq!(frame(&[0, 1]), Err(Malformed::Truncated));
        assert_eq!(frame(&[0, 0x0a, 0, 0]), Err(Malformed::Encoding(0x0a)));
        assert_eq!(frame(&sample(&[])), Err(Malformed::Empty));
        let mut s = sample(&[1, 2, 3, 4]);
        s.truncate(18);
        assert_eq!(frame(&s), Err(Malformed::Truncated));
        // A dimension count far past the sample's end.
        let mut s = vec![0, 1, 0, 0];
        s.extend_from_slice(&u32::MAX.to_le_bytes());
        assert_eq!(frame(&s), Err(Malformed::Truncated));
    }
}
