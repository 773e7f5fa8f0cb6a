//! Native broadcasts: one frame that every destination on a link receives at once.
//!
//! A link that reaches every system with one send (`LinkCaps::broadcast`, e.g. one Zenoh put
//! on a key every system subscribes to) gets one frame for all the destinations whose route
//! takes it ([`Router::send_broadcast`]). The frame is numbered in this system's *broadcast*
//! space (`FLAG_BROADCAST_SEQ`) and written for every system (`FLAG_TO_ALL`). Each destination
//! still has a send of its own, with its own token and outcome (a share, named by a
//! [`SendId`] with [`BROADCAST_SEND`] set): the one transmission counts as an attempt of every
//! share, each receiver acknowledges the one frame, and a share whose acknowledgement does
//! not come is retransmitted to that destination alone, as a copy of the frame naming it
//! (still in the broadcast space, so a receiver that had the frame after all suppresses the
//! copy as a duplicate).

use super::*;

/// The frame of one native broadcast and who it is for.
pub(super) struct BroadcastPut {
    /// The link it goes on.
    link: usize,
    /// The frame; None while the driver holds it.
    frame: Option<Vec<u8>>,
    /// Every destination it was sent to.
    dests: Vec<SystemId>,
    /// Destinations whose share has not ended yet.
    open: usize,
}

impl<T> Router<T> {
    /// The destinations one native broadcast on `link` may cover: those whose route's own
    /// path is on `link`, with the settings of the first of them (tag, acknowledgement,
    /// attempts), ascending. A destination on another link (or on this one with other
    /// settings) takes a send of its own. Only meaningful for a link that reaches every
    /// system with one send.
    pub fn broadcast_group(&self, link: usize) -> Vec<SystemId> {
        let mut group: Vec<(SystemId, Route)> = self
            .routes
            .iter()
            .filter(|(_, r)| r.route.link == link)
            .map(|(to, r)| (*to, r.route))
            .collect();
        group.sort_unstable_by_key(|(to, _)| *to);
        let Some(&(_, first)) = group.first() else {
            return Vec::new();
        };
        let same = |r: &Route| {
            (r.tag, r.acknowledged, r.attempts, r.max_frame)
                == (
                    first.tag,
                    first.acknowledged,
                    first.attempts,
                    first.max_frame,
                )
        };
        group
            .into_iter()
            .filter(|(_, r)| same(r))
            .map(|(to, _)| to)
            .collect()
    }

    /// Sends one frame for every system in `dests` (from [`Router::broadcast_group`]: their
    /// routes' own path is one link, which must reach them all with one send), to module
    /// `req.to.module` (`req.to.system` is not used). Each destination gets a send of its own,
    /// with the token `token(destination)` and an outcome as a single send has; they are
    /// returned in the order of `dests`. The frame comes out of [`Router::poll_transmit`]
    /// once, addressed to [`TO_ALL_SYSTEM`]; retransmissions go to each destination that did
    /// not acknowledge it, alone. Stamped and timed as [`Router::send`].
    ///
    /// Refused as a whole, with nothing numbered or sent, when a destination has no route,
    /// when the message does not fit, or when a destination's window is full
    /// ([`SendError::Backpressure`] naming it): the driver then sends per destination, so
    /// that only that destination's send is refused. (The one frame reaches every
    /// destination, so it cannot leave one of them out.)
    pub fn send_broadcast(
        &mut self,
        _now: Time,
        req: SendRequest<'_>,
        dests: &[SystemId],
        mut token: impl FnMut(SystemId) -> T,
    ) -> Result<Vec<SendId>, SendError> {
        let from = self.config.local;
        let Some(&first) = dests.first() else {
            return Ok(Vec::new());
        };
        let route = self
            .routes
            .get(&first)
            .map(|r| r.route)
            .ok_or(SendError::NoRoute { from, to: first })?;
        let len = HEADER_LEN + req.payload.len();
        let max = route.max_frame.min(HEADER_LEN + wire::MAX_PAYLOAD);
        if len > max {
            return Err(SendError::TooLarge {
                len,
                max,
                to: first,
            });
        }
        for &to in dests {
            let r = self
                .routes
                .get(&to)
                .map(|r| r.route)
                .ok_or(SendError::NoRoute { from, to })?;
            let towards = self.towards.get(&to);
            let (pending, bytes) = towards.map_or((0, 0), |t| (t.pending, t.pending_bytes));
            if pending >= r.max_in_flight || (pending > 0 && bytes + len > r.max_in_flight_bytes) {
                return Err(SendError::Backpressure {
                    to,
                    limit: r.max_in_flight,
                });
            }
        }
        self.broadcast_seq += 1;
        let b = self.broadcast_seq;
        let mut flags = FLAG_BROADCAST | FLAG_BROADCAST_SEQ | FLAG_TO_ALL;
        if route.acknowledged {
            flags |= FLAG_ACK_REQUESTED;
        }
        let header = Header {
            kind: FrameKind::Data,
            flags,
            priority: req.priority,
            transport: route.tag,
            source: Address {
                system: from,
                module: req.from,
            },
            destination: Address {
                system: TO_ALL_SYSTEM,
                module: req.to.module,
            },
            incarnation: self.config.incarnation,
            seq: b,
            message_type: req.message_type,
            timestamp: req.timestamp,
        };
        let frame = self.encode(&route, header, req.payload);
        let mut ids = Vec::with_capacity(dests.len());
        for &to in dests {
            let id = SendId {
                to,
                seq: BROADCAST_SEND | b,
            };
            let own = self.route(to).unwrap_or(route);
            self.keep_pending(
                id,
                Pending {
                    token: token(to),
                    route: own,
                    bytes: frame.len(),
                    frame: None,
                    attempts: 0,
                    transmitted: false,
                    session_waits: 0,
                    offered: Time::ZERO,
                    first_sent: None,
                    deadline: None,
                    broadcast: Some(b),
                    unbuilt: true,
                    awaiting_ack: false,
                    timed_out: false,
                    to_untried: false,
                    tried: 0,
                    presettled_from: None,
                },
            );
            self.stats.sends += 1;
            ids.push(id);
        }
        self.broadcasts.insert(
            b,
            BroadcastPut {
                link: route.link,
                frame: Some(frame),
                dests: dests.to_vec(),
                open: dests.len(),
            },
        );
        self.transmits.push_back(TransmitItem::Broadcast(b));
        Ok(ids)
    }

