//! [`BufferPool`] and [`FrameBuf`]: received-frame buffers that go back where they came from.
//!
//! A stream link reads each large frame into a buffer of its own and hands it over; the
//! buffer becomes the message's payload ([`PayloadBuf`](crate::PayloadBuf)) and is dropped
//! on whichever thread consumes the message. Allocating on the reader thread and freeing on
//! the module's thread is the C allocator's slow path: glibc returns the freed memory to the
//! kernel and faults it back in on the next allocation (trims, page faults and TLB
//! shoot-downs were 10–15% of a 64 KiB receiver's time). A pool lets the buffers circulate
//! between the two threads instead, and keeps them warm.

use parking_lot::Mutex;
use std::fmt;
use std::ops::Deref;
use std::sync::Arc;

/// Buffers given back by dropped [`FrameBuf`]s, for the next frames to be read into. Holds at
/// most `max_bytes` of capacity; buffers beyond that (or larger than it) are freed.
pub struct BufferPool {
    free: Mutex<Free>,
    max_bytes: usize,
}

#[derive(Default)]
struct Free {
    bufs: Vec<Vec<u8>>,
    /// Total capacity of `bufs`.
    bytes: usize,
}

impl BufferPool {
    /// A pool that keeps at most `max_bytes` of buffers.
    pub fn new(max_bytes: usize) -> Arc<Self> {
        Arc::new(BufferPool {
            free: Mutex::new(Free::default()),
            max_bytes,
        })
    }

    /// An empty buffer with room for at least `len` bytes: the most recently returned one that
    /// is large enough (its memory is the likeliest to be in cache), or a new one. When none
    /// is large enough, the most recent one is freed, so that buffers too small for the
    /// frames now arriving do not fill the pool for good.
    pub fn take(&self, len: usize) -> Vec<u8> {
        // With no upper bound, "none fits" means every kept buffer is too small.
        self.take_within(len, usize::MAX)
    }

    /// Like [`take`](BufferPool::take), but never a buffer of more than `max_capacity`
    /// bytes: for a caller that is charged for the capacity it holds (a reassembly buffer
    /// counted against its limit), a much larger kept buffer would cost more than it asked
    /// for. Kept buffers outside the range stay in the pool, except that the most recent is
    /// freed when it is too small (as with `take`). A new buffer has room for exactly `len`.
    pub fn take_within(&self, len: usize, max_capacity: usize) -> Vec<u8> {
        let mut buf = self.take_kept(len, max_capacity);
        buf.clear();
        buf
    }

    /// Like [`take`](BufferPool::take), but a kept buffer still holds its old bytes (its
    /// length is what it was when it came back): for a caller that overwrites a whole frame,
    /// `resize` then zeroes only what lies beyond the old length, not the bytes it is about
    /// to write anyway.
    pub fn take_reused(&self, len: usize) -> Vec<u8> {
        self.take_kept(len, usize::MAX)
    }

    fn take_kept(&self, len: usize, max_capacity: usize) -> Vec<u8> {
        let mut free = self.lock();
        let fits = |b: &Vec<u8>| (len..=max_capacity).contains(&b.capacity());
        let misfit = match free.bufs.iter().rposition(fits) {
            Some(i) => {
                let buf = free.bufs.swap_remove(i);
                free.bytes -= buf.capacity();
                return buf;
            }
            None if free.bufs.last().is_some_and(|b| b.capacity() < len) => free.bufs.pop(),
            None => None,
        };
        if let Some(small) = &misfit {
            free.bytes -= small.capacity();
        }
        drop(free);
        drop(misfit);
        Vec::with_capacity(len)
    }

    /// Wraps `buf` so that it comes back to this pool when dropped.
    pub fn wrap(self: &Arc<Self>, buf: Vec<u8>) -> FrameBuf {
        FrameBuf {
            buf,
            start: 0,
            pool: Some(self.clone()),
        }
    }

    /// Bytes of capacity the pool holds now.
    pub fn kept_bytes(&self) -> usize {
        self.lock().bytes
    }

    /// Takes `buf` back if there is room; frees it (outside the lock) otherwise. What a
    /// [`FrameBuf`] from [`wrap`](BufferPool::wrap) does when dropped, for a buffer its owner
    /// never handed out.
    pub fn give(&self, buf: Vec<u8>) {
        let cap = buf.capacity();
        if cap == 0 || cap > self.max_bytes {
            return;
        }
        let mut free = self.lock();
        if free.bytes + cap <= self.max_bytes {
            free.bytes += cap;
            free.bufs.push(buf);
            return;
        }
        drop(free);
        drop(buf);
    }

