//! The handshake side of the security layer: starting handshakes, answering them, completing
//! them, confirming a session the peer uses, and retrying or giving up (upkeep).

use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::Instant;

use hetcomm_core::SystemId;
use hetcomm_link::relay::RelayVerdict;
use hetcomm_link::{Link, LinkError};

use super::*;
use crate::session::{self, Entropy, Session};

impl Secured {
    /// Starts a handshake with `peer` (under its lock): the initiation to send.
    pub(super) fn start_handshake(
        &self,
        peer: SystemId,
        slot: &PeerSlot,
        st: &mut PeerState,
    ) -> Option<Vec<u8>> {
        let index = loop {
            let i = rand::random::<u32>();
            if i != 0 && st.session(i).is_none() {
                break i;
            }
        };
        let (init, pending) = session::initiate(
            (self.policy.local, &self.policy.keypair),
            (peer, &slot.public),
            index,
            self.timestamp(),
            Entropy::Os,
        )
        .ok()?;
        st.earlier = st
            .pending
            .replace((pending, Instant::now()))
            .map(|(p, _)| p);
        st.unanswered_since.get_or_insert_with(Instant::now);
        Some(init)
    }

    /// Drops frames that waited too long for a handshake; restarts initiations that got no
    /// response. Called periodically (real time only).
    pub(super) fn upkeep(&self) {
        let Some(below) = self.below() else { return };
        for (&peer, slot) in self.connected() {
            let mut st = slot.state.lock();
            if st.flushing {
                continue;
            }
            if st.queue.is_empty() {
                // A handshake started because the peer sent frames of a session we do not
                // have (nothing of ours waits): retried like any other while it is due, and
                // abandoned after TRIGGER_INTERVAL so that the peer's next frame starts
                // another. (Left pending, a lost response would block every later one.)
                let Some((_, at)) = &st.pending else { continue };
                if st
                    .last_trigger
                    .is_none_or(|t| t.elapsed() >= TRIGGER_INTERVAL)
                {
                    st.pending = None;
                    st.earlier = None;
                    st.unanswered_since = None;
                } else if at.elapsed() >= HANDSHAKE_RETRY {
                    if let Some(init) = self.start_handshake(peer, slot, &mut st) {
                        drop(st);
                        send_handshake(&*below, peer, &init);
                    }
                }
                continue;
            }
            if st
                .waiting_since
                .is_some_and(|t| t.elapsed() >= HANDSHAKE_GIVE_UP)
            {
                let n = st.queue.len() as u64;
                let why = format!(
                    "no secure session with system {peer} on transport `{}` within {} s: the frame never left",
                    self.transport,
                    HANDSHAKE_GIVE_UP.as_secs()
                );
                let receipts: Vec<_> = st.queue.drain(..).filter_map(|w| w.promise).collect();
                st.queued_bytes = 0;
                st.waiting_since = None;
                st.pending = None;
                st.earlier = None;
                st.unanswered_since = None;
                self.counters.timeouts.fetch_add(n, Ordering::Relaxed);
                drop(st);
                for promise in receipts {
                    promise.keep(RelayVerdict::Refused(why.clone()));
                }
                continue;
            }
            if st
                .pending
                .as_ref()
                .is_none_or(|(_, at)| at.elapsed() >= HANDSHAKE_RETRY)
            {
                if let Some(init) = self.start_handshake(peer, slot, &mut st) {
                    drop(st);
                    send_handshake(&*below, peer, &init);
                }
            }
        }
    }

    /// An authentic frame from `sender` opened in `session`: if that is the session we
    /// answered last, the peer holds it too, so it becomes current (and what waited for a
    /// session leaves in it).
    pub(super) fn confirmed(&self, sender: SystemId, slot: &PeerSlot, session: &Arc<Session>) {
        let mut st = slot.state.lock();
        if !st.unconfirmed.iter().any(|n| Arc::ptr_eq(n, session)) {
            return;
        }
        st.unconfirmed.clear();
        st.pending = None;
        st.earlier = None;
        st.install(session.clone());
        st.waiting_since = None;
        st.flushing = true;
        drop(st);
        self.flush_queue(sender, slot, session);
        // Frames refused for want of this session may go now.
        self.sink.on_event(LinkEvent::PeerUp(sender));
    }

