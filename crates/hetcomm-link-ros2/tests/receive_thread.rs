//! `deliver_on_receive_thread = true` (Cyclone DDS): frames are delivered inside the reader's
//! listener, and a module with inline callbacks answers from there. Two processes (this test
//! binary runs itself as the peer), so that frames really come through Cyclone's receive
//! thread: a burst of acknowledged 64 KiB messages, each answered by an acknowledged 64 KiB
//! echo sent from the callback, pushes the writers past their high watermark. A write that
//! waited there for acknowledgements would wait for the very thread it blocks; the run must
//! end with every message and every echo delivered, and the echoes must have been sent on a
//! thread that is not one of hetcomm's own (the callback ran inline, on Cyclone's thread).
#![cfg(feature = "cyclone")]

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use hetcomm::{Comm, MessageType, Outcome};

/// The peer's role, selected by this environment variable (its value: the fleet text).
const CHILD: &str = "HETCOMM_RECEIVE_THREAD_CHILD";
const DATA: MessageType = MessageType(900);
const MESSAGES: usize = 200;
const SIZE: usize = 64 * 1024;

fn fleet_text() -> String {
    format!(
        r#"[systems]
A = 0
B = 1
[modules]
M = 0
[inbox]
capacity = 4096
[transports.r]
kind = "ros2"
dds = "cyclone"
deliver_on_receive_thread = true
delivery = "acknowledged"
security = "none"
domain_id = 84
namespace = "/rx_thread_{}"
[table]
columns = ["A", "B"]
A = ["X", "r"]
B = ["r", "X"]
"#,
        std::process::id()
    )
}

/// Whether the calling thread is one of hetcomm's (callback, reader or background threads).
fn on_hetcomm_thread() -> bool {
    std::thread::current()
        .name()
        .is_some_and(|n| n.starts_with("hetcomm"))
}

/// B: echoes every message back to A from an inline callback; the first payload byte of the
/// echo says whether the callback ran on a thread of hetcomm's own (1) or not (0).
fn run_echo(fleet: &str) {
    let fleet = hetcomm::parse_fleet(fleet, "child.toml", None).expect("valid fleet");
    let comm = Comm::open_fleet(&fleet, "B").expect("open B");
    let m = Arc::new(comm.module("M").unwrap());
    m.set_inline_callbacks(true);
    let echo = m.clone();
    m.on_raw(DATA, move |msg| {
        let mut payload = msg.payload.to_vec();
        payload[0] = u8::from(on_hetcomm_thread());
        // Acknowledged: its outcome arrives later; a congested first attempt is retried.
        let _ = echo.send_raw("A", "M", DATA, &payload, Default::default());
    });
    println!("ready");
    // Until the parent closes our stdin, noting the most bytes ever waiting in the link's
    // backlog (frames the callback's thread could not write at once).
    let done = Arc::new(std::sync::atomic::AtomicBool::new(false));
    let stdin_done = done.clone();
    std::thread::spawn(move || {
        let mut line = String::new();
        let _ = std::io::stdin().read_line(&mut line);
        stdin_done.store(true, Ordering::SeqCst);
    });
    let mut most = 0;
    while !done.load(Ordering::SeqCst) {
        most = most.max(comm.stats().links[0].1.buffered_bytes);
        std::thread::sleep(Duration::from_micros(200));
    }
    println!("backlog {most}");
}

#[test]
fn inline_callbacks_answer_on_cyclones_receive_thread_without_deadlock() {
    if let Ok(fleet) = std::env::var(CHILD) {
        return run_echo(&fleet);
    }
    let text = fleet_text();
    let mut child = Command::new(std::env::current_exe().unwrap())
        .args([
            "--exact",
            "inline_callbacks_answer_on_cyclones_receive_thread_without_deadlock",
            "--nocapture",
        ])
        .env(CHILD, &text)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .expect("spawn the peer");
    let mut out = BufReader::new(child.stdout.take().unwrap());
    let mut line = String::new();
    while !line.contains("ready") {
        line.clear();
        assert!(out.read_line(&mut line).unwrap() > 0, "peer ended early");
    }

    let fleet = hetcomm::parse_fleet(&text, "parent.toml", None).expect("valid fleet");
    let comm = Comm::open_fleet(&fleet, "A").expect("open A");
    let m = comm.module("M").unwrap();
    let (echoes, inline) = (Arc::new(AtomicU64::new(0)), Arc::new(AtomicU64::new(0)));
    {
        let (echoes, inline) = (echoes.clone(), inline.clone());
        m.on_raw(DATA, move |msg| {
            echoes.fetch_add(1, Ordering::SeqCst);
            if msg.payload[0] == 0 {
                inline.fetch_add(1, Ordering::SeqCst);
            }
        });
    }
    let payload = vec![7u8; SIZE];
    // The first waits for discovery and the peer's acknowledgement.
    let first = m
        .send_raw("B", "M", DATA, &payload, Default::default())
        .expect("send")
        .wait();
    assert!(matches!(first, Outcome::Delivered { .. }), "{first:?}");
    let tickets: Vec<_> = (1..MESSAGES)
        .map(|_| m.send_raw("B", "M", DATA, &payload, Default::default()))
        .collect();
    for (n, t) in tickets.into_iter().enumerate() {
        let outcome = t.expect("send").wait();
        assert!(
            matches!(outcome, Outcome::Delivered { .. }),
            "message {}: {outcome:?}",
            n + 1
        );
    }
    let deadline = Instant::now() + Duration::from_secs(60);
    while echoes.load(Ordering::SeqCst) < MESSAGES as u64 {
        assert!(
            Instant::now() < deadline,
            "{} of {MESSAGES} echoes after 60 s",
            echoes.load(Ordering::SeqCst)
        );
        std::thread::sleep(Duration::from_millis(10));
    }
    drop(child.stdin.take());
    let mut rest = String::new();
    while out.read_line(&mut rest).unwrap_or(0) > 0 {}
    assert!(child.wait().unwrap().success(), "peer failed: {rest}");
    assert_eq!(echoes.load(Ordering::SeqCst), MESSAGES as u64);
    // Echoes are answered inline except those nested in another listener (none here: A and
    // B are different processes) and those a listener found another reader busy with.
    assert!(
        inline.load(Ordering::SeqCst) >= MESSAGES as u64 * 9 / 10,
        "only {} of {MESSAGES} echoes were sent from Cyclone's thread; peer: {rest}",
        inline.load(Ordering::SeqCst)
    );
    // The writers were throttled while the callback answered: frames went through the
    // backlog (the case that would have deadlocked a waiting write).
    let backlog: u64 = rest
        .lines()
        .find_map(|l| l.strip_prefix("backlog ")?.trim().parse().ok())
        .unwrap_or_else(|| panic!("no backlog line from the peer: {rest}"));
    assert!(backlog > 0, "the peer's writes were never deferred");
    let link = &comm.stats().links[0].1;
    assert_eq!(link.frames_dropped, 0, "{link:?}");
}
