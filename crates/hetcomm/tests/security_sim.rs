//! The attacks of issue 21 against a secured emulated link in the simulator: frames forged,
//! replayed and tampered with are put on the simulated link with `SimFleet::inject_frame`
//! (captured with `SimFleet::record_frames`), and each is refused, counted by reason, never
//! delivered, and never makes a sender's outcome lie. Seeded and deterministic: the seed is
//! in every failure message, and `HETCOMM_SEED=<n>` reruns one.
//!
//! The emulated transport `radio` runs over a `udp` transport, so it is secured (keys and
//! sessions derived from the seed; no handshake frames on the simulated network). Restarts
//! and keys are the real-time suite's (`security_attacks.rs`): a simulated system does not
//! restart on its own, and simulated keys come from the seed, not from files.

mod common;

use std::sync::{Arc, Mutex};

use common::attack::{forged_data, plain_ack, plain_data, secured_kind, secured_pair, STRANGER};
use hetcomm::observe::{Observer, SendRecord};
use hetcomm::sim::{SimFleet, SimOptions};
use hetcomm::{Comm, MessageType, Module, Outcome, SecurityStats, SendOptions, Ticket, Time};

const A: u16 = 0;
const B: u16 = 1;
const C: u16 = 2;
const PLAN: u16 = 0;
const ACT: u16 = 1;

fn seed(default: u64) -> u64 {
    std::env::var("HETCOMM_SEED")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(default)
}

/// A ↔ B, B → C on `radio` (emulated over `u`, with `loss` percent lost); C → B is `X`.
fn fleet(loss: f64) -> hetcomm::config::Fleet {
    let text = format!(
        r#"[systems]
A = 0
B = 1
C = 2
[modules]
Plan = {PLAN}
Act = {ACT}
[transports.u]
kind = "udp"
endpoints = {{ A = "127.0.0.1:1", B = "127.0.0.1:2", C = "127.0.0.1:3" }}
[transports.radio]
kind = "emulated"
over = "u"
latency_ms = 2.0
jitter_ms = 1.0
loss_percent = {loss}
[table]
columns = ["A", "B", "C"]
A = ["X", "radio", "X"]
B = ["radio", "X", "radio"]
C = ["X", "X", "X"]
"#
    );
    hetcomm::parse_fleet(&text, "sim-attack.toml", None).expect("fleet parses")
}

/// Records the headers of a system's sends.
#[derive(Default)]
struct Headers(Mutex<Vec<hetcomm::Header>>);

impl Observer for Headers {
    fn on_send(&self, r: &SendRecord<'_>) {
        self.0.lock().unwrap().push(r.header);
    }
}

struct Sim {
    seed: u64,
    sim: SimFleet,
    a: Comm,
    b: Comm,
    plan: Module,
    act: Module,
    headers: Arc<Headers>,
    _watch: hetcomm::ObserverHandle,
    tag: u8,
}

impl Sim {
    fn open(seed: u64, loss: f64) -> Sim {
        let sim = SimFleet::open(
            fleet(loss),
            SimOptions {
                seed,
                ..Default::default()
            },
        )
        .expect("simulated fleet");
        sim.record_frames(true);
        let (a, b) = (sim.system("A").unwrap(), sim.system("B").unwrap());
        let headers = Arc::new(Headers::default());
        let _watch = a.observe(headers.clone());
        Sim {
            _watch,
            seed,
            plan: a.module("Plan").unwrap(),
            act: b.module("Act").unwrap(),
            a,
            b,
            sim,
            headers,
            tag: 0,
        }
    }

    /// Runs the simulation for `ms` more milliseconds.
    fn run(&self, ms: u64) {
        self.sim
            .run_until(Time(self.sim.now().as_micros() + ms * 1000));
    }

    fn send(&self, payload: &[u8]) -> Ticket {
        self.plan
            .send_raw("B", "Act", MessageType(1), payload, SendOptions::default())
            .expect("send")
    }