    pub(super) fn receive_init(&self, sender: SystemId, slot: &PeerSlot, bytes: &[u8]) {
        if matches!(self.handshakes, Handshakes::InMemory(_)) {
            bump(&self.counters.auth);
            return;
        }
        if !slot.connected() {
            bump(&self.counters.table);
            return;
        }
        let mut st = slot.state.lock();
        let index = loop {
            let i = rand::random::<u32>();
            if i != 0 && st.session(i).is_none() {
                break i;
            }
        };
        let answer = match session::respond(
            (self.policy.local, &self.policy.keypair),
            (sender, &slot.public),
            bytes,
            index,
            Entropy::Os,
        ) {
            Ok(a) => a,
            Err(_) => {
                bump(&self.counters.auth);
                return;
            }
        };
        if st.last_init.is_some_and(|last| answer.timestamp <= last) {
            bump(&self.counters.replay);
            return;
        }
        // Both sides started at once: the lower system id stays the initiator.
        if st.pending.is_some() && self.policy.local < sender {
            return;
        }
        st.last_init = Some(answer.timestamp);
        // The session waits for the peer's first frame in it (`confirmed`); a handshake of
        // our own in progress goes on (this initiation may be a replay).
        if st.unconfirmed.len() == 2 {
            st.unconfirmed.remove(0);
        }
        st.unconfirmed.push(Arc::new(answer.session));
        drop(st);
        bump(&self.counters.handshakes);
        if let Some(below) = self.below() {
            send_handshake(&*below, sender, &answer.response);
        }
    }

    pub(super) fn receive_response(&self, sender: SystemId, slot: &PeerSlot, bytes: &[u8]) {
        let mut st = slot.state.lock();
        let (initiation, at) = if st
            .pending
            .as_ref()
            .is_some_and(|(p, _)| p.answered_by(bytes))
        {
            st.pending.take().map(|(p, at)| (p, Some(at)))
        } else if st.earlier.as_ref().is_some_and(|p| p.answered_by(bytes)) {
            st.earlier.take().map(|p| (p, None))
        } else {
            None
        }
        .unzip();
        let Some(initiation) = initiation else {
            // Not an answer to a handshake in progress: an old one replayed, or forged.
            bump(&self.counters.replay);
            return;
        };
        let session = match initiation.complete(bytes) {
            Ok(s) => Arc::new(s),
            Err(_) => {
                // Forged: keep waiting for the real response (a fresh initiation follows).
                if let Some(at) = at.flatten() {
                    st.last_trigger = Some(at);
                }
                bump(&self.counters.auth);
                return;
            }
        };
        st.pending = None;
        st.earlier = None;
        st.install(session.clone());
        st.waiting_since = None;
        st.flushing = true;
        drop(st);
        bump(&self.counters.handshakes);
        self.flush_queue(sender, slot, &session);
        // Frames refused for want of this session go now (the router sends them on this
        // thread, through this layer).
        self.sink.on_event(LinkEvent::PeerUp(sender));
        if session.sealed() == 0 {
            // Nothing to send: an empty frame tells the responder the session is in use
            // (receivers hand empty frames to nobody).
            if let Some(below) = self.below() {
                let mut buf = Vec::new();
                session.seal(&mut buf, self.policy.local, sender, &[], &[]);
                let _ = below.send(sender, &buf);
            }
        }
    }
}

/// Sends a handshake message; once more if the link refused it (a stream link reconnects on
/// the next send after a write to a connection the peer closed, as a restarted peer's was).
pub(super) fn send_handshake(below: &dyn Link, to: SystemId, message: &[u8]) {
    let _ = try_send_handshake(below, to, message);
}

/// [`send_handshake`], telling whether the link took the message in the end.
pub(super) fn try_send_handshake(
    below: &dyn Link,
    to: SystemId,
    message: &[u8],
) -> Result<(), LinkError> {
    below.send(to, message).or_else(|_| below.send(to, message))
}
