//! The frame side of the security layer: sealing what the router sends (or queueing it
//! while a handshake runs), and opening and checking what the link receives.

use std::sync::Arc;
use std::time::Instant;

use hetcomm_core::{FrameBuf, SystemId};
use hetcomm_link::relay::{relay_receipt, RelayPromise, RelayReceipt, RelayVerdict};
use hetcomm_link::{FrameSink, LinkError, Peer};

use super::*;
use crate::envelope::{self, Kind, DATA_HEADER_LEN, OVERHEAD, RECORD_HEADER, TAG_LEN};
use crate::session::Session;

/// How a frame the router hands the security layer is to leave the link below.
#[derive(Clone, Copy, PartialEq, Eq)]
pub(super) enum Leave {
    /// At once ([`Link::send`], or [`Link::send_owned`] for a large frame).
    Now,
    /// It may wait to leave with the frames after it ([`Link::send_held`]).
    Held,
    /// At once, asking the link below for a receipt from its intermediary
    /// ([`Link::send_relayed`]).
    Relayed,
}

impl Secured {
    /// Seals and sends `head` + `body` to `to`, or queues it until a session exists. The
    /// receipt is the link below's, when `leave` is [`Leave::Relayed`] and the sealed frame
    /// left at once; a frame that waits for a handshake has none (it has not left yet).
    pub(super) fn send(
        &self,
        below: &dyn Link,
        to: SystemId,
        head: &[u8],
        body: &[u8],
        leave: Leave,
    ) -> Result<Option<RelayReceipt>, LinkError> {
        let held = leave == Leave::Held;
        let slot = self.peers.get(&to).ok_or_else(|| LinkError::Unreachable {
            peer: to,
            reason: format!(
                "system {to} has no public key on transport `{}`: frames to it could not be authenticated",
                self.transport
            ),
        })?;
        let caps = below.caps();
        let max = caps.max_frame.saturating_sub(OVERHEAD);
        if head.len() + body.len() > max {
            return Err(LinkError::TooLarge {
                len: head.len() + body.len(),
                max,
            });
        }
        // Frames the router lets wait go into one data batch per peer, sealed once, that
        // fits one datagram (`mtu`) of the link below.
        let limit = caps.mtu.min(BATCH_BYTES).saturating_sub(OVERHEAD);
        let record = RECORD_HEADER + head.len() + body.len();
        let mut h = slot.held.lock();
        // A batch starts only in a session (checked once per batch): without one, a frame
        // that wants an acknowledgement must be refused now, not reported taken and refused
        // later when its batch leaves.
        if held && record <= limit && (h.frames > 0 || self.sealing_to(to, slot)) {
            if h.frames > 0 && h.records.len() + record > limit {
                // Held frames go first. Their failure is counted; the result is this frame's.
                let _ = self.send_held_batch(below, to, slot, &mut h);
            }
            envelope::push_record(&mut h.records, head, body);
            h.frames += 1;
            if limit - h.records.len() < RECORD_HEADER + MIN_FRAME {
                // No further frame can fit: holding these longer would only add latency.
                return self.send_held_batch(below, to, slot, &mut h).map(|()| None);
            }
            return Ok(None);
        }
        if h.frames > 0 {
            let _ = self.send_held_batch(below, to, slot, &mut h);
        }
        drop(h);
        self.send_now(below, to, slot, head, body, leave)
    }

