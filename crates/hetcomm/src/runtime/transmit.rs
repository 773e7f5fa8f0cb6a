//! Frames leaving for links: batching (held frames that leave together), handing frames to
//! a link and turning its refusals into the router's terms.

use super::*;

/// Frames larger than this are never held for batching (see [`SystemCore::transmit`]).
pub(super) const BATCH_FRAME_MAX: usize = 8 * 1024;
const _: () = assert!(hetcomm_router::SPLIT_PAYLOAD_MIN > BATCH_FRAME_MAX);

/// The batching policy of one link. A frame goes out at once when the link was idle for
/// the linger time, so sporadic messages never wait; while frames come faster than that,
/// they are held and leave together when the link's batch is full, when the oldest has waited
/// the linger time (checked at the next send, or by the timer thread), or when a thread of
/// the system is about to wait.
pub(crate) struct Batching {
    /// 0: never hold.
    linger_us: u64,
    /// When the last data frame was handed to this link (µs, the system's clock).
    last_send: AtomicU64,
    /// When the last acknowledgement was.
    last_ack: AtomicU64,
    /// When the oldest frame still held was held (0: nothing held).
    held_since: AtomicU64,
    /// Frames held back to share a datagram or write ([`crate::SystemStats::held_frames`]).
    held: AtomicU64,
}

impl Batching {
    pub(super) fn new(linger_us: u32) -> Self {
        Batching {
            linger_us: u64::from(linger_us),
            last_send: AtomicU64::new(0),
            last_ack: AtomicU64::new(0),
            held_since: AtomicU64::new(0),
            held: AtomicU64::new(0),
        }
    }

    /// Whether held frames should go now (and marks them gone): any held frame when `now`
    /// is None, else frames held for the linger time.
    fn take_due(&self, now: Option<Time>) -> bool {
        let since = self.held_since.load(Ordering::Relaxed);
        if since == 0 {
            return false;
        }
        if let Some(now) = now {
            if now.as_micros().saturating_sub(since) < self.linger_us {
                return false;
            }
        }
        self.held_since
            .compare_exchange(since, 0, Ordering::Relaxed, Ordering::Relaxed)
            .is_ok()
    }
}

impl SystemCore {
    /// Puts frames held for batching on their links: all of them (`None`), or those held
    /// for at least their link's linger by `Some(now)`.
    pub(crate) fn flush_held(&self, due_at: Option<Time>) {
        let (Some(links), Some(batching)) = (self.links.get(), self.batching.get()) else {
            return;
        };
        for (link, b) in links.iter().zip(batching) {
            if b.take_due(due_at) {
                // A frame lost here is counted by the link; acknowledged sends retransmit.
                let _ = link.flush();
            }
        }
    }

    /// Counts the links as idle, as a thread of this system is about to block for a
    /// message: the first frame after the wait (typically the answer to what arrives, or the
    /// next request) goes at once instead of being held. A request–answer exchange so holds
    /// nothing and never arms the batching timer, whose wake-ups would land on the
    /// exchange's path; a stream sent, or taken, without blocking still batches.
    pub(super) fn idle_before_blocking(&self) {
        for b in self.batching.get().into_iter().flatten() {
            b.last_send.store(0, Ordering::Relaxed);
            b.last_ack.store(0, Ordering::Relaxed);
        }
    }

    /// Frames held back for batching so far, all links together.
    pub(crate) fn held_frames(&self) -> u64 {
        self.batching
            .get()
            .into_iter()
            .flatten()
            .map(|b| b.held.load(Ordering::Relaxed))
            .sum()
    }

    /// When the oldest batch still held is due.
    pub(super) fn next_flush(&self) -> Option<Time> {
        self.batching
            .get()?
            .iter()
            .filter_map(|b| {
                let since = b.held_since.load(Ordering::Relaxed);
                (since != 0).then(|| Time::from_micros(since + b.linger_us))
            })
            .min()
    }

    /// Whether frames for link `index` may be held back for batching (see [`Batching`]).
    pub(super) fn holds_frames(&self, index: usize) -> bool {
        self.batching
            .get()
            .and_then(|v| v.get(index))
            .is_some_and(|b| b.linger_us > 0)
    }

