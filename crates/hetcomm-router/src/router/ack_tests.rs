//! Unit tests of acknowledgement ranges: a receiver answers consecutive frames with one ACK,
//! a sender ends every send a range covers, and a range outside the rules is malformed.

use super::*;
use hetcomm_core::{MessageType, ModuleId};

const A: SystemId = SystemId(0);
const B: SystemId = SystemId(1);

fn route() -> Route {
    Route {
        link: 0,
        tag: b'T',
        acknowledged: true,
        attempts: 3,
        max_frame: 1 << 20,
        max_in_flight: 1024,
        max_in_flight_bytes: usize::MAX,
    }
}

fn pair() -> (Router<u64>, Router<u64>) {
    let a = Router::new(RouterConfig::new(A, 1, vec![(B, route())]));
    let b = Router::new(RouterConfig::new(B, 2, vec![(A, route())]));
    (a, b)
}

/// `n` sends from `a` to `b`, their frames handed to `b`; `b`'s deliveries.
fn send_n(a: &mut Router<u64>, b: &mut Router<u64>, now: Time, n: u64) -> Vec<Delivery> {
    let to = Address {
        system: B,
        module: ModuleId(0),
    };
    for i in 0..n {
        let req = SendRequest::new(ModuleId(0), to, MessageType(1), b"x");
        a.send(now, req, i).unwrap();
    }
    while let Some(tx) = a.poll_transmit(now) {
        b.handle_frame(now, 0, &tx.frame);
        a.transmit_result(now, tx, Ok(()));
    }
    std::iter::from_fn(|| b.poll_delivery()).collect()
}

/// The ACK frames `b` hands out: (first, last, status) of each.
fn acks(b: &mut Router<u64>, now: Time) -> Vec<(u64, u64, AckStatus, Vec<u8>)> {
    std::iter::from_fn(|| b.poll_transmit(now))
        .map(|tx| {
            let f = wire::decode(&tx.frame).unwrap();
            assert_eq!(f.header.kind, FrameKind::Ack);
            let p = AckPayload::parse(f.payload, f.header.seq).unwrap();
            (p.first, f.header.seq, p.status, tx.frame.clone())
        })
        .collect()
}

fn outcomes(a: &mut Router<u64>) -> Vec<(u64, Outcome)> {
    std::iter::from_fn(|| a.poll_event())
        .map(|Event::Outcome { id, outcome, .. }| (id.seq, outcome))
        .collect()
}

#[test]
fn consecutive_acknowledgements_leave_as_one_range_and_end_every_send() {
    let now = Time::from_micros(1_000);
    let (mut a, mut b) = pair();
    let ds = send_n(&mut a, &mut b, now, 5);
    assert_eq!(ds.len(), 5);
    for d in &ds {
        b.delivery_result(now, d.token.unwrap(), AckStatus::Delivered);
    }
    let acks = acks(&mut b, now);
    assert_eq!(acks.len(), 1, "one frame for five");
    assert_eq!(
        (acks[0].0, acks[0].1, acks[0].2),
        (1, 5, AckStatus::Delivered)
    );
    assert_eq!((b.stats().acks_sent, b.stats().ack_frames_sent), (5, 1));
    // Nine bytes of payload: the status and the range's first number.
    assert_eq!(acks[0].3.len(), HEADER_LEN + 9);
    a.handle_frame(now + Duration::from_micros(50), 0, &acks[0].3);
    let got = outcomes(&mut a);
    assert_eq!(got.len(), 5);
    for (i, (seq, outcome)) in got.iter().enumerate() {
        assert_eq!(*seq, i as u64 + 1);
        assert!(
            matches!(outcome, Outcome::Delivered { attempts: 1, .. }),
            "{outcome:?}"
        );
    }
    assert_eq!(a.stats().acks_received, 5);
    assert_eq!(a.pending_to(B), 0);
    // The same range again (a duplicate): nothing pending any more, every member stale.
    a.handle_frame(now, 0, &acks[0].3);
    assert_eq!(a.stats().stale_acks, 5);
    assert!(a.poll_event().is_none());
}

#[test]
fn a_different_status_or_a_gap_starts_a_new_acknowledgement() {
    let now = Time::from_micros(1_000);
    let (mut a, mut b) = pair();
    let ds = send_n(&mut a, &mut b, now, 6);
    let status = [
        AckStatus::Delivered,
        AckStatus::Delivered,
        AckStatus::InboxFull,
        AckStatus::Delivered,
    ];
    // 1, 2 delivered; 3 refused; 4 delivered; 6 before 5.
    for (d, s) in ds.iter().zip(status) {
        b.delivery_result(now, d.token.unwrap(), s);
    }
    b.delivery_result(now, ds[5].token.unwrap(), AckStatus::Delivered);
    b.delivery_result(now, ds[4].token.unwrap(), AckStatus::Delivered);
    let got: Vec<_> = acks(&mut b, now)
        .into_iter()
        .map(|(f, l, s, _)| (f, l, s))
        .collect();
    assert_eq!(
        got,
        [
            (1, 2, AckStatus::Delivered),
            (3, 3, AckStatus::InboxFull),
            (4, 4, AckStatus::Delivered),
            (6, 6, AckStatus::Delivered),
            (5, 5, AckStatus::Delivered),
        ]
    );
}

#[test]
fn ranges_that_are_empty_reversed_or_too_wide_are_malformed() {
    let now = Time::from_micros(1_000);
    let (mut a, mut b) = pair();
    let ds = send_n(&mut a, &mut b, now, 2);
    b.delivery_result(now, ds[0].token.unwrap(), AckStatus::Delivered);
    let (_, _, _, frame) = acks(&mut b, now).remove(0);
    let h = wire::decode(&frame).unwrap().header;
    for (seq, first) in [(1, 1), (1, 2), (ACK_RANGE_MAX + 1, 1), (u64::MAX, 0)] {
        let mut payload = vec![AckStatus::Delivered as u8];
        payload.extend_from_slice(&u64::to_le_bytes(first));
        let bad = wire::encode(&Header { seq, ..h }, &payload);
        a.handle_frame(now, 0, &bad);
    }
    // A payload of neither length, and an unknown status in a range.
    a.handle_frame(now, 0, &wire::encode(&h, &[0, 0]));
    let mut unknown = vec![7u8];
    unknown.extend_from_slice(&0u64.to_le_bytes());
    a.handle_frame(now, 0, &wire::encode(&Header { seq: 2, ..h }, &unknown));
    assert_eq!(a.stats().malformed, 6);
    assert!(a.poll_event().is_none());
    assert_eq!(a.pending_to(B), 2);
    // The widest range allowed is taken.
    let mut ok = vec![AckStatus::Delivered as u8];
    ok.extend_from_slice(&1u64.to_le_bytes());
    a.handle_frame(
        now,
        0,
        &wire::encode(
            &Header {
                seq: ACK_RANGE_MAX,
                ..h
            },
            &ok,
        ),
    );
    assert_eq!(outcomes(&mut a).len(), 2);
    assert_eq!(a.stats().stale_acks, ACK_RANGE_MAX - 2);
}
