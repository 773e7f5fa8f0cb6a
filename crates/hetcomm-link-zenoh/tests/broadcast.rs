//! Native broadcasts over `zenoh` (docs/zenoh.md, "Broadcasts"): one put on `<prefix>/all`
//! reaches every system through a real router, every destination gets its own truthful
//! outcome, a system the table does not let the sender reach drops the put and counts it,
//! a destination on another transport gets its own copy, and a secured transport (which
//! cannot seal one frame for everybody) keeps a copy per destination.

mod common;

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use hetcomm::observe::{Observer, OutcomeRecord, SendRecord};
use hetcomm::SendId;

use hetcomm::{Comm, LocalFleet, MessageType, Outcome, SendOptions};
use hetcomm_link_zenoh::router::ZenohRouter;

/// A sends to B..E over zenoh `z`; the table says X from A to G (also on `z`, so G receives
/// the put); U is reached from A over the in-process transport `i`.
fn fleet_text(keys: &str) -> String {
    format!(
        r#"[systems]
A = 0
B = 1
C = 2
D = 3
E = 4
G = 5
U = 6
[modules]
M = 0
[transports.z]
kind = "zenoh"
{keys}
[transports.i]
kind = "inproc"
[table]
columns = ["A", "B", "C", "D", "E", "G", "U"]
A = ["X", "z", "z", "z", "z", "X", "i"]
B = ["z", "X", "z", "z", "z", "z", "X"]
C = ["z", "z", "X", "z", "z", "z", "X"]
D = ["z", "z", "z", "X", "z", "z", "X"]
E = ["z", "z", "z", "z", "X", "z", "X"]
G = ["z", "z", "z", "z", "z", "X", "X"]
U = ["i", "X", "X", "X", "X", "X", "X"]
"#
    )
}

const ZENOH_DESTS: [&str; 4] = ["B", "C", "D", "E"];

fn open(keys: &str) -> (LocalFleet, ZenohRouter) {
    let (router, endpoint) = common::router();
    let keys = format!(
        "mode = \"client\"\nconnect = [\"{endpoint}\"]\nmulticast_scouting = false\nprefix = \"{}\"\n{keys}",
        common::unique_prefix()
    );
    let fleet = hetcomm::parse_fleet(&fleet_text(&keys), "bcast.toml", None).expect("valid fleet");
    let local = LocalFleet::open(fleet).expect("open fleet");
    (local, router)
}

/// Frames A's zenoh link has put so far, and A's router's retransmissions.
fn sent_and_retransmitted(a: &Comm) -> (u64, u64) {
    let s = a.stats();
    let z = s
        .links
        .iter()
        .find(|(name, _)| name == "z")
        .map(|(_, l)| l.frames_sent)
        .expect("link z");
    (z, s.router.retransmissions)
}

/// Waits until A sees every zenoh destination (a point-to-point send waits for presence),
/// so that their subscriptions to the broadcast key have reached the router too.
fn warm_up(local: &LocalFleet) {
    let a = local.system("A").unwrap();
    let m = a.module("M").unwrap();
    for to in ZENOH_DESTS {
        let outcome = m
            .send_raw(to, "M", MessageType(1), &[0xc0], SendOptions::default())
            .unwrap()
            .wait();
        assert!(outcome.is_success(), "warm-up to {to}: {outcome}");
        local
            .system(to)
            .unwrap()
            .module("M")
            .unwrap()
            .recv_raw_timeout(Some(Duration::from_secs(5)))
            .expect("warm-up message");
    }
}

/// Broadcasts `rounds` messages from A and checks outcomes, deliveries and drops. Returns
/// how many frames A's zenoh link put for them, net of retransmissions.
fn broadcast_rounds(local: &LocalFleet, rounds: u8, success: fn(&Outcome) -> bool) -> u64 {
    let a = local.system("A").unwrap();
    let m = a.module("M").unwrap();
    let (sent_before, retx_before) = sent_and_retransmitted(&a);
    for i in 0..rounds {
        let ticket = m
            .broadcast_raw("M", MessageType(2), &[0x91, i], SendOptions::default())
            .expect("broadcast");
        let outcomes = ticket.wait();
        let names: Vec<&str> = outcomes.iter().map(|(n, _)| n.as_str()).collect();
        assert_eq!(names, ["B", "C", "D", "E", "U"], "G is X from A");
        for (name, outcome) in &outcomes {
            assert!(success(outcome), "{name}: {outcome}");
        }
    }
    for to in ZENOH_DESTS.iter().chain(&["U"]) {
        let m = local.system(to).unwrap().module("M").unwrap();
        let mut got = Vec::new();
        while got.len() < rounds as usize {
            let msg = m
                .recv_raw_timeout(Some(Duration::from_secs(5)))
                .unwrap_or_else(|e| panic!("{to} after {} messages: {e:?}", got.len()));
            got.push(msg.payload[1]);
        }
        got.sort_unstable();
        assert_eq!(got, (0..rounds).collect::<Vec<u8>>(), "{to}");
        // Nothing more: no message delivered twice.
        assert!(
            m.recv_raw_timeout(Some(Duration::from_millis(100)))
                .is_err(),
            "{to} got a message twice"
        );
    }
    let (sent_after, retx_after) = sent_and_retransmitted(&a);
    (sent_after - sent_before) - (retx_after - retx_before)
}

