//! `hetcomm listen` and `hetcomm send`: poking at a live fleet, as `rostopic echo` / `pub` do
//! for ROS.

use std::path::Path;
use std::sync::mpsc;
use std::time::{Duration, Instant};

use anyhow::Context;
use hetcomm::{Comm, MessageType, Outcome, RawMessage, SendOptions};

/// Options of `hetcomm listen`.
pub struct ListenArgs<'a> {
    pub fleet: &'a Path,
    pub system: &'a str,
    pub module: Option<&'a str>,
    pub count: Option<usize>,
    pub timeout: Option<Duration>,
    pub json: bool,
}

/// Prints every message arriving at a system (all modules, or one), until `count` messages or
/// `timeout`, then a line of counters on stderr.
pub fn listen(args: ListenArgs<'_>) -> anyhow::Result<()> {
    let comm = Comm::open(args.fleet, args.system)
        .with_context(|| format!("opening `{}` of {}", args.system, args.fleet.display()))?;
    let modules: Vec<String> = match args.module {
        Some(m) => vec![m.to_string()],
        None => comm
            .fleet()
            .modules
            .iter()
            .map(|m| m.name.clone())
            .collect(),
    };
    let (tx, rx) = mpsc::channel::<(String, RawMessage)>();
    for name in &modules {
        let module = comm.module(name)?;
        let tx = tx.clone();
        let name = name.clone();
        module.on_any(move |raw| {
            let _ = tx.send((name.clone(), raw));
        });
    }
    drop(tx);
    let endpoints: Vec<String> = comm
        .endpoints()
        .iter()
        .map(|(t, a)| format!("{t} {}", a.as_deref().unwrap_or("(in-process)")))
        .collect();
    eprintln!(
        "listening as {} (modules: {}) on {}",
        comm.name(),
        modules.join(", "),
        endpoints.join(", ")
    );
    let deadline = args.timeout.map(|t| Instant::now() + t);
    let mut seen = 0usize;
    let mut owed_acks = 0u64;
    while args.count.is_none_or(|c| seen < c) {
        let wait = match deadline {
            Some(d) => d.saturating_duration_since(Instant::now()),
            None => Duration::from_secs(3600),
        };
        if wait.is_zero() {
            break;
        }
        match rx.recv_timeout(wait) {
            Ok((module, raw)) => {
                seen += 1;
                if raw.envelope.header.ack_requested() {
                    owed_acks += 1;
                }
                println!("{}", describe(&module, &raw, args.json));
            }
            Err(mpsc::RecvTimeoutError::Timeout) if deadline.is_none() => continue,
            Err(_) => break,
        }
    }
    wait_for_acks(&comm, owed_acks, Duration::from_secs(1));
    let s = comm.stats();
    let dropped_links: u64 = s.links.iter().map(|(_, l)| l.frames_dropped).sum();
    eprintln!(
        "received {seen} messages; router: {} received, {} duplicates, {} malformed, {} unknown origin, {} misrouted; links dropped {dropped_links}",
        s.router.received, s.router.duplicates, s.router.malformed, s.router.unknown_origin, s.router.misrouted
    );
    Ok(())
}

/// Waits (at most `limit`) until the acknowledgements of the `owed` messages printed are on
/// the wire. The router acknowledges a message on the link's receive thread only after it is
/// in the module's inbox, so the message can be printed — and with `--count` this process
/// exit — before its acknowledgement went out; the sender would then report a failure for a
/// message that arrived. This system sends nothing but acknowledgements, so every frame its
/// links sent is one.
fn wait_for_acks(comm: &Comm, owed: u64, limit: Duration) {
    let give_up = Instant::now() + limit;
    loop {
        let s = comm.stats();
        let on_wire: u64 = s.links.iter().map(|(_, l)| l.frames_sent).sum();
        if (s.router.acks_sent >= owed && on_wire >= s.router.acks_sent)
            || Instant::now() >= give_up
        {
            return;
        }
        std::thread::sleep(Duration::from_millis(1));
    }
}

