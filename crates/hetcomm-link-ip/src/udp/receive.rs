//! The receive side: the receive thread or, for a driven link, whoever calls
//! [`Readable::read_ready`], and [`RxState`], which turns datagrams into frames (whole,
//! batched or reassembled from fragments) and counts what it drops.

use parking_lot::Mutex;
use std::collections::HashMap;
use std::io;
use std::mem::MaybeUninit;
use std::net::{SocketAddr, UdpSocket};
use std::os::fd::RawFd;
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::{Duration, Instant};

use hetcomm_core::{BufferPool, FrameBuf, SystemId};
use hetcomm_link::{FrameSink, Peer, Readable};

use super::fragment::FragmentError;
use super::reassembly::{pooled, recycle, Reassembler, Reassembly, POOLED_MIN};
use super::{add, Shared, BATCH_MAGIC, FRAGMENT_MAGIC};
use hetcomm_link::batch::batch_records;

/// Large enough for any UDP datagram, so nothing is silently truncated.
pub(super) const RECV_BUF_LEN: usize = 65_536;
/// Most bytes of large-frame buffers a link keeps for reuse when its sink keeps frames (they
/// come back as the modules drop the messages), and when it does not (they come back as soon
/// as the sink returns, or as an incomplete message is dropped).
pub(super) const RECEIVE_POOL_BYTES: usize = 8 << 20;
pub(super) const REASSEMBLY_POOL_BYTES: usize = 1 << 20;

/// The pool of a link whose sink keeps frames ([`FrameSink::takes_frames`]) or not.
pub(super) fn receive_pool(takes_frames: bool) -> Arc<BufferPool> {
    BufferPool::new(if takes_frames {
        RECEIVE_POOL_BYTES
    } else {
        REASSEMBLY_POOL_BYTES
    })
}

/// The receive side: the socket, one receive buffer reused for every datagram, and what the
/// datagrams are made into.
pub(super) struct Receiver {
    pub(super) socket: Arc<UdpSocket>,
    pub(super) buf: Vec<u8>,
    pub(super) state: RxState,
}

/// Receive errors after which reading simply goes on: timeouts, signals, and an earlier
/// send's ICMP error, which some platforms report on the next receive.
fn is_transient(e: &io::Error) -> bool {
    matches!(
        e.kind(),
        io::ErrorKind::WouldBlock
            | io::ErrorKind::TimedOut
            | io::ErrorKind::Interrupted
            | io::ErrorKind::ConnectionRefused
            | io::ErrorKind::ConnectionReset
    )
}

/// Receives one datagram if one is waiting, without blocking (the socket itself stays
/// blocking, for the sends).
fn recv_dontwait(socket: &UdpSocket, buf: &mut [u8]) -> io::Result<(usize, Option<SocketAddr>)> {
    // SAFETY: `[u8]` and `[MaybeUninit<u8>]` have the same layout, and socket2 promises never
    // to write uninitialised bytes into the buffer (it passes it straight to recvfrom(2)), so
    // `buf` stays initialised.
    let uninit = unsafe { &mut *(buf as *mut [u8] as *mut [MaybeUninit<u8>]) };
    let (n, from) =
        socket2::SockRef::from(socket).recv_from_with_flags(uninit, libc::MSG_DONTWAIT)?;
    Ok((n, from.as_socket()))
}

impl Receiver {
    /// The receive thread's loop.
    pub(super) fn run(mut self) {
        let mut consecutive_errors = 0u32;
        while !self.state.shared.closing.load(Ordering::SeqCst) {
            match self.socket.recv_from(&mut self.buf) {
                Ok((n, src)) => {
                    consecutive_errors = 0;
                    if self.state.shared.closing.load(Ordering::SeqCst) {
                        break;
                    }
                    self.state.on_datagram(&self.buf[..n], src);
                }
                Err(e) if is_transient(&e) => {}
                Err(_) => {
                    // An unexpected, possibly persistent error: pause a little so it cannot
                    // spin a core, and keep serving.
                    consecutive_errors = consecutive_errors.saturating_add(1);
                    if consecutive_errors > 3 {
                        std::thread::sleep(Duration::from_millis(10));
                    }
                }
            }
            self.state.upkeep();
        }
    }

    /// Reads at most `budget` datagrams that have arrived, without blocking; returns the
    /// number of frames handed to the sink. An unexpected error is returned only when no frame
    /// was handed on (a persistent one shows again at the next call).
    fn read_ready(&mut self, budget: usize) -> io::Result<usize> {
        let mut frames = 0;
        let mut failure = None;
        for _ in 0..budget {
            match recv_dontwait(&self.socket, &mut self.buf) {
                Ok((n, Some(src))) => frames += self.state.on_datagram(&self.buf[..n], src),
                // Not an IP source: cannot happen on a UDP/IP socket; nothing to attribute.
                Ok((_, None)) => {}
                Err(e) if e.kind() == io::ErrorKind::WouldBlock => break,
                Err(e) if is_transient(&e) => {}
                Err(e) => {
                    failure = Some(e);
                    break;
                }
            }
        }
        self.state.upkeep();
        match failure {
            Some(e) if frames == 0 => Err(e),
            _ => Ok(frames),
        }
    }
}

/// What received datagrams are made into, and where they go.
pub(super) struct RxState {
    pub(super) shared: Arc<Shared>,
    pub(super) sink: Arc<dyn FrameSink>,
    /// The sink keeps frames handed over to it: reassembled frames, and large frames that
    /// came whole, are handed over in a buffer of the pool.
    pub(super) takes_frames: bool,
    /// The buffers of large frames (shared with the reassembler).
    pub(super) pool: Arc<BufferPool>,
    pub(super) senders: HashMap<SocketAddr, SystemId>,
    pub(super) reassembler: Reassembler,
}

