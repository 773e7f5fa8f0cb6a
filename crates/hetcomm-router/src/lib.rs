//! # hetcomm-router — the sans-IO heart
//!
//! One [`Router`] per system. It turns module sends into frames for links, frames from links
//! into deliveries for module inboxes, and keeps every send's promise: exactly one
//! [`Outcome`] per send — delivered (acknowledged by the receiving router), sent without
//! confirmation, or failed with the reason and the number of attempts.
//!
//! It reads no clock and touches no socket: every input carries `now`, and the driver (the real
//! runtime in the `hetcomm` crate, or the virtual-time simulator) performs the outputs.
//! `now` must come from a monotonic clock (the real runtime's is `CLOCK_MONOTONIC`): every
//! deadline and RTT sample is computed from it, so a clock that steps would fire every
//! retransmission at once (a step forward) or stall them (a step back). The one wall-clock
//! time the router handles is the header's timestamp, which the driver puts in the request
//! ([`SendRequest::timestamp`]) and the router copies, never compares.
//!
//! | call | when |
//! |---|---|
//! | [`Router::send`] | a module sends |
//! | [`Router::send_unqueued`] / [`Router::unqueued_result`] | a module sends (the driver puts an unacknowledged send's frame on the link at once, without the router keeping it) / after the link took or refused that frame |
//! | [`Router::poll_transmit`] | after any input: frames to put on links |
//! | [`Router::transmit_result`] | after a link took (or refused) a frame from `poll_transmit` |
//! | [`Router::handle_frame`] | a link received a frame |
//! | [`Router::poll_delivery`] | after `handle_frame`: messages for local module inboxes |
//! | [`Router::delivery_result`] | after the inbox took (or refused) a delivery that wants an ack |
//! | [`Router::poll_timeout`] / [`Router::handle_timeout`] | arm a timer / when it fires |
//! | [`Router::poll_event`] | after any input: outcomes of sends |
//! | [`Router::direct_lane`] | once per in-process destination: a [`DirectLane`] numbers and counts sends the driver hands straight to an inbox of the same process, without the router's lock |
//!
//! Reliability is end to end: the sender keeps an acknowledged frame until the destination
//! router says the message is in the module's inbox, retransmitting after a timeout derived from
//! the measured round-trip time (RFC 6298 estimator, Karn's rule, exponential backoff) until the
//! attempt budget is spent. Receivers suppress duplicates by (origin, incarnation, sequence).
//!
//! ```
//! use hetcomm_core::*;
//! use hetcomm_router::*;
//!
//! let route = Route { link: 0, tag: b'R', acknowledged: true, attempts: 3, max_frame: 1 << 20, max_in_flight: 1024, max_in_flight_bytes: 1 << 22 };
//! let mut a = Router::<()>::new(RouterConfig::new(SystemId(0), 1, vec![(SystemId(1), route)]));
//! let mut b = Router::<()>::new(RouterConfig::new(SystemId(1), 2, vec![(SystemId(0), route)]));
//! let now = Time::ZERO;
//! let to = Address { system: SystemId(1), module: ModuleId(2) };
//! a.send(now, SendRequest::new(ModuleId(1), to, MessageType(7), b"hi"), ()).unwrap();
//! let tx = a.poll_transmit(now).unwrap();
//! b.handle_frame(now, tx.link, &tx.frame);
//! a.transmit_result(now, tx, Ok(()));
//! let d = b.poll_delivery().unwrap();
//! assert_eq!(d.payload, b"hi");
//! b.delivery_result(now, d.token.unwrap(), wire::AckStatus::Delivered);
//! let ack = b.poll_transmit(now).unwrap();
//! a.handle_frame(now, ack.link, &ack.frame);
//! assert!(matches!(a.poll_event(), Some(Event::Outcome { outcome: Outcome::Delivered { attempts: 1, .. }, .. })));
//! ```

mod dedup;
mod lane;
mod router;
mod rtt;

pub use lane::DirectLane;
pub use router::*;
pub use rtt::RttEstimator;

#[cfg(test)]
mod tests {
    use super::*;
    use hetcomm_core::*;
    use std::sync::Arc;