    /// A sends `n` messages to B: each is delivered, and B gets exactly these.
    fn exchange(&mut self, n: u8) {
        self.tag += 1;
        let tag = self.tag;
        let tickets: Vec<_> = (0..n).map(|i| self.send(&[tag, i])).collect();
        self.run(5_000);
        for (i, t) in tickets.iter().enumerate() {
            let o = t.try_outcome();
            assert!(
                matches!(o, Some(Outcome::Delivered { .. })),
                "seed {}: message {tag}/{i}: {o:?}",
                self.seed
            );
        }
        let mut got: Vec<Vec<u8>> = std::iter::from_fn(|| self.act.try_recv_raw())
            .map(|m| m.payload.to_vec())
            .collect();
        got.sort();
        let want: Vec<Vec<u8>> = (0..n).map(|i| vec![tag, i]).collect();
        assert_eq!(got, want, "seed {}", self.seed);
    }

    /// The sealed data messages and data batches A sent B, recorded since the last call.
    fn recorded_data(&self) -> Vec<Vec<u8>> {
        self.sim
            .take_recorded()
            .into_iter()
            .filter(|f| {
                matches!(secured_kind(&f.bytes), Some(3 | 4)) && secured_pair(&f.bytes) == (A, B)
            })
            .map(|f| f.bytes)
            .collect()
    }

    fn inject(&self, to: &str, frames: &[Vec<u8>]) {
        for f in frames {
            self.sim.inject_frame("radio", to, f).expect("inject");
        }
        self.run(1);
    }

    /// `comm`'s rejections: (auth, replay, table, unknown sender, no session).
    fn rejected(&self, comm: &Comm) -> (u64, u64, u64, u64, u64) {
        let s: SecurityStats = comm
            .stats()
            .links
            .iter()
            .find(|(n, _)| n == "radio")
            .map(|(_, l)| l.security)
            .expect("a radio link");
        assert!(s.enabled, "seed {}: the radio is secured", self.seed);
        (
            s.rejected_auth,
            s.rejected_replay,
            s.rejected_table,
            s.rejected_unknown_sender,
            s.rejected_no_session,
        )
    }

    fn nothing_delivered(&self) {
        assert!(
            self.act.try_recv_raw().is_none(),
            "seed {}: an injected frame was delivered",
            self.seed
        );
    }
}

fn flipped(frame: &[u8], at: usize) -> Vec<u8> {
    let mut f = frame.to_vec();
    f[at] ^= 0x01;
    f
}

/// Spoofed source, spoofed module and priority, `X` pair, replay, tampered payload and
/// header, one after the other on one simulated fleet, each counted exactly.
#[test]
fn forged_replayed_and_tampered_frames_are_refused_on_a_simulated_link() {
    let mut s = Sim::open(seed(21), 0.0);
    s.exchange(3);
    let data = s.recorded_data();
    assert_eq!(data.len(), 3, "seed {}", s.seed);
    let index = u32::from_le_bytes(data[0][8..12].try_into().unwrap());
    let mut expect = s.rejected(&s.b);
    let mut check = |s: &Sim, what: &str, add: (u64, u64, u64, u64, u64)| {
        expect = (
            expect.0 + add.0,
            expect.1 + add.1,
            expect.2 + add.2,
            expect.3 + add.3,
            expect.4 + add.4,
        );
        assert_eq!(s.rejected(&s.b), expect, "seed {}: {what}", s.seed);
        s.nothing_delivered();
    };

    s.inject("B", &[plain_data((A, PLAN), (B, ACT), 100, 1, 1, &[1])]);
    check(&s, "spoofed source", (1, 0, 0, 0, 0));
    s.inject(
        "B",
        &[
            plain_data((A, PLAN), (B, ACT), 255, 1, 2, b"STOP"),
            forged_data(A, B, index, 1 << 40),
        ],
    );
    check(&s, "spoofed module and priority", (2, 0, 0, 0, 0));
    s.inject(
        "B",
        &[
            plain_data((C, PLAN), (B, ACT), 100, 1, 1, &[1]),
            forged_data(STRANGER, B, 1, 1),
            forged_data(C, B, 7, 1), // (simulated sessions have indices 1 and 2)
        ],
    );
    check(&s, "C → B is X, and a stranger", (1, 0, 0, 1, 1));
    s.inject("B", &data);
    check(&s, "replays", (0, 3, 0, 0, 0));
    let f = &data[2];
    s.inject(
        "B",
        &[
            flipped(f, 20 + 48),     // payload
            flipped(f, f.len() - 1), // tag
            flipped(f, 20 + 5),      // priority (encrypted header)
            flipped(f, 12),          // counter (clear, authenticated)
        ],
    );
    check(&s, "tampered payload and header", (4, 0, 0, 0, 0));
    s.exchange(3);
}

