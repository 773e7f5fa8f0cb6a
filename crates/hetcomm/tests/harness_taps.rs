//! Harness taps (`hetcomm::harness`): every action — observe, drop, delay, duplicate, modify,
//! replace — on a message path between systems and on a topic path inside one, in real time
//! (in-process hand-over, and UDP frames through the router) and in virtual time, with the
//! same expectations in each. The receiving module uses the ordinary API throughout: it
//! cannot tell a tap is there.

mod common;

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use hetcomm::sim::{SimFleet, SimOptions};
use hetcomm::{Comm, LocalFleet, Message, Module, Outcome, TapAction, TapPath, TapVerdict, Time};
use serde::{Deserialize, Serialize};

#[derive(Serialize, Deserialize, Message, Debug, Clone, PartialEq)]
#[message(id = 40)]
struct Cmd {
    code: u32,
}

const INPROC: &str = r#"
[systems]
A = 0
B = 1
[modules]
Plan = 0
Act = 1
[transports.net]
kind = "inproc"
[table]
columns = ["A", "B"]
A = ["X", "net"]
B = ["net", "X"]
"#;

/// Where the systems run.
enum Env {
    Real(LocalFleet),
    Sim(SimFleet),
}

impl Env {
    fn real(text: &str) -> Env {
        Env::Real(LocalFleet::open(hetcomm::parse_fleet(text, "taps.toml", None).unwrap()).unwrap())
    }
    fn sim(text: &str) -> Env {
        Env::Sim(
            SimFleet::open(
                hetcomm::parse_fleet(text, "taps.toml", None).unwrap(),
                SimOptions::default(),
            )
            .unwrap(),
        )
    }
    fn all(text: &str) -> Vec<(&'static str, Env)> {
        vec![
            ("real time, in-process", Env::real(INPROC)),
            ("real time, udp", Env::real(text)),
            ("virtual time", Env::sim(INPROC)),
        ]
    }
    fn system(&self, name: &str) -> Comm {
        match self {
            Env::Real(f) => f.system(name).unwrap(),
            Env::Sim(s) => s.system(name).unwrap(),
        }
    }
    fn now(&self) -> Time {
        match self {
            Env::Real(_) => Time::now_mono(),
            Env::Sim(s) => s.now(),
        }
    }
    /// Lets `d` pass: virtual time moves; real time sleeps.
    fn pass(&self, d: Duration) {
        match self {
            Env::Real(_) => std::thread::sleep(d),
            Env::Sim(s) => s.run_until(s.now() + d),
        }
    }
    /// Takes what `m` has, waiting up to `d` (real time) or running `d` of virtual time.
    fn take(&self, m: &Module, n: usize, d: Duration) -> Vec<Cmd> {
        let mut got = Vec::new();
        let (wall, virt) = (Instant::now(), self.now());
        loop {
            if let Env::Sim(s) = self {
                s.run_until(s.now() + Duration::from_millis(10));
            }
            while let Some(r) = m.try_recv::<Cmd>().unwrap() {
                got.push(r.message);
            }
            let out = match self {
                Env::Real(_) => wall.elapsed() >= d,
                Env::Sim(s) => s.now().saturating_since(virt) >= d,
            };
            if got.len() >= n || out {
                return got;
            }
            if let Env::Real(_) = self {
                std::thread::sleep(Duration::from_millis(2));
            }
        }
    }
}

fn udp() -> String {
    common::udp_pair_text("", "Plan = 0\nAct = 1", "security = \"none\"")
}

fn send(env: &Env, plan: &Module, code: u32) -> Outcome {
    let t = plan.send("B", "Act", &Cmd { code }).unwrap();
    if let Env::Sim(s) = env {
        s.run_until(s.now() + Duration::from_millis(50));
    }
    t.wait_timeout(Duration::from_secs(5)).expect("an outcome")
}

fn path() -> TapPath {
    TapPath::messages("B").from("A").module("Act")
}

