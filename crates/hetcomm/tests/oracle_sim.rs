//! The outcome oracle's second harness: whole systems in the virtual-time simulator, over an
//! emulated radio that loses, duplicates, reorders and delays frames, into bounded inboxes
//! under every overflow policy, with native broadcasts, ordered and unordered delivery, and
//! sealed or plain links. Every message is read back from its inbox; each send's outcome is
//! judged against what was read:
//!
//! - every send has exactly one outcome;
//! - *delivered* ⇒ read from the destination's inbox exactly once (under `drop-oldest`, an
//!   evicted message was delivered but is never read: there the counts must balance instead);
//! - *failed* ⇒ never read;
//! - *sent* only on unacknowledged transports, *unconfirmed* only on acknowledged ones;
//! - nothing read twice; inbox and router counters balance.
//!
//! A failing schedule prints its parameters, seed included, and a shrunk schedule that still
//! fails. `HETCOMM_ORACLE_SIM_SCHEDULES` runs more of them.

use std::collections::BTreeMap;
use std::time::Duration;

use hetcomm::sim::{LossVisibility, SimFleet, SimOptions};
use hetcomm::{Message, Outcome, Ticket, Time};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

#[derive(Serialize, Deserialize, Message, Debug, Clone, PartialEq)]
#[message(id = 3)]
struct Tagged {
    tag: u64,
}

/// One schedule; the same value always gives the same run.
#[derive(Clone, Debug, PartialEq)]
struct Params {
    seed: u64,
    systems: usize,
    sends: u32,
    loss_percent: f64,
    duplicate_percent: f64,
    reorder_percent: f64,
    jitter_ms: f64,
    acknowledged: bool,
    ordered: bool,
    attempts: u32,
    inbox_capacity: usize,
    overflow: &'static str,
    broadcast: f64,
    secure: bool,
    /// Chance per step that a system reads its inbox (else it lets it fill).
    read: f64,
}

impl Params {
    fn random(seed: u64, sends: u32) -> Params {
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x5851_f42d_4c95_7f2d);
        let pick = |rng: &mut ChaCha8Rng, xs: &[f64]| xs[rng.gen_range(0..xs.len())];
        Params {
            seed,
            systems: rng.gen_range(2..=4),
            sends,
            loss_percent: pick(&mut rng, &[0.0, 5.0, 20.0, 40.0]),
            duplicate_percent: pick(&mut rng, &[0.0, 10.0]),
            reorder_percent: pick(&mut rng, &[0.0, 20.0]),
            jitter_ms: pick(&mut rng, &[0.0, 2.0, 20.0]),
            acknowledged: rng.gen_bool(0.7),
            ordered: rng.gen_bool(0.4),
            attempts: rng.gen_range(1..=8),
            inbox_capacity: [2, 8, 1024][rng.gen_range(0..3)],
            overflow: ["drop-newest", "block", "drop-oldest"][rng.gen_range(0..3)],
            broadcast: pick(&mut rng, &[0.0, 0.1]),
            secure: rng.gen_bool(0.3),
            read: pick(&mut rng, &[0.2, 0.9]),
        }
    }

    fn fleet_text(&self) -> String {
        let names: Vec<String> = (0..self.systems).map(|i| format!("S{i}")).collect();
        let mut text = String::from("[systems]\n");
        for (i, n) in names.iter().enumerate() {
            text += &format!("{n} = {i}\n");
        }
        text += &format!(
            "[modules]\nPlan = {{ id = 0, inbox_capacity = {}, overflow = \"{}\" }}\n",
            self.inbox_capacity, self.overflow
        );
        text += &format!(
            "[transports.radio]\nkind = \"emulated\"\ndelivery = \"{}\"\nattempts = {}\n\
             ordered = {}\nlatency_ms = 5.0\njitter_ms = {}\nloss_percent = {}\n\
             duplicate_percent = {}\nreorder_percent = {}\n",
            if self.acknowledged {
                "acknowledged"
            } else {
                "unacknowledged"
            },
            self.attempts,
            self.ordered,
            self.jitter_ms,
            self.loss_percent,
            self.duplicate_percent,
            self.reorder_percent
        );
        text += "[table]\ncolumns = [";
        text += &names
            .iter()
            .map(|n| format!("\"{n}\""))
            .collect::<Vec<_>>()
            .join(", ");
        text += "]\n";
        for (i, n) in names.iter().enumerate() {
            let row: Vec<&str> = (0..self.systems)
                .map(|j| if i == j { "\"X\"" } else { "\"radio\"" })
                .collect();
            text += &format!("{n} = [{}]\n", row.join(", "));
        }
        text
    }
}

