//! Write-behind: frames a sender gives away ([`Link::send_owned`]) and sends in a stream are
//! written by the link's writer thread, so that the sender prepares the next frame (the
//! security layer seals it) while the socket takes this one. See "Write-behind" in the
//! [module docs](super).

use parking_lot::MutexGuard;
use std::collections::VecDeque;
use std::io::{self, IoSlice};
use std::time::{Duration, Instant};

use hetcomm_core::{FrameBuf, SystemId};
use hetcomm_link::LinkError;
// Named only by doc links.
#[cfg(doc)]
use hetcomm_link::Link;

use super::framing::{record_header, write_slices, FrameParts};
use super::{
    add, bump, lock, PeerEntry, PeerSlot, Shared, StreamLink, StreamSocket, StreamTransport,
    RECORD_HEADER_LEN,
};
use crate::common::BEHIND_MAX_BYTES;

/// One record waiting for the writer: the record header (`None` for a moved batch of held
/// records, which carries its own) and the bytes.
struct Record {
    head: Option<[u8; RECORD_HEADER_LEN]>,
    bytes: FrameBuf,
    /// Frames it carries (one, or a batch's count).
    frames: usize,
}

/// What a peer's slot keeps for write-behind.
pub(super) struct Behind<S> {
    records: VecDeque<Record>,
    /// Bytes in `records`.
    queued_bytes: usize,
    /// Bytes the writer is writing now, outside the slot's lock (0: none).
    writing_bytes: usize,
    /// The writer has this peer (records outside the lock, or its turn in line): every other
    /// frame to this peer goes behind its records.
    writing: bool,
    /// The writer's handle of the peer's connection (a clone of `conn`), while it is up.
    socket: Option<S>,
    /// When the caller's last given-away frame to this peer returned.
    last_given: Option<Instant>,
}

impl<S> Behind<S> {
    pub(super) fn new() -> Self {
        Behind {
            records: VecDeque::new(),
            queued_bytes: 0,
            writing_bytes: 0,
            writing: false,
            socket: None,
            last_given: None,
        }
    }

    /// The writer has this peer's frames: any write of the caller would overtake them.
    pub(super) fn active(&self) -> bool {
        self.writing || !self.records.is_empty()
    }

    /// Bytes waiting for or being written by the writer.
    pub(super) fn bytes(&self) -> usize {
        self.queued_bytes + self.writing_bytes
    }

    /// Forgets the queued records (their connection is gone) and returns how many frames
    /// they carried.
    fn clear(&mut self) -> usize {
        let frames = self.records.iter().map(|r| r.frames).sum();
        self.records.clear();
        self.queued_bytes = 0;
        frames
    }

    /// The connection is gone: the writer's handle with it.
    pub(super) fn connection_dropped(&mut self) {
        self.socket = None;
    }
}

impl<T: StreamTransport> StreamLink<T> {
    /// [`Link::send_owned`]: written behind a streaming sender, on the caller's thread
    /// otherwise.
    pub(super) fn send_given(&self, to: SystemId, frame: FrameBuf) -> Result<(), LinkError> {
        let entry = self.entry_for(to, frame.len())?;
        let policy = self.shared.config.write_behind;
        let mut slot = lock(&entry.slot);
        let behind = slot.behind.active()
            || (policy.applies(slot.behind.last_given)
                && writer_handle(&mut slot)
                && self.start_writer());
        let result = if behind {
            let head = Some(record_header(frame.len()));
            let result;
            (slot, result) = self.enqueue(to, entry, slot, head, frame, 1);
            result
        } else if slot.conn.is_none() {
            self.queue_for_connection(to, entry, &mut slot, whole(&frame), true)
        } else {
            self.write_batch(to, entry, &mut slot, Some(whole(&frame)))
        };
        // From the return, not the call: a write on this thread is not part of the gap.
        slot.behind.last_given = Some(Instant::now());
        result
    }