#[test]
fn observe_sees_every_message_and_changes_nothing() {
    for (name, env) in Env::all(&udp()) {
        let (a, b) = (env.system("A"), env.system("B"));
        let seen = Arc::new(AtomicU64::new(0));
        let s = seen.clone();
        let _tap = b
            .tap(
                &path(),
                TapAction::observe(move |m| {
                    assert_eq!(m.decode::<Cmd>().unwrap().unwrap().code % 10, 7);
                    s.fetch_add(1, Ordering::Relaxed);
                }),
            )
            .unwrap();
        let (plan, act) = (a.module("Plan").unwrap(), b.module("Act").unwrap());
        for i in 0..5 {
            assert!(
                matches!(send(&env, &plan, i * 10 + 7), Outcome::Delivered { .. }),
                "{name}"
            );
        }
        let got = env.take(&act, 5, Duration::from_secs(2));
        assert_eq!(
            got.iter().map(|c| c.code).collect::<Vec<_>>(),
            [7, 17, 27, 37, 47],
            "{name}"
        );
        assert_eq!(seen.load(Ordering::Relaxed), 5, "{name}");
        assert_eq!(b.harness_stats().tapped, 5, "{name}");
    }
}

#[test]
fn drop_discards_and_counts_and_removing_the_tap_restores_the_path() {
    for (name, env) in Env::all(&udp()) {
        let (a, b) = (env.system("A"), env.system("B"));
        let tap = b.tap(&path(), TapAction::Drop).unwrap();
        let (plan, act) = (a.module("Plan").unwrap(), b.module("Act").unwrap());
        for i in 0..3 {
            // The system received it: the sender's outcome says so; the harness dropped it.
            assert!(
                matches!(send(&env, &plan, i), Outcome::Delivered { .. }),
                "{name}"
            );
        }
        assert!(
            env.take(&act, 1, Duration::from_millis(200)).is_empty(),
            "{name}"
        );
        assert_eq!(b.harness_stats().dropped, 3, "{name}");
        tap.remove();
        send(&env, &plan, 99);
        assert_eq!(
            env.take(&act, 1, Duration::from_secs(2)),
            [Cmd { code: 99 }],
            "{name}"
        );
    }
}

#[test]
fn delay_holds_a_message_back_for_its_time() {
    for (name, env) in Env::all(&udp()) {
        let (a, b) = (env.system("A"), env.system("B"));
        let _tap = b
            .tap(&path(), TapAction::Delay(Duration::from_millis(300)))
            .unwrap();
        let (plan, act) = (a.module("Plan").unwrap(), b.module("Act").unwrap());
        let t0 = env.now();
        send(&env, &plan, 5);
        env.pass(Duration::from_millis(100));
        assert!(
            act.try_recv::<Cmd>().unwrap().is_none(),
            "{name}: too early"
        );
        let got = env.take(&act, 1, Duration::from_secs(2));
        assert_eq!(got, [Cmd { code: 5 }], "{name}");
        let waited = env.now().saturating_since(t0);
        assert!(
            waited >= Duration::from_millis(300),
            "{name}: after {waited:?}"
        );
        assert_eq!(b.harness_stats().delayed, 1, "{name}");
    }
}

#[test]
fn duplicate_delivers_extra_copies() {
    for (name, env) in Env::all(&udp()) {
        let (a, b) = (env.system("A"), env.system("B"));
        let _tap = b.tap(&path(), TapAction::Duplicate(2)).unwrap();
        let (plan, act) = (a.module("Plan").unwrap(), b.module("Act").unwrap());
        send(&env, &plan, 8);
        let got = env.take(&act, 3, Duration::from_secs(2));
        assert_eq!(got, vec![Cmd { code: 8 }; 3], "{name}");
        assert_eq!(b.harness_stats().duplicated, 2, "{name}");
    }
}

