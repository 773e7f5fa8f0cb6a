//! Unit tests of presettled transmits ([`Transmit::presettled`]): a frame handed back late
//! changes no deadline, a refusal undoes what the router assumed, and a retransmission that
//! falls due while the frame is still out waits for it.

use super::*;
use hetcomm_core::{MessageType, ModuleId};

const A: SystemId = SystemId(0);
const B: SystemId = SystemId(1);

/// A router with one acknowledged route to B.
fn router(attempts: u32) -> Router<u32> {
    router_on(true, attempts)
}

fn router_on(acknowledged: bool, attempts: u32) -> Router<u32> {
    let route = Route {
        link: 0,
        tag: b'T',
        acknowledged,
        attempts,
        max_frame: 1 << 20,
        max_in_flight: 1024,
        max_in_flight_bytes: usize::MAX,
    };
    Router::new(RouterConfig::new(A, 1, vec![(B, route)]))
}

fn send(a: &mut Router<u32>, now: Time, token: u32) -> SendId {
    let to = Address {
        system: B,
        module: ModuleId(0),
    };
    let req = SendRequest::new(ModuleId(0), to, MessageType(1), b"x");
    a.send(now, req, token).unwrap()
}

fn outcomes(a: &mut Router<u32>) -> Vec<Outcome> {
    std::iter::from_fn(|| a.poll_event())
        .map(|Event::Outcome { outcome, .. }| outcome)
        .collect()
}

#[test]
fn an_acknowledged_attempt_is_presettled_and_its_late_return_changes_no_deadline() {
    let t0 = Time::from_micros(1_000);
    let (mut early, mut late) = (router(3), router(3));
    send(&mut early, t0, 1);
    send(&mut late, t0, 1);
    let tx = early.poll_transmit(t0).unwrap();
    assert!(tx.presettled, "acknowledged, one healthy path");
    early.transmit_result(t0, tx, Ok(()));
    let held = late.poll_transmit(t0).unwrap();
    // Armed when handed out: the deadline is there before the link has answered.
    let deadline = late.poll_timeout().expect("retransmission armed at once");
    assert_eq!(early.poll_timeout(), Some(deadline));
    // Handed back 1 ms later, stamped with when it went to the link: same deadline.
    late.transmit_result(t0, held, Ok(()));
    assert_eq!(late.poll_timeout(), Some(deadline));
    for r in [&mut early, &mut late] {
        r.handle_timeout(deadline);
        let again = r
            .poll_transmit(deadline)
            .expect("retransmitted at the deadline");
        assert_eq!(again.send.map(|id| id.seq), Some(1));
        assert_eq!(r.stats().retransmissions, 1);
    }
}

#[test]
fn a_refused_presettled_frame_is_undone_and_fails_as_never_sent() {
    let t0 = Time::from_micros(1_000);
    let mut a = router(1);
    send(&mut a, t0, 7);
    let tx = a.poll_transmit(t0).unwrap();
    assert!(tx.presettled);
    a.transmit_result(t0, tx, Err(TransmitError::Unreachable("no route".into())));
    // One attempt, refused: failed (nothing left), not unconfirmed, and no retransmission
    // timer left behind.
    assert!(matches!(
        outcomes(&mut a).as_slice(),
        [Outcome::Failed { attempts: 1, .. }]
    ));
    assert_eq!(a.poll_timeout(), None);
    assert_eq!(a.pending_to(B), 0);
}

/// A router with `attempts` whose one send's presettled frame is still with the driver when
/// its retransmission falls due: the router, the frame and that deadline.
fn frame_out_past_its_deadline(attempts: u32) -> (Router<u32>, Transmit, Time) {
    let t0 = Time::from_micros(1_000);
    let mut a = router(attempts);
    send(&mut a, t0, 3);
    let tx = a.poll_transmit(t0).unwrap();
    let deadline = a.poll_timeout().unwrap();
    a.handle_timeout(deadline);
    assert!(
        a.poll_transmit(deadline).is_none(),
        "the frame is still out"
    );
    (a, tx, deadline)
}

#[test]
fn a_retransmission_due_while_the_frame_is_out_waits_for_it() {
    let t0 = Time::from_micros(1_000);
    // With its only attempt spent the send would give up as unconfirmed, but whether the
    // frame left is unknown.
    let (mut a, tx, deadline) = frame_out_past_its_deadline(1);
    assert!(
        outcomes(&mut a).is_empty(),
        "no verdict while the frame is out"
    );
    let again = a.poll_timeout().expect("looks again later");
    assert_eq!(again, deadline + Timing::default().link_retry);
    // The link refused it after all: failed, never unconfirmed.
    a.transmit_result(t0, tx, Err(TransmitError::Unreachable("gone".into())));
    assert!(matches!(
        outcomes(&mut a).as_slice(),
        [Outcome::Failed { attempts: 1, .. }]
    ));
}

#[test]
fn a_frame_that_left_is_judged_at_the_next_look_once_it_is_back() {
    let t0 = Time::from_micros(1_000);
    let (mut a, tx, _) = frame_out_past_its_deadline(2);
    a.transmit_result(t0, tx, Ok(()));
    let look = a.poll_timeout().unwrap();
    a.handle_timeout(look);
    let second = a.poll_transmit(look).expect("the second attempt");
    assert_eq!(second.send.map(|id| id.seq), Some(1));
    a.transmit_result(look, second, Ok(()));
    // No acknowledgement ever: unconfirmed after both attempts (frames did leave).
    let end = a.poll_timeout().unwrap();
    a.handle_timeout(end);
    assert!(matches!(
        outcomes(&mut a).as_slice(),
        [Outcome::Unconfirmed { attempts: 2, .. }]
    ));
}

#[test]
fn unacknowledged_routes_are_not_presettled() {
    let t0 = Time::from_micros(1_000);
    let mut a = router_on(false, 1);
    send(&mut a, t0, 1);
    assert!(!a.poll_transmit(t0).unwrap().presettled);
}
