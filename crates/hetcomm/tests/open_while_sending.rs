//! A peer that is already sending while a system opens: every frame its link hands on is
//! accounted for. Unacknowledged frames are not sent again, so one the opening system loses
//! without a count is gone for good and nobody can tell.
//!
//! B has more transports after the one A uses, so its link to A runs for a while before the
//! rest are open. Every frame that reached B must end as a message delivered to the inbox, a
//! frame B's router counted as dropped, or one counted in the `frames_dropped` of B's link
//! (what arrives while a system opens is held for its router, bounded, and the rest counted
//! there).
//! Two ways in:
//!
//! - over an emulated transport (an in-process link under the emulation layer), from system A
//!   opened in this process: its link hands frames to B's sink on A's thread, at once, from
//!   the moment B's link exists (the frames that reached B are what A's link took);
//! - over UDP, from a raw socket at A's fleet endpoint that writes valid unacknowledged data
//!   frames (`docs/wire-format.md`, one frame per datagram) to B's endpoint before and while
//!   B opens (the frames that reached B are what its link handed on).

mod common;

use std::net::UdpSocket;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use hetcomm::wire::{self, Header};
use hetcomm::{Address, Comm, MessageType, ModuleId, SystemId, SystemStats};

/// Transports of B after the one A uses: each is a socket and a receive thread to open,
/// which keeps B's first link running before B is fully open.
const LATER_TRANSPORTS: usize = 16;

/// Systems A, B and C1..C16; A → B on transport `a` (unacknowledged, with `a_keys`), B ↔ Ci
/// on UDP transport `ci`.
fn fleet_text(a_keys: &str) -> String {
    let others: Vec<String> = (1..=LATER_TRANSPORTS).map(|i| format!("C{i}")).collect();
    let mut text = String::from("[systems]\nA = 0\nB = 1\n");
    for (i, c) in others.iter().enumerate() {
        text += &format!("{c} = {}\n", i + 2);
    }
    // Room in the inbox for everything the sender can send in one round.
    text += "[inbox]\ncapacity = 100000\n[modules]\nPlan = 0\nAct = 1\n";
    // One attempt: a send refused while B is not there yet is not tried again later (which
    // could put a frame on B's link twice).
    text += &format!("[transports.a]\ndelivery = \"unacknowledged\"\nattempts = 1\n{a_keys}\n");
    for c in &others {
        text += &format!(
            "[transports.{}]\nkind = \"udp\"\nsecurity = \"none\"\n\
             endpoints = {{ B = \"127.0.0.1:{}\", {c} = \"127.0.0.1:{}\" }}\n",
            c.to_lowercase(),
            common::free_udp_port(),
            common::free_udp_port()
        );
    }
    let names: Vec<String> = ["A", "B"]
        .iter()
        .map(|s| s.to_string())
        .chain(others.iter().cloned())
        .collect();
    text += &format!(
        "[table]\ncolumns = [{}]\n",
        names
            .iter()
            .map(|n| format!("{n:?}"))
            .collect::<Vec<_>>()
            .join(", ")
    );
    for row in &names {
        let cells: Vec<String> = names
            .iter()
            .map(|col| {
                let t = match (row.as_str(), col.as_str()) {
                    ("A", "B") | ("B", "A") => "a".to_string(),
                    ("B", c) | (c, "B") if c.starts_with('C') => c.to_lowercase(),
                    _ => "X".to_string(),
                };
                format!("{t:?}")
            })
            .collect();
        text += &format!("{row} = [{}]\n", cells.join(", "));
    }
    text
}

/// An unacknowledged data frame from A.Plan to B.Act, as A's router would send it.
fn data_frame(incarnation: u32, seq: u64) -> Vec<u8> {
    let address = |system, module| Address {
        system: SystemId(system),
        module: ModuleId(module),
    };
    let mut h = Header::data(address(0, 0), address(1, 1), MessageType(7));
    h.incarnation = incarnation;
    h.seq = seq;
    h.transport = b'a';
    wire::encode(&h, &seq.to_le_bytes())
}

/// One system's counters for its link on transport `a`.
fn link_a(stats: &SystemStats) -> hetcomm::LinkStats {
    stats
        .links
        .iter()
        .find(|(name, _)| name == "a")
        .expect("a link on transport a")
        .1
        .clone()
}

/// Every frame B accounts for: delivered, or counted as dropped (by its router, or by its
/// link on `a`, where frames that came while B opened and did not fit are counted).
fn accounted(stats: &SystemStats) -> u64 {
    let r = &stats.router;
    r.received
        + r.malformed
        + r.unknown_origin
        + r.misrouted
        + r.duplicates
        + stats.unknown_module
        + link_a(stats).frames_dropped
}

