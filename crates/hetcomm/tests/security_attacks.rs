//! The attacks of issue 21, each reproduced with real sockets against secured systems, and
//! each shown rejected, counted by reason in the receiver's `stats().links[..].security`,
//! never delivered to a module, and without making any sender's outcome lie.
//!
//! Written once, run over every network transport: `udp`, `tcp`, and (with `--features
//! ros1`, against a real `rosmaster`) `ros1`. The attacker is an unrelated raw socket (or ROS
//! node) speaking the wire format of `docs/wire-format.md` (`tests/common/attack.rs`); to
//! replay and tamper it records real secured frames with a relay between A and B (udp, tcp)
//! or a second subscriber of B's topic, a rospy node (ros1).
//!
//! Systems: A and B talk both ways on transport `t`; B sends to C; C → B is `X`.

mod common;

use std::sync::{Arc, Mutex};
use std::time::Duration;

use common::attack::{
    forged_data, forged_secured, open_retrying, plain_ack, plain_data, secured_kind, secured_pair,
    security, wait_until, KeyDir, Kind, Relay, Setup, Station, ACT, ATTEMPTS, PLAN, STRANGER,
    TABLE,
};
use hetcomm::observe::{Observer, SendRecord};
use hetcomm::{Comm, FailReason, MessageType, Module, Outcome, SecurityStats, SendOptions};

#[cfg(feature = "ros1")]
#[path = "../../hetcomm-link-ros1/tests/common/mod.rs"]
mod ros;

const WAIT: Duration = Duration::from_secs(20);
const A: u16 = 0;
const B: u16 = 1;
const C: u16 = 2;

/// Rejections by reason: (auth, replay, table, unknown sender, no session).
type Rejected = (u64, u64, u64, u64, u64);

fn rejected(s: &SecurityStats) -> Rejected {
    (
        s.rejected_auth,
        s.rejected_replay,
        s.rejected_table,
        s.rejected_unknown_sender,
        s.rejected_no_session,
    )
}

fn minus(a: Rejected, b: Rejected) -> Rejected {
    (a.0 - b.0, a.1 - b.1, a.2 - b.2, a.3 - b.3, a.4 - b.4)
}

/// Waits until `comm`'s rejections since `before` are `expected`, and asserts they are.
fn expect_rejected(comm: &Comm, before: Rejected, expected: Rejected, what: &str) {
    let now = || minus(rejected(&security(comm)), before);
    wait_until(WAIT, || now() == expected);
    assert_eq!(
        now(),
        expected,
        "{what}: rejections at {} (auth, replay, table, unknown sender, no session)",
        comm.name()
    );
}

/// A and B running; A's frames to B pass a recorder when `capture` (a relay in A's fleet
/// for udp and tcp, a second subscriber of B's topic for ros1).
struct World {
    setup: Setup,
    relay: Option<Relay>,
    sniffer: Option<Station>,
    sniffed: Mutex<Vec<Vec<u8>>>,
    a: Comm,
    plan: Module,
    b: Comm,
    act: Module,
    tag: Mutex<u8>,
}

impl World {
    fn open(kind: &Kind, capture: bool) -> World {
        let setup = Setup::new(kind.clone());
        let b = setup.open("B", &[]);
        let (relay, sniffer) = match (capture, kind) {
            (false, _) => (None, None),
            (true, Kind::Ros1(_)) => (None, Some(Station::at(&setup, "B"))),
            (true, _) => (Some(Relay::new(kind, setup.endpoint("B"))), None),
        };
        let a = setup.open("A", &relay_move(&relay));
        let w = World {
            plan: a.module("Plan").unwrap(),
            act: b.module("Act").unwrap(),
            a,
            b,
            setup,
            relay,
            sniffer,
            sniffed: Mutex::new(Vec::new()),
            tag: Mutex::new(0),
        };
        // Sessions up (and every ROS subscriber connected) before anything is counted.
        w.exchange(1);
        if w.sniffer.is_some() {
            // ROS connects subscribers asynchronously: until the sniffer has seen one of A's
            // frames, it may miss some.
            for _ in 0..50 {
                if !w.captured_data().is_empty() {
                    break;
                }
                w.exchange(1);
            }
            assert!(
                !w.captured_data().is_empty(),
                "the sniffer hears A's frames"
            );
        }
        w
    }