    /// Seals and sends the frames held for `to` as one data batch (a single frame as a data
    /// message), or, with no session to seal them in, queues them for the handshake. A batch
    /// the link refuses is counted in the link's `frames_dropped`.
    pub(super) fn send_held_batch(
        &self,
        below: &dyn Link,
        to: SystemId,
        slot: &PeerSlot,
        h: &mut Held,
    ) -> Result<(), LinkError> {
        if h.frames == 0 {
            return Ok(());
        }
        let frames = std::mem::take(&mut h.frames);
        let mut st = slot.state.lock();
        self.take_sim_session(to, &mut st);
        let result = match &st.current {
            Some(session) if !st.flushing => {
                let mut buf = take_scratch(&TX);
                if frames == 1 {
                    session.seal(
                        &mut buf,
                        self.policy.local,
                        to,
                        &h.records[RECORD_HEADER..],
                        &[],
                    );
                } else {
                    session.seal_batch(&mut buf, self.policy.local, to, &h.records);
                }
                drop(st);
                let sent = below.send(to, &buf);
                give_scratch(&TX, buf);
                if sent.is_err() {
                    self.held_dropped
                        .fetch_add(frames as u64, Ordering::Relaxed);
                }
                sent
            }
            _ => {
                // No session (or its waiting frames are leaving): these wait with them.
                drop(st);
                let mut first = Ok(());
                for r in envelope::records(&h.records) {
                    let st = slot.state.lock();
                    let queued = self.hold(below, to, slot, st, &h.records[r], &[], None);
                    if queued.is_err() {
                        self.held_dropped.fetch_add(1, Ordering::Relaxed);
                        if first.is_ok() {
                            first = queued;
                        }
                    }
                }
                first
            }
        };
        h.records.clear();
        result
    }

    /// Whether frames to `to` are sealed now, rather than waiting for a handshake.
    fn sealing_to(&self, to: SystemId, slot: &PeerSlot) -> bool {
        let mut st = slot.state.lock();
        self.take_sim_session(to, &mut st);
        st.sealing()
    }

    /// In a simulation, the session with `to` the first frame to it takes (made in memory).
    fn take_sim_session(&self, to: SystemId, st: &mut PeerState) {
        if st.current.is_none() {
            if let Handshakes::InMemory(sim) = &self.handshakes {
                if let Some(s) = sim.half(&self.transport, self.policy.local, to) {
                    st.install(s);
                    bump(&self.counters.handshakes);
                }
            }
        }
    }

    /// Seals and sends `head` + `body` to `to` now, or queues it until a session exists.
    fn send_now(
        &self,
        below: &dyn Link,
        to: SystemId,
        slot: &PeerSlot,
        head: &[u8],
        body: &[u8],
        leave: Leave,
    ) -> Result<Option<RelayReceipt>, LinkError> {
        let mut st = slot.state.lock();
        self.take_sim_session(to, &mut st);
        match &st.current {
            // Sealed under the lock (it orders nothing: the counter is atomic), which spares
            // taking a reference to the session for every frame.
            Some(session) if !st.flushing => {
                if leave == Leave::Now && head.len() + body.len() >= GIVE_AWAY_FROM {
                    // Sealed into a buffer of its own that the link may keep and write while
                    // the caller seals the next frame (a stream link writes behind a
                    // streaming sender).
                    let mut buf = self
                        .sealed_pool
                        .take_reused(OVERHEAD + head.len() + body.len());
                    session.seal(&mut buf, self.policy.local, to, head, body);
                    drop(st);
                    return below
                        .send_owned(to, self.sealed_pool.wrap(buf))
                        .map(|()| None);
                }
                let mut buf = take_scratch(&TX);
                session.seal(&mut buf, self.policy.local, to, head, body);
                drop(st);
                let sent = match leave {
                    Leave::Now => below.send(to, &buf).map(|()| None),
                    Leave::Held => below.send_held(to, &buf).map(|()| None),
                    Leave::Relayed => below.send_relayed(to, &buf, &[]),
                };
                give_scratch(&TX, buf);
                sent
            }
            // A frame that asked for a receipt gets one of this layer's: kept when the frame
            // leaves after the handshake (with the link below's verdict), refused if it never
            // does, so its send's outcome does not claim it left when it had not.
            _ if leave == Leave::Relayed => {
                let (receipt, promise) = relay_receipt();
                self.hold(below, to, slot, st, head, body, Some(promise))
                    .map(|()| Some(receipt))
            }
            _ => self
                .hold(below, to, slot, st, head, body, None)
                .map(|()| None),
        }
    }

