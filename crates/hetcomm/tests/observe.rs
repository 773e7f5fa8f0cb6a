//! The observation point (`hetcomm::observe`): an observer registered with a system sees
//! every send, every receipt and every outcome, whichever way the message went (router
//! loop, unacknowledged fast path, in-process hand-over, simulator), with ids that match
//! across the three, and nothing once its handle is dropped.

mod common;

use std::collections::{BTreeMap, BTreeSet};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use hetcomm::observe::{
    AckStatus, Observer, OutcomeRecord, ReceiptRecord, RouteKind, SendRecord, Via,
};
use hetcomm::sim::{LossVisibility, SimFleet, SimOptions};
use hetcomm::{LocalFleet, MessageType, Outcome, SendId, SystemId, Time};

const TY: MessageType = MessageType(7);

/// One send attempt as seen by an observer.
#[derive(Clone, Debug)]
struct Attempt {
    id: SendId,
    from: SystemId,
    attempt: u32,
    route: RouteKind,
    link: Option<usize>,
    ty: MessageType,
    payload: Vec<u8>,
}

/// One receipt as seen by an observer: (source system, destination system, seq) names the
/// message, as `SendId` (destination, seq) does at the sender.
#[derive(Clone, Debug)]
struct Receipt {
    from: SystemId,
    id: SendId,
    via: Via,
    status: AckStatus,
    payload: Vec<u8>,
}

#[derive(Default)]
struct Recorder {
    sends: Mutex<Vec<Attempt>>,
    retransmits: Mutex<Vec<Attempt>>,
    receipts: Mutex<Vec<Receipt>>,
    outcomes: Mutex<Vec<(SendId, Outcome, Time)>>,
}

fn attempt(r: &SendRecord<'_>) -> Attempt {
    Attempt {
        id: r.id(),
        from: r.header.source.system,
        attempt: r.attempt,
        route: r.route,
        link: r.link,
        ty: r.header.message_type,
        payload: r.payload.to_vec(),
    }
}

impl Observer for Recorder {
    fn on_send(&self, r: &SendRecord<'_>) {
        self.sends.lock().unwrap().push(attempt(r));
    }
    fn on_retransmit(&self, r: &SendRecord<'_>) {
        self.retransmits.lock().unwrap().push(attempt(r));
    }
    fn on_receipt(&self, r: &ReceiptRecord<'_>) {
        self.receipts.lock().unwrap().push(Receipt {
            from: r.header.source.system,
            id: SendId {
                to: r.header.destination.system,
                seq: r.header.seq,
            },
            via: r.via,
            status: r.status,
            payload: r.payload.to_vec(),
        });
    }
    fn on_outcome(&self, r: &OutcomeRecord<'_>) {
        self.outcomes
            .lock()
            .unwrap()
            .push((r.id, r.outcome.clone(), r.time));
    }
}

impl Recorder {
    fn counts(&self) -> (usize, usize, usize, usize) {
        (
            self.sends.lock().unwrap().len(),
            self.retransmits.lock().unwrap().len(),
            self.receipts.lock().unwrap().len(),
            self.outcomes.lock().unwrap().len(),
        )
    }
}

/// What a sender's and a receiver's recorders must agree on after `n` sends from `sender`
/// to `receiver`, all of them received: one send and one outcome per id, the same ids, a
/// receipt per id with the sent payload, and the route each took.
fn check_pair(
    sender: &Recorder,
    receiver: &Recorder,
    n: usize,
    route: RouteKind,
    via: Via,
    outcome_ok: impl Fn(&Outcome) -> bool,
) {
    let sends = sender.sends.lock().unwrap().clone();
    let outcomes = sender.outcomes.lock().unwrap().clone();
    let receipts = receiver.receipts.lock().unwrap().clone();
    assert_eq!(sends.len(), n, "one on_send per send");
    assert_eq!(outcomes.len(), n, "one on_outcome per send");
    assert_eq!(receipts.len(), n, "one on_receipt per message");
    let sent: BTreeMap<SendId, &Attempt> = sends.iter().map(|s| (s.id, s)).collect();
    assert_eq!(sent.len(), n, "send ids are unique");
    let ended: BTreeSet<SendId> = outcomes.iter().map(|(id, _, _)| *id).collect();
    assert_eq!(
        ended,
        sent.keys().copied().collect(),
        "outcome ids = send ids"
    );
    for (id, outcome, _) in &outcomes {
        assert!(outcome_ok(outcome), "{id:?} ended {outcome}");
    }
    for s in &sends {
        assert_eq!((s.attempt, s.route, s.ty), (1, route, TY), "{s:?}");
        assert_eq!(s.link.is_none(), route == RouteKind::Direct);
    }
    for r in &receipts {
        let s = sent.get(&r.id).expect("a receipt names a send");
        assert_eq!(r.from, s.from);
        assert_eq!(r.payload, s.payload);
        assert_eq!((r.via, r.status), (via, AckStatus::Delivered));
    }
    let received: BTreeSet<SendId> = receipts.iter().map(|r| r.id).collect();
    assert_eq!(received.len(), n, "each message received once");
    // A retransmission (a loaded machine may be slow to acknowledge) is reported apart and
    // names its send; it only happens on the router's loop.
    for r in sender.retransmits.lock().unwrap().iter() {
        assert!(sent.contains_key(&r.id) && r.attempt > 1 && r.route == RouteKind::Routed);
    }
}

