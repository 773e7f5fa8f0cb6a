//! Unit tests of native broadcasts (`broadcast.rs`).

use super::*;
use hetcomm_core::{MessageType, ModuleId};

const A: SystemId = SystemId(0);
const B: SystemId = SystemId(1);
const C: SystemId = SystemId(2);
const D: SystemId = SystemId(3);
/// Reached on another link than the others.
const E: SystemId = SystemId(4);

fn route(link: usize, acknowledged: bool) -> Route {
    Route {
        link,
        tag: if link == 0 { b'Z' } else { b'U' },
        acknowledged,
        attempts: 3,
        max_frame: 1 << 20,
        max_in_flight: 4,
        max_in_flight_bytes: usize::MAX,
    }
}

/// A sends to B, C, D on link 0 (the broadcast link) and to E on link 1.
fn sender(acknowledged: bool) -> Router<SystemId> {
    let routes = [B, C, D, E]
        .iter()
        .map(|&s| (s, route(if s == E { 1 } else { 0 }, acknowledged)))
        .collect();
    Router::new(RouterConfig::new(A, 7, routes))
}

/// A receiver that hears A on link 0.
fn receiver(me: SystemId) -> Router<()> {
    Router::new(RouterConfig::new(me, 1, vec![(A, route(0, true))]))
}

fn request(payload: &[u8]) -> SendRequest<'_> {
    let to = Address {
        system: TO_ALL_SYSTEM,
        module: ModuleId(2),
    };
    SendRequest {
        broadcast: true,
        ..SendRequest::new(ModuleId(1), to, MessageType(9), payload)
    }
}

fn outcomes(a: &mut Router<SystemId>) -> Vec<(SystemId, Outcome)> {
    let mut all = Vec::new();
    while let Some(Event::Outcome {
        id, token, outcome, ..
    }) = a.poll_event()
    {
        assert_eq!(id.to, token);
        assert!(id.is_broadcast());
        all.push((token, outcome));
    }
    all.sort_by_key(|(s, _)| *s);
    all
}

/// Hands `frame` to `r` and, if it delivers, reports the inbox took it and returns its
/// acknowledgement frame.
fn receive(r: &mut Router<()>, now: Time, link: usize, frame: &[u8]) -> Option<Vec<u8>> {
    r.handle_frame(now, link, frame);
    if let Some(d) = r.poll_delivery() {
        assert_eq!(d.header.destination.system, r.local());
        assert_eq!(d.payload, b"all hands");
        if let Some(token) = d.token {
            r.delivery_result(now, token, AckStatus::Delivered);
        }
    }
    r.poll_transmit(now).map(|t| t.frame)
}

#[test]
fn one_frame_reaches_every_destination_and_each_has_its_outcome() {
    let now = Time::from_micros(1_000);
    let mut a = sender(true);
    assert_eq!(a.broadcast_group(0), [B, C, D]);
    assert_eq!(a.broadcast_group(1), [E]);
    let ids = a
        .send_broadcast(now, request(b"all hands"), &[B, C, D], |s| s)
        .unwrap();
    assert_eq!(ids.iter().map(|i| i.to).collect::<Vec<_>>(), [B, C, D]);
    let tx = a.poll_transmit(now).unwrap();
    assert!(a.poll_transmit(now).is_none(), "one frame for all");
    assert_eq!((tx.link, tx.to), (0, TO_ALL_SYSTEM));
    let h = wire::decode(&tx.frame).unwrap().header;
    assert_eq!(
        h.flags,
        FLAG_ACK_REQUESTED | FLAG_BROADCAST | FLAG_BROADCAST_SEQ | FLAG_TO_ALL
    );
    assert_eq!(
        (h.destination.system, h.seq, h.transport),
        (TO_ALL_SYSTEM, 1, b'Z')
    );
    let frame = tx.frame.clone();
    a.transmit_result(now, tx, Ok(()));
    let later = now + Duration::from_millis(3);
    for s in [B, C, D] {
        let mut r = receiver(s);
        let ack = receive(&mut r, now, 0, &frame).expect("acknowledged");
        let ah = wire::decode(&ack).unwrap().header;
        assert_eq!(
            (ah.kind, ah.flags, ah.seq),
            (FrameKind::Ack, FLAG_BROADCAST_SEQ, 1)
        );
        assert_eq!((ah.source.system, ah.destination.system), (s, A));
        a.handle_frame(later, 0, &ack);
    }
    let got = outcomes(&mut a);
    assert_eq!(got.len(), 3);
    for (s, (to, outcome)) in [B, C, D].iter().zip(&got) {
        assert_eq!(s, to);
        assert_eq!(
            *outcome,
            Outcome::Delivered {
                attempts: 1,
                latency: Duration::from_millis(3)
            }
        );
    }
    let s = a.stats();
    assert_eq!((s.sends, s.transmissions, s.delivered), (3, 1, 3));
    assert_eq!((s.in_flight(), a.poll_timeout()), (0, None));
    assert!(a.broadcasts.is_empty());
}

