//! Paths in the router: a route with fallbacks, health per path from link events and link
//! results, failover with the frame rewritten for the path it leaves on, RTT per path, and
//! one timer table for retransmissions and in-order holds.

use std::time::Duration;

use hetcomm_core::wire::{self, AckStatus};
use hetcomm_core::*;
use hetcomm_router::*;

const A: SystemId = SystemId(0);
const B: SystemId = SystemId(1);
const WIRED: Path = Path { link: 0, tag: b'W' };
const RADIO: Path = Path { link: 1, tag: b'R' };

fn route(path: Path) -> Route {
    Route {
        link: path.link,
        tag: path.tag,
        acknowledged: true,
        attempts: 4,
        max_frame: 1 << 16,
        max_in_flight: 64,
        max_in_flight_bytes: usize::MAX,
    }
}

/// A with a wired route to B and a radio fallback; B answers on either.
fn pair() -> (Router<u32>, Router<u32>) {
    let a = Router::new(RouterConfig::new(A, 1, vec![(B, route(WIRED))]).with_fallback(B, RADIO));
    let b = Router::new(RouterConfig::new(B, 2, vec![(A, route(WIRED))]).with_fallback(A, RADIO));
    (a, b)
}

fn request() -> SendRequest<'static> {
    let to = Address {
        system: B,
        module: ModuleId(0),
    };
    SendRequest::new(ModuleId(0), to, MessageType(1), b"payload")
}

/// Hands `tx` to `b` on the link it names, delivers, and returns b's acknowledgement.
fn deliver(b: &mut Router<u32>, now: Time, tx: &Transmit) -> Transmit {
    b.handle_frame(now, tx.link, &tx.frame);
    let d = b.poll_delivery().expect("delivered");
    assert_eq!(&d.payload[..], b"payload");
    b.delivery_result(now, d.token.expect("wants an ack"), AckStatus::Delivered);
    b.poll_transmit(now).expect("an acknowledgement")
}

/// A frame `b` sends to A (unacknowledged or not, as its route says), as it leaves.
fn frame_to_a(b: &mut Router<u32>, now: Time, payload: &[u8]) -> Transmit {
    let to_a = Address {
        system: A,
        module: ModuleId(0),
    };
    let req = SendRequest::new(ModuleId(0), to_a, MessageType(1), payload);
    b.send(now, req, 0).unwrap();
    b.poll_transmit(now).unwrap()
}

fn outcome(a: &mut Router<u32>) -> Option<Outcome> {
    a.poll_event().map(|Event::Outcome { outcome, .. }| outcome)
}

#[test]
fn a_peer_down_on_the_active_path_fails_over_and_retransmits_there_at_once() {
    let (mut a, mut b) = pair();
    let t0 = Time::from_micros(1_000);
    a.send(t0, request(), 7).unwrap();
    let first = a.poll_transmit(t0).unwrap();
    assert_eq!(first.link, WIRED.link);
    assert_eq!(wire::decode(&first.frame).unwrap().header.transport, b'W');
    a.transmit_result(t0, first, Ok(()));

    // The wired link loses B before the acknowledgement comes.
    let t1 = t0 + Duration::from_millis(1);
    a.handle_link_event(t1, LinkEvent::PeerDown { link: 0, peer: B });
    assert_eq!(
        a.poll_path_change(),
        Some(PathChange {
            to: B,
            from: WIRED,
            now: RADIO
        })
    );
    assert_eq!(a.route(B).map(|r| (r.link, r.tag)), Some((1, b'R')));
    // The retransmission is due now, not after the RTO.
    assert_eq!(a.poll_timeout(), Some(t1));
    a.handle_timeout(t1);
    let again = a.poll_transmit(t1).unwrap();
    assert_eq!(again.link, RADIO.link);
    // Rewritten for the radio: its tag, and a frame that checks.
    let h = wire::decode(&again.frame).expect("a valid frame").header;
    assert_eq!((h.transport, h.seq), (b'R', 1));
    let ack = deliver(&mut b, t1, &again);
    a.transmit_result(t1, again, Ok(()));
    a.handle_frame(t1, ack.link, &ack.frame);
    assert!(
        matches!(
            outcome(&mut a),
            Some(Outcome::Delivered { attempts: 2, .. })
        ),
        "delivered over the fallback"
    );
    assert_eq!(a.stats().path_changes, 1);
    let paths = a.paths(B);
    assert_eq!(paths.len(), 2);
    assert!(!paths[0].up && !paths[0].active);
    assert!(paths[1].up && paths[1].active);
}