#[test]
fn modify_changes_the_payload_with_a_user_function() {
    for (name, env) in Env::all(&udp()) {
        let (a, b) = (env.system("A"), env.system("B"));
        let _tap = b
            .tap(
                &path(),
                TapAction::modify(|m| {
                    let mut c: Cmd = m.decode().unwrap().unwrap();
                    if c.code == 13 {
                        return TapVerdict::Drop;
                    }
                    c.code *= 2;
                    m.encode(&c).unwrap();
                    TapVerdict::Pass
                }),
            )
            .unwrap();
        let (plan, act) = (a.module("Plan").unwrap(), b.module("Act").unwrap());
        for c in [1, 13, 21] {
            send(&env, &plan, c);
        }
        let got = env.take(&act, 2, Duration::from_secs(2));
        assert_eq!(got, [Cmd { code: 2 }, Cmd { code: 42 }], "{name}");
        let s = b.harness_stats();
        assert_eq!((s.modified, s.dropped), (2, 1), "{name}");
    }
}

#[test]
fn replace_discards_the_real_source_and_injects_as_if_from_it() {
    for (name, env) in Env::all(&udp()) {
        let (a, b) = (env.system("A"), env.system("B"));
        let (plan, act) = (a.module("Plan").unwrap(), b.module("Act").unwrap());
        let replacement = b.replace(&path()).unwrap();
        send(&env, &plan, 1);
        replacement.inject(&Cmd { code: 500 }).unwrap();
        let got = act
            .try_recv::<Cmd>()
            .unwrap()
            .expect("the injected message");
        assert_eq!(got.message, Cmd { code: 500 }, "{name}");
        assert_eq!(
            got.envelope.source_system, "A",
            "{name}: looks as from the real source"
        );
        assert!(
            env.take(&act, 1, Duration::from_millis(200)).is_empty(),
            "{name}"
        );
        assert_eq!(b.harness_stats().replaced, 1, "{name}");
        // A second replacement of the same path at once is refused.
        assert!(b.replace(&path()).is_err(), "{name}");
        replacement.end();
        send(&env, &plan, 2);
        assert_eq!(
            env.take(&act, 1, Duration::from_secs(2)),
            [Cmd { code: 2 }],
            "{name}"
        );
    }
}

#[test]
fn taps_on_a_topic_act_before_its_subscribers() {
    for (name, env) in [
        ("real time", Env::real(INPROC)),
        ("virtual time", Env::sim(INPROC)),
    ] {
        let b = env.system("B");
        let (plan, act) = (b.node("Plan").unwrap(), b.node("Act").unwrap());
        let publisher = plan.advertise::<Cmd>("cmd").unwrap();
        let sub = act.subscribe::<Cmd>("cmd").unwrap();
        let topic = TapPath::topic("B", "cmd");
        {
            let _t = b
                .tap(
                    &topic,
                    TapAction::modify(|m| {
                        let c = m.value::<Cmd>().unwrap().code;
                        m.set_value(Cmd { code: c + 1 });
                        TapVerdict::Duplicate(1)
                    }),
                )
                .unwrap();
            publisher.publish(Cmd { code: 1 }).unwrap();
            assert_eq!(sub.try_recv().unwrap().code, 2, "{name}");
            assert_eq!(sub.try_recv().unwrap().code, 2, "{name}");
        }
        {
            let _t = b.tap(&topic, TapAction::Drop).unwrap();
            publisher.publish(Cmd { code: 3 }).unwrap();
            assert!(sub.try_recv().is_none(), "{name}");
        }
        {
            let _t = b
                .tap(&topic, TapAction::Delay(Duration::from_millis(200)))
                .unwrap();
            publisher.publish(Cmd { code: 4 }).unwrap();
            assert!(sub.try_recv().is_none(), "{name}");
            env.pass(Duration::from_millis(250));
            assert_eq!(sub.try_recv().map(|c| c.code), Some(4), "{name}");
        }
        {
            let r = b.replace(&topic).unwrap();
            publisher.publish(Cmd { code: 5 }).unwrap();
            r.publish(Cmd { code: 77 }).unwrap();
            assert_eq!(sub.try_recv().map(|c| c.code), Some(77), "{name}");
            assert!(sub.try_recv().is_none(), "{name}");
        }
        publisher.publish(Cmd { code: 6 }).unwrap();
        assert_eq!(sub.try_recv().map(|c| c.code), Some(6), "{name}");
        let s = b.harness_stats();
        assert_eq!(
            (
                s.modified,
                s.duplicated,
                s.dropped,
                s.delayed,
                s.replaced,
                s.injected
            ),
            (1, 1, 1, 1, 1, 1),
            "{name}"
        );
    }
}

