//! Frames in: acknowledgements, duplicates, in-order release, deliveries.

use super::*;

impl<T> Router<T> {
    /// Handles a frame a link received. Bad frames are counted and dropped.
    pub fn handle_frame(&mut self, now: Time, link: usize, bytes: &[u8]) {
        self.handle_frame_from(now, link, None, bytes);
    }

    /// Like [`Router::handle_frame`], with the system the link saw the frame come from
    /// (`peer`: its connection or source address belongs to that system; None when the link
    /// cannot tell). The link's view decides which path is heard from; a frame claiming
    /// another origin is counted ([`RouterStats::peer_mismatch`]) and still handled, since
    /// telling a forged origin from a moved one is authentication's work.
    pub fn handle_frame_from(
        &mut self,
        now: Time,
        link: usize,
        peer: Option<SystemId>,
        bytes: &[u8],
    ) {
        let frame = match wire::decode(bytes) {
            Ok(f) => f,
            Err(_) => {
                self.stats.malformed += 1;
                return;
            }
        };
        self.handle_decoded(
            now,
            link,
            peer,
            frame.header,
            PayloadSource::Borrowed(frame.payload),
        );
    }

    /// Like [`Router::handle_frame`], for a frame the link handed over in a buffer of its own:
    /// a data frame's payload is delivered in that same buffer, without a copy.
    ///
    /// The frame is what `frame` reads as: bytes a layer stripped in front of it
    /// ([`FrameBuf::strip_prefix`], e.g. a security layer's prefix) are not part of it, and
    /// the payload's place is taken from the decoded frame itself, not from a fixed offset
    /// into the buffer.
    pub fn handle_frame_owned(&mut self, now: Time, link: usize, frame: impl Into<FrameBuf>) {
        self.handle_frame_owned_from(now, link, None, frame);
    }

    /// Like [`Router::handle_frame_owned`], with the system the link saw the frame come from
    /// (see [`Router::handle_frame_from`]).
    pub fn handle_frame_owned_from(
        &mut self,
        now: Time,
        link: usize,
        peer: Option<SystemId>,
        frame: impl Into<FrameBuf>,
    ) {
        let frame = frame.into();
        let (header, payload_at) = match wire::decode(&frame) {
            // The payload is the frame's tail (the decoder checked the length exactly).
            Ok(f) => (f.header, frame.len() - f.payload.len()),
            Err(_) => {
                self.stats.malformed += 1;
                return;
            }
        };
        self.handle_decoded(
            now,
            link,
            peer,
            header,
            PayloadSource::Owned(PayloadBuf::from_frame(frame, payload_at)),
        );
    }

    pub(super) fn handle_decoded(
        &mut self,
        now: Time,
        link: usize,
        peer: Option<SystemId>,
        h: Header,
        body: PayloadSource<'_>,
    ) {
        if !h.payload_checked() && !self.link_checksums_payload(link) {
            // Only the header was checksummed, on a link that does not vouch for the rest.
            self.stats.malformed += 1;
            return;
        }
        if !self.config.known_systems.contains(&h.source.system) {
            self.stats.unknown_origin += 1;
            return;
        }
        let mut h = h;
        if h.to_all() || h.broadcast_seq() {
            // A frame of a native broadcast: for every system when FLAG_TO_ALL, which only a
            // broadcast's data frame carries, in the broadcast space.
            let valid =
                !h.to_all() || (h.kind == FrameKind::Data && h.broadcast_seq() && h.is_broadcast());
            if !valid {
                self.stats.malformed += 1;
                return;
            }
        }
        if h.to_all() {
            // Every system on the transport receives it: take it only where the table
            // allows this sender to send here on this link.
            if !self.config.inbound.contains(&(h.source.system, link)) {
                self.stats.misrouted += 1;
                return;
            }
            h.destination.system = self.config.local;
        } else if h.destination.system != self.config.local {
            self.stats.misrouted += 1;
            return;
        }
        if peer.is_some_and(|p| p != h.source.system) {
            self.stats.peer_mismatch += 1;
        }
        let ack = h.kind == FrameKind::Ack;
        self.path_heard(now, peer.unwrap_or(h.source.system), link, ack);
        match h.kind {
            FrameKind::Ack => self.handle_ack(now, link, &h, body.as_slice()),
            FrameKind::Data => self.handle_data(now, link, &h, body),
        }
    }