    /// Queues `head` + `body` for `to` while there is no session (starting the handshake if
    /// needed), or behind the frames that waited for it while they leave. A data frame that
    /// requests an acknowledgement is refused instead ([`LinkError::NoSession`]): the router
    /// keeps it and tries again, so its outcome can say truthfully whether anything left. (A
    /// queued copy could leave after the router gave up and reported it failed.) `promise`:
    /// the frame's receipt's, if its send asked for one.
    #[allow(clippy::too_many_arguments)] // one frame's whole description
    fn hold(
        &self,
        below: &dyn Link,
        to: SystemId,
        slot: &PeerSlot,
        mut st: parking_lot::MutexGuard<'_, PeerState>,
        head: &[u8],
        body: &[u8],
        promise: Option<RelayPromise>,
    ) -> Result<(), LinkError> {
        let waiting = |promise| {
            let mut frame = Vec::with_capacity(head.len() + body.len());
            frame.extend_from_slice(head);
            frame.extend_from_slice(body);
            Waiting { frame, promise }
        };
        if st.flushing {
            // Behind the frames that waited for the handshake, which are leaving now.
            st.queued_bytes += head.len() + body.len();
            st.queue.push_back(waiting(promise));
            return Ok(());
        }
        if requests_ack(head, body) {
            return self.refuse(below, to, slot, st);
        }
        // Wait for the handshake; start (or restart) it if needed.
        if st.queue.len() >= QUEUE_FRAMES || st.queued_bytes + head.len() + body.len() > QUEUE_BYTES
        {
            return Err(LinkError::Congested {
                peer: to,
                reason: "frames waiting for the security handshake".into(),
            });
        }
        st.queued_bytes += head.len() + body.len();
        st.queue.push_back(waiting(promise));
        st.waiting_since.get_or_insert_with(Instant::now);
        let stale = st
            .pending
            .as_ref()
            .is_none_or(|(_, at)| at.elapsed() >= HANDSHAKE_RETRY);
        let init = if stale {
            self.start_handshake(to, slot, &mut st)
        } else {
            None
        };
        drop(st);
        if let Some(init) = init {
            if let Err(e) = try_send_handshake(below, to, &init) {
                // The link cannot reach the peer (no subscriber, no route): say so now, as
                // the bare link would, instead of holding the frame for a handshake that
                // cannot start. Later frames try again.
                let mut st = slot.state.lock();
                st.pending = None;
                if let Some(w) = st.queue.pop_back() {
                    st.queued_bytes -= w.frame.len();
                }
                if st.queue.is_empty() {
                    st.waiting_since = None;
                }
                return Err(e);
            }
        }
        Ok(())
    }

    /// Refuses a frame to `to` for want of a session: starts the handshake (or restarts one
    /// that went unanswered) and says where it stands. Nothing of the frame is kept.
    fn refuse(
        &self,
        below: &dyn Link,
        to: SystemId,
        slot: &PeerSlot,
        mut st: parking_lot::MutexGuard<'_, PeerState>,
    ) -> Result<(), LinkError> {
        // Upkeep retries a handshake nothing is queued for while it was wanted within the
        // last TRIGGER_INTERVAL: the router's next attempt finds it complete, or still running.
        st.last_trigger = Some(Instant::now());
        let stale = st
            .pending
            .as_ref()
            .is_none_or(|(_, at)| at.elapsed() >= HANDSHAKE_RETRY);
        let init = if stale {
            self.start_handshake(to, slot, &mut st)
        } else {
            None
        };
        let reason = unanswered(st.unanswered_since);
        drop(st);
        if let Some(init) = init {
            if let Err(e) = try_send_handshake(below, to, &init) {
                // The link cannot reach the peer: that is the better reason.
                let mut st = slot.state.lock();
                st.pending = None;
                st.unanswered_since = None;
                return Err(e);
            }
        }
        Err(LinkError::NoSession { peer: to, reason })
    }