    /// Puts one frame, `frame` followed by `body`, on link `index`, holding it back to share a
    /// write with the next ones when the link batches and is busy (see [`Batching`]).
    #[allow(clippy::too_many_arguments)] // one frame's whole description
    pub(super) fn transmit(
        &self,
        index: usize,
        link: &dyn Link,
        to: SystemId,
        frame: &[u8],
        body: &[u8],
        now: Time,
        traffic: Traffic,
    ) -> Result<(), LinkError> {
        let Some(b) = self.batching.get().and_then(|v| v.get(index)) else {
            return link.send_parts(to, frame, body);
        };
        if b.linger_us == 0 {
            return link.send_parts(to, frame, body);
        }
        let stamp = match traffic {
            Traffic::Data => &b.last_send,
            Traffic::Ack => &b.last_ack,
        };
        let last = stamp.swap(now.as_micros(), Ordering::Relaxed);
        if frame.len() + body.len() > BATCH_FRAME_MAX {
            // A large frame fills a write on its own: holding it would only cost a timer
            // wake-up. It goes now, after whatever is held for the same peer. (Only such
            // frames come in two pieces: SPLIT_PAYLOAD_MIN > BATCH_FRAME_MAX.)
            return link.send_parts(to, frame, body);
        }
        debug_assert!(body.is_empty(), "small frames come whole");
        if now.as_micros().saturating_sub(last) >= b.linger_us {
            // The link was idle: this frame goes now (with anything still held for this
            // peer before it), so sporadic traffic never waits. Frames held for other peers
            // stay on the timer.
            return link.send(to, frame);
        }
        let result = link.send_held(to, frame);
        b.held.fetch_add(1, Ordering::Relaxed);
        let since = b.held_since.load(Ordering::Relaxed);
        if since == 0 {
            b.held_since
                .store(now.as_micros().max(1), Ordering::Relaxed);
            // The timer thread sends the batch should nothing else come along.
            self.timer
                .arm(Some(Time::from_micros(now.as_micros() + b.linger_us)));
        } else if b.take_due(Some(now)) {
            let _ = link.flush();
        }
        result
    }

    /// Puts the frame `frame` + `body` on link `index` (see [`SystemCore::transmit`]), in the
    /// router's terms. Frames reach it through [`SystemCore::leave`].
    pub(super) fn put_on_link(
        &self,
        index: usize,
        to: SystemId,
        frame: &[u8],
        body: &[u8],
        now: Time,
        traffic: Traffic,
    ) -> Result<(), TransmitError> {
        match self.links().get(index) {
            Some(link) => self
                .transmit(index, &**link, to, frame, body, now, traffic)
                .map_err(|e| transmit_error(&self.directory, e)),
            None => Err(TransmitError::Other("no such link".into())),
        }
    }
}

/// A link's refusal in the router's terms. The outcome it ends up in belongs to a ticket that
/// names its destination, so the text says why, not who again; where a peer is named, it is by
/// its name in the fleet, not its id.
pub(super) fn transmit_error(directory: &Directory, e: LinkError) -> TransmitError {
    match e {
        LinkError::Unreachable { reason, .. } => TransmitError::Unreachable(reason),
        LinkError::TooLarge { .. } => TransmitError::TooLarge(e.to_string()),
        LinkError::Refused { reason, .. } => TransmitError::Refused(reason),
        LinkError::Congested { peer, reason } => TransmitError::Congested(format!(
            "link to {} is congested: {reason}",
            directory.system_name(peer)
        )),
        LinkError::NoSession { peer, reason } => TransmitError::NoSession(format!(
            "no secure session with {}: {reason}",
            directory.system_name(peer)
        )),
        LinkError::Io(io) => TransmitError::Io {
            kind: io.kind(),
            reason: format!("i/o error: {io}"),
        },
        LinkError::Closed => TransmitError::Closed(e.to_string()),
        other => TransmitError::Other(other.to_string()),
    }
}
