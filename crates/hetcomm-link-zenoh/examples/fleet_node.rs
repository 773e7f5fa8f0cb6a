//! One system of a fleet as its own process, driven line by line on stdin, reporting on stdout
//! (one JSON object a line): what `scripts/zenoh-multihost.py` runs on every host.
//!
//! ```text
//! fleet_node FLEET.toml SYSTEM
//! fleet_node --router ENDPOINT LEASE_MS
//! ```
//!
//! It opens SYSTEM (its `zenoh` links find the others through Zenoh), prints
//! `{"event":"ready"}`, and then obeys:
//!
//! | command | what it does, what it prints |
//! |---|---|
//! | `send DEST N TAG` | N messages to DEST's module `M` (payload: the text `TAG/i`), each outcome as `{"event":"outcome","tag":..,"to":..,"outcome":"delivered\|sent\|unconfirmed\|failed","detail":..}` once known |
//! | `broadcast N TAG` | N broadcasts to module `M`, an outcome line per destination |
//! | `received` | `{"event":"received","count":C,"duplicates":D,"tags":{TAG: C}}`: messages that reached module `M` since the start, how many of them a second time (same sender and text) |
//! | `quit` | closes the system and exits |
//!
//! On **SIGHUP** it reloads FLEET.toml into the running system (`Comm::reload`, as `hetcomm
//! listen` does) and prints `{"event":"reload","ok":true|false,"lines":[..]}`: the lines
//! `hetcomm listen` prints for a reload (`hetcomm::describe_reload`): the difference and what
//! was applied, or why nothing changed (`ok` false).
//!
//! Every join and leave its Zenoh links see is printed as
//! `{"event":"joined"|"left","system":..,"links":N}`, N the number of its links that see that
//! system now (a system on two `zenoh` transports has joined fully at 2, left fully at 0).
//!
//! With `RUST_LOG` set (e.g. `zenoh=debug`), Zenoh's log lines (not JSON) go to stdout too.

use std::collections::HashMap;
use std::io::{BufRead, Write};
use std::path::Path;
use std::sync::{Arc, Mutex};

use hetcomm::{Comm, MessageType, Outcome, SendOptions, Ticket};
use hetcomm_link_zenoh::PresenceEvent;

/// `fleet_node --router ENDPOINT LEASE_MS`: what `hetcomm zenoh-router --listen ENDPOINT
/// --lease-ms LEASE_MS` runs (the same [`hetcomm_link_zenoh::router::ZenohRouter`]), with
/// Zenoh's log on stdout after `ready` when `RUST_LOG` asks for it.
fn router(endpoint: &str, lease_ms: &str) -> ! {
    let Ok(lease_ms) = lease_ms.parse() else {
        eprintln!("--router: LEASE_MS must be a number of milliseconds");
        std::process::exit(2);
    };
    // Kept open (closed at exit).
    let _router = match hetcomm_link_zenoh::router::ZenohRouter::start_with_lease(
        &[endpoint.into()],
        false,
        lease_ms,
    ) {
        Ok(r) => r,
        Err(e) => {
            eprintln!("router: {e}");
            std::process::exit(1);
        }
    };
    emit("ready".into());
    loop {
        std::thread::park();
    }
}

/// One JSON line on stdout, whole (lines from several threads do not interleave).
fn emit(line: String) {
    let mut out = std::io::stdout().lock();
    let _ = writeln!(out, "{line}");
    let _ = out.flush();
}

fn quote(s: &str) -> String {
    serde_json::Value::String(s.to_string()).to_string()
}

/// A MessagePack str (fixstr or str8) holding `text`.
fn msgpack_str(text: &str) -> Vec<u8> {
    let b = text.as_bytes();
    let mut out = if b.len() < 32 {
        vec![0xa0 | b.len() as u8]
    } else {
        vec![0xd9, b.len() as u8]
    };
    out.extend_from_slice(b);
    out
}

