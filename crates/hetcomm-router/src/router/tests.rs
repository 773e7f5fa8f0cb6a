//! Unit tests of the router state machine.

use super::*;
use hetcomm_core::{MessageType, ModuleId};

const A: SystemId = SystemId(0);
const B: SystemId = SystemId(1);

fn route(acknowledged: bool) -> Route {
    Route {
        link: 0,
        tag: b'T',
        acknowledged,
        attempts: 3,
        max_frame: 1 << 20,
        max_in_flight: 1024,
        max_in_flight_bytes: usize::MAX,
    }
}

fn pair(acknowledged: bool) -> (Router<()>, Router<()>) {
    let a = Router::new(RouterConfig::new(A, 1, vec![(B, route(acknowledged))]));
    let b = Router::new(RouterConfig::new(B, 2, vec![(A, route(acknowledged))]));
    (a, b)
}

fn to_b() -> Address {
    Address {
        system: B,
        module: ModuleId(0),
    }
}

fn payload(len: usize) -> Vec<u8> {
    (0..len).map(|i| (i % 251) as u8).collect()
}

/// Sends `bytes` from `a` and returns the frame it hands out (after reporting success).
fn sent_frame(a: &mut Router<()>, now: Time, bytes: &[u8]) -> Vec<u8> {
    a.send(
        now,
        SendRequest::new(ModuleId(0), to_b(), MessageType(1), bytes),
        (),
    )
    .unwrap();
    let tx = a.poll_transmit(now).unwrap();
    let frame = tx.frame.clone();
    a.transmit_result(now, tx, Ok(()));
    frame
}

#[test]
fn links_that_check_the_payload_get_a_header_only_crc() {
    let now = Time::from_micros(1_000);
    let (mut a, mut b) = pair(true);
    assert!(!a.link_checksums_payload(0));
    let full = sent_frame(&mut a, now, &payload(1000));
    assert!(wire::decode(&full).unwrap().header.payload_checked());
    a.set_link_checksums_payload(0, true);
    assert!(a.link_checksums_payload(0) && !a.link_checksums_payload(1));
    let frame = sent_frame(&mut a, now, &payload(1000));
    let h = wire::decode(&frame).unwrap().header;
    assert_eq!(h.flags, FLAG_ACK_REQUESTED | FLAG_HEADER_CRC);
    // The payload is not covered: a changed payload byte still decodes.
    let mut changed = frame.clone();
    changed[HEADER_LEN + 10] ^= 0xff;
    assert!(wire::decode(&changed).is_ok());

    // A receiver whose link does not vouch for payloads refuses such frames…
    b.handle_frame(now, 0, &frame);
    assert_eq!(b.stats().malformed, 1);
    assert!(b.poll_delivery().is_none());
    // …one whose link does accepts them, and full-CRC frames as before.
    b.set_link_checksums_payload(0, true);
    b.handle_frame(now, 0, &frame);
    b.handle_frame(now, 0, &full);
    let d = b.poll_delivery().unwrap();
    assert_eq!(d.payload, payload(1000));
    assert_eq!(d.header.seq, 2);
    assert_eq!(b.poll_delivery().unwrap().header.seq, 1);
    assert_eq!(b.stats().malformed, 1);
    // Acknowledgements keep flags 0 and a full CRC.
    b.delivery_result(now, d.token.unwrap(), AckStatus::Delivered);
    let ack = b.poll_transmit(now).unwrap();
    let ack_h = wire::decode(&ack.frame).unwrap().header;
    assert_eq!((ack_h.kind, ack_h.flags), (FrameKind::Ack, 0));
}