#[test]
fn only_the_missing_receiver_gets_a_retransmission_and_nobody_gets_it_twice() {
    let now = Time::from_micros(1_000);
    let mut a = sender(true);
    a.send_broadcast(now, request(b"all hands"), &[B, C, D], |s| s)
        .unwrap();
    let tx = a.poll_transmit(now).unwrap();
    let frame = tx.frame.clone();
    a.transmit_result(now, tx, Ok(()));
    let (mut b, mut c, mut d) = (receiver(B), receiver(C), receiver(D));
    a.handle_frame(now, 0, &receive(&mut b, now, 0, &frame).unwrap());
    // C receives the frame but its acknowledgement is lost; D never receives it.
    receive(&mut c, now, 0, &frame).unwrap();
    let due = a.poll_timeout().unwrap();
    a.handle_timeout(due);
    let mut copies = Vec::new();
    while let Some(tx) = a.poll_transmit(due) {
        copies.push((tx.to, tx.link, tx.frame.clone()));
        a.transmit_result(due, tx, Ok(()));
    }
    copies.sort();
    assert_eq!(
        copies.iter().map(|c| (c.0, c.1)).collect::<Vec<_>>(),
        [(C, 0), (D, 0)],
        "B acknowledged: no retransmission to it"
    );
    for (to, _, copy) in &copies {
        let h = wire::decode(copy).unwrap().header;
        assert_eq!(h.destination.system, *to);
        assert_eq!(
            h.flags,
            FLAG_ACK_REQUESTED | FLAG_BROADCAST | FLAG_BROADCAST_SEQ,
            "a copy names its destination"
        );
        assert_eq!(h.seq, 1, "still the broadcast's number");
    }
    // C suppresses the copy (it delivered the frame) and acknowledges again; D delivers it.
    let ack_c = receive(&mut c, due, 0, &copies[0].2).expect("acknowledged again");
    assert_eq!((c.stats().received, c.stats().duplicates), (1, 1));
    let ack_d = receive(&mut d, due, 0, &copies[1].2).unwrap();
    assert_eq!(d.stats().received, 1);
    // The original frame, arriving late at D, is a duplicate too.
    receive(&mut d, due, 0, &frame);
    assert_eq!((d.stats().received, d.stats().duplicates), (1, 1));
    a.handle_frame(due, 0, &ack_c);
    a.handle_frame(due, 0, &ack_d);
    let got = outcomes(&mut a);
    assert!(matches!(
        got[0],
        (B, Outcome::Delivered { attempts: 1, .. })
    ));
    assert!(matches!(
        got[1],
        (C, Outcome::Delivered { attempts: 2, .. })
    ));
    assert!(matches!(
        got[2],
        (D, Outcome::Delivered { attempts: 2, .. })
    ));
    let s = a.stats();
    assert_eq!((s.transmissions, s.retransmissions), (3, 2));
}