/// Outcomes of a run, by kind: delivered, sent, unconfirmed, failed.
type Tally = [u64; 4];

/// Runs one schedule; returns its falsehoods.
fn judge(p: &Params) -> Vec<String> {
    judge_counting(p).0
}

/// [`judge`], with the outcomes it saw.
fn judge_counting(p: &Params) -> (Vec<String>, Tally) {
    let mut tally = [0; 4];
    let mut fleet = hetcomm::config::parse_str(&p.fleet_text(), "oracle.toml", None)
        .expect("the oracle's fleet parses");
    fleet.secure_in_process = p.secure;
    let sim = SimFleet::open(
        fleet,
        SimOptions {
            seed: p.seed,
            losses: LossVisibility::Silent,
            timing: None,
        },
    )
    .expect("the oracle's fleet opens");
    let names: Vec<String> = (0..p.systems).map(|i| format!("S{i}")).collect();
    let modules: Vec<_> = names
        .iter()
        .map(|n| sim.system(n).unwrap().module("Plan").unwrap())
        .collect();
    let mut rng = ChaCha8Rng::seed_from_u64(p.seed);
    // (tag, destination) → the ticket.
    let mut sends: BTreeMap<(u64, String), Ticket> = BTreeMap::new();
    // (tag, reader) → times read.
    let mut read: BTreeMap<(u64, String), u32> = BTreeMap::new();
    let mut wrong = Vec::new();
    let drain = |i: usize, read: &mut BTreeMap<(u64, String), u32>, wrong: &mut Vec<String>| loop {
        match modules[i].try_recv::<Tagged>() {
            Ok(Some(r)) => *read.entry((r.message.tag, names[i].clone())).or_default() += 1,
            Ok(None) => return,
            Err(e) => {
                wrong.push(format!("{} could not read: {e}", names[i]));
                return;
            }
        }
    };
    for tag in 0..u64::from(p.sends) {
        let from = rng.gen_range(0..p.systems);
        let msg = Tagged { tag };
        if rng.gen_bool(p.broadcast) {
            match modules[from].broadcast("Plan", &msg) {
                Ok(b) => {
                    for t in b.tickets() {
                        sends.insert((tag, t.destination().to_string()), t.clone());
                    }
                }
                Err(e) => wrong.push(format!("broadcast {tag} refused: {e}")),
            }
        } else {
            let mut to = rng.gen_range(0..p.systems - 1);
            if to >= from {
                to += 1;
            }
            match modules[from].send(&names[to], "Plan", &msg) {
                Ok(t) => {
                    sends.insert((tag, names[to].clone()), t);
                }
                Err(e) => wrong.push(format!("send {tag} refused: {e}")),
            }
        }
        sim.run_until(sim.now() + Duration::from_micros(rng.gen_range(0..3_000)));
        for i in 0..p.systems {
            if rng.gen_bool(p.read) {
                drain(i, &mut read, &mut wrong);
            }
        }
    }
    // Let every retransmission and hold run out, reading as messages come.
    for _ in 0..200 {
        sim.run_until(sim.now() + Duration::from_millis(100));
        for i in 0..p.systems {
            drain(i, &mut read, &mut wrong);
        }
    }
    sim.run_idle(Time::from_secs_f64(sim.now().as_secs_f64() + 3600.0));
    for i in 0..p.systems {
        drain(i, &mut read, &mut wrong);
    }
    for ((tag, reader), n) in &read {
        if *n > 1 {
            wrong.push(format!("message {tag} read {n} times by {reader}"));
        }
    }
    let evicting = p.overflow == "drop-oldest";
    let mut delivered = 0;
    for ((tag, to), ticket) in &sends {
        let got = read.get(&(*tag, to.clone())).copied().unwrap_or(0);
        let Some(outcome) = ticket.try_outcome() else {
            wrong.push(format!("send {tag} to {to}: no outcome"));
            continue;
        };
        let lie = match &outcome {
            Outcome::Delivered { .. } if !p.acknowledged => Some("delivered without an ack"),
            Outcome::Delivered { .. } if got == 0 && !evicting => Some("delivered, never read"),
            Outcome::Failed { .. } if got > 0 => Some("failed, but read"),
            Outcome::Sent { .. } if p.acknowledged => Some("sent on an acknowledged transport"),
            Outcome::Unconfirmed { .. } if !p.acknowledged => Some("unconfirmed, unacknowledged"),
            _ => None,
        };
        tally[match outcome {
            Outcome::Delivered { .. } => 0,
            Outcome::Sent { .. } | Outcome::Relayed { .. } => 1,
            Outcome::Unconfirmed { .. } => 2,
            Outcome::Failed { .. } => 3,
        }] += 1;
        if matches!(outcome, Outcome::Delivered { .. }) {
            delivered += 1;
        }
        if let Some(lie) = lie {
            wrong.push(format!("send {tag} to {to}: {lie}: {outcome}"));
        }
    }
    let (mut accepted, mut taken, mut evicted) = (0, 0, 0);
    for (i, m) in modules.iter().enumerate() {
        let s = m.inbox_stats();
        if s.accepted != s.taken + s.dropped_oldest + s.len as u64 {
            wrong.push(format!("{}'s inbox counts do not balance: {s:?}", names[i]));
        }
        accepted += s.accepted;
        taken += s.taken;
        evicted += s.dropped_oldest;
    }
    let total_read: u64 = read.values().map(|n| u64::from(*n)).sum();
    if taken != total_read {
        wrong.push(format!(
            "inboxes say {taken} taken, the readers read {total_read}"
        ));
    }
    if p.acknowledged && delivered > accepted {
        wrong.push(format!(
            "{delivered} delivered outcomes, only {accepted} accepted ({evicted} evicted)"
        ));
    }
    for (i, c) in sim.systems().iter().enumerate() {
        let r = c.stats().router;
        if r.in_flight() != 0 {
            wrong.push(format!(
                "{} still has {} in flight",
                names[i],
                r.in_flight()
            ));
        }
    }
    (wrong, tally)
}