    pub(super) fn handle_ack(&mut self, now: Time, link: usize, h: &Header, payload: &[u8]) {
        let Some(AckPayload { status, first }) = AckPayload::parse(payload, h.seq) else {
            self.stats.malformed += 1;
            return;
        };
        // One round-trip sample per acknowledgement frame: its oldest send taken once (the
        // others' latencies overlap it).
        let mut sampled = false;
        for seq in first..=h.seq {
            let one = Header { seq, ..*h };
            sampled |= self.handle_ack_of(now, link, &one, status, !sampled);
        }
    }

    /// The acknowledgement of the one send `h` names (a range's member, or a single ACK);
    /// whether it took a round-trip sample (only when `sample`).
    fn handle_ack_of(
        &mut self,
        now: Time,
        link: usize,
        h: &Header,
        status: AckStatus,
        sample: bool,
    ) -> bool {
        let id = SendId {
            to: h.source.system,
            seq: space_seq(h),
        };
        let matches = h.incarnation == self.config.incarnation
            && self.pending.get(&id).is_some_and(|p| p.attempts > 0);
        if !matches {
            self.stats.stale_acks += 1;
            return false;
        }
        self.stats.acks_received += 1;
        let p = &self.pending[&id];
        let attempts = p.attempts;
        let latency = now.saturating_since(p.first_sent.unwrap_or(now));
        let sent_on = p.route.link;
        let sampled = sample && attempts == 1 && link == sent_on;
        if sampled {
            // Karn: only unambiguous samples.
            self.rtt_sample(id.to, sent_on, latency);
        }
        if link != sent_on {
            // Confirmed on another path than its last frame took (a probe's copy, or an
            // earlier frame's acknowledgement after a failover): the outcome names the path
            // that carried the confirmation.
            let route = self.route_written_for(id.to, link, self.pending[&id].route);
            if let Some(p) = self.pending.get_mut(&id) {
                p.route = route;
            }
        }
        self.finish(id, Outcome::acknowledged(status, attempts, latency));
        sampled
    }

    pub(super) fn handle_data(
        &mut self,
        now: Time,
        link: usize,
        h: &Header,
        payload: PayloadSource<'_>,
    ) {
        let origin = h.source.system;
        // The acknowledgement of a broadcast's frame says which space its number is in.
        let ack_header = Header {
            kind: FrameKind::Ack,
            flags: h.flags & FLAG_BROADCAST_SEQ,
            priority: h.priority,
            transport: h.transport,
            source: h.destination,
            destination: h.source,
            incarnation: h.incarnation,
            seq: h.seq,
            message_type: h.message_type,
            timestamp: h.timestamp,
        };
        let key = (origin, h.incarnation);
        let seq = space_seq(h);
        let dedup = match h.broadcast_seq() {
            true => &mut self.broadcast_dedup,
            false => &mut self.dedup,
        };
        let answer = match dedup.check_and_insert(origin, h.incarnation, h.seq) {
            Verdict::New => None,
            Verdict::Duplicate => Some(AckStatus::Delivered),
            Verdict::Refused(status) => Some(status),
            Verdict::TooOld => {
                // Whether an earlier copy entered the inbox is forgotten: delivering it could
                // deliver it twice, acknowledging it could claim a delivery that never was.
                // Silence leaves the sender's outcome unconfirmed, which is true.
                self.stats.too_old += 1;
                return;
            }
        };
        if let Some(status) = answer {
            self.stats.duplicates += 1;
            // The earlier acknowledgement may have been lost: say it again, unless the first
            // copy is still waiting for its inbox or its turn (its ack comes then).
            let waiting = self
                .awaiting
                .values()
                .any(|d| d.origin == origin && d.incarnation == h.incarnation && d.seq == seq)
                || (!h.broadcast_seq()
                    && self
                        .order
                        .get(&key)
                        .is_some_and(|o| o.held.contains_key(&h.seq)));
            if h.ack_requested() && !waiting {
                self.queue_ack(link, ack_header, status);
            }
            return;
        }
        // In-order delivery follows a sender's space towards this system; its broadcasts,
        // numbered in a space of their own, are delivered as they come.
        if h.broadcast_seq() || !self.config.ordered_sources.contains(&origin) {
            self.accept(link, *h, payload.into_buf(), ack_header);
            return;
        }
        let hold = self.config.timing.hold_timeout;
        let state = self.order.entry(key).or_insert_with(|| OrderState {
            next: 1,
            ..OrderState::default()
        });
        if h.seq > state.next {
            self.stats.held += 1;
            state.held.insert(
                h.seq,
                Held {
                    header: *h,
                    payload: payload.into_buf(),
                    link,
                    ack_header,
                },
            );
            if state.deadline.is_none() {
                state.deadline = Some(now + hold);
                self.timers.insert((now + hold, Timer::Hold(key.0, key.1)));
            }
            return;
        }
        if h.seq == state.next {
            state.next += 1;
        }
        // In order (or older than a gap already given up): deliver, then whatever it unblocks.
        self.accept(link, *h, payload.into_buf(), ack_header);
        self.release_in_order(now, key);
    }