    /// A write of the caller's to a peer whose frames the writer has (the slot is
    /// [`Behind::active`]): the frame is copied behind them, after the held batch, so that
    /// nothing overtakes what was sent first. Without a frame, only the held batch moves.
    pub(super) fn copy_behind(
        &self,
        to: SystemId,
        entry: &PeerEntry<T>,
        mut slot: MutexGuard<'_, PeerSlot<T::Socket>>,
        frame: Option<FrameParts<'_>>,
    ) -> Result<(), LinkError> {
        let Some(frame) = frame else {
            move_held_behind(&mut slot);
            return Ok(());
        };
        let mut bytes = Vec::with_capacity(frame.len());
        bytes.extend_from_slice(frame.head);
        bytes.extend_from_slice(frame.body);
        let head = Some(record_header(bytes.len()));
        self.enqueue(to, entry, slot, head, bytes.into(), 1).1
    }

    /// Queues `bytes` for the writer behind the held batch, waiting (up to the write timeout)
    /// while the queue is full, and hands the peer to the writer if it had nothing of it.
    /// The writer thread runs ([`start_writer`](Self::start_writer)).
    fn enqueue<'a>(
        &self,
        to: SystemId,
        entry: &'a PeerEntry<T>,
        mut slot: MutexGuard<'a, PeerSlot<T::Socket>>,
        head: Option<[u8; RECORD_HEADER_LEN]>,
        bytes: FrameBuf,
        frames: usize,
    ) -> (MutexGuard<'a, PeerSlot<T::Socket>>, Result<(), LinkError>) {
        let deadline = Instant::now() + self.shared.config.write_timeout;
        while !slot.behind.records.is_empty()
            && slot.behind.queued_bytes + bytes.len() > BEHIND_MAX_BYTES
        {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                let e = LinkError::Congested {
                    peer: to,
                    reason: format!(
                        "{} bytes have waited for {} for the {} ms write timeout",
                        slot.behind.bytes(),
                        entry.addr,
                        self.shared.config.write_timeout.as_millis()
                    ),
                };
                return (slot, Err(e));
            }
            entry.room.wait_for(&mut slot, left);
        }
        let was_active = slot.behind.active();
        if !was_active && slot.conn.is_none() {
            // The writer dropped the connection while we waited (its frames are counted).
            let e = LinkError::Unreachable {
                peer: to,
                reason: format!(
                    "the connection to {} failed; the next send reconnects",
                    entry.addr
                ),
            };
            return (slot, Err(e));
        }
        move_held_behind(&mut slot);
        slot.behind.queued_bytes += bytes.len() + head.map_or(0, |h| h.len());
        slot.behind.records.push_back(Record {
            head,
            bytes,
            frames,
        });
        if !was_active {
            // The writer takes it from here: nothing else writes to this peer until it is done.
            slot.behind.writing = true;
            self.writer.ready(to);
        }
        (slot, Ok(()))
    }

    /// Starts the writer thread unless it runs; false if it cannot (the caller then writes).
    fn start_writer(&self) -> bool {
        let shared = self.shared.clone();
        let peers = self.peers.clone();
        self.writer.start(
            format!("hetcomm-{}-tx-{}", T::NAME, self.local()),
            move |to| peers.get(&to).is_some_and(|e| write_behind(&shared, e)),
        )
    }
}

/// Moves the held batch, if any, behind the writer's records (it was sent before anything
/// queued after it).
fn move_held_behind<S>(slot: &mut PeerSlot<S>) {
    if slot.held_frames == 0 {
        return;
    }
    let batch = std::mem::take(&mut slot.out);
    slot.behind.queued_bytes += batch.len();
    slot.behind.records.push_back(Record {
        head: None,
        bytes: batch.into(),
        frames: std::mem::take(&mut slot.held_frames),
    });
}

/// Makes sure the writer has its own handle of the peer's connection; false without a
/// connection or if the socket cannot be cloned (the caller then writes itself).
fn writer_handle<S: StreamSocket>(slot: &mut PeerSlot<S>) -> bool {
    if slot.behind.socket.is_none() {
        slot.behind.socket = slot.conn.as_ref().and_then(|c| c.try_clone().ok());
    }
    slot.behind.socket.is_some()
}

fn whole(frame: &FrameBuf) -> FrameParts<'_> {
    FrameParts::whole(frame)
}