#[test]
fn owned_frames_become_the_payload_without_a_copy() {
    let now = Time::from_micros(1_000);
    for ordered in [false, true] {
        let (mut a, mut b) = pair(false);
        if ordered {
            b.config.ordered_sources.insert(A);
        }
        let first = sent_frame(&mut a, now, &payload(5000));
        let second = sent_frame(&mut a, now, &payload(70_000));
        // The second arrives first when ordered: it is held, then released.
        let handed = second.clone();
        let ptr = handed.as_ptr();
        b.handle_frame_owned(now, 0, handed);
        if !ordered {
            let d = b.poll_delivery().unwrap();
            assert_eq!(d.payload.as_ptr(), ptr.wrapping_add(HEADER_LEN));
            assert_eq!(d.payload, payload(70_000));
        }
        let ptr_first = first.as_ptr();
        b.handle_frame_owned(now, 0, first);
        let d = b.poll_delivery().unwrap();
        assert_eq!(d.header.seq, 1, "ordered: {ordered}");
        assert_eq!(d.payload.as_ptr(), ptr_first.wrapping_add(HEADER_LEN));
        assert_eq!(d.payload, payload(5000));
        if ordered {
            // Held, then released: still the buffer it arrived in.
            let d = b.poll_delivery().unwrap();
            assert_eq!(d.header.seq, 2);
            assert_eq!(d.payload.as_ptr(), ptr.wrapping_add(HEADER_LEN));
            assert_eq!(d.payload, payload(70_000));
        }
        // A duplicate is dropped, a small payload copied inline, garbage counted.
        b.handle_frame_owned(now, 0, second);
        assert_eq!(b.stats().duplicates, 1);
        let small = sent_frame(&mut a, now, b"tiny");
        b.handle_frame_owned(now, 0, small);
        let d = b.poll_delivery().unwrap();
        assert!(d.payload.is_inline());
        assert_eq!(d.payload, b"tiny");
        b.handle_frame_owned(now, 0, vec![1, 2, 3]);
        assert_eq!(b.stats().malformed, 1);
        assert!(b.poll_delivery().is_none());
    }
}

#[test]
fn an_owned_frame_behind_a_stripped_prefix_is_still_delivered_in_place() {
    let now = Time::from_micros(1_000);
    let (mut a, mut b) = pair(false);
    let frame = sent_frame(&mut a, now, &payload(5000));
    // A layer's 24-byte prefix in front of the frame, stripped before the router sees it.
    let mut sealed = vec![0xa5; 24];
    sealed.extend_from_slice(&frame);
    let mut handed = FrameBuf::from(sealed);
    let base = handed.as_ptr();
    handed.strip_prefix(24);
    b.handle_frame_owned(now, 0, handed);
    let d = b.poll_delivery().unwrap();
    assert_eq!(d.payload, payload(5000));
    assert_eq!(
        d.payload.as_ptr(),
        base.wrapping_add(24 + HEADER_LEN),
        "not copied"
    );
}

fn unqueued<'a>(a: &mut Router<u32>, now: Time, bytes: &'a [u8]) -> Unqueued<'a> {
    let req = SendRequest::new(ModuleId(0), to_b(), MessageType(1), bytes);
    match a.send_unqueued(now, req, || panic!("no token for an unacknowledged send")) {
        Ok(Admitted::Transmit(tx)) => tx,
        other => panic!("expected an unqueued frame, got {other:?}"),
    }
}

fn router_with(acknowledged: bool, attempts: u32) -> Router<u32> {
    let r = Route {
        attempts,
        ..route(acknowledged)
    };
    Router::new(RouterConfig::new(A, 1, vec![(B, r)]))
}

#[test]
fn an_unqueued_send_is_sent_when_the_link_takes_it() {
    let now = Time::from_micros(1_000);
    let mut a = router_with(false, 3);
    let (_, mut b) = pair(false);
    let tx = unqueued(&mut a, now, b"hello");
    assert_eq!((tx.link, tx.to, tx.id()), (0, B, SendId { to: B, seq: 1 }));
    // Counted as sent and in flight until the link answers; nothing queued or pending.
    assert_eq!((a.stats().sends, a.stats().transmissions), (1, 1));
    assert_eq!(a.stats().in_flight(), 1);
    assert!(a.poll_transmit(now).is_none() && a.poll_timeout().is_none());
    // The frame is an ordinary unacknowledged data frame.
    b.handle_frame(now, 0, &tx.frame);
    let d = b.poll_delivery().unwrap();
    assert_eq!((d.payload.as_slice(), d.header.seq), (&b"hello"[..], 1));
    assert!(d.token.is_none() && !d.header.ack_requested());
    let ptr = tx.frame.as_ptr();
    let outcome = a.unqueued_result(now, tx, Ok(()), || panic!("no token when sent"));
    assert_eq!(outcome, Some(Outcome::Sent { attempts: 1 }));
    let s = a.stats().clone();
    assert_eq!((s.sent, s.failed, s.in_flight()), (1, 0, 0));
    assert!(
        a.poll_event().is_none(),
        "the outcome was returned, not queued"
    );
    // The next send reuses the frame buffer and takes the next number.
    let tx = unqueued(&mut a, now, b"again");
    assert_eq!((tx.frame.as_ptr(), tx.id().seq), (ptr, 2));
    let _ = a.unqueued_result(now, tx, Ok(()), || 0);
}