    #[test]
    fn an_acknowledged_send_leaves_no_timer_behind() {
        let route = Route {
            link: 0,
            tag: b'R',
            acknowledged: true,
            attempts: 3,
            max_frame: 1 << 20,
            max_in_flight: 1024,
            max_in_flight_bytes: usize::MAX,
        };
        let mut a = Router::<()>::new(RouterConfig::new(
            SystemId(0),
            1,
            vec![(SystemId(1), route)],
        ));
        let mut b = Router::<()>::new(RouterConfig::new(
            SystemId(1),
            2,
            vec![(SystemId(0), route)],
        ));
        let now = Time::from_micros(1_000);
        let to = Address {
            system: SystemId(1),
            module: ModuleId(0),
        };
        a.send(
            now,
            SendRequest::new(ModuleId(0), to, MessageType(1), b"x"),
            (),
        )
        .unwrap();
        let tx = a.poll_transmit(now).unwrap();
        b.handle_frame(now, tx.link, &tx.frame);
        a.transmit_result(now, tx, Ok(()));
        assert!(a.poll_timeout().is_some(), "armed while unacknowledged");
        let d = b.poll_delivery().unwrap();
        b.delivery_result(now, d.token.unwrap(), wire::AckStatus::Delivered);
        let ack = b.poll_transmit(now).unwrap();
        a.handle_frame(now, ack.link, &ack.frame);
        assert!(matches!(
            a.poll_event(),
            Some(Event::Outcome {
                outcome: Outcome::Delivered { .. },
                ..
            })
        ));
        assert_eq!(
            a.poll_timeout(),
            None,
            "a delivered send must not keep a timer"
        );
    }

    /// The header carries the request's (wall-clock) stamp; every deadline counts from the
    /// (monotonic) `now`, however far apart the two clocks are.
    #[test]
    fn the_header_is_stamped_with_the_request_and_timed_by_now() {
        let route = direct_route(true);
        let mut a = Router::<()>::new(RouterConfig::new(
            SystemId(0),
            1,
            vec![(SystemId(1), route)],
        ));
        let (now, wall) = (
            Time::from_micros(5_000),
            Time::from_micros(1_700_000_000_000_000),
        );
        let to = Address {
            system: SystemId(1),
            module: ModuleId(0),
        };
        let req = SendRequest::new(ModuleId(0), to, MessageType(1), b"x").stamped(wall);
        a.send(now, req, ()).unwrap();
        let tx = a.poll_transmit(now).unwrap();
        let header = wire::decode(&tx.frame).unwrap().header;
        assert_eq!(header.timestamp, wall);
        a.transmit_result(now, tx, Ok(()));
        let deadline = a.poll_timeout().expect("armed while unacknowledged");
        assert_eq!(deadline, now + Timing::default().initial_rto);
        // A later `now` retransmits when due, whatever the stamp said.
        a.handle_timeout(deadline);
        let again = a
            .poll_transmit(deadline)
            .expect("retransmitted at its deadline");
        assert_eq!(wire::decode(&again.frame).unwrap().header.timestamp, wall);
    }

    fn direct_route(acknowledged: bool) -> Route {
        Route {
            link: 0,
            tag: b'I',
            acknowledged,
            attempts: 3,
            max_frame: 64,
            max_in_flight: 1024,
            max_in_flight_bytes: usize::MAX,
        }
    }

    fn to(s: u16) -> Address {
        Address {
            system: SystemId(s),
            module: ModuleId(0),
        }
    }