/// The writer's turn at one peer: writes every record queued now in one vectored write (or
/// as few as the socket allows). True if more were queued meanwhile: the peer goes to the
/// back of the line, so that one streaming peer does not starve the others. A failed write
/// drops the connection (the next send reconnects) and counts every frame it had as dropped.
fn write_behind<T: StreamTransport>(shared: &Shared<T>, entry: &PeerEntry<T>) -> bool {
    let mut slot = lock(&entry.slot);
    let records: Vec<Record> = slot.behind.records.drain(..).collect();
    let frames: usize = records.iter().map(|r| r.frames).sum();
    slot.behind.writing_bytes = std::mem::take(&mut slot.behind.queued_bytes);
    // Made before the first record was queued (`writer_handle`), kept between turns.
    let socket = slot.behind.socket.take();
    drop(slot);
    // The queue is empty again: room for senders waiting on it.
    entry.room.notify_all();
    let result = match socket {
        Some(mut s) => write_records(&mut s, &records, shared.config.write_timeout).map(|()| s),
        None => Err(io::Error::other(
            "no handle of the connection for the writer",
        )),
    };
    // Back to the sender's pool before the lock is taken again.
    drop(records);
    let mut slot = lock(&entry.slot);
    slot.behind.writing_bytes = 0;
    match result {
        Ok(s) => {
            add(&shared.counters.frames_sent, frames);
            add(&shared.counters.frames_written_behind, frames);
            slot.behind.socket = Some(s);
        }
        Err(_) => {
            bump(&shared.counters.write_failures);
            let queued = slot.behind.clear();
            add(&shared.counters.held_frames_dropped, frames + queued);
            slot.drop_connection();
        }
    }
    let more = !slot.behind.records.is_empty();
    if !more {
        slot.behind.writing = false;
        drop(slot);
        // Senders waiting for the writer to finish go on.
        entry.room.notify_all();
    }
    more
}

