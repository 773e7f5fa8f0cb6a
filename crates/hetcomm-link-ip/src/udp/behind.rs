//! Write-behind: frames a sender gives away ([`Link::send_owned`]) and sends in a stream are
//! sent by the link's writer thread, so that the sender prepares the next frame (the security
//! layer seals it) while the socket takes this one. See "Write-behind" in the
//! [module docs](super).

use std::collections::VecDeque;
use std::sync::Arc;
use std::time::{Duration, Instant};

use hetcomm_core::{FrameBuf, SystemId};
use hetcomm_link::LinkError;
// Named only by doc links.
#[cfg(doc)]
use hetcomm_link::Link;

use super::{add, lock, SendSide, UdpPeer};
use crate::common::BEHIND_MAX_BYTES;

/// How long a sender waits for room in the writer's queue, or for the writer to be done with
/// a peer before it sends itself, before it gets [`LinkError::Congested`]. Sending a full
/// queue takes a few milliseconds; only a socket that stopped taking datagrams takes this long.
pub(super) const WRITER_WAIT: Duration = Duration::from_secs(2);

/// What a peer keeps for write-behind.
#[derive(Default)]
pub(super) struct Behind {
    /// Frames waiting for the writer, in send order.
    queued: VecDeque<FrameBuf>,
    /// Bytes in `queued`.
    queued_bytes: usize,
    /// Bytes the writer is sending now, outside the lock (0: none).
    sending_bytes: usize,
    /// The writer has this peer (frames outside the lock, or its turn in line): a sender
    /// sends nothing itself to this peer until the writer is done.
    writing: bool,
    /// When the caller's last given-away frame to this peer returned.
    last_given: Option<Instant>,
    /// The queue's previous storage, kept so that a turn allocates nothing.
    spare: VecDeque<FrameBuf>,
}

impl Behind {
    /// The writer has this peer's frames: anything the caller sent now would overtake them.
    fn active(&self) -> bool {
        self.writing || !self.queued.is_empty()
    }
}

impl SendSide {
    /// [`Link::send_owned`]: sent behind a streaming sender, on the caller's thread otherwise.
    pub(super) fn send_given(
        self: &Arc<Self>,
        to: SystemId,
        frame: FrameBuf,
    ) -> Result<(), LinkError> {
        self.check_size(&frame)?;
        let peer = self.peer(to)?;
        {
            let mut b = lock(&peer.batch);
            if b.frames > 0 {
                // Held frames go first. Their failure is counted; the result is this frame's.
                self.wait_for_writer(to, peer)?;
                let _ = self.send_batch(to, peer.addr, &mut b, 0);
            }
        }
        let mut behind = lock(&peer.behind);
        let result = if behind.active()
            || (self.write_behind.applies(behind.last_given) && self.start_writer())
        {
            let deadline = Instant::now() + WRITER_WAIT;
            while !behind.queued.is_empty() && behind.queued_bytes + frame.len() > BEHIND_MAX_BYTES
            {
                let left = deadline.saturating_duration_since(Instant::now());
                if left.is_zero() {
                    return Err(self.writer_stuck(to, peer, behind.queued_bytes));
                }
                peer.room.wait_for(&mut behind, left);
            }
            behind.queued_bytes += frame.len();
            behind.queued.push_back(frame);
            if !behind.writing {
                // The writer takes it from here: nothing else goes to this peer until it is done.
                behind.writing = true;
                self.writer.ready(to);
            }
            Ok(())
        } else {
            drop(behind);
            let result = self.send_now(to, peer.addr, &frame);
            // The buffer goes back to its pool before the lock is taken again.
            drop(frame);
            behind = lock(&peer.behind);
            result
        };
        // From the return, not the call: a send on this thread is not part of the gap.
        behind.last_given = Some(Instant::now());
        result
    }