#[test]
fn a_tap_on_a_path_that_does_not_exist_is_refused() {
    let env = Env::real(INPROC);
    let b = env.system("B");
    let err = b
        .tap(&TapPath::messages("B").from("Z"), TapAction::Drop)
        .unwrap_err();
    assert!(err.to_string().contains("no system `Z`"), "{err}");
    let err = b
        .tap(&TapPath::messages("B").module("Nope"), TapAction::Drop)
        .unwrap_err();
    assert!(err.to_string().contains("no module `Nope`"), "{err}");
    let err = b.tap(&TapPath::messages("A"), TapAction::Drop).unwrap_err();
    assert!(err.to_string().contains("acts at system `A`"), "{err}");
}

#[test]
fn a_tap_function_may_send_through_another_tapped_system() {
    for (name, env) in [
        ("real time", Env::real(INPROC)),
        ("virtual time", Env::sim(INPROC)),
    ] {
        let (a, b) = (env.system("A"), env.system("B"));
        let seen_at_a = Arc::new(AtomicU64::new(0));
        let s = seen_at_a.clone();
        let _at_a = a
            .tap(
                &TapPath::messages("A"),
                TapAction::observe(move |_| {
                    s.fetch_add(1, Ordering::Relaxed);
                }),
            )
            .unwrap();
        // B echoes every message it sees back to A, from inside its tap.
        let echo = b.module("Plan").unwrap();
        let _at_b = b
            .tap(
                &path(),
                TapAction::observe(move |m| {
                    let c: Cmd = m.decode().unwrap().unwrap();
                    echo.send("A", "Act", &Cmd { code: c.code + 1 }).unwrap();
                }),
            )
            .unwrap();
        let plan = a.module("Plan").unwrap();
        send(&env, &plan, 1);
        send(&env, &plan, 10);
        let back = env.take(&a.module("Act").unwrap(), 2, Duration::from_secs(2));
        assert_eq!(back, [Cmd { code: 2 }, Cmd { code: 11 }], "{name}");
        assert_eq!(seen_at_a.load(Ordering::Relaxed), 2, "{name}");
        assert_eq!(
            env.take(&b.module("Act").unwrap(), 2, Duration::from_secs(2))
                .len(),
            2,
            "{name}"
        );
    }
}

/// Taps written in the fleet file: dropping A's messages to B.Act, delaying those to B.Plan
/// by 300 ms, and observing B's topic `cmd`.
const FLEET_TAPS: &str = r#"
[[tap]]
to = "B"
from = "A"
module = "Act"
type = 40
action = "drop"

[[tap]]
to = "B"
module = "Plan"
action = "delay"
delay_ms = 300

[[tap]]
system = "B"
topic = "cmd"
action = "observe"
"#;

#[test]
fn taps_from_the_fleet_file_act_from_the_start_in_real_and_virtual_time() {
    let envs = [
        (
            "real time, in-process",
            Env::real(&format!("{INPROC}{FLEET_TAPS}")),
        ),
        (
            "real time, udp",
            Env::real(&format!("{}{FLEET_TAPS}", udp())),
        ),
        ("virtual time", Env::sim(&format!("{INPROC}{FLEET_TAPS}"))),
    ];
    for (name, env) in envs {
        let (a, b) = (env.system("A"), env.system("B"));
        let plan = a.module("Plan").unwrap();
        let (b_plan, b_act) = (b.module("Plan").unwrap(), b.module("Act").unwrap());
        // Dropped at B (B received it: the sender's outcome says so).
        assert!(
            matches!(send(&env, &plan, 1), Outcome::Delivered { .. }),
            "{name}"
        );
        assert!(
            env.take(&b_act, 1, Duration::from_millis(200)).is_empty(),
            "{name}"
        );
        // Delayed by 300 ms.
        let t0 = env.now();
        let ticket = plan.send("B", "Plan", &Cmd { code: 2 }).unwrap();
        env.pass(Duration::from_millis(100));
        assert!(
            b_plan.try_recv::<Cmd>().unwrap().is_none(),
            "{name}: too early"
        );
        assert_eq!(
            env.take(&b_plan, 1, Duration::from_secs(2)),
            [Cmd { code: 2 }],
            "{name}"
        );
        assert!(
            env.now().saturating_since(t0) >= Duration::from_millis(300),
            "{name}"
        );
        assert!(ticket.try_outcome().is_some(), "{name}");
        // Observed on the topic, which still reaches its subscriber.
        let publisher = b.node("Plan").unwrap().advertise::<Cmd>("cmd").unwrap();
        let sub = b.node("Act").unwrap().subscribe::<Cmd>("cmd").unwrap();
        publisher.publish(Cmd { code: 3 }).unwrap();
        assert_eq!(sub.try_recv().map(|c| c.code), Some(3), "{name}");
        let s = b.harness_stats();
        assert_eq!((s.dropped, s.delayed, s.tapped), (1, 1, 3), "{name}");
        // A places none of them: they act at B.
        assert_eq!(a.harness_stats().tapped, 0, "{name}");
    }
}