/// G is on the zenoh transport but X from A: it receives every put and drops it, counted.
fn g_dropped(local: &LocalFleet, rounds: u64) {
    let g = local.system("G").unwrap();
    let deadline = Instant::now() + Duration::from_secs(5);
    while g.stats().router.misrouted < rounds {
        assert!(Instant::now() < deadline, "{:?}", g.stats().router);
        std::thread::sleep(Duration::from_millis(20));
    }
    assert_eq!(g.stats().router.misrouted, rounds);
    assert!(g
        .module("M")
        .unwrap()
        .recv_raw_timeout(Some(Duration::from_millis(100)))
        .is_err());
}

/// The ids of the sends and outcomes an observer of A sees.
#[derive(Default)]
struct Ids {
    sends: Mutex<Vec<SendId>>,
    outcomes: Mutex<Vec<SendId>>,
}

impl Observer for Ids {
    fn on_send(&self, r: &SendRecord<'_>) {
        self.sends.lock().unwrap().push(r.id());
    }
    fn on_outcome(&self, r: &OutcomeRecord<'_>) {
        self.outcomes.lock().unwrap().push(r.id);
    }
}

#[test]
fn one_put_reaches_every_system_and_each_destination_is_delivered() {
    let (local, _router) = open("security = \"none\"");
    warm_up(&local);
    let ids = Arc::new(Ids::default());
    let _observing = local.system("A").unwrap().observe(ids.clone());
    let rounds = 20;
    let puts = broadcast_rounds(&local, rounds, |o| matches!(o, Outcome::Delivered { .. }));
    // One put per broadcast for the four zenoh destinations (a copy each would be 80).
    assert_eq!(puts, rounds as u64);
    g_dropped(&local, rounds as u64);
    let s = local.system("B").unwrap().stats().router;
    assert_eq!((s.malformed, s.misrouted), (0, 0), "{s:?}");
    // Observers see the one frame as a send per destination, each matching its outcome.
    let (mut sends, mut outcomes) = (
        ids.sends.lock().unwrap().clone(),
        ids.outcomes.lock().unwrap().clone(),
    );
    sends.sort();
    outcomes.sort();
    assert_eq!(sends.len(), 5 * rounds as usize);
    assert_eq!(sends, outcomes);
    assert_eq!(sends.iter().filter(|id| id.is_broadcast()).count(), 80);
}

#[test]
fn an_unacknowledged_broadcast_is_one_put_sent_without_confirmation() {
    let (local, _router) = open("security = \"none\"\ndelivery = \"unacknowledged\"");
    warm_up(&local);
    let rounds = 20;
    let puts = broadcast_rounds(&local, rounds, |o| {
        // U is acknowledged (its transport's default).
        matches!(o, Outcome::Sent { attempts: 1 } | Outcome::Delivered { .. })
    });
    assert_eq!(puts, rounds as u64);
    g_dropped(&local, rounds as u64);
}

#[test]
fn a_secured_transport_sends_a_copy_per_destination() {
    // No `security = "none"`: LocalFleet makes keys for the run.
    let (local, _router) = open("");
    warm_up(&local);
    let rounds = 5;
    let puts = broadcast_rounds(&local, rounds, |o| matches!(o, Outcome::Delivered { .. }));
    assert_eq!(
        puts,
        4 * rounds as u64,
        "one sealed copy per zenoh destination"
    );
    // G never hears of them: the copies go to their destinations only.
    let g = local.system("G").unwrap().stats();
    assert_eq!(g.router.misrouted, 0);
}