    /// Waits until the writer is done with `to`'s frames, so that what the caller sends now
    /// does not overtake them; [`LinkError::Congested`] after [`WRITER_WAIT`].
    pub(super) fn wait_for_writer(&self, to: SystemId, peer: &UdpPeer) -> Result<(), LinkError> {
        let mut behind = lock(&peer.behind);
        if !behind.active() {
            return Ok(());
        }
        let deadline = Instant::now() + WRITER_WAIT;
        while behind.active() {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                let bytes = behind.queued_bytes + behind.sending_bytes;
                return Err(self.writer_stuck(to, peer, bytes));
            }
            peer.room.wait_for(&mut behind, left);
        }
        Ok(())
    }

    fn writer_stuck(&self, to: SystemId, peer: &UdpPeer, bytes: usize) -> LinkError {
        LinkError::Congested {
            peer: to,
            reason: format!(
                "{bytes} bytes have waited {} ms to be sent to {}",
                WRITER_WAIT.as_millis(),
                peer.addr
            ),
        }
    }

    /// Bytes queued for or being sent by the writer, over all peers.
    pub(super) fn behind_bytes(&self) -> u64 {
        self.peers
            .values()
            .map(|p| {
                let b = lock(&p.behind);
                (b.queued_bytes + b.sending_bytes) as u64
            })
            .sum()
    }

    /// Starts the writer thread unless it runs; false if it cannot (the caller then sends).
    fn start_writer(self: &Arc<Self>) -> bool {
        let tx = self.clone();
        self.writer
            .start(format!("hetcomm-udp-tx-{}", self.local), move |to| {
                tx.send_behind(to)
            })
    }

    /// The writer's turn at one peer: sends every frame queued now. True if more were queued
    /// meanwhile. A frame that cannot be sent (or only in part) is counted as dropped; the
    /// frames after it are still sent, each datagram stands on its own.
    fn send_behind(&self, to: SystemId) -> bool {
        let Some(peer) = self.peers.get(&to) else {
            return false;
        };
        let mut behind = lock(&peer.behind);
        let mut frames = std::mem::take(&mut behind.spare);
        std::mem::swap(&mut frames, &mut behind.queued);
        behind.sending_bytes = std::mem::take(&mut behind.queued_bytes);
        drop(behind);
        // The queue is empty again: room for senders waiting on it.
        peer.room.notify_all();
        let counters = &self.shared.counters;
        let (mut sent, mut failed) = (0u64, 0u64);
        for frame in frames.drain(..) {
            match self.send_now(to, peer.addr, &frame) {
                Ok(()) => sent += 1,
                Err(_) => failed += 1,
            }
            // `frame` goes back to its pool here, outside the lock.
        }
        add(&counters.frames_written_behind, sent);
        add(&counters.held_frames_dropped, failed);
        let mut behind = lock(&peer.behind);
        behind.sending_bytes = 0;
        behind.spare = frames;
        let more = !behind.queued.is_empty();
        if !more {
            behind.writing = false;
            drop(behind);
            // Senders waiting for the writer to be done go on.
            peer.room.notify_all();
        }
        more
    }
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeMap;
    use std::net::UdpSocket;
    use std::sync::Arc;
    use std::time::Duration;

    use hetcomm_core::{BufferPool, FrameBuf, SystemId};
    use hetcomm_link::{FrameSink, Link, Peer};

    use super::super::{UdpConfig, UdpLink};
    use crate::WriteBehind;

    struct Nobody;
    impl FrameSink for Nobody {
        fn on_frame(&self, _: &[u8], _: Peer) {}
    }

    const A: SystemId = SystemId(1);
    const B: SystemId = SystemId(2);

    /// A's link, whose peer B is at `b_endpoint`.
    fn link_a(b_endpoint: String, write_behind: WriteBehind) -> UdpLink {
        let socket = UdpSocket::bind("127.0.0.1:0").unwrap();
        let endpoints = BTreeMap::from([(B, b_endpoint)]);
        let config = UdpConfig {
            write_behind,
            ..UdpConfig::loopback()
        };
        UdpLink::with_socket(A, socket, &endpoints, Arc::new(Nobody), config).unwrap()
    }

    fn frame(i: usize, len: usize) -> Vec<u8> {
        // Never starts with a datagram magic ("HF", "HB"): each arrives as sent.
        (0..len).map(|j| (i * 7 + j) as u8 | 0x80).collect()
    }

    fn given(pool: &Arc<BufferPool>, bytes: &[u8]) -> FrameBuf {
        let mut buf = pool.take(bytes.len());
        buf.extend_from_slice(bytes);
        pool.wrap(buf)
    }

    /// Bursts of given-away frames, with a plain and a held-and-flushed frame in each, all
    /// reach the peer intact, the given-away ones sent by the writer thread. Each burst is
    /// read before the next, so that a small receive buffer drops nothing.
    #[test]
    fn given_frames_are_sent_behind_the_sender_and_all_arrive() {
        let raw_b = UdpSocket::bind("127.0.0.1:0").unwrap();
        raw_b
            .set_read_timeout(Some(Duration::from_secs(10)))
            .unwrap();
        let a = link_a(raw_b.local_addr().unwrap().to_string(), WriteBehind::Always);
        let pool = BufferPool::new(16 << 20);
        let mut buf = vec![0; 65_536];
        let mut sent = 0;
        for burst in 0..30 {
            let frames: Vec<Vec<u8>> = (0..6).map(|i| frame(burst * 6 + i, 40 << 10)).collect();
            for (i, f) in frames.iter().enumerate() {
                let result = match i {
                    3 => a.send(B, f),
                    5 => a.send_held(B, &f[..1000]).and_then(|()| a.flush()),
                    _ => a.send_owned(B, given(&pool, f)),
                };
                result.unwrap_or_else(|e| panic!("burst {burst} frame {i}: {e}"));
            }
            let mut got = Vec::new();
            for _ in 0..frames.len() {
                let n = raw_b.recv(&mut buf).expect("a frame of the burst");
                got.push(buf[..n].to_vec());
            }
            let mut want: Vec<Vec<u8>> = frames.clone();
            want[5].truncate(1000);
            got.sort();
            want.sort();
            assert!(got == want, "burst {burst}: the frames arrive intact");
            sent += frames.len() as u64;
        }
        let s = a.udp_stats();
        assert_eq!(s.frames_sent, sent, "{s:?}");
        assert_eq!(s.frames_written_behind, 30 * 4, "{s:?}");
        assert_eq!(s.held_frames_dropped, 0, "{s:?}");
        assert_eq!(s.buffered_bytes, 0, "{s:?}");
        drop(a);
        assert!(pool.kept_bytes() > 0, "the buffers came back to their pool");
    }

    /// Frames the link took but the writer could not send are counted as dropped: every
    /// frame is either refused to the caller or counted, none is lost silently.
    #[test]
    fn frames_the_writer_cannot_send_are_counted() {
        // An IPv6 peer of an IPv4 socket: every send fails.
        let a = link_a("[::1]:9".into(), WriteBehind::Always);
        let pool = BufferPool::new(16 << 20);
        let f = frame(1, 20 << 10);
        let (mut taken, mut refused) = (0u64, 0u64);
        for _ in 0..2000 {
            match a.send_owned(B, given(&pool, &f)) {
                Ok(()) => taken += 1,
                Err(_) => refused += 1,
            }
        }
        // Waits for the writer to be done with B, then has nothing held to send.
        a.flush().unwrap();
        let s = a.udp_stats();
        assert_eq!(refused, 0, "the writer fails, not the caller");
        assert_eq!(taken, 2000, "{s:?}");
        assert_eq!(s.frames_sent, 0, "{s:?}");
        assert_eq!(s.held_frames_dropped, taken, "{s:?}");
        assert_eq!(s.frames_dropped, taken, "{s:?}");
    }

    /// Which given-away frames go behind the sender follows the link's [`WriteBehind`]: none
    /// with `Never`, even from a sender in a tight loop; none by default from a sender that
    /// pauses between frames, as one waiting for answers does; all with `Always`.
    #[test]
    fn the_write_behind_policy_decides_which_frames_go_behind() {
        let raw_b = UdpSocket::bind("127.0.0.1:0").unwrap();
        raw_b
            .set_read_timeout(Some(Duration::from_secs(10)))
            .unwrap();
        let pool = BufferPool::new(16 << 20);
        let f = frame(3, 20 << 10);
        let mut buf = vec![0; 65_536];
        for (policy, pause, behind) in [
            (WriteBehind::Never, Duration::ZERO, 0),
            (WriteBehind::Streaming, Duration::from_millis(2), 0),
            (WriteBehind::Always, Duration::from_millis(2), 20),
        ] {
            let a = link_a(raw_b.local_addr().unwrap().to_string(), policy);
            for _ in 0..20 {
                a.send_owned(B, given(&pool, &f)).unwrap();
                assert_eq!(raw_b.recv(&mut buf).unwrap(), f.len());
                std::thread::sleep(pause);
            }
            let s = a.udp_stats();
            assert_eq!(s.frames_sent, 20, "{policy:?}: {s:?}");
            assert_eq!(s.frames_written_behind, behind, "{policy:?}: {s:?}");
        }
    }
}