/// A and B: UDP (`delivery`) between them.
fn udp_fleet(delivery: &str) -> LocalFleet {
    let text = common::udp_pair_text("", "M = 0", &format!("delivery = \"{delivery}\""));
    LocalFleet::open(hetcomm::config::parse_str(&text, "observe.toml", None).unwrap()).unwrap()
}

/// A and B: in-process (`delivery`) between them.
fn inproc_fleet(delivery: &str) -> LocalFleet {
    let text = format!(
        r#"
[systems]
A = 0
B = 1
[modules]
M = 0
[transports.p]
kind = "inproc"
delivery = "{delivery}"
[table]
columns = ["A", "B"]
A = ["X", "p"]
B = ["p", "X"]
"#
    );
    LocalFleet::open(hetcomm::config::parse_str(&text, "observe-inproc.toml", None).unwrap())
        .unwrap()
}

fn wait_for(what: &str, mut done: impl FnMut() -> bool) {
    let deadline = Instant::now() + Duration::from_secs(10);
    while !done() {
        assert!(Instant::now() < deadline, "timed out waiting for {what}");
        std::thread::sleep(Duration::from_millis(2));
    }
}

/// Sends `n` payloads from module M of A to M of B; returns once every outcome is known.
fn send_n(f: &LocalFleet, n: usize) {
    let a = f.system("A").unwrap().module("M").unwrap();
    for i in 0..n {
        let t = a
            .send_raw("B", "M", TY, &(i as u32).to_le_bytes(), Default::default())
            .unwrap();
        t.wait();
    }
}

/// Registers recorders on A and B, sends `n` messages A → B, checks them, then drops the
/// handles and checks that nothing more is seen.
fn observe_pair(f: &LocalFleet, n: usize, route: RouteKind, via: Via, ok: fn(&Outcome) -> bool) {
    let (ra, rb) = (Arc::new(Recorder::default()), Arc::new(Recorder::default()));
    let ha = f.system("A").unwrap().observe(ra.clone());
    let hb = f.system("B").unwrap().observe(rb.clone());
    send_n(f, n);
    wait_for("every receipt", || rb.counts().2 == n);
    check_pair(&ra, &rb, n, route, via, ok);
    // B sent nothing; A received nothing.
    let retransmits = ra.counts().1;
    assert_eq!(rb.counts(), (0, 0, n, 0));
    assert_eq!(ra.counts(), (n, retransmits, 0, n));

    drop(ha);
    hb.remove();
    let b = f.system("B").unwrap().module("M").unwrap();
    let before_b = b.inbox_stats();
    send_n(f, 10);
    wait_for("the last messages", || {
        b.inbox_stats().accepted >= before_b.accepted + 10
    });
    assert_eq!(
        ra.counts(),
        (n, retransmits, 0, n),
        "nothing after the handle is dropped"
    );
    assert_eq!(rb.counts(), (0, 0, n, 0), "nothing after remove");
}

#[test]
fn acknowledged_udp_sends_are_observed_through_the_router_loop() {
    let f = udp_fleet("acknowledged");
    observe_pair(&f, 200, RouteKind::Routed, Via::Link(0), |o| {
        matches!(o, Outcome::Delivered { .. })
    });
}

#[test]
fn unacknowledged_udp_sends_are_observed_on_the_fast_path() {
    let f = udp_fleet("unacknowledged");
    observe_pair(&f, 200, RouteKind::Unqueued, Via::Link(0), |o| {
        matches!(o, Outcome::Sent { attempts: 1 })
    });
}