fn text_of(payload: &[u8]) -> Option<String> {
    let (len, start) = match *payload.first()? {
        b @ 0xa0..=0xbf => ((b & 0x1f) as usize, 1),
        0xd9 => (*payload.get(1)? as usize, 2),
        _ => return None,
    };
    String::from_utf8(payload.get(start..start + len)?.to_vec()).ok()
}

fn describe(o: &Outcome) -> &'static str {
    match o {
        Outcome::Delivered { .. } => "delivered",
        Outcome::Sent { .. } => "sent",
        Outcome::Relayed { .. } => "relayed",
        Outcome::Unconfirmed { .. } => "unconfirmed",
        Outcome::Failed { .. } => "failed",
    }
}

/// Waits for each ticket on a thread of its own batch and prints its outcome.
fn report(tag: String, tickets: Vec<(String, Ticket)>) {
    std::thread::spawn(move || {
        for (to, t) in tickets {
            let o = t.wait();
            emit(format!(
                "{{\"event\":\"outcome\",\"tag\":{},\"to\":{},\"outcome\":\"{}\",\"detail\":{}}}",
                quote(&tag),
                quote(&to),
                describe(&o),
                quote(&o.to_string())
            ));
        }
    });
}

#[derive(Default)]
struct Received {
    seen: HashMap<(String, String), u32>,
    duplicates: u64,
    tags: HashMap<String, u64>,
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if let [flag, endpoint, lease_ms] = args.as_slice() {
        if flag == "--router" {
            // As a router process should (before any thread and anything of Zenoh's).
            hetcomm_link_zenoh::router::use_router_runtime();
            zenoh::try_init_log_from_env();
            router(endpoint, lease_ms);
        }
    }
    // SIGHUP reloads the fleet file: blocked first, before any thread exists (threads
    // inherit the mask; one that did not block it would die of it), taken by one thread.
    let signals = match hetcomm::signals::StopSignals::block_reload() {
        Ok(s) => s,
        Err(e) => {
            eprintln!("fleet_node: blocking SIGHUP: {e}");
            std::process::exit(1);
        }
    };
    // Zenoh's own log when RUST_LOG asks for it: on stdout, between the JSON lines (Zenoh's
    // formatter writes there; scripts/zenoh-multihost.py keeps the lines that are not JSON in
    // a file with HCZ_LOG_DIR). How reconnections are looked into.
    zenoh::try_init_log_from_env();
    let [fleet, system] = args.as_slice() else {
        eprintln!("usage: fleet_node FLEET.toml SYSTEM");
        std::process::exit(2);
    };
    let names_fleet = match hetcomm::load_fleet(std::path::Path::new(fleet)) {
        Ok(f) => f,
        Err(e) => {
            eprintln!("{e}");
            std::process::exit(2);
        }
    };
    let names: HashMap<_, _> = names_fleet
        .systems
        .iter()
        .map(|s| (s.id, s.name.clone()))
        .collect();
    let me = names_fleet
        .systems
        .iter()
        .find(|s| &s.name == system)
        .map(|s| s.id);
    let presence = hetcomm_link_zenoh::watch_presence();
    std::thread::spawn(move || {
        let mut links: HashMap<hetcomm::SystemId, u32> = HashMap::new();
        for (local, event) in presence {
            if Some(local) != me {
                continue;
            }
            let (id, what) = match event {
                PresenceEvent::Joined(id) => (id, "joined"),
                PresenceEvent::Left(id) => (id, "left"),
            };
            let n = links.entry(id).or_insert(0);
            match event {
                PresenceEvent::Joined(_) => *n += 1,
                PresenceEvent::Left(_) => *n = n.saturating_sub(1),
            }
            let name = names.get(&id).cloned().unwrap_or_else(|| id.to_string());
            emit(format!(
                "{{\"event\":\"{what}\",\"system\":{},\"links\":{n}}}",
                quote(&name)
            ));
        }
    });
    let comm = match Comm::open(fleet, system) {
        Ok(c) => c,
        Err(e) => {
            eprintln!("open {system}: {e}");
            std::process::exit(1);
        }
    };
    {
        let (comm, fleet) = (comm.clone(), fleet.clone());
        let watching = signals.watch(move |_| {
            let path = Path::new(&fleet);
            let result = comm.reload(path);
            let lines: Vec<String> = hetcomm::describe_reload(path, &result)
                .iter()
                .map(|l| quote(l))
                .collect();
            emit(format!(
                "{{\"event\":\"reload\",\"ok\":{},\"lines\":[{}]}}",
                result.is_ok(),
                lines.join(",")
            ));
        });
        if let Err(e) = watching {
            eprintln!("fleet_node: watching SIGHUP: {e}");
            std::process::exit(1);
        }
    }
    let module = comm.module("M").expect("module M");
    let received = Arc::new(Mutex::new(Received::default()));
    {
        let received = received.clone();
        module.on_any(move |m| {
            let text = text_of(&m.payload).unwrap_or_default();
            let tag = text.split('/').next().unwrap_or_default().to_string();
            let mut r = received.lock().unwrap();
            let n = r
                .seen
                .entry((m.envelope.source_system.to_string(), text))
                .or_insert(0);
            *n += 1;
            if *n > 1 {
                r.duplicates += 1;
            } else {
                *r.tags.entry(tag).or_insert(0) += 1;
            }
        });
    }
    emit("{\"event\":\"ready\"}".into());
    for line in std::io::stdin().lock().lines() {
        let Ok(line) = line else { break };
        let words: Vec<&str> = line.split_whitespace().collect();
        match words.as_slice() {
            ["send", dest, n, tag] => {
                let n: u32 = n.parse().unwrap_or(1);
                let mut tickets = Vec::new();
                for i in 0..n {
                    let payload = msgpack_str(&format!("{tag}/{i}"));
                    match module.send_raw(dest, "M", MessageType(1), &payload, SendOptions::default()) {
                        Ok(t) => tickets.push((dest.to_string(), t)),
                        Err(e) => emit(format!(
                            "{{\"event\":\"outcome\",\"tag\":{},\"to\":{},\"outcome\":\"refused\",\"detail\":{}}}",
                            quote(tag),
                            quote(dest),
                            quote(&e.to_string())
                        )),
                    }
                }
                report(tag.to_string(), tickets);
            }
            ["broadcast", n, tag] => {
                let n: u32 = n.parse().unwrap_or(1);
                let mut tickets = Vec::new();
                for i in 0..n {
                    let payload = msgpack_str(&format!("{tag}/{i}"));
                    match module.broadcast_raw("M", MessageType(1), &payload, SendOptions::default()) {
                        Ok(b) => tickets.extend(
                            b.tickets().iter().map(|t| (t.destination().to_string(), t.clone())),
                        ),
                        Err(e) => emit(format!(
                            "{{\"event\":\"outcome\",\"tag\":{},\"to\":\"All\",\"outcome\":\"refused\",\"detail\":{}}}",
                            quote(tag),
                            quote(&e.to_string())
                        )),
                    }
                }
                report(tag.to_string(), tickets);
            }
            ["received"] => {
                let r = received.lock().unwrap();
                let tags: Vec<String> = r
                    .tags
                    .iter()
                    .map(|(t, c)| format!("{}:{c}", quote(t)))
                    .collect();
                emit(format!(
                    "{{\"event\":\"received\",\"count\":{},\"duplicates\":{},\"tags\":{{{}}}}}",
                    r.seen.len(),
                    r.duplicates,
                    tags.join(",")
                ));
            }
            ["quit"] => break,
            _ => eprintln!("fleet_node: unknown command {line:?}"),
        }
    }
    drop(module);
    drop(comm);
}
