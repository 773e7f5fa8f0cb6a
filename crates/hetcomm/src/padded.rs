//! [`CachePadded`]: keeps a value on cache lines of its own.

use std::ops::Deref;

/// A value aligned (and so padded) to 128 bytes, the span adjacent-line prefetchers pull in
/// together on x86: data written by one thread at a high rate (a counter, a lock) must not
/// share a line with data another thread reads or writes, or every write moves the line
/// between cores ("false sharing").
#[derive(Debug, Default)]
#[repr(align(128))]
pub(crate) struct CachePadded<T>(pub T);

impl<T> Deref for CachePadded<T> {
    type Target = T;
    fn deref(&self) -> &T {
        &self.0
    }
}