/// The attacker knows A's incarnation and next sequence numbers and the session index: 20 000
/// unsecured frames numbered after A's last one and 2 000 sealed-looking ones with high
/// counters, then A's next 30 messages are all delivered.
#[test]
fn sequence_window_poisoning_does_not_stop_later_messages_in_simulation() {
    let mut s = Sim::open(seed(22), 0.0);
    s.exchange(1);
    let h = s.headers.0.lock().unwrap()[0];
    let index = u32::from_le_bytes(s.recorded_data()[0][8..12].try_into().unwrap());
    let before = s.rejected(&s.b);
    let mut flood: Vec<Vec<u8>> = (1..=20_000)
        .map(|k| plain_data((A, PLAN), (B, ACT), 255, h.incarnation, h.seq + k, b"x"))
        .collect();
    flood.extend((0..2_000).map(|k| forged_data(A, B, index, (1 << 32) + k)));
    s.inject("B", &flood);
    let after = s.rejected(&s.b);
    assert_eq!(after.0 - before.0, 22_000, "seed {}", s.seed);
    assert_eq!((after.1, after.4), (before.1, before.4), "seed {}", s.seed);
    s.nothing_delivered();
    let dups = s.b.stats().router.duplicates;
    s.exchange(30);
    assert_eq!(s.b.stats().router.duplicates, dups, "seed {}", s.seed);
}

/// Every frame from A to B is lost; forged acknowledgements (unsecured, with the right
/// incarnation and sequence number; and sealed-looking) do not make A report "delivered".
#[test]
fn forged_acknowledgements_do_not_confirm_a_lost_message_in_simulation() {
    let s = Sim::open(seed(23), 100.0);
    let ticket = s.send(b"lost");
    s.run(1);
    let h = s.headers.0.lock().unwrap()[0];
    s.inject(
        "A",
        &[
            plain_ack((B, ACT), (A, PLAN), h.incarnation, h.seq),
            forged_data(B, A, 7, 0),
        ],
    );
    assert_eq!(s.rejected(&s.a), (1, 0, 0, 0, 1), "seed {}", s.seed);
    s.run(10_000);
    let o = ticket.try_outcome();
    assert!(
        matches!(o, Some(Outcome::Unconfirmed { .. })),
        "seed {}: {o:?}",
        s.seed
    );
    assert_eq!(s.a.stats().router.delivered, 0, "seed {}", s.seed);
}

/// A run's sealed frames replayed into a run with another seed open nothing: the session
/// indices are the same (simulated sessions are numbered 1 and 2), the keys are not, so they
/// fail authentication. (With the same seed the keys are the same: simulation keys are derived from
/// the seed and must never be used outside a simulation.)
#[test]
fn frames_of_another_simulated_run_are_refused() {
    let mut first = Sim::open(seed(24), 0.0);
    first.exchange(3);
    let data = first.recorded_data();
    let mut second = Sim::open(first.seed + 1, 0.0);
    second.exchange(1);
    let before = second.rejected(&second.b);
    second.inject("B", &data);
    let after = second.rejected(&second.b);
    assert_eq!(
        (after.0 - before.0, after.4 - before.4),
        (3, 0),
        "seeds {} and {}: {before:?} → {after:?}",
        first.seed,
        second.seed
    );
    second.nothing_delivered();
}

/// The same seed gives the same counters: the attacks above are deterministic.
#[test]
fn a_simulated_attack_repeats_exactly_for_a_seed() {
    let run = |seed: u64| {
        let s = Sim::open(seed, 20.0);
        s.plan
            .send_raw("B", "Act", MessageType(1), &[0], SendOptions::default())
            .unwrap();
        s.run(2_000);
        let data = s.recorded_data();
        s.inject("B", &data);
        s.inject("B", &[plain_data((A, PLAN), (B, ACT), 255, 1, 9, b"x")]);
        (
            s.rejected(&s.b),
            s.sim.net_stats(),
            s.b.stats().router.received,
        )
    };
    let s = seed(25);
    assert_eq!(run(s), run(s), "seed {s}");
}