fn shrink(mut failing: Params) -> Params {
    let still_fails = |p: &Params| !judge(p).is_empty();
    loop {
        let mut candidates = Vec::new();
        if failing.sends > 1 {
            candidates.push(Params {
                sends: failing.sends / 2,
                ..failing.clone()
            });
        }
        if failing.systems > 2 {
            candidates.push(Params {
                systems: failing.systems - 1,
                ..failing.clone()
            });
        }
        let off: [fn(&mut Params); 7] = [
            |p| p.loss_percent = 0.0,
            |p| p.duplicate_percent = 0.0,
            |p| p.reorder_percent = 0.0,
            |p| p.jitter_ms = 0.0,
            |p| p.broadcast = 0.0,
            |p| p.secure = false,
            |p| p.ordered = false,
        ];
        for f in off {
            let mut p = failing.clone();
            f(&mut p);
            if p != failing {
                candidates.push(p);
            }
        }
        match candidates.into_iter().find(still_fails) {
            Some(smaller) => failing = smaller,
            None => return failing,
        }
    }
}

#[test]
fn every_outcome_of_simulated_systems_is_true() {
    let schedules = std::env::var("HETCOMM_ORACLE_SIM_SCHEDULES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(24u64);
    let first = std::env::var("HETCOMM_SEED")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(0u64);
    let mut total: Tally = [0; 4];
    for seed in first..first + schedules {
        let params = Params::random(seed, 150);
        let (wrong, tally) = judge_counting(&params);
        for (t, n) in total.iter_mut().zip(tally) {
            *t += n;
        }
        if !wrong.is_empty() {
            let small = shrink(params.clone());
            panic!(
                "the simulated oracle caught false outcomes with seed {seed} \
                 (HETCOMM_SEED={seed} HETCOMM_ORACLE_SIM_SCHEDULES=1 reruns it)\n\
                 schedule: {params:?}\n{}\nshrunk to: {small:?}\nwhich says: {}",
                wrong[..wrong.len().min(5)].join("\n"),
                judge(&small)[..].join("\n")
            );
        }
    }
    let [delivered, sent, unconfirmed, failed] = total;
    println!(
        "{schedules} schedules: {delivered} delivered, {sent} sent, {unconfirmed} unconfirmed, \
         {failed} failed, every one true"
    );
    if schedules >= 24 {
        // The schedules must reach every kind of outcome, or they test less than they claim.
        assert!(
            delivered > 1000 && sent > 100 && unconfirmed > 0 && failed > 0,
            "{total:?}"
        );
    }
}
