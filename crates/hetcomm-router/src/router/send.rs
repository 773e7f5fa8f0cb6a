//! Admitting a send: the window, numbering, framing and direct lanes.

use super::*;

impl<T> Router<T> {
    /// Accepts a send: assigns its sequence number and queues its frame. Its outcome arrives
    /// later through [`Router::poll_event`]. The header is stamped with `req.timestamp`;
    /// `now`, the driver's monotonic time as for every input, is not needed to admit a send
    /// (its timers start when its frame is polled).
    pub fn send(&mut self, now: Time, req: SendRequest<'_>, token: T) -> Result<SendId, SendError> {
        let (route, header) = self.admit(&req)?;
        let id = self.queue(route, header, req.payload, token);
        if self.judging && self.unhealthy_paths > 0 {
            self.probe_soon(now, id);
        }
        Ok(id)
    }

    /// Encodes a send's frame (into a spare buffer when one is big enough).
    pub(super) fn encode(&mut self, route: &Route, header: Header, payload: &[u8]) -> Vec<u8> {
        let (header, mut frame) = self.frame_buffer(route, header, HEADER_LEN + payload.len());
        wire::encode_into(&header, payload, &mut frame);
        frame
    }

    /// Only the header of the frame [`Router::encode`] would make.
    pub(super) fn encode_header(
        &mut self,
        route: &Route,
        header: Header,
        payload: &[u8],
    ) -> Vec<u8> {
        let (header, mut frame) = self.frame_buffer(route, header, HEADER_LEN);
        wire::encode_header_into(&header, payload, &mut frame);
        frame
    }

    /// The header as sent on `route`'s link, and an empty buffer for `len` bytes of frame.
    pub(super) fn frame_buffer(
        &mut self,
        route: &Route,
        mut header: Header,
        len: usize,
    ) -> (Header, Vec<u8>) {
        if self.link_checksums_payload(route.link) {
            header.flags |= FLAG_HEADER_CRC;
        }
        let frame = match self.spare_frames.pop() {
            Some(mut f) => {
                self.spare_bytes -= f.capacity();
                f.clear();
                f.reserve(len);
                f
            }
            None => Vec::with_capacity(len),
        };
        (header, frame)
    }

    /// Keeps an admitted send as pending and queues its first transmission.
    pub(super) fn queue(
        &mut self,
        route: Route,
        header: Header,
        payload: &[u8],
        token: T,
    ) -> SendId {
        let id = SendId {
            to: header.destination.system,
            seq: header.seq,
        };
        let frame = self.encode(&route, header, payload);
        self.keep_pending(
            id,
            Pending {
                token,
                route,
                bytes: frame.len(),
                frame: Some(frame),
                attempts: 0,
                transmitted: false,
                session_waits: 0,
                offered: Time::ZERO,
                first_sent: None,
                deadline: None,
                broadcast: None,
                unbuilt: false,
                awaiting_ack: false,
                timed_out: false,
                to_untried: false,
                tried: 0,
                presettled_from: None,
            },
        );
        self.transmits.push_back(TransmitItem::Send(id));
        self.stats.sends += 1;
        id
    }