#[test]
fn in_process_hand_overs_are_observed_without_frames() {
    for delivery in ["acknowledged", "unacknowledged"] {
        let f = inproc_fleet(delivery);
        observe_pair(&f, 300, RouteKind::Direct, Via::Direct, |o| o.is_success());
    }
}

/// Several observers on one system each see everything; a sender made once
/// (`Module::raw_sender`) goes the direct way too; removing one observer leaves the other.
#[test]
fn several_observers_and_senders() {
    let f = inproc_fleet("acknowledged");
    let (r1, r2, rb) = (
        Arc::new(Recorder::default()),
        Arc::new(Recorder::default()),
        Arc::new(Recorder::default()),
    );
    let alpha = f.system("A").unwrap();
    let h1 = alpha.observe(r1.clone());
    let h2 = alpha.observe(r2.clone());
    let _hb = f.system("B").unwrap().observe(rb.clone());
    let sender = alpha.module("M").unwrap().raw_sender("B", "M", TY).unwrap();
    for i in 0..50u32 {
        let o = sender.send(&i.to_le_bytes(), Default::default()).unwrap();
        assert!(matches!(o.wait(), Outcome::Delivered { .. }));
    }
    for r in [&r1, &r2] {
        check_pair(r, &rb, 50, RouteKind::Direct, Via::Direct, |o| {
            o.is_success()
        });
    }
    h1.remove();
    sender.send(&[1], Default::default()).unwrap().wait();
    assert_eq!(r1.counts(), (50, 0, 0, 50));
    assert_eq!(r2.counts(), (51, 0, 0, 51));
    drop(h2);
}

fn lossy_fleet(delivery: &str) -> hetcomm::config::Fleet {
    let text = format!(
        r#"
[systems]
A = 0
B = 1
C = 2
[modules]
Plan = 0
[transports.radio]
kind = "emulated"
delivery = "{delivery}"
attempts = 4
latency_ms = 5.0
jitter_ms = 2.0
loss_percent = 30.0
[table]
columns = ["A", "B", "C"]
A = ["X", "radio", "radio"]
B = ["radio", "X", "radio"]
C = ["radio", "radio", "X"]
"#
    );
    hetcomm::config::parse_str(&text, "observe-sim.toml", None).unwrap()
}

