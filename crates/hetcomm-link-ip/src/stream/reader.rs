//! [`RecordReader`]: splitting a connection's byte stream into frames, small records
//! through a read buffer and large frames straight into a buffer of their own (see
//! "Receiving" in the [module docs](super)).

use std::io::{self, IoSliceMut, Read};
use std::sync::Arc;

use hetcomm_core::{BufferPool, FrameBuf};

use super::framing::decode_record_header;
use super::{
    StreamSocket, DIRECT_READ_MIN, LARGE_BUF_KEEP, POOLED_BUF_STEP, READ_AHEAD_AFTER_LARGE,
    READ_BUF_LEN, RECORD_HEADER_LEN,
};

/// Why a connection's record stream ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum StreamEnd {
    /// End of stream (or a read error) between records.
    Clean,
    /// End of stream or a read error inside a record: that frame is lost.
    Cut,
    /// A record header that is malformed.
    Bad,
    /// A well-formed record header announcing more than `max_frame` bytes (this many): the
    /// sender's `max_message_bytes` is larger than the receiver's.
    Oversize(usize),
    /// Not an end: a non-blocking socket has nothing more for now. The reader keeps what it
    /// has read and resumes with the next call.
    Pending,
}

/// Where [`RecordReader::next_record`] left a complete frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum FrameAt {
    /// In the read buffer, at this range.
    Buffered(usize, usize),
    /// At the start of the large-frame buffer, this long.
    Large(usize),
}

/// What a [`RecordReader`] reads from: any [`Read`], and, when it has one, the file
/// descriptor behind it (see [`StreamSocket::raw_fd`]).
pub(super) trait RecordSource: Read {
    /// A descriptor that `readv(2)` may read instead of [`Read`] (`None`: never).
    fn fd(&self) -> Option<std::os::fd::RawFd> {
        None
    }
}

impl<S: StreamSocket> RecordSource for S {
    fn fd(&self) -> Option<std::os::fd::RawFd> {
        self.raw_fd().map(|fd| std::os::fd::AsRawFd::as_raw_fd(&fd))
    }
}

impl RecordSource for &[u8] {}

/// `readv(2)` of `fd` into `spare` (memory not yet initialised), then `ahead`. Returns the
/// number of bytes read; the first `min(n, spare.len())` bytes of `spare` are then initialised.
fn readv_uninit(
    fd: std::os::fd::RawFd,
    spare: &mut [std::mem::MaybeUninit<u8>],
    ahead: &mut [u8],
) -> io::Result<usize> {
    let iov = [
        libc::iovec {
            iov_base: spare.as_mut_ptr().cast(),
            iov_len: spare.len(),
        },
        libc::iovec {
            iov_base: ahead.as_mut_ptr().cast(),
            iov_len: ahead.len(),
        },
    ];
    // SAFETY: both iovecs describe memory we hold exclusively for the call, with their true
    // lengths; the kernel only writes into them. Writing into uninitialised bytes is fine.
    let n = unsafe { libc::readv(fd, iov.as_ptr(), 2) };
    if n < 0 {
        Err(io::Error::last_os_error())
    } else {
        Ok(n as usize)
    }
}

/// Splits a connection's byte stream into frames: small records through a read buffer (as
/// many per read as have arrived), large frames straight into a buffer of their own size.
pub(super) struct RecordReader {
    max_frame: usize,
    /// The read buffer, [`READ_BUF_LEN`] bytes once the first read needs it (empty before, so
    /// that idle connections cost no buffer).
    buf: Box<[u8]>,
    /// Unconsumed bytes are `buf[start..end]`.
    start: usize,
    end: usize,
    /// The last frame was read directly: read only a little ahead into `buf` (see
    /// [`READ_AHEAD_AFTER_LARGE`]), since another large frame is likely next.
    after_large: bool,
    /// Reused for frames over [`DIRECT_READ_MIN`]; at least as long as the longest recent one.
    /// When handing out, a buffer from `pool` each time instead.
    pub(super) large: Vec<u8>,
    /// Large frames are given away ([`take_large`](Self::take_large)) rather than reused, in
    /// buffers that come back to this pool when the sink drops them.
    pool: Option<Arc<BufferPool>>,
    /// A large frame whose reading a non-blocking socket interrupted: its length, and how
    /// many of its bytes are in `large`.
    partial: Option<(usize, usize)>,
}

