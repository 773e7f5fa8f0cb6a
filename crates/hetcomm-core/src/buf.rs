//! [`PayloadBuf`]: the bytes of one message payload, owned, stored inline when small.
//!
//! Most robot messages (a pose, a command, a status) are a few dozen bytes. Keeping those
//! inside the value instead of on the heap means a message handed from one thread to another
//! costs no allocation on the sender and no free on the receiver — with glibc's per-thread
//! caches, an allocation freed by another thread is the slow path on both sides. Large
//! payloads stay on the heap, and a received frame buffer can become the payload without
//! moving its bytes ([`PayloadBuf::from_frame`]).

use std::fmt;
use std::ops::Deref;

use crate::pool::FrameBuf;

/// Payloads up to this many bytes are stored inline.
pub const INLINE_PAYLOAD: usize = 64;

/// An owned payload: inline up to [`INLINE_PAYLOAD`] bytes, on the heap beyond. Reads as a
/// `[u8]` (it derefs to one); compare it with slices and vectors directly.
#[derive(Clone)]
pub struct PayloadBuf(Repr);

#[derive(Clone)]
enum Repr {
    Inline {
        len: u8,
        bytes: [u8; INLINE_PAYLOAD],
    },
    /// `buf[start..]` is the payload (a whole received frame, header skipped, or a vector).
    Heap { buf: FrameBuf, start: usize },
}

impl PayloadBuf {
    /// An empty payload.
    pub const fn new() -> Self {
        PayloadBuf(Repr::Inline {
            len: 0,
            bytes: [0; INLINE_PAYLOAD],
        })
    }

    /// A copy of `bytes` (inline when it fits).
    pub fn copy_from_slice(bytes: &[u8]) -> Self {
        if bytes.len() <= INLINE_PAYLOAD {
            let mut inline = [0; INLINE_PAYLOAD];
            inline[..bytes.len()].copy_from_slice(bytes);
            PayloadBuf(Repr::Inline {
                len: bytes.len() as u8,
                bytes: inline,
            })
        } else {
            PayloadBuf(Repr::Heap {
                buf: bytes.to_vec().into(),
                start: 0,
            })
        }
    }

    /// Takes `vec` over: a small one is copied inline (and freed here, on the thread that
    /// made it), a large one is kept as it is.
    pub fn from_vec(vec: Vec<u8>) -> Self {
        if vec.len() <= INLINE_PAYLOAD {
            Self::copy_from_slice(&vec)
        } else {
            PayloadBuf(Repr::Heap {
                buf: vec.into(),
                start: 0,
            })
        }
    }

    /// The payload `frame[start..]` of a received frame, without copying it (a pooled frame
    /// goes back to its pool when the payload is dropped). A `start` past the end gives an
    /// empty payload.
    pub fn from_frame(frame: impl Into<FrameBuf>, start: usize) -> Self {
        let frame = frame.into();
        if start >= frame.len() {
            return Self::new();
        }
        if frame.len() - start <= INLINE_PAYLOAD {
            return Self::copy_from_slice(&frame[start..]);
        }
        PayloadBuf(Repr::Heap { buf: frame, start })
    }

    /// The bytes.
    pub fn as_slice(&self) -> &[u8] {
        match &self.0 {
            Repr::Inline { len, bytes } => &bytes[..usize::from(*len)],
            Repr::Heap { buf, start } => &buf[*start..],
        }
    }

    /// The bytes as a vector; free when the payload is a heap vector from its start.
    pub fn into_vec(self) -> Vec<u8> {
        match self.0 {
            Repr::Heap { buf, start: 0 } => buf.into_vec(),
            _ => self.as_slice().to_vec(),
        }
    }

    /// Whether the bytes are stored inline.
    pub fn is_inline(&self) -> bool {
        matches!(self.0, Repr::Inline { .. })
    }
}

impl Default for PayloadBuf {
    fn default() -> Self {
        Self::new()
    }
}

impl Deref for PayloadBuf {
    type Target = [u8];
    fn deref(&self) -> &[u8] {
        self.as_slice()
    }
}

impl AsRef<[u8]> for PayloadBuf {
    fn as_ref(&self) -> &[u8] {
        self.as_slice()
    }
}

impl fmt::Debug for PayloadBuf {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        fmt::Debug::fmt(self.as_slice(), f)
    }
}

impl PartialEq for PayloadBuf {
    fn eq(&self, other: &Self) -> bool {
        self.as_slice() == other.as_slice()
    }
}
impl Eq for PayloadBuf {}