    /// Sends what waited for `peer`'s handshake, now that `session` exists, and what joins
    /// the queue meanwhile (see [`PeerState::flushing`]), in order. Called with `flushing`
    /// set; clears it when the queue is empty.
    pub(super) fn flush_queue(&self, peer: SystemId, slot: &PeerSlot, session: &Session) {
        let below = self.below();
        let mut buf = Vec::new();
        loop {
            let batch = {
                let mut st = slot.state.lock();
                if st.queue.is_empty() {
                    st.flushing = false;
                    return;
                }
                st.queued_bytes = 0;
                std::mem::take(&mut st.queue)
            };
            for Waiting { frame, promise } in batch {
                session.seal(&mut buf, self.policy.local, peer, &frame, &[]);
                let Some(below) = &below else { continue };
                let Some(promise) = promise else {
                    let _ = below.send(peer, &buf);
                    continue;
                };
                match below.send_relayed(peer, &buf, &[]) {
                    Ok(Some(receipt)) => receipt.then(move |verdict| promise.keep(verdict)),
                    Ok(None) => promise.keep(RelayVerdict::Left),
                    Err(e) => promise.keep(RelayVerdict::Refused(format!(
                        "the frame waited for the security handshake, then the link refused it: {e}"
                    ))),
                }
            }
        }
    }

    /// A frame from the link: checked, opened, and handed to the router if it passes.
    pub(super) fn receive(&self, frame: Incoming<'_>) {
        if let Some((prefix, slot)) = self.check_prefix(frame.bytes()) {
            self.dispatch(prefix, slot, frame);
        }
    }

    /// The checks of the clear prefix: a secured frame, for this system, from a system with a
    /// key. None (counted) if it fails one.
    fn check_prefix(&self, bytes: &[u8]) -> Option<(envelope::Prefix, &PeerSlot)> {
        let Some(prefix) = envelope::prefix(bytes) else {
            // Not a secured frame: an unsecured sender, or garbage. Nothing is trusted.
            bump(&self.counters.auth);
            return None;
        };
        if prefix.receiver != self.policy.local {
            bump(&self.counters.table);
            return None;
        }
        let Some(slot) = self.peers.get(&prefix.sender) else {
            bump(&self.counters.unknown);
            return None;
        };
        if !slot.connected() {
            // A member of the fleet the table does not connect to this system on this
            // transport: nothing of it is looked at (no session, no handshake started).
            bump(&self.counters.table);
            return None;
        }
        Some((prefix, slot))
    }

    fn dispatch(&self, prefix: envelope::Prefix, slot: &PeerSlot, frame: Incoming<'_>) {
        match prefix.kind {
            Kind::Data => self.receive_data(prefix.sender, slot, frame),
            Kind::Batch => self.receive_batch(&mut std::iter::once(frame.bytes())),
            Kind::Init => self.receive_init(prefix.sender, slot, frame.bytes()),
            Kind::Response => self.receive_response(prefix.sender, slot, frame.bytes()),
        }
    }