#[test]
fn a_large_unqueued_payload_is_left_out_of_the_frame_on_a_link_that_checksums_it() {
    let now = Time::from_micros(1_000);
    let big = payload(SPLIT_PAYLOAD_MIN);
    // A link that does not checksum payloads: the whole frame, as always.
    let mut a = router_with(false, 3);
    let tx = unqueued(&mut a, now, &big);
    assert_eq!((tx.frame.len(), tx.body.len()), (HEADER_LEN + big.len(), 0));
    let _ = a.unqueued_result(now, tx, Ok(()), || 0);
    // One that does: only the header, the payload is the caller's own bytes.
    let mut a = router_with(false, 3);
    a.set_link_checksums_payload(0, true);
    let (_, mut b) = pair(false);
    b.set_link_checksums_payload(0, true);
    let tx = unqueued(&mut a, now, &big);
    assert_eq!(tx.frame.len(), HEADER_LEN);
    assert_eq!(tx.body.as_ptr(), big.as_ptr());
    let mut whole = tx.frame.clone();
    whole.extend_from_slice(tx.body);
    b.handle_frame(now, 0, &whole);
    assert_eq!(b.poll_delivery().unwrap().payload, big);
    assert_eq!(
        a.unqueued_result(now, tx, Ok(()), || 0),
        Some(Outcome::Sent { attempts: 1 })
    );
    // Just under the threshold: copied.
    let tx = unqueued(&mut a, now, &big[1..]);
    assert!(tx.body.is_empty());
    let _ = a.unqueued_result(now, tx, Ok(()), || 0);
    // Refused with attempts left: the pending retry keeps the whole frame.
    let tx = unqueued(&mut a, now, &big);
    let err = Err(TransmitError::Other("congested".into()));
    assert_eq!(a.unqueued_result(now, tx, err, || 5), None);
    let later = a.poll_timeout().unwrap();
    a.handle_timeout(later);
    let tx = a.poll_transmit(later).expect("a retransmission");
    b.handle_frame(later, 0, &tx.frame);
    let d = b.poll_delivery().unwrap();
    assert_eq!((d.payload.as_slice(), d.header.seq), (&big[..], 3));
    a.transmit_result(later, tx, Ok(()));
}

#[test]
fn an_unqueued_send_refused_by_its_link_is_retried_then_fails() {
    let t0 = Time::from_micros(1_000);
    let mut a = router_with(false, 3);
    let tx = unqueued(&mut a, t0, b"x");
    let refused = || Err(TransmitError::Unreachable("peer down".into()));
    // Attempts left: the send becomes pending with its token, retried after link_retry.
    assert_eq!(a.unqueued_result(t0, tx, refused(), || 7), None);
    let retry = a.config.timing.link_retry;
    assert_eq!(a.poll_timeout(), Some(t0 + retry));
    assert_eq!(a.stats().in_flight(), 1);
    for attempt in 2..=3u32 {
        let now = a.poll_timeout().unwrap();
        a.handle_timeout(now);
        let tx = a.poll_transmit(now).expect("a retransmission");
        assert_eq!(tx.send, Some(SendId { to: B, seq: 1 }));
        a.transmit_result(now, tx, refused());
        assert_eq!(a.stats().retransmissions, u64::from(attempt - 1));
    }
    match a.poll_event() {
        Some(Event::Outcome {
            token: 7,
            outcome:
                Outcome::Failed {
                    reason: FailReason::Unreachable(why),
                    attempts: 3,
                },
            ..
        }) => assert!(why.contains("peer down")),
        other => panic!("expected a failure after 3 attempts, got {other:?}"),
    }
    let s = a.stats().clone();
    assert_eq!(
        (s.sends, s.transmissions, s.retransmissions, s.failed),
        (1, 3, 2, 1)
    );
    assert_eq!((s.sent, s.in_flight()), (0, 0));
    assert!(a.poll_timeout().is_none());
}

#[test]
fn an_unqueued_send_retried_after_a_refusal_can_still_be_sent() {
    let t0 = Time::from_micros(1_000);
    let mut a = router_with(false, 3);
    let tx = unqueued(&mut a, t0, b"x");
    let err = Err(TransmitError::Other("congested".into()));
    assert_eq!(a.unqueued_result(t0, tx, err, || 9), None);
    let now = a.poll_timeout().unwrap();
    a.handle_timeout(now);
    let tx = a.poll_transmit(now).unwrap();
    a.transmit_result(now, tx, Ok(()));
    assert!(matches!(
        a.poll_event(),
        Some(Event::Outcome {
            token: 9,
            outcome: Outcome::Sent { attempts: 2 },
            ..
        })
    ));
    let s = a.stats().clone();
    assert_eq!((s.sent, s.retransmissions, s.in_flight()), (1, 1, 0));
}