impl RecordReader {
    pub(super) fn new(max_frame: usize) -> Self {
        RecordReader {
            max_frame,
            buf: Box::default(),
            start: 0,
            end: 0,
            after_large: false,
            large: Vec::new(),
            pool: None,
            partial: None,
        }
    }

    /// A reader that gives large frames away: each one is read into a buffer of its own from
    /// `pool`, taken with [`take_large`](Self::take_large).
    pub(super) fn handing_out(max_frame: usize, pool: Arc<BufferPool>) -> Self {
        RecordReader {
            pool: Some(pool),
            ..RecordReader::new(max_frame)
        }
    }

    /// Whether large frames are given away.
    pub(super) fn hands_out(&self) -> bool {
        self.pool.is_some()
    }

    /// The buffer of a [`FrameAt::Large`] frame, exactly its bytes, for a reader
    /// [`handing_out`](Self::handing_out) (the next large frame gets another buffer).
    pub(super) fn take_large(&mut self) -> FrameBuf {
        let frame = std::mem::take(&mut self.large);
        match &self.pool {
            Some(pool) => pool.wrap(frame),
            None => frame.into(),
        }
    }

    /// The bytes of a frame [`next_record`](Self::next_record) returned.
    pub(super) fn frame(&self, at: FrameAt) -> &[u8] {
        match at {
            FrameAt::Buffered(from, to) => &self.buf[from..to],
            FrameAt::Large(len) => &self.large[..len],
        }
    }

    /// Reads until `buf[start..]` holds at least `need` bytes (`need` ≤ the buffer's size),
    /// first moving what is left to the front if it would not fit.
    fn fill<R: Read>(&mut self, r: &mut R, need: usize) -> Result<(), StreamEnd> {
        if self.buf.is_empty() {
            self.buf = vec![0; READ_BUF_LEN].into_boxed_slice();
        }
        if self.start == self.end {
            self.start = 0;
            self.end = 0;
        } else if self.start + need > self.buf.len() {
            self.buf.copy_within(self.start..self.end, 0);
            self.end -= self.start;
            self.start = 0;
        }
        while self.end - self.start < need {
            let limit = if self.after_large {
                (self.start + READ_AHEAD_AFTER_LARGE.max(need)).min(self.buf.len())
            } else {
                self.buf.len()
            };
            match r.read(&mut self.buf[self.end..limit]) {
                Ok(0) => break,
                Ok(n) => self.end += n,
                Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                Err(e) if e.kind() == io::ErrorKind::WouldBlock => return Err(StreamEnd::Pending),
                Err(_) => break,
            }
        }
        match self.end - self.start {
            n if n >= need => Ok(()),
            0 => Err(StreamEnd::Clean),
            _ => Err(StreamEnd::Cut),
        }
    }

    /// Reads the next record; its frame is then [`frame`](Self::frame)`(at)` until the next
    /// call.
    pub(super) fn next_record<R: RecordSource>(&mut self, r: &mut R) -> Result<FrameAt, StreamEnd> {
        if let Some((len, got)) = self.partial {
            self.finish_large(r, len, got)?;
            return Ok(FrameAt::Large(len));
        }
        self.fill(r, RECORD_HEADER_LEN)?;
        let mut head = [0u8; RECORD_HEADER_LEN];
        head.copy_from_slice(&self.buf[self.start..self.start + RECORD_HEADER_LEN]);
        // Checked before anything is allocated or read for it.
        let len = match decode_record_header(&head, usize::MAX) {
            None => return Err(StreamEnd::Bad),
            Some(len) if len > self.max_frame => return Err(StreamEnd::Oversize(len)),
            Some(len) => len,
        };
        let body = self.start + RECORD_HEADER_LEN;
        if body + len <= self.end || len <= DIRECT_READ_MIN {
            if body + len > self.end {
                // A small partial record: completing it in the buffer costs at most a move of
                // DIRECT_READ_MIN bytes per buffer's worth of records.
                self.fill(r, RECORD_HEADER_LEN + len).map_err(|e| match e {
                    StreamEnd::Pending => StreamEnd::Pending,
                    _ => StreamEnd::Cut,
                })?;
            }
            let from = self.start + RECORD_HEADER_LEN;
            self.start = from + len;
            self.after_large = false;
            return Ok(FrameAt::Buffered(from, from + len));
        }
        self.read_large(r, body, len)?;
        Ok(FrameAt::Large(len))
    }