fn describe(module: &str, raw: &RawMessage, json: bool) -> String {
    let e = &raw.envelope;
    let payload = hetcomm::payload::to_json(&raw.payload);
    if json {
        serde_json::json!({
            "to_module": module,
            "from_system": e.source_system,
            "from_module": e.source_module,
            "id": { "origin": e.id().origin.0, "seq": e.id().seq },
            "type": e.message_type().0,
            "priority": e.priority().0,
            "timestamp_us": e.timestamp().as_micros(),
            "received_us": e.received_at.as_micros(),
            "broadcast": e.is_broadcast(),
            "size": raw.payload.len(),
            "payload": payload,
            "payload_hex": if payload.is_none() { Some(hex(&raw.payload)) } else { None },
        })
        .to_string()
    } else {
        let body = payload
            .map(|p| p.to_string())
            .unwrap_or_else(|| format!("hex:{}", hex(&raw.payload)));
        format!(
            "{}.{} -> {module}  type={} prio={} ts={}us size={}{}  {body}",
            e.source_system,
            e.source_module,
            e.message_type(),
            e.priority(),
            e.timestamp().as_micros(),
            raw.payload.len(),
            if e.is_broadcast() { " broadcast" } else { "" },
        )
    }
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// Options of `hetcomm send`.
pub struct SendArgs<'a> {
    pub fleet: &'a Path,
    pub system: &'a str,
    pub from_module: Option<&'a str>,
    pub to: &'a str,
    pub module: &'a str,
    pub message_type: u32,
    pub json: &'a str,
    pub priority: u8,
    pub timeout: Duration,
}

/// What `hetcomm send` learned about its sends, worst first.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum SendVerdict {
    /// Every send was delivered (in the destination module's inbox) or sent without
    /// confirmation on a transport that cannot confirm. Exit code 0.
    Success,
    /// At least one send may or may not have arrived (frames left, no acknowledgement, or no
    /// outcome before the timeout), none certainly failed. Exit code 3.
    Unconfirmed,
    /// At least one send certainly did not arrive. Exit code 1.
    Failed,
}

impl SendVerdict {
    /// The process exit code for this verdict.
    pub fn exit_code(self) -> std::process::ExitCode {
        std::process::ExitCode::from(match self {
            SendVerdict::Success => 0,
            SendVerdict::Failed => 1,
            SendVerdict::Unconfirmed => 3,
        })
    }
}

/// Sends one message (payload given as JSON, encoded as the language-neutral payload) and
/// prints its outcome. `--to All` broadcasts. Returns the worst outcome's verdict.
pub fn send(args: SendArgs<'_>) -> anyhow::Result<SendVerdict> {
    let value: serde_json::Value =
        serde_json::from_str(args.json).context("--json is not valid JSON")?;
    let payload = hetcomm::payload::from_json(&value)?;
    let comm = Comm::open(args.fleet, args.system)
        .with_context(|| format!("opening `{}` of {}", args.system, args.fleet.display()))?;
    let from = match args.from_module {
        Some(m) => m.to_string(),
        None => comm
            .fleet()
            .modules
            .first()
            .map(|m| m.name.clone())
            .context("the fleet has no modules")?,
    };
    let module = comm.module(&from)?;
    let opts = SendOptions::priority(args.priority);
    let ty = MessageType(args.message_type);
    let tickets = if args.to == "All" {
        module
            .broadcast_raw(args.module, ty, &payload, opts)?
            .tickets()
            .to_vec()
    } else {
        vec![module.send_raw(args.to, args.module, ty, &payload, opts)?]
    };
    let mut verdict = SendVerdict::Success;
    for t in tickets {
        let (line, this) = match t.wait_timeout(args.timeout) {
            Some(o @ (Outcome::Delivered { .. } | Outcome::Sent { .. })) => {
                (o.to_string(), SendVerdict::Success)
            }
            Some(o @ Outcome::Unconfirmed { .. }) => {
                let hint = format!(
                    "\n  hint: is `hetcomm listen {} --as {}` (or the system itself) running?",
                    args.fleet.display(),
                    t.destination()
                );
                (format!("{o}{hint}"), SendVerdict::Unconfirmed)
            }
            Some(o) => (o.to_string(), SendVerdict::Failed),
            None => (
                format!(
                    "no outcome within {:.1} s: it may or may not have arrived",
                    args.timeout.as_secs_f64()
                ),
                SendVerdict::Unconfirmed,
            ),
        };
        println!("{}: {line}", t.destination());
        verdict = verdict.max(this);
    }
    Ok(verdict)
}