    /// The frames of one batch datagram (or one data batch): each checked and opened as
    /// [`Self::receive`] does, into one buffer, and what passes handed to the router in one
    /// call (one router lock and one wake-up per datagram, as without security) instead of
    /// one call per frame. A data batch's inner frames are checked against the table one by
    /// one, after the batch passed authentication and the replay window as one frame.
    pub(super) fn receive_batch(&self, frames: &mut dyn Iterator<Item = &[u8]>) {
        let mut batch = BATCH.with(|c| c.take());
        // The session of the previous frame: a batch comes from one peer, so its state is
        // locked once per batch, not once per frame.
        let mut cached: Option<(SystemId, Arc<Session>, bool)> = None;
        for frame in frames {
            let Some((prefix, slot)) = self.check_prefix(frame) else {
                continue;
            };
            let sender = prefix.sender;
            let kind = prefix.kind;
            if !matches!(kind, Kind::Data | Kind::Batch) {
                // Handshakes (rare) act at once: what opened before them goes first.
                batch.deliver(&*self.sink);
                cached = None;
                self.dispatch(prefix, slot, Incoming::Borrowed(frame));
                continue;
            }
            if frame.len() < OVERHEAD {
                bump(&self.counters.auth);
                continue;
            }
            let index = envelope::u32_at(frame, 8);
            let hit = matches!(&cached, Some((s, session, _)) if *s == sender && session.my_index == index);
            if !hit {
                cached = self
                    .data_session(sender, slot, index)
                    .map(|(session, unconfirmed)| (sender, session, unconfirmed));
            }
            let Some((_, session, unconfirmed)) = &mut cached else {
                continue;
            };
            if batch.sender != Some(sender) {
                batch.deliver(&*self.sink);
                batch.sender = Some(sender);
            }
            let Batch { arena, ranges, .. } = &mut batch;
            let start = arena.len();
            arena.resize(start + envelope::inner_len(frame.len()), 0);
            if !session.open_into(frame, &mut arena[start..]) {
                bump(&self.counters.auth);
                arena.truncate(start);
                continue;
            }
            if !self.fresh(session, envelope::data_counter(frame)) {
                arena.truncate(start);
                continue;
            }
            let before = ranges.len();
            let mut passed = false;
            if kind == Kind::Data {
                passed = self.admit(slot, sender, &arena[start..]);
                if passed && arena.len() > start {
                    ranges.push(start..arena.len());
                }
            } else {
                // The records' length fields stay in the buffer, between the frames.
                let mut records = envelope::records(&arena[start..]);
                for r in records.by_ref() {
                    let r = start + r.start..start + r.end;
                    if self.admit(slot, sender, &arena[r.clone()]) {
                        passed = true;
                        ranges.push(r);
                    }
                }
                if records.malformed {
                    bump(&self.counters.auth);
                }
            }
            if ranges.len() == before {
                arena.truncate(start);
            }
            if passed && *unconfirmed {
                self.confirmed(sender, slot, session);
                *unconfirmed = false;
            }
        }
        batch.deliver(&*self.sink);
        batch.sender = None;
        if batch.arena.capacity() <= SCRATCH_KEEP {
            BATCH.with(|c| c.set(batch));
        }
    }

    /// The session a data frame from `sender` names by `index`, and whether it is one this
    /// side answered that the peer has not used yet. None (counted) if there is none; then a
    /// handshake may start.
    fn data_session(
        &self,
        sender: SystemId,
        slot: &PeerSlot,
        index: u32,
    ) -> Option<(Arc<Session>, bool)> {
        let mut st = slot.state.lock();
        if let Some(s) = st.session(index) {
            let unconfirmed = st.unconfirmed.iter().any(|n| Arc::ptr_eq(n, &s));
            return Some((s, unconfirmed));
        }
        if let Handshakes::InMemory(sim) = &self.handshakes {
            // The peer made the session first: take our half.
            return match sim.half(&self.transport, self.policy.local, sender) {
                Some(s) if s.my_index == index => {
                    st.install(s.clone());
                    bump(&self.counters.handshakes);
                    Some((s, false))
                }
                _ => {
                    bump(&self.counters.no_session);
                    None
                }
            };
        }
        bump(&self.counters.no_session);
        // The peer has a session we do not (it or we restarted): start a new one, at most
        // once a second, since anyone can forge this.
        let due = st.pending.is_none()
            && st
                .last_trigger
                .is_none_or(|t| t.elapsed() >= TRIGGER_INTERVAL);
        if due {
            st.last_trigger = Some(Instant::now());
            let init = self.start_handshake(sender, slot, &mut st);
            drop(st);
            if let (Some(init), Some(below)) = (init, self.below()) {
                send_handshake(&*below, sender, &init);
            }
        }
        None
    }

    /// What an authenticated frame must pass before the router sees it, in this order: the
    /// replay window, then the table (its inner header against its authenticated sender).
    /// A frame that passes in an unconfirmed session confirms it.
    fn accept(
        &self,
        sender: SystemId,
        slot: &PeerSlot,
        session: &Arc<Session>,
        unconfirmed: &mut bool,
        counter: u64,
        inner: &[u8],
    ) -> bool {
        if !self.fresh(session, counter) || !self.admit(slot, sender, inner) {
            return false;
        }
        if *unconfirmed {
            self.confirmed(sender, slot, session);
            *unconfirmed = false;
        }
        true
    }