#[test]
fn an_unqueued_send_fails_at_once_without_attempts_left_or_when_too_large() {
    let now = Time::from_micros(1_000);
    let mut a = router_with(false, 1);
    let tx = unqueued(&mut a, now, b"x");
    let err = Err(TransmitError::Unreachable("peer down".into()));
    let outcome = a.unqueued_result(now, tx, err, || panic!("nothing to retry"));
    assert!(matches!(
        outcome,
        Some(Outcome::Failed {
            reason: FailReason::Unreachable(_),
            attempts: 1
        })
    ));
    // A frame the link can never carry is not retried, whatever the budget.
    let mut a3 = router_with(false, 3);
    let tx = unqueued(&mut a3, now, b"x");
    let err = Err(TransmitError::TooLarge("too big".into()));
    let outcome = a3.unqueued_result(now, tx, err, || panic!("nothing to retry"));
    assert!(matches!(
        outcome,
        Some(Outcome::Failed {
            reason: FailReason::Link(_),
            attempts: 1
        })
    ));
    // Nor one whose content the link refuses (a bridge's conversion): its own reason.
    let mut r3 = router_with(false, 3);
    let tx = unqueued(&mut r3, now, b"x");
    let err = Err(TransmitError::Refused("does not convert".into()));
    let outcome = r3.unqueued_result(now, tx, err, || panic!("nothing to retry"));
    assert_eq!(
        outcome,
        Some(Outcome::Failed {
            reason: FailReason::Refused("does not convert".into()),
            attempts: 1
        })
    );
    assert_eq!(
        FailReason::Refused("x".into()).to_string(),
        "refused by the link: x"
    );
    for r in [&a, &a3, &r3] {
        let s = r.stats();
        assert_eq!(
            (s.sends, s.transmissions, s.failed, s.in_flight()),
            (1, 1, 1, 0)
        );
        assert!(r.poll_timeout().is_none() && r.pending.is_empty());
    }
}

#[test]
fn an_acknowledged_send_offered_unqueued_is_queued_with_its_token() {
    let now = Time::from_micros(1_000);
    let mut a = router_with(true, 3);
    let req = SendRequest::new(ModuleId(0), to_b(), MessageType(1), b"x");
    let admitted = a.send_unqueued(now, req, || 5).unwrap();
    assert!(matches!(admitted, Admitted::Queued(SendId { seq: 1, .. })));
    let tx = a.poll_transmit(now).unwrap();
    assert!(wire::decode(&tx.frame).unwrap().header.ack_requested());
    a.transmit_result(now, tx, Ok(()));
    assert!(a.poll_timeout().is_some(), "waits for its acknowledgement");
    a.shutdown();
    assert!(matches!(
        a.poll_event(),
        Some(Event::Outcome { token: 5, .. })
    ));
    // Refusals are the router's as with `send`.
    let far = Address {
        system: SystemId(9),
        module: ModuleId(0),
    };
    let req = SendRequest::new(ModuleId(0), far, MessageType(1), b"x");
    assert!(matches!(
        a.send_unqueued(now, req, || 0),
        Err(SendError::NoRoute { .. })
    ));
}

#[test]
fn frame_buffers_of_ended_sends_are_reused() {
    let now = Time::from_micros(1_000);
    let (mut a, _) = pair(false);
    let big = payload(65_536);
    a.send(
        now,
        SendRequest::new(ModuleId(0), to_b(), MessageType(1), &big),
        (),
    )
    .unwrap();
    let tx = a.poll_transmit(now).unwrap();
    let ptr = tx.frame.as_ptr();
    a.transmit_result(now, tx, Ok(()));
    assert!(matches!(
        a.poll_event(),
        Some(Event::Outcome {
            outcome: Outcome::Sent { .. },
            ..
        })
    ));
    // The next send, no larger, is encoded into the same buffer; a larger one is not.
    let small = payload(100);
    a.send(
        now,
        SendRequest::new(ModuleId(0), to_b(), MessageType(1), &small),
        (),
    )
    .unwrap();
    let tx = a.poll_transmit(now).unwrap();
    assert_eq!(tx.frame.as_ptr(), ptr);
    assert_eq!(wire::decode(&tx.frame).unwrap().payload, &small[..]);
    a.transmit_result(now, tx, Ok(()));
    let bigger = payload(200_000);
    let frame = sent_frame(&mut a, now, &bigger);
    assert_eq!(wire::decode(&frame).unwrap().payload, &bigger[..]);
    assert!(a.spare_frames.len() <= SPARE_FRAMES);
}