    /// Closes A and opens it again (same keys, same endpoints).
    fn restart_a(&mut self) {
        // Every handle of A goes (the placeholders are B's), so A closes before it reopens.
        self.plan = self.b.module("Plan").unwrap();
        self.a = self.b.clone();
        self.a = self.setup.open("A", &relay_move(&self.relay));
        self.plan = self.a.module("Plan").unwrap();
    }

    /// Closes B and opens it again (same keys, same endpoint).
    fn restart_b(&mut self) {
        self.act = self.a.module("Act").unwrap();
        self.b = self.a.clone();
        self.b = self.setup.open("B", &[]);
        self.act = self.b.module("Act").unwrap();
    }

    /// A sends `n` messages to B's Act: every one is delivered, and B gets exactly these.
    fn exchange(&self, n: u8) {
        let tag = {
            let mut t = self.tag.lock().unwrap();
            *t += 1;
            *t
        };
        let tickets: Vec<_> = (0..n)
            .map(|i| {
                self.plan
                    .send_raw(
                        "B",
                        "Act",
                        MessageType(1),
                        &[tag, i],
                        SendOptions::default(),
                    )
                    .expect("send")
            })
            .collect();
        for (i, t) in tickets.iter().enumerate() {
            let outcome = t.wait_timeout(WAIT).expect("an outcome");
            assert!(
                matches!(outcome, Outcome::Delivered { .. }),
                "message {tag}/{i}: {outcome:?}\nA: {:?}\nB: {:?}",
                security(&self.a),
                security(&self.b)
            );
        }
        let mut got: Vec<Vec<u8>> = (0..n)
            .map(|_| {
                let m = self.act.recv_raw_timeout(Some(WAIT)).expect("a message");
                assert_eq!(m.envelope.source_system, "A");
                m.payload.to_vec()
            })
            .collect();
        got.sort();
        let want: Vec<Vec<u8>> = (0..n).map(|i| vec![tag, i]).collect();
        assert_eq!(got, want, "B got A's messages once each");
        self.nothing_delivered();
    }

    /// After B restarted: A's messages sealed in the session B no longer has are lost (and
    /// truthfully reported unconfirmed) until the two have made a new one, which the first
    /// of them starts (B answers frames of an unknown session with a handshake). Sends until
    /// one is delivered, then takes them out of B's inbox.
    fn rekeyed(&self) {
        let delivered = (0..20u8).any(|i| {
            let t = self
                .plan
                .send_raw(
                    "B",
                    "Act",
                    MessageType(1),
                    &[0xEE, i],
                    SendOptions::default(),
                )
                .expect("send");
            matches!(t.wait_timeout(WAIT), Some(Outcome::Delivered { .. }))
        });
        assert!(delivered, "A and B never re-keyed");
        while let Some(m) = self.act.try_recv_raw() {
            assert_eq!(m.payload[0], 0xEE, "only A's messages after the restart");
        }
    }

    /// B's module has nothing waiting.
    fn nothing_delivered(&self) {
        if let Some(m) = self.act.try_recv_raw() {
            panic!(
                "delivered to B: {:?} from {}",
                m.payload, m.envelope.source_system
            );
        }
    }

    /// Every frame recorded on the way to B so far.
    fn captured(&self) -> Vec<Vec<u8>> {
        match (&self.relay, &self.sniffer) {
            (Some(r), _) => r.frames(),
            (_, Some(s)) => {
                let mut all = self.sniffed.lock().unwrap();
                all.extend(s.drain());
                all.clone()
            }
            _ => panic!("this world records nothing"),
        }
    }

    /// Recorded secured frames of `kind` from A to B.
    fn captured_of(&self, kind: u8) -> Vec<Vec<u8>> {
        self.captured()
            .into_iter()
            .filter(|f| secured_kind(f) == Some(kind) && secured_pair(f) == (A, B))
            .collect()
    }