#[test]
fn a_destination_that_never_answers_ends_unconfirmed_alone() {
    let now = Time::from_micros(1_000);
    let mut a = sender(true);
    a.send_broadcast(now, request(b"all hands"), &[B, C], |s| s)
        .unwrap();
    let tx = a.poll_transmit(now).unwrap();
    let frame = tx.frame.clone();
    a.transmit_result(now, tx, Ok(()));
    a.handle_frame(now, 0, &receive(&mut receiver(B), now, 0, &frame).unwrap());
    let mut copies = 0;
    while let Some(due) = a.poll_timeout() {
        a.handle_timeout(due);
        while let Some(tx) = a.poll_transmit(due) {
            assert_eq!(tx.to, C);
            copies += 1;
            a.transmit_result(due, tx, Ok(()));
        }
    }
    assert_eq!(copies, 2, "attempts = 3: the frame and two copies");
    let got = outcomes(&mut a);
    assert!(matches!(
        got[0],
        (B, Outcome::Delivered { attempts: 1, .. })
    ));
    assert_eq!(
        got[1],
        (
            C,
            Outcome::Unconfirmed {
                reason: FailReason::NoAcknowledgement,
                attempts: 3
            }
        )
    );
    assert!(a.broadcasts.is_empty());
}

#[test]
fn unacknowledged_broadcast_is_one_frame_sent_without_confirmation_to_each() {
    let now = Time::from_micros(1_000);
    let mut a = sender(false);
    a.send_broadcast(now, request(b"all hands"), &[B, C, D], |s| s)
        .unwrap();
    let tx = a.poll_transmit(now).unwrap();
    assert_eq!(
        wire::decode(&tx.frame).unwrap().header.flags,
        FLAG_BROADCAST | FLAG_BROADCAST_SEQ | FLAG_TO_ALL
    );
    let frame = tx.frame.clone();
    a.transmit_result(now, tx, Ok(()));
    assert!(a.poll_transmit(now).is_none());
    let got = outcomes(&mut a);
    assert_eq!(
        got,
        [B, C, D].map(|s| (s, Outcome::Sent { attempts: 1 })),
        "sent without confirmation, per destination"
    );
    // A receiver delivers it and sends no acknowledgement.
    let mut r = Router::<()>::new(RouterConfig::new(B, 1, vec![(A, route(0, false))]));
    assert!(receive(&mut r, now, 0, &frame).is_none());
    assert_eq!(r.stats().received, 1);
}

#[test]
fn a_refused_frame_is_retried_as_copies_and_fails_when_none_left() {
    let now = Time::from_micros(1_000);
    let mut a = sender(true);
    a.send_broadcast(now, request(b"all hands"), &[B, C], |s| s)
        .unwrap();
    let mut refused = 0;
    let mut t = now;
    loop {
        while let Some(tx) = a.poll_transmit(t) {
            refused += 1;
            a.transmit_result(t, tx, Err(TransmitError::Other("no session".into())));
        }
        let Some(due) = a.poll_timeout() else { break };
        t = due;
        a.handle_timeout(due);
    }
    assert_eq!(refused, 1 + 2 * 2, "the frame, then two copies each");
    for (_, outcome) in outcomes(&mut a) {
        assert!(
            matches!(outcome, Outcome::Failed { attempts: 3, .. }),
            "{outcome:?}"
        );
    }
}