    /// The replay window's verdict on an authenticated frame's counter (counted if it is a
    /// replay).
    fn fresh(&self, session: &Session, counter: u64) -> bool {
        let fresh = session.accept_counter(counter);
        if !fresh {
            bump(&self.counters.replay);
        }
        fresh
    }

    /// The table's verdict on an authenticated inner frame (counted if it refuses it).
    fn admit(&self, slot: &PeerSlot, sender: SystemId, inner: &[u8]) -> bool {
        let ok = allowed(slot, sender, self.policy.local, inner);
        if !ok {
            bump(&self.counters.table);
        }
        ok
    }

    pub(super) fn receive_data(&self, sender: SystemId, slot: &PeerSlot, frame: Incoming<'_>) {
        let bytes = frame.bytes();
        if bytes.len() < OVERHEAD {
            bump(&self.counters.auth);
            return;
        }
        let counter = envelope::data_counter(bytes);
        let Some((session, mut unconfirmed)) =
            self.data_session(sender, slot, envelope::u32_at(bytes, 8))
        else {
            return;
        };
        let Some(inner) = frame.open(&session) else {
            bump(&self.counters.auth);
            return;
        };
        if self.accept(
            sender,
            slot,
            &session,
            &mut unconfirmed,
            counter,
            inner.bytes(),
        ) {
            inner.deliver(&*self.sink, Peer::System(sender));
        }
    }
}

/// Whether the frame `head` + `body` is a data frame that requests an acknowledgement.
fn requests_ack(head: &[u8], body: &[u8]) -> bool {
    let at = |i: usize| head.get(i).or_else(|| body.get(i - head.len())).copied();
    at(0) == Some(hetcomm_core::wire::MAGIC[0])
        && at(1) == Some(hetcomm_core::wire::MAGIC[1])
        && at(3) == Some(0)
        && at(4).is_some_and(|f| f & hetcomm_core::wire::FLAG_ACK_REQUESTED != 0)
}

/// Where a handshake that started at `since` stands, for a frame refused meanwhile.
fn unanswered(since: Option<Instant>) -> String {
    let waited = since.map(|t| t.elapsed()).unwrap_or_default();
    if waited < std::time::Duration::from_millis(1) {
        "handshake just started; the frame was not sent".into()
    } else {
        format!(
            "handshake unanswered for {:.1} s; the frame was not sent",
            waited.as_secs_f64()
        )
    }
}

/// Whether the inner frame's header agrees with its authenticated sender and the table.
fn allowed(slot: &PeerSlot, sender: SystemId, local: SystemId, inner: &[u8]) -> bool {
    // Not a hetcomm frame (too short, no magic): authentic but meaningless, and the router
    // counts it as malformed.
    if inner.len() < 16 || inner[0..2] != hetcomm_core::wire::MAGIC {
        return true;
    }
    let source = SystemId(u16::from_le_bytes([inner[8], inner[9]]));
    let destination = SystemId(u16::from_le_bytes([inner[12], inner[13]]));
    if source != sender || destination != local {
        return false;
    }
    match inner[3] {
        0 => slot.sends_data,
        1 => slot.sends_acks,
        // Unknown kinds: the router refuses them.
        _ => true,
    }
}

/// A received frame, borrowed or owned: opened in a scratch copy or where it lies.
pub(super) enum Incoming<'a> {
    Borrowed(&'a [u8]),
    Owned(FrameBuf),
}

/// An opened inner frame, ready for the router.
pub(super) enum Opened {
    Scratch(Vec<u8>),
    Owned(FrameBuf),
}