    /// A's data messages and data batches to B (types 3 and 4: frames the router lets wait
    /// leave as one batch).
    fn captured_data(&self) -> Vec<Vec<u8>> {
        self.captured()
            .into_iter()
            .filter(|f| matches!(secured_kind(f), Some(3 | 4)) && secured_pair(f) == (A, B))
            .collect()
    }

    fn b_rejected(&self) -> Rejected {
        rejected(&security(&self.b))
    }
}

fn relay_move(relay: &Option<Relay>) -> Vec<(&'static str, std::net::SocketAddr)> {
    relay.iter().map(|r| ("B", r.addr)).collect()
}

/// Records the headers of a system's sends.
#[derive(Default)]
struct Headers(Mutex<Vec<hetcomm::Header>>);

impl Observer for Headers {
    fn on_send(&self, r: &SendRecord<'_>) {
        self.0.lock().unwrap().push(r.header);
    }
}

// ---- the attacks -------------------------------------------------------------------------

/// A frame claiming to come from A's Plan module, to B's Act, from an unrelated socket: an
/// unsecured one, and one in the secured format with a session B never made.
fn spoofed_source(kind: &Kind) {
    let w = World::open(kind, false);
    let before = w.b_rejected();
    let received = w.b.stats().router.received;
    let eve = Station::anywhere(&w.setup, A);
    eve.send(
        "B",
        &[
            plain_data((A, PLAN), (B, ACT), 100, 0x1234, 1, &[1]),
            forged_data(A, B, 0x5eed, 1),
        ],
    );
    expect_rejected(&w.b, before, (1, 0, 0, 0, 1), "spoofed source");
    w.nothing_delivered();
    assert_eq!(w.b.stats().router.received, received);
    w.exchange(3);
}

/// "A STOP from Plan at priority 255": unsecured, and sealed-looking under the real
/// session's index (read off the wire) with a made-up counter and tag.
fn spoofed_module_priority(kind: &Kind) {
    let w = World::open(kind, true);
    let index = u32::from_le_bytes(w.captured_data()[0][8..12].try_into().unwrap());
    let before = w.b_rejected();
    let eve = Station::anywhere(&w.setup, A);
    eve.send(
        "B",
        &[
            plain_data((A, PLAN), (B, ACT), 255, 0x1234, 7, b"STOP"),
            forged_data(A, B, index, 1 << 40),
        ],
    );
    expect_rejected(&w.b, before, (2, 0, 0, 0, 0), "spoofed module and priority");
    w.nothing_delivered();
    w.exchange(3);
}