    fn req(s: u16, p: &[u8]) -> SendRequest<'_> {
        SendRequest::new(ModuleId(0), to(s), MessageType(1), p)
    }

    #[test]
    fn direct_sends_are_numbered_checked_and_counted() {
        let mut a = Router::<()>::new(RouterConfig::new(
            SystemId(0),
            1,
            vec![
                (SystemId(1), direct_route(true)),
                (SystemId(2), direct_route(false)),
            ],
        ));
        let now = Time::from_micros(5);
        let acked = a.direct_lane(SystemId(1)).unwrap();
        assert!(Arc::ptr_eq(&acked, &a.direct_lane(SystemId(1)).unwrap()));
        let h1 = acked.send(&req(1, b"a").stamped(now)).unwrap();
        let h2 = acked.send(&req(1, b"b")).unwrap();
        assert_eq!(
            (h1.timestamp, h2.timestamp),
            (now, Time::ZERO),
            "the request's stamp"
        );
        assert_eq!((h1.seq, h2.seq), (1, 2), "numbered per destination");
        assert!(h1.ack_requested());
        assert_eq!((h1.source.system, h1.incarnation), (SystemId(0), 1));
        assert_eq!(a.route_link(SystemId(1)), Some(0));
        assert!(matches!(
            a.direct_lane(SystemId(3)),
            Err(SendError::NoRoute { .. })
        ));
        assert!(matches!(
            acked.send(&req(1, &[0; 64])),
            Err(SendError::TooLarge { .. })
        ));
        assert_eq!(a.stats().in_flight(), 2, "counted as sent before they end");
        let delivered = acked.result(&h1, wire::AckStatus::Delivered);
        assert!(matches!(delivered, Outcome::Delivered { attempts: 1, .. }));
        let full = acked.result(&h2, wire::AckStatus::InboxFull);
        assert!(matches!(
            full,
            Outcome::Failed {
                reason: FailReason::InboxFull,
                ..
            }
        ));
        // Unacknowledged: `Sent` whatever the inbox said, as over a link.
        let unacked = a.direct_lane(SystemId(2)).unwrap();
        let h3 = unacked.send(&req(2, b"c")).unwrap();
        let sent = unacked.result(&h3, wire::AckStatus::InboxFull);
        assert_eq!(sent, Outcome::Sent { attempts: 1 });
        let s = a.stats();
        assert_eq!(
            (s.sends, s.transmissions, s.delivered, s.failed, s.sent),
            (3, 3, 1, 1, 1)
        );
        assert_eq!(s.in_flight(), 0);
    }

    #[test]
    fn a_lane_and_the_router_number_one_destination_from_one_counter() {
        let mut a = Router::<()>::new(RouterConfig::new(
            SystemId(0),
            1,
            vec![(SystemId(1), direct_route(false))],
        ));
        let now = Time::from_micros(5);
        // Two sends through the router before the lane exists, then alternating.
        let mut numbers = Vec::new();
        for _ in 0..2 {
            a.send(now, req(1, b"r"), ()).unwrap();
            let t = a.poll_transmit(now).unwrap();
            numbers.push(wire::decode(&t.frame).unwrap().header.seq);
            a.transmit_result(now, t, Ok(()));
        }
        let lane = a.direct_lane(SystemId(1)).unwrap();
        for _ in 0..3 {
            numbers.push(lane.send(&req(1, b"l")).unwrap().seq);
            a.send(now, req(1, b"r"), ()).unwrap();
            let t = a.poll_transmit(now).unwrap();
            numbers.push(wire::decode(&t.frame).unwrap().header.seq);
            a.transmit_result(now, t, Ok(()));
        }
        assert_eq!(numbers, (1..=8).collect::<Vec<_>>());
        let s = a.stats();
        assert_eq!((s.sends, s.sent), (8, 8));
    }

    #[test]
    fn lane_sends_from_many_threads_get_unique_numbers_and_are_all_counted() {
        let mut a = Router::<()>::new(RouterConfig::new(
            SystemId(0),
            1,
            vec![(SystemId(1), direct_route(true))],
        ));
        let lane = a.direct_lane(SystemId(1)).unwrap();
        let threads: Vec<_> = (0..4)
            .map(|t| {
                let lane = lane.clone();
                std::thread::spawn(move || {
                    (0..1000)
                        .map(|i| {
                            let h = lane.send(&req(1, b"x")).unwrap();
                            let status = if (i + t) % 3 == 0 {
                                wire::AckStatus::InboxFull
                            } else {
                                wire::AckStatus::Delivered
                            };
                            lane.result(&h, status);
                            h.seq
                        })
                        .collect::<Vec<_>>()
                })
            })
            .collect();
        // Stats read while the threads run never count an outcome before its send.
        while !threads.iter().all(|t| t.is_finished()) {
            let s = a.stats();
            assert!(s.delivered + s.failed <= s.sends, "{s:?}");
        }
        let mut all: Vec<u64> = threads
            .into_iter()
            .flat_map(|t| t.join().unwrap())
            .collect();
        all.sort_unstable();
        assert_eq!(all, (1..=4000).collect::<Vec<_>>());
        let s = a.stats();
        assert_eq!((s.sends, s.delivered + s.failed), (4000, 4000));
        assert_eq!(
            s.failed, 1334,
            "(i + t) % 3 == 0 for 1334 of the 4000 sends"
        );
        assert_eq!(s.in_flight(), 0);
    }
}