impl PartialEq<[u8]> for PayloadBuf {
    fn eq(&self, other: &[u8]) -> bool {
        self.as_slice() == other
    }
}
impl PartialEq<&[u8]> for PayloadBuf {
    fn eq(&self, other: &&[u8]) -> bool {
        self.as_slice() == *other
    }
}
impl<const N: usize> PartialEq<[u8; N]> for PayloadBuf {
    fn eq(&self, other: &[u8; N]) -> bool {
        self.as_slice() == other
    }
}
impl<const N: usize> PartialEq<&[u8; N]> for PayloadBuf {
    fn eq(&self, other: &&[u8; N]) -> bool {
        self.as_slice() == *other
    }
}
impl PartialEq<Vec<u8>> for PayloadBuf {
    fn eq(&self, other: &Vec<u8>) -> bool {
        self.as_slice() == other.as_slice()
    }
}

impl From<Vec<u8>> for PayloadBuf {
    fn from(vec: Vec<u8>) -> Self {
        Self::from_vec(vec)
    }
}
impl From<&[u8]> for PayloadBuf {
    fn from(bytes: &[u8]) -> Self {
        Self::copy_from_slice(bytes)
    }
}
impl From<PayloadBuf> for Vec<u8> {
    fn from(p: PayloadBuf) -> Self {
        p.into_vec()
    }
}

/// Payload bytes on their way into a message: borrowed from the caller (copied only where
/// they must be kept) or already owned (moved there).
#[derive(Debug)]
pub enum PayloadSource<'a> {
    /// The caller's bytes.
    Borrowed(&'a [u8]),
    /// Bytes the message may keep as they are.
    Owned(PayloadBuf),
}

impl PayloadSource<'_> {
    /// The bytes.
    pub fn as_slice(&self) -> &[u8] {
        match self {
            PayloadSource::Borrowed(b) => b,
            PayloadSource::Owned(p) => p,
        }
    }

    /// The bytes as an owned payload (a copy only when borrowed).
    pub fn into_buf(self) -> PayloadBuf {
        match self {
            PayloadSource::Borrowed(b) => PayloadBuf::copy_from_slice(b),
            PayloadSource::Owned(p) => p,
        }
    }
}

/// Appends, moving to the heap once the inline room is used up (the payload encoder writes
/// straight into a `PayloadBuf`).
impl std::io::Write for PayloadBuf {
    fn write(&mut self, data: &[u8]) -> std::io::Result<usize> {
        match &mut self.0 {
            Repr::Inline { len, bytes } => {
                let used = usize::from(*len);
                if used + data.len() <= INLINE_PAYLOAD {
                    bytes[used..used + data.len()].copy_from_slice(data);
                    *len = (used + data.len()) as u8;
                } else {
                    let mut buf = Vec::with_capacity((used + data.len()).max(2 * INLINE_PAYLOAD));
                    buf.extend_from_slice(&bytes[..used]);
                    buf.extend_from_slice(data);
                    self.0 = Repr::Heap {
                        buf: buf.into(),
                        start: 0,
                    };
                }
            }
            Repr::Heap { buf, .. } => buf.extend_from_slice(data),
        }
        Ok(data.len())
    }

    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Write;

    #[test]
    fn small_is_inline_large_is_not() {
        let small = PayloadBuf::from_vec(vec![1; INLINE_PAYLOAD]);
        assert!(small.is_inline());
        assert_eq!(small, vec![1; INLINE_PAYLOAD]);
        let large = PayloadBuf::from_vec(vec![2; INLINE_PAYLOAD + 1]);
        assert!(!large.is_inline());
        assert_eq!(large.len(), INLINE_PAYLOAD + 1);
        assert_eq!(large.into_vec(), vec![2; INLINE_PAYLOAD + 1]);
    }

    #[test]
    fn frame_payload_skips_the_header_without_copying() {
        let mut frame = vec![0u8; 48];
        frame.extend(0..200u8);
        let ptr = frame.as_ptr();
        let p = PayloadBuf::from_frame(frame, 48);
        assert_eq!(p.as_ptr(), ptr.wrapping_add(48));
        assert_eq!(&p[..3], &[0, 1, 2]);
        assert_eq!(p.len(), 200);
        assert_eq!(p.clone().into_vec(), (0..200u8).collect::<Vec<_>>());
        assert!(PayloadBuf::from_frame(vec![1, 2], 5).is_empty());
        assert_eq!(PayloadBuf::from_frame(vec![9, 1, 2], 1), [1u8, 2]);
    }

    #[test]
    fn writing_spills_to_the_heap_in_order() {
        let mut p = PayloadBuf::new();
        for i in 0..100u8 {
            p.write_all(&[i]).unwrap();
        }
        assert!(!p.is_inline());
        assert_eq!(p, (0..100u8).collect::<Vec<_>>());
        let mut q = PayloadBuf::new();
        q.write_all(b"abc").unwrap();
        assert!(q.is_inline());
        assert_eq!(q, b"abc");
    }
}