#[test]
fn a_refusal_as_unreachable_takes_the_path_down_and_the_retry_goes_on_the_next() {
    let (mut a, _) = pair();
    let t0 = Time::from_micros(1_000);
    a.send(t0, request(), 7).unwrap();
    let first = a.poll_transmit(t0).unwrap();
    a.transmit_result(
        t0,
        first,
        Err(TransmitError::Unreachable("connection refused".into())),
    );
    assert_eq!(a.poll_path_change().map(|c| c.now), Some(RADIO));
    // Retried at once on the new path, not after the link back-off.
    assert_eq!(a.poll_timeout(), Some(t0));
    a.handle_timeout(t0);
    let retry = a.poll_transmit(t0).unwrap();
    assert_eq!(retry.link, RADIO.link);
    a.transmit_result(t0, retry, Ok(()));
    // Nothing answers on either path: the outcome says the frame left (on the radio).
    while let Some(now) = a.poll_timeout() {
        a.handle_timeout(now);
        while let Some(tx) = a.poll_transmit(now) {
            assert_eq!(tx.link, RADIO.link);
            a.transmit_result(now, tx, Ok(()));
        }
    }
    assert!(matches!(
        outcome(&mut a),
        Some(Outcome::Unconfirmed {
            reason: FailReason::NoAcknowledgement,
            attempts: 4
        })
    ));
}

#[test]
fn the_first_path_is_taken_again_when_it_comes_back() {
    let (mut a, _) = pair();
    let t0 = Time::from_micros(1_000);
    a.handle_link_event(t0, LinkEvent::PeerDown { link: 0, peer: B });
    assert_eq!(a.route_link(B), Some(1));
    a.handle_link_event(t0, LinkEvent::PeerUp { link: 0, peer: B });
    assert_eq!(a.route_link(B), Some(0));
    let changes: Vec<_> = std::iter::from_fn(|| a.poll_path_change()).collect();
    assert_eq!(
        changes,
        [
            PathChange {
                to: B,
                from: WIRED,
                now: RADIO
            },
            PathChange {
                to: B,
                from: RADIO,
                now: WIRED
            }
        ]
    );
    // A frame heard from B on the wired link also says the path works.
    a.handle_link_event(t0, LinkEvent::PeerDown { link: 0, peer: B });
    let (_, mut b) = pair();
    let tx = frame_to_a(&mut b, t0, b"hi");
    a.handle_frame(t0, 0, &tx.frame);
    assert_eq!(a.route_link(B), Some(0));
}

#[test]
fn a_congested_path_is_passed_over_while_another_is_free() {
    let (mut a, _) = pair();
    let t0 = Time::from_micros(1_000);
    a.handle_link_event(t0, LinkEvent::Congested { link: 0, peer: B });
    assert_eq!(a.route_link(B), Some(1));
    // Congested on both: the first that is up is used.
    a.handle_link_event(t0, LinkEvent::Congested { link: 1, peer: B });
    assert_eq!(a.route_link(B), Some(0));
    let paths = a.paths(B);
    assert!(paths.iter().all(|p| p.up && p.congested));
    // A frame the wired link takes clears its congestion.
    a.send(t0, request(), 1).unwrap();
    let tx = a.poll_transmit(t0).unwrap();
    a.transmit_result(t0, tx, Ok(()));
    assert!(!a.paths(B)[0].congested);
}

#[test]
fn round_trip_times_are_measured_per_path() {
    let (mut a, mut b) = pair();
    let t0 = Time::from_micros(1_000);
    a.send(t0, request(), 1).unwrap();
    let tx = a.poll_transmit(t0).unwrap();
    let t1 = t0 + Duration::from_millis(10);
    let ack = deliver(&mut b, t1, &tx);
    a.transmit_result(t0, tx, Ok(()));
    a.handle_frame(t1, ack.link, &ack.frame);
    let paths = a.paths(B);
    assert_eq!(paths[0].srtt, Some(Duration::from_millis(10)));
    assert_eq!(paths[1].srtt, None, "nothing measured on the radio yet");
    assert_eq!(a.srtt(B), Some(Duration::from_millis(10)));
    // On the radio, the estimate is the radio's own (none yet), not the wire's.
    a.handle_link_event(t1, LinkEvent::PeerDown { link: 0, peer: B });
    assert_eq!(a.srtt(B), None);
}

#[test]
fn a_route_without_fallbacks_keeps_its_one_path_whatever_happens() {
    let mut a = Router::<u32>::new(RouterConfig::new(A, 1, vec![(B, route(WIRED))]));
    let t0 = Time::from_micros(1_000);
    a.handle_link_event(t0, LinkEvent::PeerDown { link: 0, peer: B });
    assert_eq!(a.route_link(B), Some(0));
    assert_eq!(a.poll_path_change(), None);
    assert!(!a.paths(B)[0].up);
    // Events for links or peers it does not know are ignored.
    a.handle_link_event(t0, LinkEvent::PeerDown { link: 9, peer: B });
    a.handle_link_event(
        t0,
        LinkEvent::PeerDown {
            link: 0,
            peer: SystemId(9),
        },
    );
    assert_eq!(a.stats().path_changes, 0);
}