impl RxState {
    /// Takes one datagram from `src`; returns the number of frames handed to the sink.
    fn on_datagram(&mut self, d: &[u8], src: SocketAddr) -> usize {
        let c = &self.shared.counters;
        let system = self.senders.get(&src).copied();
        let from = match system {
            Some(id) => Peer::System(id),
            None => Peer::Unknown,
        };
        if d.starts_with(&BATCH_MAGIC) {
            return self.deliver_batch(d, from);
        }
        if !d.starts_with(&FRAGMENT_MAGIC) {
            if self.takes_frames && d.len() >= POOLED_MIN {
                // One copy into a buffer the sink keeps (as the message's payload), instead of
                // one into a fresh allocation per frame made by the sink.
                let mut buf = pooled(&self.pool, d.len());
                buf.extend_from_slice(d);
                self.deliver_owned(buf, from);
            } else {
                self.deliver(d, from);
            }
            return 1;
        }
        let evictions_before = self.reassembler.evictions();
        let outcome = self.reassembler.on_fragment(d, src, system, Instant::now());
        add(
            &c.reassembly_evictions,
            self.reassembler.evictions() - evictions_before,
        );
        match outcome {
            Reassembly::Complete(frame) => {
                if self.takes_frames {
                    self.deliver_owned(frame, from);
                } else {
                    self.deliver(&frame, from);
                    recycle(Some(&self.pool), frame);
                }
                1
            }
            Reassembly::Pending => 0,
            Reassembly::Duplicate => {
                add(&c.duplicate_fragments, 1);
                0
            }
            Reassembly::Rejected { dropped, error } => {
                add(&c.bad_datagrams, 1);
                add(&c.reassembly_evictions, dropped as u64);
                if let FragmentError::BadGeometry { total, max, .. } = error {
                    if total as usize > max {
                        self.on_oversize(total, max, src);
                    }
                }
                0
            }
        }
    }

    /// A well-formed fragment of a message larger than this link's `max_frame`: the sender's
    /// `max_message_bytes` is larger than ours. Counted; the first one is logged.
    fn on_oversize(&self, total: u32, max: usize, src: SocketAddr) {
        let c = &self.shared.counters;
        add(&c.oversize_fragments, 1);
        if !c.oversize_logged.swap(true, Ordering::Relaxed) {
            eprintln!(
                "hetcomm udp link: dropped a fragment from {src} of a {total}-byte frame, more \
                 than this link's largest frame of {max} bytes: the sender's max_message_bytes \
                 is larger than ours (further such fragments are only counted in \
                 oversize_fragments)"
            );
        }
    }

    /// Counts a frame about to be handed to the sink: first, so that whoever the sink wakes
    /// sees the counters already updated.
    fn count_frame(&self, from: Peer) {
        let c = &self.shared.counters;
        if from == Peer::Unknown {
            add(&c.from_unknown_address, 1);
        }
        add(&c.frames_received, 1);
    }

    fn deliver(&self, frame: &[u8], from: Peer) {
        self.count_frame(from);
        self.sink.on_frame(frame, from);
    }

    /// Hands `frame` over to a sink that keeps frames; a large buffer comes back to the pool
    /// when the sink drops it.
    fn deliver_owned(&self, frame: Vec<u8>, from: Peer) {
        self.count_frame(from);
        let frame = if frame.capacity() >= POOLED_MIN {
            self.pool.wrap(frame)
        } else {
            FrameBuf::from(frame)
        };
        self.sink.on_frame_owned(frame, from);
    }

    /// Hands up the complete frames of batch datagram `d`; returns how many.
    fn deliver_batch(&self, d: &[u8], from: Peer) -> usize {
        let c = &self.shared.counters;
        let Some(records) = batch_records(d) else {
            // A batch header this version does not read: nothing in it can be trusted.
            add(&c.bad_datagrams, 1);
            return 0;
        };
        // Walked once to count, so that the counters are updated (once per datagram) before
        // the sink wakes anyone; the walk only reads the records' lengths.
        let mut walk = records.clone();
        let n = walk.by_ref().count();
        if !walk.rest().is_empty() || n == 0 {
            add(&c.bad_datagrams, 1);
        }
        if n == 0 {
            return 0;
        }
        add(&c.batches_received, 1);
        if from == Peer::Unknown {
            add(&c.from_unknown_address, n as u64);
        }
        add(&c.frames_received, n as u64);
        // Every frame of the batch carries the peer the datagram came from.
        self.sink.on_frames(&mut records.clone(), from);
        n
    }

    /// Expires incomplete messages whose time ran out and publishes the bytes held.
    fn upkeep(&mut self) {
        let c = &self.shared.counters;
        if self.reassembler.needs_upkeep() {
            let expired = self.reassembler.expire(Instant::now());
            add(&c.reassembly_timeouts, expired as u64);
        }
        c.buffered_bytes
            .store(self.reassembler.held_bytes() as u64, Ordering::Relaxed);
    }
}

/// The receive side of a driven link, read by whichever thread calls
/// [`Readable::read_ready`].
pub(super) struct DrivenReceiver {
    pub(super) fd: RawFd,
    pub(super) receiver: Mutex<Receiver>,
}

impl Readable for DrivenReceiver {
    fn fd(&self) -> RawFd {
        self.fd
    }

    fn read_ready(&self, budget: usize) -> io::Result<usize> {
        let mut rx = match self.receiver.try_lock() {
            Some(rx) => rx,
            // Another thread is reading (or a sink called back in): this call must not block,
            // and that reader hands on whatever has arrived.
            None => return Ok(0),
        };
        rx.read_ready(budget)
    }
}