    /// Delivers held messages that are now next in line.
    pub(super) fn release_in_order(&mut self, now: Time, key: (SystemId, u32)) {
        let hold = self.config.timing.hold_timeout;
        let mut ready = Vec::new();
        if let Some(state) = self.order.get_mut(&key) {
            while let Some(held) = state.held.remove(&state.next) {
                state.next += 1;
                ready.push(held);
            }
            let deadline = if state.held.is_empty() {
                None
            } else {
                Some(now + hold)
            };
            if state.deadline != deadline {
                if let Some(old) = state.deadline {
                    self.timers.remove(&(old, Timer::Hold(key.0, key.1)));
                }
                if let Some(new) = deadline {
                    self.timers.insert((new, Timer::Hold(key.0, key.1)));
                }
                state.deadline = deadline;
            }
        }
        for held in ready {
            self.accept(held.link, held.header, held.payload, held.ack_header);
        }
    }

    /// Hands a message to the driver for its inbox (with a token when it wants an ack).
    pub(super) fn accept(
        &mut self,
        link: usize,
        header: Header,
        payload: PayloadBuf,
        ack_header: Header,
    ) {
        self.stats.received += 1;
        let token = if header.ack_requested() {
            let token = DeliveryToken(self.next_token);
            self.next_token += 1;
            self.awaiting.insert(
                token,
                PendingDelivery {
                    origin: header.source.system,
                    incarnation: header.incarnation,
                    seq: space_seq(&header),
                    link,
                    ack_header,
                },
            );
            Some(token)
        } else {
            None
        };
        self.deliveries.push_back(Delivery {
            header,
            payload,
            link,
            token,
        });
    }

    pub(super) fn queue_ack(&mut self, link: usize, header: Header, status: AckStatus) {
        self.stats.acks_sent += 1;
        // The acknowledgement of the frame after the one the last queued acknowledgement
        // covers, from and to the same modules with the same status: one frame for both.
        // (Acknowledgements queue while a batch of deliveries is answered, and leave at the
        // next poll: widening one delays nothing.)
        if let Some(TransmitItem::Ack {
            link: l,
            header: last,
            status: s,
            first,
        }) = self.transmits.back_mut()
        {
            let next = last.seq.checked_add(1) == Some(header.seq);
            if next
                && *l == link
                && *s == status
                && last.flags == header.flags
                && last.source == header.source
                && last.destination == header.destination
                && last.incarnation == header.incarnation
                && last.transport == header.transport
                && header.seq - *first < ACK_RANGE_MAX
            {
                *last = header;
                return;
            }
        }
        self.transmits.push_back(TransmitItem::Ack {
            link,
            header,
            status,
            first: header.seq,
        });
    }

    /// The next message for a local module.
    pub fn poll_delivery(&mut self) -> Option<Delivery> {
        self.deliveries.pop_front()
    }

    /// Reports what the destination inbox did with a delivery that carried a token; the
    /// router acknowledges accordingly. A refused message stays refused: a retransmission
    /// (its sender did not hear the refusal) is answered with the same status, so that every
    /// acknowledgement of one message says the same thing whatever order they arrive in.
    pub fn delivery_result(&mut self, _now: Time, token: DeliveryToken, status: AckStatus) {
        let Some(d) = self.awaiting.remove(&token) else {
            return;
        };
        if status != AckStatus::Delivered {
            match d.seq & BROADCAST_SEND != 0 {
                true => self.broadcast_dedup.refuse(
                    d.origin,
                    d.incarnation,
                    d.seq & !BROADCAST_SEND,
                    status,
                ),
                false => self.dedup.refuse(d.origin, d.incarnation, d.seq, status),
            }
            self.stats.received -= 1;
        }
        self.queue_ack(d.link, d.ack_header, status);
    }
}

/// A frame's sequence number as the router keys it: with [`BROADCAST_SEND`] set when it
/// counts in the sender's broadcast space.
fn space_seq(h: &Header) -> u64 {
    match h.broadcast_seq() {
        true => BROADCAST_SEND | h.seq,
        false => h.seq,
    }
}
