//! `hetcomm send`: poking at a live fleet, as `rostopic pub` does for ROS (`hetcomm listen`,
//! its counterpart, is in `listen.rs`).

use std::path::Path;
use std::time::Duration;

use anyhow::Context;
use hetcomm::config::{Fleet, TransportKind};
use hetcomm::{FailReason, MessageType, Outcome, SendOptions};

use crate::names;
use crate::security::SecurityArgs;

/// Options of `hetcomm send`.
pub struct SendArgs<'a> {
    pub fleet: &'a Path,
    /// `--keys` / `--insecure`.
    pub security: &'a SecurityArgs,
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
    let fleet = names::load_fleet(args.fleet, args.security)?;
    names::check_system(&fleet, args.fleet, "--as", args.system, &[])?;
    names::check_destination(&fleet, args.fleet, args.to, args.system)?;
    names::check_module(&fleet, args.fleet, "--module", args.module)?;
    if let Some(m) = args.from_module {
        names::check_module(&fleet, args.fleet, "--from-module", m)?;
    }
    let comm = names::open_system(args.fleet, &fleet, args.system)?;
    // HETCOMM_MONITOR=host:port: its statistics for `hetcomm monitor`, reported once more as
    // it exits (docs/record-replay.md).
    let _publisher = hetcomm_record::stats::Publisher::from_env(std::slice::from_ref(&comm))
        .map_err(anyhow::Error::msg)?;
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
        let outcome = t.wait_timeout(args.timeout);
        let (line, this) = match &outcome {
            Some(o) if o.is_success() => (o.to_string(), SendVerdict::Success),
            Some(o @ Outcome::Unconfirmed { .. }) => (o.to_string(), SendVerdict::Unconfirmed),
            Some(o) => (o.to_string(), SendVerdict::Failed),
            None => (
                format!(
                    "no outcome within {:.1} s: it may or may not have arrived",
                    args.timeout.as_secs_f64()
                ),
                SendVerdict::Unconfirmed,
            ),
        };
        // Where the cell lists several transports, which one carried it (docs/failover.md).
        let several = match (
            fleet.system_by_name(args.system),
            fleet.system_by_name(t.destination()),
        ) {
            (Some(a), Some(b)) => fleet.fallbacks.contains_key(&(a.id, b.id)),
            _ => false,
        };
        match t.transport().filter(|_| several) {
            Some(via) => println!("{}: {line} via {via}", t.destination()),
            None => println!("{}: {line}", t.destination()),
        }
        let hint = outcome
            .as_ref()
            .and_then(|o| hint(o, args.fleet, &fleet, args.system, t.destination()));
        if let Some(hint) = hint {
            eprintln!("hint: {hint}");
        }
        verdict = verdict.max(this);
    }
    Ok(verdict)
}

/// What to check when an outcome suggests a mistake in how the fleet is run.
fn hint(
    outcome: &Outcome,
    path: &Path,
    fleet: &Fleet,
    from: &str,
    destination: &str,
) -> Option<String> {
    match outcome {
        // Frames went out, nothing came back.
        Outcome::Unconfirmed {
            reason: FailReason::NoAcknowledgement,
            ..
        } => Some(format!(
            "nothing acknowledged it: is `{destination}` running, e.g. `hetcomm listen {} --as {destination}`?",
            path.display()
        )),
        // Only the handshake left. A receiver that refuses a key or a pair does not answer
        // (an answer could not be authenticated), so the sender cannot tell it from one that
        // is not running: name both.
        Outcome::Failed {
            reason: FailReason::NoSession(_),
            ..
        } => Some(format!(
            "`{destination}` did not answer the security handshake, so the message was not sent: either it is not running (`hetcomm listen {} --as {destination}`), or it refuses `{from}`'s key or this pair (its listener counts them as rejected_auth, rejected_unknown_sender or rejected_table); check that both sides use the same fleet file and keys",
            path.display()
        )),
        Outcome::Failed {
            reason: FailReason::Unreachable(_),
            ..
        } if transport_kind(fleet, from, destination) == Some(TransportKind::Inproc) => {
            Some(format!(
                "`{from}` reaches `{destination}` over an in-process transport, which reaches only systems opened by the same process: give the pair a udp or tcp transport in {} to reach another process",
                path.display()
            ))
        }
        _ => None,
    }
}

/// The kind of transport carrying `from` → `to` in the fleet's table.
fn transport_kind(fleet: &Fleet, from: &str, to: &str) -> Option<TransportKind> {
    let id = |name: &str| fleet.systems.iter().find(|s| s.name == name).map(|s| s.id);
    let index = fleet.table.get(&(id(from)?, id(to)?))?;
    fleet.transports.get(*index).map(|t| t.kind)
}