#[test]
fn hold_and_retransmission_deadlines_share_one_timer_table() {
    // B delivers A's messages in order; A's second message arrives before its first.
    let mut config = RouterConfig::new(B, 2, vec![(A, route(WIRED))]);
    config.ordered_sources.insert(A);
    config.timing.hold_timeout = Duration::from_millis(50);
    config.timing.initial_rto = Duration::from_millis(200);
    let mut b = Router::<u32>::new(config);
    let mut a = Router::<u32>::new(RouterConfig::new(A, 1, vec![(B, route(WIRED))]));
    let t0 = Time::from_micros(1_000);
    for _ in 0..2 {
        a.send(t0, request(), 0).unwrap();
    }
    let first = a.poll_transmit(t0).unwrap();
    let second = a.poll_transmit(t0).unwrap();
    b.handle_frame(t0, 0, &second.frame);
    assert!(b.poll_delivery().is_none(), "held for the gap");
    // B's own retransmission deadline (a send of its own) is later than the hold.
    let tx = frame_to_a(&mut b, t0, b"x");
    b.transmit_result(t0, tx, Ok(()));
    let hold = t0 + Duration::from_millis(50);
    assert_eq!(b.poll_timeout(), Some(hold), "the earlier of the two");
    b.handle_timeout(hold);
    let d = b.poll_delivery().expect("the gap given up");
    assert_eq!(d.header.seq, 2);
    assert_eq!(b.stats().gaps_skipped, 1);
    assert_eq!(
        b.poll_timeout(),
        Some(t0 + Duration::from_millis(200)),
        "the retransmission is next"
    );
    // The first message arriving late is delivered after all (older than the gap).
    b.handle_frame(hold, 0, &first.frame);
    assert_eq!(b.poll_delivery().map(|d| d.header.seq), Some(1));
}

#[test]
fn the_link_s_view_of_the_sender_decides_which_path_is_heard_and_mismatches_are_counted() {
    let (mut a, mut b) = pair();
    let t0 = Time::from_micros(1_000);
    a.handle_link_event(t0, LinkEvent::PeerDown { link: 0, peer: B });
    let tx = frame_to_a(&mut b, t0, b"hi");
    // The wired link says the frame came from a system that is not B: B's wired path is not
    // proven by it, and the mismatch is counted (the frame is still handled).
    a.handle_frame_from(t0, 0, Some(SystemId(7)), &tx.frame);
    assert_eq!(a.route_link(B), Some(1));
    assert_eq!(a.stats().peer_mismatch, 1);
    assert_eq!(a.stats().received, 1);
    // From B as the link saw it: the wired path is back.
    let tx = frame_to_a(&mut b, t0, b"again");
    a.handle_frame_from(t0, 0, Some(B), &tx.frame);
    assert_eq!(a.route_link(B), Some(0));
    assert_eq!(a.stats().peer_mismatch, 1);
}

#[test]
fn a_route_s_paths_are_replaced_while_running() {
    let (mut a, _) = pair();
    let t0 = Time::from_micros(1_000);
    // A send in flight on the wired path, then the radio is put first.
    a.send(t0, request(), 1).unwrap();
    let first = a.poll_transmit(t0).unwrap();
    assert_eq!(first.link, WIRED.link);
    a.transmit_result(t0, first, Ok(()));
    assert!(a.set_paths(t0, B, &[RADIO, WIRED]));
    assert_eq!(a.route(B).map(|r| (r.link, r.tag)), Some((1, b'R')));
    assert_eq!(
        a.poll_path_change(),
        Some(PathChange {
            to: B,
            from: WIRED,
            now: RADIO
        })
    );
    // The wired path is still there (not lost): the send in flight waits for its ack.
    assert!(a.poll_transmit(t0).is_none());
    // Only the radio: the wired path is gone, so what waited goes again on the radio now.
    let t1 = t0 + Duration::from_millis(1);
    assert!(a.set_paths(t1, B, &[WIRED]));
    assert!(a.set_paths(t1, B, &[RADIO]));
    let changes: Vec<_> = std::iter::from_fn(|| a.poll_path_change()).collect();
    assert_eq!(changes.len(), 2, "{changes:?}");
    a.handle_timeout(t1);
    let again = a.poll_transmit(t1).expect("retransmitted on the radio");
    assert_eq!(again.link, RADIO.link);
    assert_eq!(wire::decode(&again.frame).unwrap().header.transport, b'R');
    assert_eq!(a.paths(B).len(), 1);
    // Nothing changes for an unknown destination or no paths.
    assert!(!a.set_paths(t1, SystemId(9), &[RADIO]));
    assert!(!a.set_paths(t1, B, &[]));
    assert_eq!(a.route_link(B), Some(1));
}