fn write_records<S: StreamSocket>(
    socket: &mut S,
    records: &[Record],
    timeout: Duration,
) -> io::Result<()> {
    let mut slices = Vec::with_capacity(records.len() * 2);
    for r in records {
        if let Some(h) = &r.head {
            slices.push(IoSlice::new(h));
        }
        slices.push(IoSlice::new(&r.bytes));
    }
    write_slices(socket, &mut slices, timeout)
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeMap;
    use std::io::Read;
    use std::os::unix::net::UnixListener;
    use std::path::PathBuf;
    use std::sync::Arc;
    use std::time::{Duration, Instant};

    use hetcomm_core::{BufferPool, SystemId};
    use hetcomm_link::{FrameSink, Link, Peer};

    use super::super::framing::{encode_hello, record_header};
    use super::super::{StreamConfig, StreamLink};
    use crate::unix::{UnixAddr, UnixTransport};
    use crate::WriteBehind;

    struct Nobody;
    impl FrameSink for Nobody {
        fn on_frame(&self, _: &[u8], _: Peer) {}
    }

    const A: SystemId = SystemId(1);
    const B: SystemId = SystemId(2);

    /// A link of A whose peer B is a raw listener, so that the test reads what A writes.
    fn link_to_raw_listener(
        name: &str,
        write_behind: WriteBehind,
    ) -> (StreamLink<UnixTransport>, UnixListener, PathBuf) {
        let dir =
            std::env::temp_dir().join(format!("hetcomm-behind-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let raw_b = UnixListener::bind(dir.join("b.sock")).unwrap();
        let a = StreamLink::new(
            UnixTransport,
            A,
            UnixListener::bind(dir.join("a.sock")).unwrap(),
            BTreeMap::from([(B, UnixAddr(dir.join("b.sock")))]),
            Arc::new(Nobody),
            StreamConfig {
                write_behind,
                ..StreamConfig::default()
            },
        )
        .unwrap();
        (a, raw_b, dir)
    }

    /// Sends `first` and waits until the connector has written it: the connection is up.
    fn connect_with(a: &StreamLink<UnixTransport>, first: &[u8]) {
        a.send(B, first).unwrap();
        let deadline = Instant::now() + Duration::from_secs(10);
        while a.stream_stats().frames_sent == 0 && Instant::now() < deadline {
            std::thread::sleep(Duration::from_millis(1));
        }
        assert_eq!(
            a.stream_stats().frames_sent,
            1,
            "the connection did not come up"
        );
    }

    fn frame(i: usize, len: usize) -> Vec<u8> {
        (0..len).map(|j| (i * 7 + j) as u8).collect()
    }

    fn given(pool: &Arc<BufferPool>, bytes: &[u8]) -> hetcomm_core::FrameBuf {
        let mut buf = pool.take(bytes.len());
        buf.extend_from_slice(bytes);
        pool.wrap(buf)
    }

    /// A stream of given-away frames, with plain, held and flushed frames among them, leaves
    /// in send order; most of it through the writer thread, while the reader is slow enough
    /// that senders wait for room. Dropping the link writes what is still queued.
    #[test]
    fn given_frames_are_written_behind_the_sender_in_order() {
        let (a, raw_b, dir) = link_to_raw_listener("order", WriteBehind::Always);
        let pool = BufferPool::new(64 << 20);
        let frames: Vec<Vec<u8>> = (0..120)
            .map(|i| frame(i, if i % 10 == 5 { 300 } else { 64 << 10 }))
            .collect();
        let mut expected = encode_hello(A).to_vec();
        let first = frame(999, 10);
        for f in std::iter::once(&first).chain(&frames) {
            expected.extend_from_slice(&record_header(f.len()));
            expected.extend_from_slice(f);
        }
        let want = expected.len();
        let reader = std::thread::spawn(move || {
            let (mut conn, _) = raw_b.accept().unwrap();
            // Slow at first: the socket fills and the writer's queue with it.
            std::thread::sleep(Duration::from_millis(200));
            let mut got = vec![0; want];
            conn.read_exact(&mut got).unwrap();
            got
        });
        connect_with(&a, &first);
        for (i, f) in frames.iter().enumerate() {
            let result = match i % 30 {
                5 => a.send(B, f),
                15 => a.send_held(B, f),
                25 => a.send_held(B, f).and_then(|()| a.flush()),
                _ => a.send_owned(B, given(&pool, f)),
            };
            result.unwrap_or_else(|e| panic!("frame {i}: {e}"));
        }
        // The reader takes everything in the end: wait until the writer has written it all.
        let deadline = Instant::now() + Duration::from_secs(10);
        while a.pending_bytes() > 0 && Instant::now() < deadline {
            std::thread::sleep(Duration::from_millis(1));
        }
        let behind = a.stream_stats().frames_written_behind;
        drop(a);
        let got = reader.join().unwrap();
        assert!(
            got == expected,
            "the bytes on the connection are the frames in send order"
        );
        // Every given-away frame (108 of 120), and those sent otherwise while the writer had
        // the peer's frames.
        assert!(behind >= 108, "{behind} frames written behind the sender");
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// When the connection fails under the writer, every frame it had is counted as dropped
    /// (never lost silently), later sends get errors or reconnect, and nothing hangs.
    #[test]
    fn frames_lost_behind_the_sender_are_counted() {
        let (a, raw_b, dir) = link_to_raw_listener("fail", WriteBehind::Always);
        let pool = BufferPool::new(64 << 20);
        let closer = std::thread::spawn(move || {
            let (mut conn, _) = raw_b.accept().unwrap();
            // The hello, the first frame and some of the stream.
            let mut some = vec![0; 256 << 10];
            conn.read_exact(&mut some).unwrap();
            drop(conn);
            raw_b
        });
        connect_with(&a, &frame(0, 10));
        let f = frame(1, 64 << 10);
        let mut taken = 1u64;
        for _ in 0..400 {
            if a.send_owned(B, given(&pool, &f)).is_ok() {
                taken += 1;
            }
        }
        let _listener = closer.join().unwrap();
        // Whatever is still queued or being written is settled within the write timeout.
        let deadline = Instant::now() + Duration::from_secs(10);
        while a.pending_bytes() > 0 && Instant::now() < deadline {
            std::thread::sleep(Duration::from_millis(10));
        }
        let s = a.stream_stats();
        drop(a);
        assert!(s.write_failures >= 1, "{s:?}");
        assert!(s.held_frames_dropped >= 1, "{s:?}");
        // Every frame the link took was written to the socket or counted as dropped.
        assert_eq!(
            s.frames_sent + s.held_frames_dropped + s.frames_lost_connecting,
            taken,
            "{s:?}"
        );
        let _ = std::fs::remove_dir_all(&dir);
    }
}