    fn lock(&self) -> parking_lot::MutexGuard<'_, Free> {
        // The lists stay consistent whatever panicked while holding the lock.
        self.free.lock()
    }
}

impl fmt::Debug for BufferPool {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("BufferPool")
            .field("kept_bytes", &self.kept_bytes())
            .field("max_bytes", &self.max_bytes)
            .finish()
    }
}

/// An owned byte buffer that returns to its [`BufferPool`] (if it has one) when dropped.
/// Reads as a `[u8]`. A plain vector converts into one without a pool.
///
/// A layer between a link and the router that wraps frames in bytes of its own (a security
/// layer's prefix) strips them with [`FrameBuf::strip_prefix`] without moving the frame: what
/// the buffer reads as, and every offset into it (the router's payload offset included), then
/// starts at the frame the layer hands on.
pub struct FrameBuf {
    buf: Vec<u8>,
    /// Bytes at the front of `buf` that are not part of the frame (stripped prefixes).
    start: usize,
    pool: Option<Arc<BufferPool>>,
}

impl FrameBuf {
    /// The bytes (after any stripped prefix).
    pub fn as_slice(&self) -> &[u8] {
        &self.buf[self.start..]
    }

    /// The bytes as a vector, which then no longer returns to the pool (free without a
    /// stripped prefix; with one, the bytes move to the front).
    pub fn into_vec(mut self) -> Vec<u8> {
        self.pool = None;
        let mut buf = std::mem::take(&mut self.buf);
        buf.drain(..self.start);
        buf
    }

    /// Drops the first `n` bytes (all of them if fewer) from what the buffer reads as, without
    /// moving the rest: a layer's prefix in front of the frame it hands on.
    pub fn strip_prefix(&mut self, n: usize) {
        self.start += n.min(self.buf.len() - self.start);
    }

    /// The bytes (after any stripped prefix), to change in place: a layer that decrypts a
    /// frame where it lies.
    pub fn as_mut_slice(&mut self) -> &mut [u8] {
        &mut self.buf[self.start..]
    }

    /// Keeps only the first `len` bytes of what the buffer reads as (all of them if it has
    /// fewer): a layer's suffix behind the frame it hands on (an authentication tag).
    pub fn truncate(&mut self, len: usize) {
        self.buf.truncate(self.start + len);
    }

    /// How many bytes in front of the frame were stripped ([`FrameBuf::strip_prefix`]).
    pub fn stripped(&self) -> usize {
        self.start
    }

    /// Appends `bytes`.
    pub fn extend_from_slice(&mut self, bytes: &[u8]) {
        self.buf.extend_from_slice(bytes);
    }

    /// Whether the buffer goes back to a pool when dropped.
    pub fn is_pooled(&self) -> bool {
        self.pool.is_some()
    }
}

impl Drop for FrameBuf {
    fn drop(&mut self) {
        if let Some(pool) = self.pool.take() {
            pool.give(std::mem::take(&mut self.buf));
        }
    }
}

impl From<Vec<u8>> for FrameBuf {
    fn from(buf: Vec<u8>) -> Self {
        FrameBuf {
            buf,
            start: 0,
            pool: None,
        }
    }
}

/// A copy that belongs to no pool.
impl Clone for FrameBuf {
    fn clone(&self) -> Self {
        FrameBuf::from(self.as_slice().to_vec())
    }
}

impl Deref for FrameBuf {
    type Target = [u8];
    fn deref(&self) -> &[u8] {
        self.as_slice()
    }
}