impl Incoming<'_> {
    pub(super) fn bytes(&self) -> &[u8] {
        match self {
            Incoming::Borrowed(b) => b,
            Incoming::Owned(f) => f,
        }
    }

    pub(super) fn open(self, session: &Session) -> Option<Opened> {
        match self {
            Incoming::Borrowed(b) => {
                // Decrypted from where the link lent it straight into the scratch buffer.
                let mut buf = take_scratch(&RX);
                buf.resize(OVERHEAD + envelope::inner_len(b.len()), 0);
                let end = buf.len() - TAG_LEN;
                if !session.open_into(b, &mut buf[DATA_HEADER_LEN..end]) {
                    give_scratch(&RX, buf);
                    return None;
                }
                Some(Opened::Scratch(buf))
            }
            Incoming::Owned(mut f) => {
                if !session.open(f.as_mut_slice()) {
                    return None;
                }
                let len = f.len();
                f.truncate(len - TAG_LEN);
                f.strip_prefix(DATA_HEADER_LEN);
                Some(Opened::Owned(f))
            }
        }
    }
}

impl Opened {
    pub(super) fn bytes(&self) -> &[u8] {
        match self {
            Opened::Scratch(b) => &b[DATA_HEADER_LEN..b.len() - TAG_LEN],
            Opened::Owned(f) => f,
        }
    }

    pub(super) fn deliver(self, sink: &dyn FrameSink, from: Peer) {
        match self {
            Opened::Scratch(buf) => {
                let inner = &buf[DATA_HEADER_LEN..buf.len() - TAG_LEN];
                if !inner.is_empty() {
                    sink.on_frame(inner, from);
                }
                give_scratch(&RX, buf);
            }
            Opened::Owned(f) => {
                if !f.is_empty() {
                    sink.on_frame_owned(f, from);
                }
            }
        }
    }
}

/// The frames of a batch datagram opened so far, all from `sender`: their inner frames lie in
/// `arena` at `ranges`.
#[derive(Default)]
struct Batch {
    sender: Option<SystemId>,
    arena: Vec<u8>,
    ranges: Vec<std::ops::Range<usize>>,
}

impl Batch {
    /// Hands what was opened to the router in one call, and empties the batch.
    fn deliver(&mut self, sink: &dyn FrameSink) {
        if let (Some(sender), false) = (self.sender, self.ranges.is_empty()) {
            let arena = &self.arena;
            sink.on_frames(
                &mut self.ranges.iter().map(|r| &arena[r.clone()]),
                Peer::System(sender),
            );
        }
        self.ranges.clear();
        self.arena.clear();
    }
}

/// Frames from this size on are sealed into a buffer that is given to the link below
/// ([`Link::send_owned`]) rather than lent from a scratch buffer: for them, overlapping the
/// cipher with the link's write is worth a pooled buffer.
const GIVE_AWAY_FROM: usize = 16 << 10;

/// The largest data batch (before sealing), on links whose datagrams (`mtu`) are larger.
const BATCH_BYTES: usize = 64 << 10;

/// The smallest inner frame (a header): a batch with less room left than this and a record
/// length is full.
const MIN_FRAME: usize = hetcomm_core::wire::HEADER_LEN;

/// Scratch buffers larger than this are not kept: one 16 MiB frame should not pin 16 MiB
/// per thread.
const SCRATCH_KEEP: usize = 256 << 10;

thread_local! {
    /// The batch being opened on this thread (taken out while in use, like the buffers below).
    static BATCH: std::cell::Cell<Batch> = std::cell::Cell::new(Batch::default());

    /// Per-thread buffers for sealing (TX) and opening (RX), so the common path allocates
    /// nothing. Taken out while in use: a nested call (a receive that sends an
    /// acknowledgement on the same thread) gets a fresh one.
    static TX: std::cell::Cell<Vec<u8>> = const { std::cell::Cell::new(Vec::new()) };
    static RX: std::cell::Cell<Vec<u8>> = const { std::cell::Cell::new(Vec::new()) };
}

type Scratch = std::thread::LocalKey<std::cell::Cell<Vec<u8>>>;

pub(super) fn take_scratch(key: &'static Scratch) -> Vec<u8> {
    key.with(|c| c.take())
}

pub(super) fn give_scratch(key: &'static Scratch, buf: Vec<u8>) {
    if buf.capacity() <= SCRATCH_KEEP {
        key.with(|c| c.set(buf));
    }
}