    /// Reads the frame of `len` bytes whose first bytes are `buf[body..end]` into `large`.
    fn read_large<R: RecordSource>(
        &mut self,
        r: &mut R,
        body: usize,
        len: usize,
    ) -> Result<(), StreamEnd> {
        let have = self.end - body;
        if let Some(pool) = &self.pool {
            // The last one left with its frame (or is still here after an error: replaced).
            // Rounded up so that frames of similar sizes can reuse each other's buffers.
            self.large = pool.take(len.next_multiple_of(POOLED_BUF_STEP));
            self.large.extend_from_slice(&self.buf[body..self.end]);
            if r.fd().is_none() {
                // Read through `Read`, which needs initialised memory.
                self.large.resize(len, 0);
            }
        } else {
            if self.large.len() > LARGE_BUF_KEEP && len < LARGE_BUF_KEEP / 4 {
                self.large = Vec::new();
            }
            if self.large.len() < len {
                // A fresh zeroed allocation rather than `resize`, which would copy the old
                // bytes.
                self.large = vec![0; len];
            }
            self.large[..have].copy_from_slice(&self.buf[body..self.end]);
        }
        self.start = 0;
        self.end = 0;
        self.after_large = true;
        self.finish_large(r, len, have)
    }

    /// Reads the rest of a large frame, of which `got` bytes are in `large`: in place, with
    /// whatever follows it (the next record header, with luck) into the front of the read
    /// buffer in the same read, but at most [`READ_AHEAD_AFTER_LARGE`] bytes of it. A handed-out
    /// buffer is read into straight from the descriptor, uninitialised (`large.len()` is then
    /// `got`). On [`StreamEnd::Pending`] the progress is kept in `partial`.
    fn finish_large<R: RecordSource>(
        &mut self,
        r: &mut R,
        len: usize,
        mut got: usize,
    ) -> Result<(), StreamEnd> {
        self.partial = None;
        let uninit = if self.pool.is_some() { r.fd() } else { None };
        while got < len {
            let want = len - got;
            let ahead = &mut self.buf[..READ_AHEAD_AFTER_LARGE];
            let result = match uninit {
                Some(fd) => readv_uninit(fd, &mut self.large.spare_capacity_mut()[..want], ahead),
                None => r.read_vectored(&mut [
                    IoSliceMut::new(&mut self.large[got..len]),
                    IoSliceMut::new(ahead),
                ]),
            };
            match result {
                Ok(0) => return Err(StreamEnd::Cut),
                Ok(n) => {
                    let into_frame = n.min(want);
                    if uninit.is_some() {
                        // SAFETY: the kernel wrote the first `into_frame` bytes of the spare
                        // capacity (and the rest of n into `buf`).
                        unsafe { self.large.set_len(got + into_frame) };
                    }
                    got += into_frame;
                    if n > want {
                        self.end = n - want;
                    }
                }
                Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                Err(e) if e.kind() == io::ErrorKind::WouldBlock => {
                    self.partial = Some((len, got));
                    return Err(StreamEnd::Pending);
                }
                Err(_) => return Err(StreamEnd::Cut),
            }
        }
        Ok(())
    }

    /// Whether the read buffer holds a whole record (or a bad header) that
    /// [`next_record`](Self::next_record) can return without reading the socket.
    pub(super) fn has_buffered_record(&self) -> bool {
        if self.partial.is_some() || self.end - self.start < RECORD_HEADER_LEN {
            return false;
        }
        let mut head = [0u8; RECORD_HEADER_LEN];
        head.copy_from_slice(&self.buf[self.start..self.start + RECORD_HEADER_LEN]);
        match decode_record_header(&head, self.max_frame) {
            None => true,
            Some(len) => self.start + RECORD_HEADER_LEN + len <= self.end,
        }
    }
}