    /// Like [`Router::send`], except that an unacknowledged send is not kept: its outcome is
    /// known as soon as the link takes or refuses its one frame, so the router numbers and
    /// counts it and hands the frame straight back ([`Admitted::Transmit`]) instead of keeping
    /// a pending entry, a queued transmission and an event for it. The driver puts the frame
    /// on the link and reports with [`Router::unqueued_result`]. An acknowledged send is
    /// queued as by [`Router::send`] ([`Admitted::Queued`]); `token` is only called then,
    /// or later by `unqueued_result` should a refused frame be retried, so a driver whose
    /// token is costly (a shared slot for the outcome) makes one only when it is needed.
    /// Stamped and timed as [`Router::send`].
    pub fn send_unqueued<'a>(
        &mut self,
        now: Time,
        req: SendRequest<'a>,
        token: impl FnOnce() -> T,
    ) -> Result<Admitted<'a>, SendError> {
        let (route, header) = self.admit(&req)?;
        if route.acknowledged {
            let id = self.queue(route, header, req.payload, token());
            if self.judging && self.unhealthy_paths > 0 {
                self.probe_soon(now, id);
            }
            return Ok(Admitted::Queued(id));
        }
        let id = SendId {
            to: header.destination.system,
            seq: header.seq,
        };
        let split =
            req.payload.len() >= SPLIT_PAYLOAD_MIN && self.link_checksums_payload(route.link);
        let (frame, body) = if split {
            (self.encode_header(&route, header, req.payload), req.payload)
        } else {
            (self.encode(&route, header, req.payload), &[][..])
        };
        self.stats.sends += 1;
        self.stats.transmissions += 1;
        Ok(Admitted::Transmit(Unqueued {
            link: route.link,
            to: id.to,
            frame,
            body,
            id,
        }))
    }

    /// Reports what the link did with the frame of an unqueued send
    /// ([`Router::send_unqueued`]) and returns the send's outcome when it is known now: `Sent`
    /// when the link took the frame, `Failed` when it refused it for good (too large, or the
    /// route allows one attempt). A refusal with attempts left makes the send pending with
    /// `token` and retries it after [`Timing::link_retry`], exactly as a queued send; its
    /// outcome then comes out of [`Router::poll_event`] and this returns None.
    pub fn unqueued_result(
        &mut self,
        now: Time,
        tx: Unqueued<'_>,
        result: Result<(), TransmitError>,
        token: impl FnOnce() -> T,
    ) -> Option<Outcome> {
        let Unqueued {
            mut frame,
            body,
            id,
            link: tx_link,
            ..
        } = tx;
        let err = match result {
            Ok(()) => {
                self.recycle(frame);
                self.stats.sent += 1;
                return Some(Outcome::Sent { attempts: 1 });
            }
            Err(err) => err,
        };
        self.path_result(now, id.to, tx_link, &Err(err.clone()));
        let route = self.route(id.to);
        let retry = match (&err, route) {
            (TransmitError::TooLarge(_) | TransmitError::Refused(_), _) | (_, None) => None,
            (_, Some(route)) => Some(route).filter(|r| r.attempts > 1),
        };
        // The frame stays written for the path it was refused on; a retry on another path
        // rewrites it (see `poll_transmit`).
        let retry = retry.map(|r| self.route_written_for(id.to, tx_link, r));
        let Some(route) = retry else {
            self.recycle(frame);
            self.stats.failed += 1;
            return Some(Outcome::Failed {
                reason: err.into(),
                attempts: 1,
            });
        };
        // The first attempt failed: from here on the send is an ordinary pending one, which
        // keeps its whole frame.
        frame.extend_from_slice(body);
        let deadline = now + self.config.timing.link_retry;
        self.keep_pending(
            id,
            Pending {
                token: token(),
                route,
                bytes: frame.len(),
                frame: Some(frame),
                attempts: 1,
                transmitted: false,
                session_waits: 0,
                offered: Time::ZERO,
                first_sent: Some(now),
                deadline: Some(deadline),
                broadcast: None,
                unbuilt: false,
                awaiting_ack: false,
                timed_out: false,
                to_untried: false,
                tried: link_bit(tx_link),
                presettled_from: None,
            },
        );
        self.timers.insert((deadline, Timer::Retransmit(id)));
        None
    }

    /// Records an unresolved send (counted against its destination's window).
    pub(super) fn keep_pending(&mut self, id: SendId, p: Pending<T>) {
        let towards = self.towards.entry(id.to).or_default();
        towards.pending += 1;
        towards.pending_bytes += p.bytes;
        self.pending.insert(id, p);
    }

    /// Sends to `to` awaiting their outcome (at most its route's [`Route::max_in_flight`]).
    pub fn pending_to(&self, to: SystemId) -> u32 {
        self.towards.get(&to).map_or(0, |t| t.pending)
    }

    /// Keeps an ended send's frame buffer for the next sends (see [`SPARE_FRAMES`]).
    pub(super) fn recycle(&mut self, frame: Vec<u8>) {
        let cap = frame.capacity();
        if self.spare_frames.len() < SPARE_FRAMES
            && cap <= SPARE_FRAME_MAX
            && self.spare_bytes + cap <= SPARE_BYTES
        {
            self.spare_bytes += cap;
            self.spare_frames.push(frame);
        }
    }

    /// Checks a send against the routing table and the size limit, gives it the next
    /// sequence number towards its destination and builds its header.
    pub(super) fn admit(&mut self, req: &SendRequest<'_>) -> Result<(Route, Header), SendError> {
        let to = req.to.system;
        let route = self.route(to).ok_or(SendError::NoRoute {
            from: self.config.local,
            to,
        })?;
        let len = HEADER_LEN + req.payload.len();
        let max = route.max_frame.min(HEADER_LEN + wire::MAX_PAYLOAD);
        if len > max {
            return Err(SendError::TooLarge { len, max, to });
        }
        let towards = self.towards.entry(to).or_default();
        // Refused before numbering: a refused send leaves no gap in the sequence.
        let over_bytes =
            towards.pending > 0 && towards.pending_bytes + len > route.max_in_flight_bytes;
        if towards.pending >= route.max_in_flight || over_bytes {
            self.stats.backpressured += 1;
            return Err(SendError::Backpressure {
                to,
                limit: route.max_in_flight,
            });
        }
        let seq = match &towards.lane {
            Some(lane) => {
                towards.numbered_here += 1;
                lane.last_seq.fetch_add(1, Ordering::Relaxed) + 1
            }
            None => {
                towards.last_seq += 1;
                towards.last_seq
            }
        };
        let mut flags = 0;
        if route.acknowledged {
            flags |= FLAG_ACK_REQUESTED;
        }
        if req.broadcast {
            flags |= FLAG_BROADCAST;
        }
        let header = Header {
            kind: FrameKind::Data,
            flags,
            priority: req.priority,
            transport: route.tag,
            source: Address {
                system: self.config.local,
                module: req.from,
            },
            destination: req.to,
            incarnation: self.config.incarnation,
            seq,
            message_type: req.message_type,
            timestamp: req.timestamp,
        };
        Ok((route, header))
    }

    /// The link a send to `to` would take.
    pub fn route_link(&self, to: SystemId) -> Option<usize> {
        self.routes.get(&to).map(|r| r.paths[r.active].path.link)
    }

    /// The lane for sends that the driver hands straight to `to` in the same process (an
    /// in-process link, which is reliable, ordered and synchronous), skipping the frame, its
    /// checksum, the destination's router and this router's lock ([`DirectLane`]). Made at
    /// the first call; later calls return the same lane.
    pub fn direct_lane(&mut self, to: SystemId) -> Result<Arc<DirectLane>, SendError> {
        let route = self.route(to).ok_or(SendError::NoRoute {
            from: self.config.local,
            to,
        })?;
        let (local, incarnation) = (self.config.local, self.config.incarnation);
        let towards = self.towards.entry(to).or_default();
        if towards.lane.is_none() {
            // The numbers given so far were the router's.
            towards.numbered_here = towards.last_seq;
        }
        let lane = towards.lane.get_or_insert_with(|| {
            Arc::new(DirectLane::new(
                local,
                incarnation,
                to,
                route,
                towards.last_seq,
            ))
        });
        Ok(lane.clone())
    }
}
