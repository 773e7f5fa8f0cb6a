//! Batch framing (`"HB"`): many small frames in one datagram or message, each as a record (a
//! u32 little-endian length and the frame) behind a 4-byte header. Shared by the links that
//! put several held frames in one unit of their transport (UDP datagrams, Zenoh puts), so
//! the format is defined once; each link decides when frames are held and how a batch is
//! told from a lone frame on its wire.

/// Magic of a batch: `"HB"`.
pub const BATCH_MAGIC: [u8; 2] = *b"HB";
/// Version of the batch header.
pub const BATCH_VERSION: u8 = 1;
/// Size of the batch header: magic, version, a reserved byte.
pub const BATCH_HEADER_LEN: usize = 4;
/// Size of the length (u32, little-endian) in front of each frame of a batch.
pub const BATCH_LENGTH_LEN: usize = 4;

/// The header every batch starts with.
pub fn batch_header() -> [u8; BATCH_HEADER_LEN] {
    [BATCH_MAGIC[0], BATCH_MAGIC[1], BATCH_VERSION, 0]
}

/// Appends `frame` as a record to the batch being built in `buf` (starting it with the batch
/// header if `buf` is empty); the caller has checked that it fits (a record is far below
/// 4 GiB).
pub fn push_record(buf: &mut Vec<u8>, frame: &[u8]) {
    if buf.is_empty() {
        buf.extend_from_slice(&batch_header());
    }
    buf.extend_from_slice(&(frame.len() as u32).to_le_bytes());
    buf.extend_from_slice(frame);
}

/// Bytes a batch of this one frame takes: header, length and frame.
pub fn batch_len_of(frame_len: usize) -> usize {
    BATCH_HEADER_LEN + BATCH_LENGTH_LEN + frame_len
}

/// Checks the batch header of `d` (which starts with [`BATCH_MAGIC`]); returns the records
/// behind it, or `None` if the header is not one this version reads.
pub fn batch_records(d: &[u8]) -> Option<BatchFrames<'_>> {
    (d.len() >= BATCH_HEADER_LEN && d[..BATCH_HEADER_LEN] == batch_header()).then(|| BatchFrames {
        rest: &d[BATCH_HEADER_LEN..],
    })
}

/// The frames of a batch's records, front to back. Stops at the first record that does not
/// fit in what is left (or a length cut short) and leaves it, with everything after it, in
/// [`BatchFrames::rest`].
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
