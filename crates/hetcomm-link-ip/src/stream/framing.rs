//! The byte format (see "Byte format" in the [module docs](super)): encoding and checking
//! hellos and record headers, and writing records with as few vectored writes as the
//! socket allows.

use std::io::{self, IoSlice};
use std::time::{Duration, Instant};

use hetcomm_core::SystemId;
// Named only by doc links.
#[cfg(doc)]
use hetcomm_link::Link;

use super::{
    StreamSocket, HELLO_LEN, HELLO_MAGIC, RECORD_HEADER_LEN, RECORD_MAGIC, STREAM_VERSION,
};

/// The record header of a frame of `len` bytes (callers have checked `len` against
/// `max_frame`, which is far below 4 GiB).
pub(super) fn record_header(len: usize) -> [u8; RECORD_HEADER_LEN] {
    let len = u32::try_from(len).unwrap_or(u32::MAX);
    let mut head = [0u8; RECORD_HEADER_LEN];
    head[0..2].copy_from_slice(&RECORD_MAGIC);
    head[2] = STREAM_VERSION;
    head[4..8].copy_from_slice(&len.to_le_bytes());
    head
}

pub(super) fn append_record(out: &mut Vec<u8>, frame: FrameParts<'_>) {
    out.extend_from_slice(&record_header(frame.len()));
    out.extend_from_slice(frame.head);
    out.extend_from_slice(frame.body);
}

/// One frame, given as `head` followed by `body` ([`Link::send_parts`]), or whole in `head`.
#[derive(Clone, Copy)]
pub(super) struct FrameParts<'a> {
    pub(super) head: &'a [u8],
    pub(super) body: &'a [u8],
}

impl<'a> FrameParts<'a> {
    pub(super) fn whole(frame: &'a [u8]) -> Self {
        FrameParts {
            head: frame,
            body: &[],
        }
    }

    pub(super) fn len(&self) -> usize {
        self.head.len() + self.body.len()
    }
}

/// Writes all of `parts`, in order (see [`write_slices`]).
pub(super) fn write_parts<S: StreamSocket, const N: usize>(
    socket: &mut S,
    parts: &[&[u8]; N],
    timeout: Duration,
) -> io::Result<()> {
    let mut slices = [IoSlice::new(&[]); N];
    let mut n = 0;
    for part in parts.iter().filter(|p| !p.is_empty()) {
        slices[n] = IoSlice::new(part);
        n += 1;
    }
    write_slices(socket, &mut slices[..n], timeout)
}

/// The most slices one vectored write is given (Linux's `IOV_MAX` is 1024).
const MAX_SLICES_PER_WRITE: usize = 1024;

/// Writes all of `slices`, in order, with as few vectored writes as the socket allows,
/// bounded by `timeout` in total (the socket's own timeout bounds each call; it is shortened
/// after a partial write so that the sum stays within `timeout`, and restored at the end).
pub(super) fn write_slices<S: StreamSocket>(
    socket: &mut S,
    mut slices: &mut [IoSlice<'_>],
    timeout: Duration,
) -> io::Result<()> {
    let deadline = Instant::now() + timeout;
    let mut shortened = false;
    IoSlice::advance_slices(&mut slices, 0);
    while !slices.is_empty() {
        let result = match &slices[..slices.len().min(MAX_SLICES_PER_WRITE)] {
            [one] => socket.write(one),
            many => socket.write_vectored(many),
        };
        match result {
            Ok(0) => return Err(io::ErrorKind::WriteZero.into()),
            Ok(n) => IoSlice::advance_slices(&mut slices, n),
            Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
            Err(e) => return Err(e),
        }
        if !slices.is_empty() {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Err(io::ErrorKind::TimedOut.into());
            }
            socket.set_write_timeout(Some(left))?;
            shortened = true;
        }
    }
    if shortened {
        socket.set_write_timeout(Some(timeout))?;
    }
    Ok(())
}

/// Encodes the hello of system `id`.
pub fn encode_hello(id: SystemId) -> [u8; HELLO_LEN] {
    let mut h = [0u8; HELLO_LEN];
    h[0..2].copy_from_slice(&HELLO_MAGIC);
    h[2] = STREAM_VERSION;
    h[4..6].copy_from_slice(&id.0.to_le_bytes());
    h
}

/// Decodes a hello; `None` if it is not one this version writes.
pub fn decode_hello(h: &[u8; HELLO_LEN]) -> Option<SystemId> {
    let ok = h[0..2] == HELLO_MAGIC && h[2] == STREAM_VERSION && h[3] == 0 && h[6..8] == [0, 0];
    ok.then(|| SystemId(u16::from_le_bytes([h[4], h[5]])))
}

/// Checks a record header against `max_frame` and returns the frame length it announces.
pub fn decode_record_header(h: &[u8; RECORD_HEADER_LEN], max_frame: usize) -> Option<usize> {
    if h[0..2] != RECORD_MAGIC || h[2] != STREAM_VERSION || h[3] != 0 {
        return None;
    }
    let len = u32::from_le_bytes([h[4], h[5], h[6], h[7]]) as usize;
    (len <= max_frame).then_some(len)
}