#[test]
fn the_table_decides_who_takes_the_frame() {
    let now = Time::from_micros(1_000);
    let mut a = sender(true);
    a.send_broadcast(now, request(b"all hands"), &[B], |s| s)
        .unwrap();
    let frame = a.poll_transmit(now).unwrap().frame;
    // X with A: the system receives the frame (it is on the transport) and drops it.
    let mut x = Router::<()>::new(RouterConfig::new(C, 1, vec![]));
    x.config.known_systems.insert(A);
    // A pair on another transport (link 1 here): the frame came on link 0.
    let mut other = Router::<()>::new(RouterConfig::new(D, 1, vec![(A, route(1, true))]));
    for r in [&mut x, &mut other] {
        assert!(receive(r, now, 0, &frame).is_none());
        assert_eq!((r.stats().misrouted, r.stats().received), (1, 0));
    }
    // The same receiver takes it on the transport the table names.
    let mut ok = receiver(B);
    assert!(receive(&mut ok, now, 0, &frame).is_some());
    assert_eq!(ok.stats().received, 1);
}

#[test]
fn broadcast_and_point_to_point_numbers_do_not_collide() {
    let now = Time::from_micros(1_000);
    let mut a = sender(true);
    let mut b = receiver(B);
    a.send_broadcast(now, request(b"all hands"), &[B], |s| s)
        .unwrap();
    let to = Address {
        system: B,
        module: ModuleId(2),
    };
    a.send(
        now,
        SendRequest::new(ModuleId(1), to, MessageType(9), b"all hands"),
        B,
    )
    .unwrap();
    let mut seqs = Vec::new();
    while let Some(tx) = a.poll_transmit(now) {
        seqs.push(wire::decode(&tx.frame).unwrap().header.seq);
        let ack = receive(&mut b, now, 0, &tx.frame).unwrap();
        a.transmit_result(now, tx, Ok(()));
        a.handle_frame(now, 0, &ack);
    }
    assert_eq!(seqs, [1, 1], "each in its own space");
    assert_eq!((b.stats().received, b.stats().duplicates), (2, 0));
    let mut ended = Vec::new();
    while let Some(Event::Outcome { id, outcome, .. }) = a.poll_event() {
        assert!(outcome.is_success());
        ended.push(id.is_broadcast());
    }
    ended.sort();
    assert_eq!(ended, [false, true]);
}

#[test]
fn a_full_window_refuses_the_whole_broadcast_before_numbering() {
    let now = Time::from_micros(1_000);
    let mut a = sender(true);
    let to = Address {
        system: C,
        module: ModuleId(2),
    };
    for _ in 0..4 {
        a.send(
            now,
            SendRequest::new(ModuleId(1), to, MessageType(9), b"x"),
            C,
        )
        .unwrap();
    }
    let err = a
        .send_broadcast(now, request(b"all hands"), &[B, C, D], |s| s)
        .unwrap_err();
    assert_eq!(err, SendError::Backpressure { to: C, limit: 4 });
    assert_eq!(a.stats().sends, 4);
    let ids = a
        .send_broadcast(now, request(b"all hands"), &[B, D], |s| s)
        .unwrap();
    assert_eq!(ids[0].wire_seq(), 1, "the refused broadcast took no number");
}

#[test]
fn to_all_is_only_valid_on_a_broadcast_data_frame() {
    let now = Time::from_micros(1_000);
    let mut b = receiver(B);
    let mut h = Header::data(
        Address {
            system: A,
            module: ModuleId(1),
        },
        Address {
            system: TO_ALL_SYSTEM,
            module: ModuleId(2),
        },
        MessageType(9),
    );
    h.seq = 1;
    for flags in [
        FLAG_TO_ALL,
        FLAG_TO_ALL | FLAG_BROADCAST,
        FLAG_TO_ALL | FLAG_BROADCAST_SEQ,
    ] {
        h.flags = flags;
        b.handle_frame(now, 0, &wire::encode(&h, b"x"));
    }
    h.kind = FrameKind::Ack;
    h.flags = FLAG_TO_ALL | FLAG_BROADCAST | FLAG_BROADCAST_SEQ;
    b.handle_frame(now, 0, &wire::encode(&h, &[0]));
    assert_eq!((b.stats().malformed, b.stats().received), (4, 0));
}