impl fmt::Debug for FrameBuf {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("FrameBuf")
            .field("len", &self.len())
            .field("stripped", &self.start)
            .field("pooled", &self.is_pooled())
            .finish()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dropped_buffers_come_back_and_are_reused() {
        let pool = BufferPool::new(1 << 20);
        let mut v = pool.take(1000);
        assert!(v.capacity() >= 1000);
        v.extend_from_slice(&[5; 1000]);
        let ptr = v.as_ptr();
        let f = pool.wrap(v);
        assert!(f.is_pooled());
        assert_eq!(&f[..2], &[5, 5]);
        assert_eq!(pool.kept_bytes(), 0);
        drop(f);
        assert!(pool.kept_bytes() >= 1000);
        // The same memory, emptied.
        let again = pool.take(800);
        assert_eq!(again.as_ptr(), ptr);
        assert!(again.is_empty());
        assert_eq!(pool.kept_bytes(), 0);
        // Too small for the request: a new buffer, and the small one is let go.
        drop(pool.wrap(again));
        let big = pool.take(5000);
        assert!(big.capacity() >= 5000);
        assert_eq!(pool.kept_bytes(), 0);
        // Larger ones serve smaller requests.
        drop(pool.wrap(big));
        assert!(pool.take(100).capacity() >= 5000);
    }

    #[test]
    fn a_bounded_take_leaves_larger_buffers_in_the_pool() {
        let pool = BufferPool::new(1 << 20);
        drop(pool.wrap(Vec::with_capacity(5000)));
        drop(pool.wrap(Vec::with_capacity(100_000)));
        // The 100 000-byte buffer is too large for the bound: a new one, and both stay.
        let v = pool.take_within(20_000, 24_000);
        assert_eq!(v.capacity(), 20_000);
        assert_eq!(pool.kept_bytes(), 105_000);
        // The large one serves a request it fits.
        assert_eq!(pool.take_within(90_000, 120_000).capacity(), 100_000);
        assert_eq!(pool.kept_bytes(), 5000);
        // The 5000-byte one is now the most recent, and too small: freed.
        assert_eq!(pool.take_within(20_000, 24_000).capacity(), 20_000);
        assert_eq!(pool.kept_bytes(), 0);
        drop(pool.wrap(v));
        assert_eq!(pool.take_within(19_000, 20_000).capacity(), 20_000);
    }

    #[test]
    fn the_pool_keeps_no_more_than_its_bound() {
        let pool = BufferPool::new(10_000);
        let bufs: Vec<_> = (0..5)
            .map(|_| pool.wrap(Vec::with_capacity(4000)))
            .collect();
        drop(bufs);
        assert!(pool.kept_bytes() <= 10_000, "{}", pool.kept_bytes());
        assert_eq!(pool.kept_bytes(), 8000);
        // Larger than the whole pool: never kept.
        drop(pool.wrap(Vec::with_capacity(20_000)));
        assert_eq!(pool.kept_bytes(), 8000);
    }

    #[test]
    fn detached_and_cloned_buffers_do_not_return() {
        let pool = BufferPool::new(1 << 20);
        let f = pool.wrap(vec![1, 2, 3]);
        let c = f.clone();
        assert!(!c.is_pooled());
        assert_eq!(c.as_slice(), &[1, 2, 3]);
        drop(c);
        assert_eq!(pool.kept_bytes(), 0);
        assert_eq!(f.into_vec(), vec![1, 2, 3]);
        assert_eq!(pool.kept_bytes(), 0);
        let plain = FrameBuf::from(vec![9; 10]);
        assert!(!plain.is_pooled());
    }

    #[test]
    fn take_reused_keeps_the_old_bytes_and_take_clears_them() {
        let pool = BufferPool::new(1 << 20);
        pool.give(vec![7u8; 100]);
        let buf = pool.take_reused(50);
        assert_eq!(
            buf,
            vec![7u8; 100],
            "the old bytes, so resize need not zero them"
        );
        pool.give(buf);
        assert!(pool.take(50).is_empty());
    }

    #[test]
    fn a_stripped_prefix_is_skipped_without_moving_the_frame() {
        let pool = BufferPool::new(1 << 20);
        let mut f = pool.wrap(b"PREFIXframe bytes".to_vec());
        let at = f.as_ptr();
        f.strip_prefix(6);
        assert_eq!((&f[..], f.stripped()), (&b"frame bytes"[..], 6));
        assert_eq!(f.as_ptr(), at.wrapping_add(6), "not moved");
        assert_eq!(f.clone().as_slice(), b"frame bytes");
        f.strip_prefix(100);
        assert!(f.is_empty());
        drop(f);
        assert!(
            pool.kept_bytes() > 0,
            "the whole buffer goes back to its pool"
        );
        let mut g = FrameBuf::from(b"..xy".to_vec());
        g.strip_prefix(2);
        assert_eq!(g.into_vec(), b"xy");
    }
}
