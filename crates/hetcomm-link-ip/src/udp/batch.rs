//! Batches (`"HB"`, the framing of [`hetcomm_link::batch`]) in UDP datagrams: which frames
//! may travel in one, and the frames that must not travel bare because they would be read
//! as a fragment or a batch.

use hetcomm_link::batch::{self, BATCH_MAGIC};

use super::{Batch, FRAGMENT_MAGIC};

/// Appends `frame` as a record to batch `b` (starting the batch with its header if it is
/// empty); the caller has checked that it fits.
pub(super) fn push_record(b: &mut Batch, frame: &[u8]) {
    batch::push_record(&mut b.buf, frame);
    b.frames += 1;
}

/// Whether `frame` may travel in a batch: its record fits one datagram with the batch header.
/// Any bytes may: the link never looks inside a frame.
pub(super) fn batchable(frame: &[u8], mtu: usize) -> bool {
    batch::batch_len_of(frame.len()) <= mtu
}

/// Whether a frame that fits one datagram must nevertheless be sent as a one-fragment message,
/// because a receiver would take the bare datagram for a fragment or a batch.
pub(super) fn misread_alone(frame: &[u8]) -> bool {
    frame.starts_with(&FRAGMENT_MAGIC) || frame.starts_with(&BATCH_MAGIC)
}