/// Opens B while `sender` runs (it started before and is stopped 100 ms after B is open),
/// then checks that B accounts for every frame that reached it (`reached`, read once the
/// sender stopped).
fn open_b_while_sending(
    fleet: &hetcomm::config::Fleet,
    round: u32,
    sender: impl FnOnce(Arc<AtomicBool>) -> std::thread::JoinHandle<()>,
    reached: impl Fn(&Comm) -> u64,
) {
    let stop = Arc::new(AtomicBool::new(false));
    let sending = sender(stop.clone());
    // The stream is running before B's link exists.
    std::thread::sleep(Duration::from_millis(20));
    let b = Comm::open_fleet(fleet, "B").expect("open B");
    std::thread::sleep(Duration::from_millis(100));
    stop.store(true, Ordering::Relaxed);
    sending.join().expect("the sender");

    // Until B's links have handed on what is queued for them, and its router took it all.
    let deadline = Instant::now() + Duration::from_secs(5);
    let mut now = (reached(&b), accounted(&b.stats()));
    let mut last = (u64::MAX, u64::MAX);
    while (now.0 != now.1 || last != now) && Instant::now() < deadline {
        last = now;
        std::thread::sleep(Duration::from_millis(50));
        now = (reached(&b), accounted(&b.stats()));
    }
    let (reached, accounted) = now;
    let stats = b.stats();
    assert!(reached > 0, "round {round}: no frame reached B");
    assert_eq!(
        reached,
        accounted,
        "round {round}: {reached} frames reached B, B accounts for {accounted} \
         (router {:?}, link {:?})",
        stats.router,
        link_a(&stats)
    );
    // The stream was valid: nothing of it is a drop except what opening could not hold.
    assert_eq!(
        stats.router.received + link_a(&stats).frames_dropped,
        reached,
        "round {round}: {:?}",
        stats.router
    );
}

/// A in this process sends over an emulated (in-process) transport: its link hands each
/// frame to B's sink during the send, so frames reach B from the moment B's link is open.
#[test]
fn frames_from_a_system_of_this_process_while_b_opens_are_delivered_or_counted() {
    for round in 0..10u32 {
        let text = fleet_text("kind = \"emulated\"");
        let fleet = hetcomm::parse_fleet(&text, &format!("open_emulated_{round}.toml"), None)
            .unwrap_or_else(|e| panic!("{e}\n{text}"));
        let a = Comm::open_fleet(&fleet, "A").expect("open A");
        let plan = a.module("Plan").expect("module Plan");
        open_b_while_sending(
            &fleet,
            round,
            |stop| {
                std::thread::spawn(move || {
                    let mut n = 0u64;
                    while !stop.load(Ordering::Relaxed) {
                        // Bursts with a yield between: as fast as the machine lets it without
                        // keeping B from opening.
                        for _ in 0..20 {
                            n += 1;
                            // Refused until B's link exists; those never reach B.
                            let _ = plan.send_raw(
                                "B",
                                "Act",
                                MessageType(7),
                                &n.to_le_bytes(),
                                Default::default(),
                            );
                        }
                        std::thread::yield_now();
                    }
                })
            },
            // The frames A's link took: each was in B's sink when the send returned.
            |_| link_a(&a.stats()).frames_sent,
        );
    }
}

/// A raw socket at A's UDP endpoint writes frames to B's endpoint before and while B opens.
#[test]
fn datagrams_sent_while_b_opens_are_delivered_or_counted() {
    for round in 0..10u32 {
        let (pa, pb) = (common::free_udp_port(), common::free_udp_port());
        let text = fleet_text(&format!(
            "kind = \"udp\"\nsecurity = \"none\"\n\
             endpoints = {{ A = \"127.0.0.1:{pa}\", B = \"127.0.0.1:{pb}\" }}"
        ));
        let fleet = hetcomm::parse_fleet(&text, "open_udp.toml", None)
            .unwrap_or_else(|e| panic!("{e}\n{text}"));
        let socket = UdpSocket::bind(("127.0.0.1", pa)).expect("bind A's endpoint");
        let sent = Arc::new(AtomicU64::new(0));
        let counted = sent.clone();
        open_b_while_sending(
            &fleet,
            round,
            move |stop| {
                std::thread::spawn(move || {
                    let mut seq = 0u64;
                    while !stop.load(Ordering::Relaxed) {
                        for _ in 0..20 {
                            seq += 1;
                            let frame = data_frame(0x5eed_0000 + round, seq);
                            // Refused (or lost) until B's socket exists; those never reach B.
                            let _ = socket.send_to(&frame, ("127.0.0.1", pb));
                        }
                        counted.store(seq, Ordering::Relaxed);
                        std::thread::sleep(Duration::from_micros(500));
                    }
                })
            },
            |b| link_a(&b.stats()).frames_received,
        );
        assert!(sent.load(Ordering::Relaxed) > 0);
    }
}
