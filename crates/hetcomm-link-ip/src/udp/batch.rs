//! Batches (`"HB"`): many small frames in one datagram, each as a record (a u32 length
//! and the frame); building a batch and walking a received one.

use super::{
    Batch, BATCH_HEADER_LEN, BATCH_LENGTH_LEN, BATCH_MAGIC, BATCH_VERSION, FRAGMENT_MAGIC,
};

/// Appends `frame` as a record to batch `b` (starting the batch with its header if it is
/// empty); the caller has checked that it fits.
pub(super) fn push_record(b: &mut Batch, frame: &[u8]) {
    if b.buf.is_empty() {
        b.buf.extend_from_slice(&batch_header());
    }
    // A frame that fits a datagram is far below 4 GiB.
    b.buf.extend_from_slice(&(frame.len() as u32).to_le_bytes());
    b.buf.extend_from_slice(frame);
    b.frames += 1;
}

/// Whether `frame` may travel in a batch: its record fits one datagram with the batch header.
/// Any bytes may: the link never looks inside a frame.
pub(super) fn batchable(frame: &[u8], mtu: usize) -> bool {
    BATCH_HEADER_LEN + BATCH_LENGTH_LEN + frame.len() <= mtu
}

/// Whether a frame that fits one datagram must nevertheless be sent as a one-fragment message,
/// because a receiver would take the bare datagram for a fragment or a batch.
pub(super) fn misread_alone(frame: &[u8]) -> bool {
    frame.starts_with(&FRAGMENT_MAGIC) || frame.starts_with(&BATCH_MAGIC)
}

/// The batch header every batch datagram starts with.
fn batch_header() -> [u8; BATCH_HEADER_LEN] {
    [BATCH_MAGIC[0], BATCH_MAGIC[1], BATCH_VERSION, 0]
}

/// Checks the batch header of datagram `d` (which starts with [`BATCH_MAGIC`]); returns the
/// records behind it, or `None` if the header is not one this version reads.
pub fn batch_records(d: &[u8]) -> Option<BatchFrames<'_>> {
    (d.len() >= BATCH_HEADER_LEN && d[..BATCH_HEADER_LEN] == batch_header()).then(|| BatchFrames {
        rest: &d[BATCH_HEADER_LEN..],
    })
}

/// The frames of a batch datagram's records, front to back. Stops at the first record that
/// does not fit in what is left (or a length cut short) and leaves it, with everything after
/// it, in [`BatchFrames::rest`].
#[derive(Clone, Debug)]
pub struct BatchFrames<'a> {
    rest: &'a [u8],
}

impl<'a> BatchFrames<'a> {
    /// What the walk has not taken: empty after a well-formed batch, else its malformed tail.
    pub fn rest(&self) -> &'a [u8] {
        self.rest
    }
}

impl<'a> Iterator for BatchFrames<'a> {
    type Item = &'a [u8];

    fn next(&mut self) -> Option<&'a [u8]> {
        // Every record takes at least its 4-byte length, so every step makes progress.
        let (len, body) = self.rest.split_first_chunk::<BATCH_LENGTH_LEN>()?;
        let n = u32::from_le_bytes(*len) as usize;
        if n > body.len() {
            return None;
        }
        let (frame, rest) = body.split_at(n);
        self.rest = rest;
        Some(frame)
    }
}