#[test]
fn a_fleet_built_in_code_with_a_tap_that_cannot_be_placed_fails_to_open_at_its_line() {
    let mut fleet =
        hetcomm::parse_fleet(&format!("{INPROC}{FLEET_TAPS}"), "taps.toml", None).unwrap();
    // The loader refuses this; a fleet edited in code can still hold it.
    if let hetcomm::config::scenario::TapSpec::Messages { module, .. } = &mut fleet.taps[0].path {
        *module = Some("Nope".into());
    }
    let line = fleet.taps[0].line;
    let err = match LocalFleet::open(fleet) {
        Err(e) => e.to_string(),
        Ok(_) => panic!("opened with a tap on a module that does not exist"),
    };
    assert!(
        err.contains(&format!(
            "the fleet file:{line}:1: tap on A -> B.Nope type 40: no module `Nope`"
        )),
        "{err}"
    );
}

#[test]
fn many_taps_each_take_exactly_their_paths() {
    // Eleven taps on B.Act, more than the delivery gate keeps apart (eight): types 0 to 9,
    // and 26, which shares type 5's bit in the gate's filter (as does 47, untapped).
    let types: Vec<u32> = (0..10).chain([26]).collect();
    for (name, env) in [
        ("real time", Env::real(INPROC)),
        ("virtual time", Env::sim(INPROC)),
    ] {
        let (a, b) = (env.system("A"), env.system("B"));
        let counts: Vec<Arc<AtomicU64>> = types.iter().map(|_| Arc::default()).collect();
        let _taps: Vec<_> = types
            .iter()
            .zip(&counts)
            .map(|(&t, c)| {
                let c = c.clone();
                let path = TapPath::messages("B")
                    .from("A")
                    .module("Act")
                    .message_type(hetcomm::MessageType(t));
                b.tap(
                    &path,
                    TapAction::observe(move |_| {
                        c.fetch_add(1, Ordering::Relaxed);
                    }),
                )
                .unwrap()
            })
            .collect();
        let (plan, act) = (a.module("Plan").unwrap(), b.module("Act").unwrap());
        let sent = [9u32, 5, 47, 26, 9];
        for t in sent {
            plan.send_raw(
                "B",
                "Act",
                hetcomm::MessageType(t),
                &[1, 2, 3],
                Default::default(),
            )
            .unwrap();
        }
        env.pass(Duration::from_millis(50));
        let mut got = Vec::new();
        while let Some(m) = act.try_recv_raw() {
            got.push(m.envelope.header.message_type.0);
        }
        assert_eq!(got, sent, "{name}: every message arrives, in order");
        let seen: Vec<u64> = counts.iter().map(|c| c.load(Ordering::Relaxed)).collect();
        let mut want = vec![0u64; types.len()];
        want[9] = 2;
        want[5] = 1;
        want[10] = 1; // type 26
        assert_eq!(seen, want, "{name}");
        assert_eq!(
            b.harness_stats().tapped,
            4,
            "{name}: 47 went through no tap"
        );
    }
}