/// A simulated fleet over a lossy radio: per system, one on_send and one on_outcome per
/// send, retransmissions reported apart with their attempt number and adding up to each
/// outcome's attempts, every receipt naming a send of its source, every delivered send
/// received, and times on the virtual clock.
#[test]
fn a_simulated_fleet_is_observed_in_virtual_time() {
    for delivery in ["acknowledged", "unacknowledged"] {
        let sim = SimFleet::open(
            lossy_fleet(delivery),
            SimOptions {
                seed: 7,
                losses: LossVisibility::Silent,
                timing: None,
            },
        )
        .unwrap();
        let names = ["A", "B", "C"];
        let recorders: Vec<Arc<Recorder>> = names
            .iter()
            .map(|_| Arc::new(Recorder::default()))
            .collect();
        let handles: Vec<_> = names
            .iter()
            .zip(&recorders)
            .map(|(n, r)| sim.system(n).unwrap().observe(r.clone()))
            .collect();
        const N: u32 = 60;
        let mut tickets = Vec::new();
        for round in 0..N {
            for (i, from) in names.iter().enumerate() {
                let to = names[(i + 1 + (round as usize % 2)) % 3];
                let m = sim.system(from).unwrap().module("Plan").unwrap();
                tickets.push(
                    m.send_raw(to, "Plan", TY, &round.to_le_bytes(), Default::default())
                        .unwrap(),
                );
            }
            sim.run_until(Time::from_micros(sim.now().as_micros() + 1_000));
        }
        sim.run_idle(Time::from_micros(600_000_000));
        assert!(tickets.iter().all(|t| t.try_outcome().is_some()));

        let mut all_sends = BTreeMap::new();
        let mut delivered = BTreeSet::new();
        let mut retransmitted = 0;
        for (name, r) in names.iter().zip(&recorders) {
            let me = sim.system(name).unwrap().id();
            let sends = r.sends.lock().unwrap().clone();
            let retransmits = r.retransmits.lock().unwrap().clone();
            let outcomes = r.outcomes.lock().unwrap().clone();
            assert_eq!(sends.len(), N as usize, "{delivery} {name}: sends");
            assert_eq!(outcomes.len(), N as usize, "{delivery} {name}: outcomes");
            let mut transmissions: BTreeMap<SendId, u32> = BTreeMap::new();
            for s in &sends {
                assert_eq!((s.from, s.attempt), (me, 1));
                let expected = match delivery {
                    "acknowledged" => RouteKind::Routed,
                    _ => RouteKind::Unqueued,
                };
                assert_eq!(s.route, expected);
                assert!(transmissions.insert(s.id, 1).is_none(), "unique ids");
                all_sends.insert((me, s.id), s.payload.clone());
            }
            for s in &retransmits {
                assert_eq!(s.route, RouteKind::Routed);
                let count = transmissions.get_mut(&s.id).expect("retransmits a send");
                *count += 1;
                assert_eq!(s.attempt, *count, "attempts numbered in order");
            }
            retransmitted += retransmits.len();
            for (id, outcome, time) in &outcomes {
                assert_eq!(
                    Some(&outcome.attempts()),
                    transmissions.get(id),
                    "{delivery} {name} {id:?}: every transmission was observed"
                );
                assert!(*time <= sim.now());
                if matches!(outcome, Outcome::Delivered { .. }) {
                    delivered.insert((me, *id));
                }
            }
            assert_eq!(
                transmissions.keys().collect::<Vec<_>>(),
                outcomes
                    .iter()
                    .map(|(id, _, _)| id)
                    .collect::<BTreeSet<_>>()
                    .into_iter()
                    .collect::<Vec<_>>()
            );
        }
        let mut received = BTreeSet::new();
        for (name, r) in names.iter().zip(&recorders) {
            let me = sim.system(name).unwrap().id();
            for rc in r.receipts.lock().unwrap().iter() {
                assert_eq!(rc.id.to, me);
                assert!(matches!(rc.via, Via::Link(_)));
                assert_eq!(rc.status, AckStatus::Delivered);
                assert_eq!(
                    all_sends.get(&(rc.from, rc.id)),
                    Some(&rc.payload),
                    "a receipt names a send"
                );
                assert!(received.insert((rc.from, rc.id)), "received once");
            }
        }
        assert!(
            delivered.is_subset(&received),
            "every delivered send was received"
        );
        assert!(!received.is_empty());
        if delivery == "acknowledged" {
            assert!(retransmitted > 0, "30% loss makes retransmissions");
            assert!(!delivered.is_empty());
        } else {
            assert_eq!(retransmitted, 0, "silent loss: nothing is retried");
        }

        // Nothing after the handles go.
        let before: Vec<_> = recorders.iter().map(|r| r.counts()).collect();
        drop(handles);
        let m = sim.system("A").unwrap().module("Plan").unwrap();
        m.send_raw("B", "Plan", TY, &[0], Default::default())
            .unwrap();
        sim.run_idle(Time::from_micros(sim.now().as_micros() + 60_000_000));
        let after: Vec<_> = recorders.iter().map(|r| r.counts()).collect();
        assert_eq!(before, after);
    }
}

/// A receipt carries the inbox's answer, and the sender's outcome agrees with it: a full
/// `drop-newest` inbox refuses, the receipt says so, the send fails `InboxFull`.
#[test]
fn receipts_carry_the_inbox_answer() {
    let text = r#"
[systems]
A = 0
B = 1
[modules]
M = 0
[inbox]
capacity = 2
overflow = "drop-newest"
[transports.p]
kind = "inproc"
[table]
columns = ["A", "B"]
A = ["X", "p"]
B = ["p", "X"]
"#;
    let f = LocalFleet::open(hetcomm::config::parse_str(text, "observe-full.toml", None).unwrap())
        .unwrap();
    let (ra, rb) = (Arc::new(Recorder::default()), Arc::new(Recorder::default()));
    let _ha = f.system("A").unwrap().observe(ra.clone());
    let _hb = f.system("B").unwrap().observe(rb.clone());
    send_n(&f, 5);
    let receipts = rb.receipts.lock().unwrap().clone();
    let statuses: Vec<AckStatus> = receipts.iter().map(|r| r.status).collect();
    use AckStatus::{Delivered, InboxFull};
    assert_eq!(
        statuses,
        [Delivered, Delivered, InboxFull, InboxFull, InboxFull]
    );
    let outcomes = ra.outcomes.lock().unwrap().clone();
    assert_eq!(outcomes.len(), 5);
    for ((id, outcome, _), receipt) in outcomes.iter().zip(&receipts) {
        assert_eq!(*id, receipt.id);
        assert_eq!(
            outcome.is_success(),
            receipt.status == Delivered,
            "{id:?}: {outcome}"
        );
    }
}