    /// The destinations of native broadcast `b` (the `wire_seq` of its frame's
    /// [`Transmit::send`]) whose share has not ended, ascending; empty once all have.
    pub fn broadcast_destinations(&self, b: u64) -> Vec<SystemId> {
        let Some(put) = self.broadcasts.get(&b) else {
            return Vec::new();
        };
        put.dests
            .iter()
            .copied()
            .filter(|&to| {
                self.pending.contains_key(&SendId {
                    to,
                    seq: BROADCAST_SEND | b,
                })
            })
            .collect()
    }

    /// Whether the shares of native broadcast `b` still open are acknowledged (they share one
    /// route's settings); None once all have ended.
    pub(super) fn broadcast_acknowledged(&self, b: u64) -> Option<bool> {
        let put = self.broadcasts.get(&b)?;
        put.dests.iter().find_map(|&to| {
            let id = SendId {
                to,
                seq: BROADCAST_SEND | b,
            };
            self.pending.get(&id).map(|p| p.route.acknowledged)
        })
    }

    /// The one frame of broadcast `b`, counted as an attempt of each share still open.
    pub(super) fn poll_broadcast(&mut self, now: Time, b: u64) -> Option<Transmit> {
        let put = self.broadcasts.get_mut(&b)?;
        let frame = put.frame.take()?;
        let link = put.link;
        for &to in &put.dests {
            let id = SendId {
                to,
                seq: BROADCAST_SEND | b,
            };
            if let Some(p) = self.pending.get_mut(&id) {
                p.attempts += 1;
                p.tried |= link_bit(link);
                p.first_sent.get_or_insert(now);
            }
        }
        self.stats.transmissions += 1;
        Some(Transmit {
            link: put.link,
            to: TO_ALL_SYSTEM,
            frame,
            send: Some(SendId {
                to: TO_ALL_SYSTEM,
                seq: BROADCAST_SEND | b,
            }),
            probe: None,
            presettled: false,
        })
    }

    /// What the link did with a broadcast's one frame: the result of an attempt of every
    /// share still open.
    pub(super) fn broadcast_result(
        &mut self,
        now: Time,
        tx: Transmit,
        result: Result<(), TransmitError>,
    ) {
        let b = tx.send.map_or(0, |id| id.wire_seq());
        let Some(put) = self.broadcasts.get_mut(&b) else {
            // Every share ended while the driver held the frame (acknowledged already).
            self.recycle(tx.frame);
            return;
        };
        put.frame = Some(tx.frame);
        let (link, dests) = (put.link, put.dests.clone());
        for to in dests {
            let id = SendId {
                to,
                seq: BROADCAST_SEND | b,
            };
            self.settle(now, id, link, result.clone());
        }
    }

    /// A copy of broadcast `id`'s frame for its destination alone, written for the path it
    /// takes now (a retransmission to a destination that did not acknowledge). None (and
    /// the retransmission put off) while the driver still holds the broadcast's frame.
    pub(super) fn broadcast_copy(&mut self, now: Time, id: SendId) -> Option<Vec<u8>> {
        let b = id.wire_seq();
        let route = self.route(id.to)?;
        let copy = self
            .broadcasts
            .get(&b)
            .and_then(|put| put.frame.as_deref())
            .and_then(|frame| wire::decode(frame).ok())
            .map(|put| {
                let mut header = put.header;
                header.destination.system = id.to;
                header.transport = route.tag;
                header.flags &= !(FLAG_TO_ALL | FLAG_HEADER_CRC);
                if self.link_checksums_payload(route.link) {
                    header.flags |= FLAG_HEADER_CRC;
                }
                wire::encode(&header, put.payload)
            });
        let p = self.pending.get_mut(&id)?;
        match copy {
            Some(copy) => {
                p.unbuilt = false;
                p.route.link = route.link;
                p.route.tag = route.tag;
                Some(copy)
            }
            None => {
                let deadline = now + self.config.timing.link_retry;
                p.deadline = Some(deadline);
                self.timers.insert((deadline, Timer::Retransmit(id)));
                None
            }
        }
    }

    /// One share of broadcast `b` ended: the broadcast is forgotten with its last share.
    pub(super) fn broadcast_share_ended(&mut self, b: u64) {
        let Some(put) = self.broadcasts.get_mut(&b) else {
            return;
        };
        put.open -= 1;
        if put.open == 0 {
            if let Some(frame) = self.broadcasts.remove(&b).and_then(|p| p.frame) {
                self.recycle(frame);
            }
        }
    }
}