/// C → B is `X`: an unsecured frame from C, a secured-format frame from a system outside the
/// fleet, and C itself — holding its real key, with its own copy of the fleet file edited
/// to allow C → B — sending to B. Every one is refused; C is never told "delivered".
fn x_pair(kind: &Kind) {
    let w = World::open(kind, false);
    let before = w.b_rejected();
    // (TCP: B's link refuses a hello naming a system outside the fleet, so the stranger's
    // frame comes on a connection that claims C.)
    let eve = Station::anywhere(&w.setup, C);
    eve.send(
        "B",
        &[
            plain_data((C, PLAN), (B, ACT), 100, 0x1234, 1, &[1]),
            forged_data(STRANGER, B, 1, 1),
        ],
    );
    expect_rejected(&w.b, before, (1, 0, 0, 1, 0), "C and a stranger");
    let rows = [TABLE[0], TABLE[1], r#"C = ["X", "t", "X"]"#];
    let c = open_retrying(&w.setup.fleet_for("C", &[], rows), "C");
    let outcome = c
        .module("Plan")
        .unwrap()
        .send_raw(
            "B",
            "Act",
            MessageType(1),
            b"from C",
            SendOptions::default(),
        )
        .expect("C's edited table allows the send")
        .wait_timeout(WAIT)
        .expect("an outcome");
    assert!(
        matches!(
            outcome,
            Outcome::Unconfirmed {
                attempts: ATTEMPTS,
                ..
            }
        ),
        "C's send: {outcome:?}"
    );
    // Each of C's transmissions authenticated and was refused by B's table.
    let n = u64::from(ATTEMPTS);
    expect_rejected(&w.b, before, (1, 0, n, 1, 0), "C over an X pair");
    w.nothing_delivered();
    w.exchange(2);
}

/// A and C are `X` both ways, so A does not even answer C's handshake. C, holding its real
/// key, with its own copy of the fleet file edited to allow C → A, is refused by A's table
/// (C is a member with a valid key, not a stranger), and, since only its handshakes left, C
/// is told its send failed, not that it may have arrived.
fn x_pair_both_ways(kind: &Kind) {
    let setup = Setup::new(kind.clone());
    let a = setup.open("A", &[]);
    let before = rejected(&security(&a));
    let rows = [TABLE[0], TABLE[1], r#"C = ["t", "X", "X"]"#];
    let c = open_retrying(&setup.fleet_for("C", &[], rows), "C");
    let outcome = c
        .module("Plan")
        .unwrap()
        .send_raw(
            "A",
            "Act",
            MessageType(1),
            b"from C",
            SendOptions::default(),
        )
        .expect("C's edited table allows the send")
        .wait_timeout(WAIT)
        .expect("an outcome");
    // What A counted first: that is the point of this test.
    let s = security(&a);
    let (auth, replay, table, unknown, no_session) = minus(rejected(&s), before);
    assert!(
        table >= 1,
        "C's handshakes are the table's to refuse: {s:?}"
    );
    assert_eq!((auth, replay, unknown, no_session), (0, 0, 0, 0), "{s:?}");
    assert_eq!(s.handshakes, 0, "{s:?}");
    assert!(
        matches!(
            &outcome,
            Outcome::Failed {
                reason: FailReason::NoSession(why),
                attempts: ATTEMPTS,
            } if why.starts_with("no secure session with A: handshake ")
        ),
        "C's send: {outcome:?}"
    );
    assert!(a.module("Act").unwrap().try_recv_raw().is_none());
    assert_eq!(a.stats().router.received, 0);
}

/// B is not running; an attacker in its place answers A's handshake with a forged response
/// and A's message with a forged acknowledgement that carries the right incarnation and
/// sequence number (leaked to it: the worst case). A never reports "delivered".
fn forged_ack(kind: &Kind) {
    let setup = Setup::new(kind.clone());
    let a = setup.open("A", &[]);
    let headers = Arc::new(Headers::default());
    let _watch = a.observe(headers.clone());
    let eve = Station::at(&setup, "B");
    // Connected to A before A's first frame (ROS: publisher and subscription up), so the
    // forged response is in time for the initiation it names.
    eve.send("A", &[]);
    let before = rejected(&security(&a));
    let ticket = a
        .module("Plan")
        .unwrap()
        .send_raw("B", "Act", MessageType(1), &[1], SendOptions::default())
        .unwrap();
    let mut init = eve.recv_secured(1, WAIT).expect("A's handshake initiation");
    // The newest initiation (A sends another every 250 ms while unanswered).
    while let Some(f) = eve.recv(Duration::from_millis(1)) {
        if secured_kind(&f) == Some(1) {
            init = f;
        }
    }
    let h = headers.0.lock().unwrap()[0];
    // A response naming A's initiation (its index, read off the wire), with made-up Noise.
    let mut response = init[8..12].to_vec();
    response.extend_from_slice(&[0x42; 48]);
    eve.send(
        "A",
        &[
            plain_ack((B, ACT), (A, PLAN), h.incarnation, h.seq),
            forged_secured(2, B, A, 77, &response),
        ],
    );
    let outcome = ticket.wait_timeout(WAIT).expect("an outcome");
    // Only A's handshakes left (the layer sends no data frame before a session exists), so
    // the message certainly did not arrive.
    assert!(
        matches!(
            outcome,
            Outcome::Failed {
                reason: FailReason::NoSession(_),
                ..
            }
        ),
        "A's send to a B that is not running: {outcome:?}"
    );
    let s = security(&a);
    assert_eq!(s.handshakes, 0, "{s:?}");
    expect_rejected(
        &a,
        before,
        (2, 0, 0, 0, 0),
        "forged response and acknowledgement",
    );
    assert_eq!(a.stats().router.delivered, 0);
}

/// Every captured frame of A's (data and handshake initiations) sent to B again.
fn replay_within_run(kind: &Kind) {
    let w = World::open(kind, true);
    w.exchange(5);
    let (data, inits) = (w.captured_data(), w.captured_of(1));
    // Five messages and the frames that confirm the session, alone or in data batches.
    assert!(!data.is_empty(), "captured no data frames");
    let (before, dups) = (w.b_rejected(), w.b.stats().router.duplicates);
    let eve = Station::anywhere(&w.setup, A);
    eve.send("B", &data);
    eve.send("B", &inits);
    let n = (data.len() + inits.len()) as u64;
    expect_rejected(&w.b, before, (0, n, 0, 0, 0), "replays within a run");
    w.nothing_delivered();
    assert_eq!(w.b.stats().router.duplicates, dups, "the router saw none");
    w.exchange(3);
}

/// B restarts (same keys, same endpoint); A's captured frames are replayed to it.
fn replay_after_receiver_restart(kind: &Kind) {
    let mut w = World::open(kind, true);
    w.exchange(5);
    let (data, inits) = (w.captured_data(), w.captured_of(1));
    w.restart_b();
    let before = w.b_rejected();
    let eve = Station::anywhere(&w.setup, A);
    eve.send("B", &data);
    // Frames of a session the new B never had: none opens.
    expect_rejected(&w.b, before, (0, 0, 0, 0, data.len() as u64), "data");
    // A replayed initiation makes the new B answer into a session nobody else holds: its
    // response is refused at A, and the session never becomes B's current one (that takes
    // a frame from A in it), so B's own handshake with A goes on.
    eve.send("B", &inits);
    w.nothing_delivered();
    assert_eq!(w.b.stats().router.received, 0);
    w.rekeyed();
    w.exchange(3);
    let s = security(&w.b);
    assert_eq!((s.rejected_auth, s.rejected_table), (0, 0), "{s:?}");
}

/// A restarts (same keys, same endpoint) and talks to B in a new session; the frames of its
/// old session are replayed to B.
fn replay_after_sender_restart(kind: &Kind) {
    let mut w = World::open(kind, true);
    w.exchange(5);
    let (data, inits) = (w.captured_data(), w.captured_of(1));
    w.restart_a();
    w.exchange(1);
    let before = w.b_rejected();
    let eve = Station::anywhere(&w.setup, A);
    eve.send("B", &data);
    eve.send("B", &inits);
    let n = (data.len() + inits.len()) as u64;
    expect_rejected(&w.b, before, (0, n, 0, 0, 0), "the old session's frames");
    w.nothing_delivered();
    w.exchange(3);
}

fn flipped(frame: &[u8], at: usize) -> Vec<u8> {
    let mut f = frame.to_vec();
    f[at] ^= 0x01;
    f
}

/// Captured data frames with a payload byte or a tag byte changed.
fn tampered_payload(kind: &Kind) {
    let w = World::open(kind, true);
    w.exchange(2);
    let data = w.captured_data();
    let last = data.last().unwrap();
    let before = w.b_rejected();
    let eve = Station::anywhere(&w.setup, A);
    eve.send(
        "B",
        &[
            flipped(last, 20 + 48),
            flipped(last, last.len() - 1),
            flipped(&data[0], 20 + 48 + 1),
        ],
    );
    expect_rejected(&w.b, before, (3, 0, 0, 0, 0), "tampered payloads");
    w.nothing_delivered();
    w.exchange(2);
}

/// Captured data frames with a header byte changed: inside the encrypted header (priority,
/// source system), and in the clear prefix (counter, sender, receiver).
fn tampered_header(kind: &Kind) {
    let w = World::open(kind, true);
    w.exchange(2);
    let f = w.captured_data().pop().unwrap();
    let before = w.b_rejected();
    let eve = Station::anywhere(&w.setup, A);
    eve.send(
        "B",
        &[
            flipped(&f, 20 + 5), // priority (encrypted)
            flipped(&f, 20 + 8), // source system (encrypted)
            flipped(&f, 12),     // counter (clear, authenticated)
            flipped(&f, 4),      // sender: A (0) becomes 1, B itself, whose key B does not list
            flipped(&f, 7),      // receiver: B (1) becomes 257, not B
        ],
    );
    expect_rejected(&w.b, before, (3, 0, 1, 1, 0), "tampered headers");
    w.nothing_delivered();
    w.exchange(2);
}

/// The attacker knows A's incarnation and its last sequence number (the worst case) and
/// floods B with 20 000 unsecured frames numbered after it, then 2 000 sealed-looking frames
/// under the real session index with high counters. A's next 30 messages are all delivered.
fn window_poisoning(kind: &Kind) {
    let w = World::open(kind, true);
    let headers = Arc::new(Headers::default());
    let _watch = w.a.observe(headers.clone());
    w.exchange(1);
    let h = headers.0.lock().unwrap()[0];
    let index = u32::from_le_bytes(w.captured_data()[0][8..12].try_into().unwrap());
    let before = w.b_rejected();
    let eve = Station::anywhere(&w.setup, A);
    let mut sent = 0u64;
    let chunk = |frames: Vec<Vec<u8>>, sent: &mut u64| {
        eve.send("B", &frames);
        *sent += frames.len() as u64;
        // Paced so no kernel buffer drops any: every one is counted.
        expect_rejected(&w.b, before, (*sent, 0, 0, 0, 0), "the flood");
    };
    for k in 0..40u64 {
        let frames = (0..500)
            .map(|i| {
                let seq = h.seq + 1 + k * 500 + i;
                plain_data((A, PLAN), (B, ACT), 255, h.incarnation, seq, b"poison")
            })
            .collect();
        chunk(frames, &mut sent);
    }
    for k in 0..4u64 {
        let frames = (0..500)
            .map(|i| forged_data(A, B, index, (1 << 32) + k * 500 + i))
            .collect();
        chunk(frames, &mut sent);
    }
    assert_eq!(sent, 22_000);
    // Every one delivered, each exactly once (the router may still see a retransmission
    // whose acknowledgement was late as a duplicate: that is not what the flood did).
    w.exchange(30);
}

/// Over TCP: a connection to B whose hello claims A, then frames claiming A.
fn hello_impersonation(kind: &Kind) {
    let w = World::open(kind, false);
    let before = w.b_rejected();
    let eve = Station::anywhere(&w.setup, A);
    eve.send(
        "B",
        &[
            plain_data((A, PLAN), (B, ACT), 255, 0x1234, 1, b"STOP"),
            forged_data(A, B, 0x5eed, 1),
        ],
    );
    expect_rejected(
        &w.b,
        before,
        (1, 0, 0, 0, 1),
        "frames after a hello claiming A",
    );
    w.nothing_delivered();
    // A's own connection still carries A's traffic.
    w.exchange(5);
}

/// A system opened with another system's private key does not open; a process holding a key
/// B does not know for A ("Mallory") cannot make a session with B, and gets no "delivered".
fn wrong_key(kind: &Kind) {
    let setup = Setup::new(kind.clone());
    let mut fleet = setup.fleet_for("A", &[], TABLE);
    fleet.systems[0].private_key_file = Some(setup.keys.private_file("C"));
    let err = Comm::open_fleet(&fleet, "A").err().expect("A with C's key");
    let msg = err.to_string();
    assert!(
        msg.contains("does not belong") && msg.contains("give A's own private key"),
        "{msg}"
    );

    let b = setup.open("B", &[]);
    let mallory = KeyDir::new(&["Mallory"]);
    let mut fleet = setup.fleet_for("A", &[], TABLE);
    fleet.systems[0].public_key = Some(mallory.pairs["Mallory"].public.0);
    fleet.systems[0].private_key_file = Some(mallory.private_file("Mallory"));
    let impostor = open_retrying(&fleet, "A");
    let outcome = impostor
        .module("Plan")
        .unwrap()
        .send_raw("B", "Act", MessageType(1), b"STOP", SendOptions::default())
        .unwrap()
        .wait_timeout(WAIT)
        .expect("an outcome");
    // No session, so no data frame left: certainly not delivered.
    assert!(
        matches!(
            outcome,
            Outcome::Failed {
                reason: FailReason::NoSession(_),
                ..
            }
        ),
        "{outcome:?}"
    );
    let s = security(&b);
    assert!(s.rejected_auth >= 1, "{s:?}");
    assert_eq!(s.handshakes, 0, "{s:?}");
    let (_, replay, table, unknown, no_session) = rejected(&s);
    assert_eq!((replay, table, unknown, no_session), (0, 0, 0, 0), "{s:?}");
    assert!(b.module("Act").unwrap().try_recv_raw().is_none());
    assert_eq!(b.stats().router.received, 0);
}

/// A secured transport without keys does not open, and the error says how to fix it.
fn missing_key(kind: &Kind) {
    let setup = Setup::new(kind.clone());
    let text = setup.text(&[], TABLE);
    let fleet = hetcomm::parse_fleet(&text, "attack.toml", None).unwrap();
    let msg = Comm::open_fleet(&fleet, "A")
        .err()
        .expect("no keys")
        .to_string();
    for want in [
        "no public key for A, B",
        "hetcomm keygen",
        "security = \"none\"",
    ] {
        assert!(msg.contains(want), "missing {want:?} in: {msg}");
    }
    let mut fleet = setup.fleet_for("A", &[], TABLE);
    fleet.systems[0].private_key_file = None;
    let msg = Comm::open_fleet(&fleet, "A")
        .err()
        .expect("no private key")
        .to_string();
    for want in [
        "no private key for system A",
        "HETCOMM_PRIVATE_KEY",
        "private_key_file",
    ] {
        assert!(msg.contains(want), "missing {want:?} in: {msg}");
    }
}

// ---- one test per attack and transport ---------------------------------------------------

macro_rules! suite {
    ($kind:ident, $make:expr; $($attack:ident),* $(,)?) => {
        mod $kind {
            $(
                #[test]
                fn $attack() {
                    #[allow(clippy::redundant_closure_call)]
                    let (kind, _guard) = ($make)();
                    super::$attack(&kind);
                }
            )*
        }
    };
}

type Guard = Box<dyn std::any::Any>;

fn udp() -> (Kind, Guard) {
    (Kind::Udp, Box::new(()))
}

fn tcp() -> (Kind, Guard) {
    (Kind::Tcp, Box::new(()))
}

/// A real master per test (the test fails if ROS is not installed).
#[cfg(feature = "ros1")]
fn ros1() -> (Kind, Guard) {
    let master = ros::Master::start();
    (Kind::Ros1(master.uri()), Box::new(master))
}

suite!(udp, super::udp;
    spoofed_source, spoofed_module_priority, x_pair, x_pair_both_ways, forged_ack, replay_within_run,
    replay_after_receiver_restart, replay_after_sender_restart, tampered_payload,
    tampered_header, window_poisoning, wrong_key, missing_key);
suite!(tcp, super::tcp;
    spoofed_source, spoofed_module_priority, x_pair, x_pair_both_ways, forged_ack, replay_within_run,
    replay_after_receiver_restart, replay_after_sender_restart, tampered_payload,
    tampered_header, window_poisoning, hello_impersonation, wrong_key, missing_key);
#[cfg(feature = "ros1")]
suite!(ros1, super::ros1;
    spoofed_source, spoofed_module_priority, x_pair, x_pair_both_ways, forged_ack, replay_within_run,
    replay_after_receiver_restart, replay_after_sender_restart, tampered_payload,
    tampered_header, window_poisoning, wrong_key, missing_key);
