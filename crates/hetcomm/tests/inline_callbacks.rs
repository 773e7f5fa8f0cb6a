//! `Module::set_inline_callbacks`: callbacks run at the delivery, on the delivering thread
//! (the sender's for an in-process link, the socket's reader for UDP) instead of the module's
//! callback thread; an in-process ping–pong between two inline modules does not recurse.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use hetcomm::{LocalFleet, MessageType, Module, Outcome};

mod common;

const TY: MessageType = MessageType(1);

/// A and B on one transport of `kind` (`udp` on loopback, or `inproc`), acknowledged.
fn fleet(kind: &str) -> LocalFleet {
    let endpoints = match kind {
        "udp" => format!(
            "endpoints = {{ A = \"127.0.0.1:{}\", B = \"127.0.0.1:{}\" }}\nsecurity = \"none\"",
            common::free_udp_port(),
            common::free_udp_port()
        ),
        _ => String::new(),
    };
    let text = format!(
        r#"
[systems]
A = 0
B = 1
[modules]
M = 0
[transports.t]
kind = "{kind}"
delivery = "acknowledged"
{endpoints}
[table]
columns = ["A", "B"]
A = ["X", "t"]
B = ["t", "X"]
"#
    );
    LocalFleet::open(hetcomm::config::parse_str(&text, "inline.toml", None).unwrap()).unwrap()
}

/// The names of the threads `m`'s callbacks ran on, for `n` messages sent by `from`.
fn callback_threads(from: &Module, m: &Module, n: usize) -> Vec<String> {
    let names = Arc::new(Mutex::new(Vec::new()));
    let seen = names.clone();
    m.on_raw(TY, move |_| {
        let name = std::thread::current().name().unwrap_or("").to_string();
        seen.lock().unwrap().push(name);
    });
    for _ in 0..n {
        let outcome = from
            .send_raw("B", "M", TY, b"x", Default::default())
            .unwrap()
            .wait();
        assert!(matches!(outcome, Outcome::Delivered { .. }), "{outcome:?}");
    }
    let deadline = Instant::now() + Duration::from_secs(5);
    while names.lock().unwrap().len() < n {
        assert!(Instant::now() < deadline, "callbacks missing");
        std::thread::sleep(Duration::from_millis(1));
    }
    let names = names.lock().unwrap().clone();
    names
}

#[test]
fn inline_callbacks_run_on_the_senders_thread_in_process() {
    let f = fleet("inproc");
    let a = f.system("A").unwrap().module("M").unwrap();
    let b = f.system("B").unwrap().module("M").unwrap();
    b.set_inline_callbacks(true);
    let here = std::thread::current().name().unwrap_or("").to_string();
    let names = std::thread::scope(|s| {
        s.spawn(|| {
            let me = std::thread::current().name().unwrap_or("").to_string();
            (me, callback_threads(&a, &b, 10))
        })
        .join()
        .unwrap()
    });
    assert!(names.1.iter().all(|n| *n == names.0), "{names:?} ({here})");
}

#[test]
fn callbacks_run_on_the_callback_thread_unless_inline() {
    for kind in ["inproc", "udp"] {
        let f = fleet(kind);
        let a = f.system("A").unwrap().module("M").unwrap();
        let b = f.system("B").unwrap().module("M").unwrap();
        let names = callback_threads(&a, &b, 10);
        assert!(
            names.iter().all(|n| n == "hetcomm-cb-M"),
            "{kind}: {names:?}"
        );
    }
}

#[test]
fn inline_callbacks_run_on_the_udp_reader() {
    let f = fleet("udp");
    let a = f.system("A").unwrap().module("M").unwrap();
    let b = f.system("B").unwrap().module("M").unwrap();
    b.set_inline_callbacks(true);
    // Nobody waits in B's `recv`: B's background thread reads the socket and runs them.
    let names = callback_threads(&a, &b, 10);
    assert!(
        names
            .iter()
            .all(|n| n != "hetcomm-cb-M" && n.starts_with("hetcomm")),
        "{names:?}"
    );
}

/// A and B echo a counter to each other from inline callbacks until it reaches `LAST`: each
/// send delivers on the sending thread, where the other module's callback would send again.
/// The nested one goes to the callback thread instead, so the chain ends without recursing
/// and every step arrives once, in order.
#[test]
fn an_in_process_ping_pong_of_inline_callbacks_does_not_recurse() {
    const LAST: u64 = 2000;
    let f = fleet("inproc");
    let seen = Arc::new(AtomicU64::new(0));
    let mut modules = Vec::new();
    for (me, other) in [("A", "B"), ("B", "A")] {
        let m = f.system(me).unwrap().module("M").unwrap();
        let sender = f.system(me).unwrap().module("M").unwrap();
        m.set_inline_callbacks(true);
        let seen = seen.clone();
        m.on_raw(TY, move |msg| {
            let n = u64::from_le_bytes(msg.payload[..8].try_into().unwrap());
            assert_eq!(seen.fetch_add(1, Ordering::SeqCst), n, "out of order");
            if n < LAST {
                let next = (n + 1).to_le_bytes();
                let _ = sender.send_raw(other, "M", TY, &next, Default::default());
            }
        });
        modules.push(m);
    }
    modules[0]
        .send_raw("B", "M", TY, &0u64.to_le_bytes(), Default::default())
        .unwrap();
    let deadline = Instant::now() + Duration::from_secs(20);
    while seen.load(Ordering::SeqCst) <= LAST {
        assert!(
            Instant::now() < deadline,
            "stuck at {}",
            seen.load(Ordering::SeqCst)
        );
        std::thread::sleep(Duration::from_millis(2));
    }
    assert_eq!(seen.load(Ordering::SeqCst), LAST + 1);
    let failures: u64 = ["A", "B"]
        .iter()
        .map(|s| f.system(s).unwrap().stats().callback_failures)
        .sum();
    assert_eq!(failures, 0);
}