/// A router from A with a route to each of `to` (acknowledged or not) and a window of
/// `window` sends.
fn windowed(acknowledged: bool, window: u32, to: &[SystemId]) -> Router<u32> {
    let r = Route {
        max_in_flight: window,
        max_in_flight_bytes: usize::MAX,
        ..route(acknowledged)
    };
    Router::new(RouterConfig::new(
        A,
        1,
        to.iter().map(|&s| (s, r)).collect(),
    ))
}

fn request(to: SystemId) -> SendRequest<'static> {
    let to = Address {
        system: to,
        module: ModuleId(0),
    };
    SendRequest::new(ModuleId(0), to, MessageType(1), b"w")
}

#[test]
fn acknowledged_sends_beyond_the_window_are_refused_unnumbered_until_an_outcome_frees_a_place() {
    let now = Time::from_micros(1_000);
    let mut a = windowed(true, 3, &[B]);
    let (_, mut b) = pair(true);
    for seq in 1..=3 {
        assert_eq!(a.send(now, request(B), 0), Ok(SendId { to: B, seq }));
    }
    assert_eq!(a.pending_to(B), 3);
    for _ in 0..2 {
        assert_eq!(
            a.send(now, request(B), 0),
            Err(SendError::Backpressure { to: B, limit: 3 })
        );
    }
    let s = a.stats();
    assert_eq!((s.sends, s.backpressured, s.in_flight()), (3, 2, 3));
    // The first send is acknowledged: one place frees, and the next send takes the next
    // number (the refused ones left no gap for an ordered receiver to wait on).
    let tx = a.poll_transmit(now).unwrap();
    b.handle_frame(now, 0, &tx.frame);
    a.transmit_result(now, tx, Ok(()));
    let d = b.poll_delivery().unwrap();
    b.delivery_result(now, d.token.unwrap(), AckStatus::Delivered);
    let ack = b.poll_transmit(now).unwrap();
    a.handle_frame(now, ack.link, &ack.frame);
    assert!(matches!(
        a.poll_event(),
        Some(Event::Outcome {
            outcome: Outcome::Delivered { .. },
            ..
        })
    ));
    assert_eq!(a.pending_to(B), 2);
    assert_eq!(a.send(now, request(B), 0), Ok(SendId { to: B, seq: 4 }));
    assert_eq!(
        a.send(now, request(B), 0),
        Err(SendError::Backpressure { to: B, limit: 3 })
    );
}

#[test]
fn a_send_that_fails_frees_its_place_and_windows_are_per_destination() {
    let c = SystemId(2);
    let t0 = Time::from_micros(1_000);
    let mut a = windowed(true, 1, &[B, c]);
    a.send(t0, request(B), 0).unwrap();
    assert!(matches!(
        a.send(t0, request(B), 0),
        Err(SendError::Backpressure { .. })
    ));
    // Another destination has a window of its own.
    assert_eq!(a.send(t0, request(c), 0), Ok(SendId { to: c, seq: 1 }));
    // Nothing answers: every attempt times out and both sends end unconfirmed.
    let mut now = t0;
    loop {
        while let Some(tx) = a.poll_transmit(now) {
            a.transmit_result(now, tx, Ok(()));
        }
        match a.poll_timeout() {
            Some(t) => {
                now = t;
                a.handle_timeout(now);
            }
            None => break,
        }
    }
    let mut unconfirmed = 0;
    while let Some(e) = a.poll_event() {
        if let Event::Outcome {
            outcome: Outcome::Unconfirmed { .. },
            ..
        } = e
        {
            unconfirmed += 1;
        }
    }
    assert_eq!(unconfirmed, 2);
    assert_eq!((a.pending_to(B), a.pending_to(c)), (0, 0));
    assert_eq!(a.send(now, request(B), 0), Ok(SendId { to: B, seq: 2 }));
}

#[test]
fn unacknowledged_sends_wait_for_nothing_unless_their_link_refuses_them() {
    let now = Time::from_micros(1_000);
    let mut a = windowed(false, 1, &[B]);
    // Taken by the link: never pending, so the window of one never fills.
    for seq in 1..=5 {
        let tx = unqueued(&mut a, now, b"w");
        assert_eq!(tx.id().seq, seq);
        assert!(a.unqueued_result(now, tx, Ok(()), || 0).is_some());
    }
    assert_eq!(a.pending_to(B), 0);
    // Refused with attempts left: it waits for its retry, and fills the window.
    let tx = unqueued(&mut a, now, b"w");
    let refused = Err(TransmitError::Unreachable("peer down".into()));
    assert_eq!(a.unqueued_result(now, tx, refused, || 9), None);
    assert_eq!(a.pending_to(B), 1);
    assert!(matches!(
        a.send_unqueued(now, request(B), || 0),
        Err(SendError::Backpressure { to: B, limit: 1 })
    ));
}
