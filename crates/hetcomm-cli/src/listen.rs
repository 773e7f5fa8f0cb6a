//! `hetcomm listen`: prints every message arriving at a system of a live fleet, as
//! `rostopic echo` does for ROS, and what that system dropped while it ran.
//!
//! Output: one line per message on stdout (text or `--json`); on stderr the `listening as`
//! line, a status line when a drop counter moved (at most once a second, or a line per change
//! with `--verbose`), and a summary of the counters when it ends — after `--count` messages,
//! at `--timeout`, or on Ctrl-C (SIGINT) or SIGTERM. A second Ctrl-C exits at once.

use std::io::{self, Write};
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{mpsc, Arc};
use std::time::{Duration, Instant};

use hetcomm::{Comm, RawMessage, SystemStats, Time};

use crate::names;
use crate::security::SecurityArgs;

/// Options of `hetcomm listen`.
pub struct ListenArgs<'a> {
    pub fleet: &'a Path,
    /// `--keys` / `--insecure`.
    pub security: &'a SecurityArgs,
    pub system: &'a str,
    pub module: Option<&'a str>,
    pub count: Option<usize>,
    pub timeout: Option<Duration>,
    pub json: bool,
    /// A stderr line per drop counter change as soon as it is seen, instead of a status line
    /// at most once a second.
    pub verbose: bool,
    /// Times as raw microseconds since the UNIX epoch instead of seconds since the start.
    pub raw_times: bool,
    /// `--foxglove HOST:PORT`: the system served to Foxglove while it listens.
    pub foxglove: &'a crate::foxglove::FoxgloveArgs,
}

/// What the main loop waits for.
enum Event {
    /// A message for module `.0`.
    Message(String, RawMessage),
    /// SIGINT or SIGTERM (its name).
    Stop(&'static str),
    /// SIGHUP: reload the fleet file.
    Reload,
    /// A system joined or left a Zenoh network or an MQTT broker this system is on (a line
    /// for stderr).
    #[cfg_attr(not(any(feature = "zenoh", feature = "mqtt")), allow(dead_code))]
    Presence(String),
}

/// How often the counters are looked at: the status line comes at most this often.
const STATUS_EVERY: Duration = Duration::from_secs(1);
/// How often `--verbose` looks at the counters.
const VERBOSE_EVERY: Duration = Duration::from_millis(20);

/// Prints every message arriving at a system (all modules, or one) until `count` messages,
/// `timeout`, or SIGINT/SIGTERM, with drop counters on stderr while it runs and at the end.
pub fn listen(args: ListenArgs<'_>) -> anyhow::Result<()> {
    // First, before any thread exists: every thread started later inherits the mask, so
    // the signals reach only the thread that waits for them.
    let signals = StopSignals::block_with_reload()?;
    let (tx, rx) = mpsc::channel::<Event>();
    // Until the system is open and listening there is nothing to summarise: a signal then
    // ends the process at once, as it would without this thread (opening may wait, e.g. for
    // a ROS master).
    let listening = Arc::new(AtomicBool::new(false));
    {
        let listening = listening.clone();
        let tx = tx.clone();
        signals.watch(move |signal| {
            if signal == libc::SIGHUP {
                // Before the system is open there is nothing to reload into: it opens with
                // the file as it is then.
                if listening.load(Ordering::SeqCst) {
                    let _ = tx.send(Event::Reload);
                }
            } else if listening.load(Ordering::SeqCst) {
                let _ = tx.send(Event::Stop(signal_name(signal)));
            } else {
                std::process::exit(128 + signal);
            }
        })?;
    }
    let fleet = names::load_fleet(args.fleet, args.security)?;
    names::check_system(&fleet, args.fleet, "--as", args.system, &[])?;
    if let Some(m) = args.module {
        names::check_module(&fleet, args.fleet, "--module", m)?;
    }
    #[cfg(feature = "zenoh")]
    forward_presence(
        &fleet,
        args.system,
        tx.clone(),
        ("zenoh", hetcomm_link_zenoh::watch_presence()),
        |e| match e {
            hetcomm_link_zenoh::PresenceEvent::Joined(id) => (id, true),
            hetcomm_link_zenoh::PresenceEvent::Left(id) => (id, false),
        },
    );
    #[cfg(feature = "mqtt")]
    forward_presence(
        &fleet,
        args.system,
        tx.clone(),
        ("mqtt", hetcomm_link_mqtt::watch_presence()),
        |e| match e {
            hetcomm_link_mqtt::PresenceEvent::Joined(id) => (id, true),
            hetcomm_link_mqtt::PresenceEvent::Left(id) => (id, false),
        },
    );
    // Before the system opens: a refused flag (a build without the feature, an address in
    // use) must not cost the user a system opened for nothing.
    let live = args.foxglove.start("hetcomm listen")?;
    let comm = names::open_system(args.fleet, &fleet, args.system)?;
    // HETCOMM_MONITOR=host:port: statistics for `hetcomm monitor` (docs/record-replay.md).
    let _publisher = hetcomm_record::stats::Publisher::from_env(std::slice::from_ref(&comm))
        .map_err(anyhow::Error::msg)?;
    if let Some(live) = &live {
        live.watch(std::slice::from_ref(&comm))?;
    }
    let start = Time::now_wall();
    let started = Instant::now();
    let modules: Vec<String> = match args.module {
        Some(m) => vec![m.to_string()],
        None => comm
            .fleet()
            .modules
            .iter()
            .map(|m| m.name.clone())
            .collect(),
    };
    for name in &modules {
        let module = comm.module(name)?;
        let tx = tx.clone();
        let name = name.clone();
        module.on_any(move |raw| {
            let _ = tx.send(Event::Message(name.clone(), raw));
        });
    }
    drop(tx);
    listening.store(true, Ordering::SeqCst);
    let endpoints: Vec<String> = comm
        .endpoints()
        .iter()
        .map(|(t, a)| format!("{t} {}", a.as_deref().unwrap_or("(in-process)")))
        .collect();
    eprintln!(
        "listening as {} (modules: {}) on {}; Ctrl-C to stop, SIGHUP to reload the fleet file",
        comm.name(),
        modules.join(", "),
        endpoints.join(", ")
    );
    let clock = Clock {
        start,
        raw: args.raw_times,
    };
    let deadline = args.timeout.map(|t| started + t);
    let every = if args.verbose {
        VERBOSE_EVERY
    } else {
        STATUS_EVERY
    };
    let mut next_look = Instant::now() + every;
    // Shown so far: drops before the first look (e.g. while opening) show at the first look.
    let mut shown = Drops::default();
    let mut seen = 0usize;
    let mut owed_acks = 0u64;
    // Why the loop ended early, when it did.
    let mut stopped = None;
    let mut out = io::stdout().lock();
    while args.count.is_none_or(|c| seen < c) {
        let now = Instant::now();
        if deadline.is_some_and(|d| now >= d) {
            break;
        }
        if now >= next_look {
            print_path_changes(&comm, &clock);
            let drops = Drops::of(&comm.stats());
            if drops != shown {
                print_moved(&drops, &shown, seen, args.verbose, &clock);
                shown = drops;
            }
            next_look = now + every;
        }
        let wait = deadline.map_or(next_look, |d| d.min(next_look)) - now;
        match rx.recv_timeout(wait) {
            Ok(Event::Message(module, raw)) => {
                seen += 1;
                if raw.envelope.header.ack_requested() {
                    owed_acks += 1;
                }
                // A reader that went away (`hetcomm listen … | head -3`) ends the listener
                // like a signal, summary included.
                if writeln!(out, "{}", describe(&module, &raw, args.json, &clock)).is_err() {
                    stopped = Some("stopped: standard output was closed".to_string());
                    break;
                }
            }
            Ok(Event::Presence(line)) => {
                eprintln!("{}  {line}", clock.format(Time::now_wall()));
            }
            Ok(Event::Stop(signal)) => {
                stopped = Some(format!("stopped by {signal}"));
                break;
            }
            Ok(Event::Reload) => {
                let at = clock.format(Time::now_wall());
                for line in reload_lines(&comm, args.fleet) {
                    eprintln!("{at}  {line}");
                }
                print_path_changes(&comm, &clock);
            }
            Err(mpsc::RecvTimeoutError::Timeout) => {}
            Err(mpsc::RecvTimeoutError::Disconnected) => break,
        }
    }
    wait_for_acks(&comm, owed_acks, Duration::from_secs(1));
    if let Some(why) = stopped {
        eprintln!("{why}");
    }
    print_path_changes(&comm, &clock);
    let stats = comm.stats();
    // What moved since the last look (up to a second ago) gets its status line too, so the
    // last moments before the end read like the rest.
    let drops = Drops::of(&stats);
    if drops != shown {
        print_moved(&drops, &shown, seen, args.verbose, &clock);
    }
    eprintln!("{}", summary(seen, &stats));
    if let Some(live) = &live {
        live.finish();
    }
    Ok(())
}

/// Forwards the joins and leaves that `system`'s links of one kind see (Zenoh liveliness
/// tokens, MQTT presence messages: the kind's feed of every link of the process, each event
/// read by `event` as (system, joined)) to the main loop, which prints them on stderr.
/// Started before the system opens, so the systems already present are reported too.
#[cfg(any(feature = "zenoh", feature = "mqtt"))]
fn forward_presence<E: Send + 'static>(
    fleet: &hetcomm::config::Fleet,
    system: &str,
    tx: mpsc::Sender<Event>,
    (kind, feed): (&'static str, mpsc::Receiver<(hetcomm::SystemId, E)>),
    event: fn(E) -> (hetcomm::SystemId, bool),
) {
    let Some(me) = fleet
        .systems
        .iter()
        .find(|s| s.name == system)
        .map(|s| s.id)
    else {
        return;
    };
    let names: std::collections::HashMap<_, _> = fleet
        .systems
        .iter()
        .map(|s| (s.id, s.name.clone()))
        .collect();
    let _ = std::thread::Builder::new()
        .name("listen-presence".into())
        .spawn(move || {
            for (local, e) in feed {
                if local != me {
                    continue;
                }
                let (id, joined) = event(e);
                let what = if joined { "joined" } else { "left" };
                let name = names.get(&id).cloned().unwrap_or_else(|| id.to_string());
                if tx
                    .send(Event::Presence(format!("{name} {what} ({kind})")))
                    .is_err()
                {
                    break;
                }
            }
        });
}

/// The status line for counters that moved since `shown` (each change on its own line when
/// `verbose`), on stderr.
fn print_moved(drops: &Drops, shown: &Drops, seen: usize, verbose: bool, clock: &Clock) {
    let at = clock.format(Time::now_wall());
    if verbose {
        for line in drops.changes_since(shown) {
            eprintln!("{at}  {line}");
        }
    } else {
        eprintln!("{at}  {}", drops.status(seen));
    }
}

/// The line printed at the end: messages printed, then every counter (zeros included, so
/// scripts can parse it).
/// One line per change of the transport a destination's traffic takes since the last look
/// (pairs whose table cell lists several transports: docs/failover.md).
fn print_path_changes(comm: &Comm, clock: &Clock) {
    for c in comm.path_changes() {
        eprintln!(
            "{}  traffic to {} moved from transport {} to {}",
            clock.format(Time::now_wall()),
            c.to,
            c.from,
            c.now
        );
    }
}

fn summary(seen: usize, s: &SystemStats) -> String {
    let d = Drops::of(s);
    let mut line = format!(
        "received {seen} message{}; router: {} received, {} duplicates, {} too old, {} malformed, {} unknown origin, {} misrouted, {} unknown module; inboxes dropped {}; links dropped {}",
        if seen == 1 { "" } else { "s" },
        s.router.received,
        d.duplicates,
        d.too_old,
        d.malformed,
        d.unknown_origin,
        d.misrouted,
        d.unknown_module,
        d.inbox,
        d.links,
    );
    if let Some(k) = d.kernel {
        line.push_str(&format!("; kernel dropped {k}"));
    }
    if s.router.path_changes > 0 {
        line.push_str(&format!("; path changes {}", s.router.path_changes));
    }
    if d.security.enabled {
        let counters: Vec<String> = security_counters(&d.security)
            .iter()
            .map(|(name, n)| format!("{name} {n}"))
            .collect();
        line.push_str(&format!("; security: {}", counters.join(", ")));
    }
    line
}

/// The security layer's counters by name, as docs/security.md lists them.
fn security_counters(sec: &hetcomm::SecurityStats) -> [(&'static str, u64); 7] {
    [
        ("rejected_auth", sec.rejected_auth),
        ("rejected_replay", sec.rejected_replay),
        ("rejected_table", sec.rejected_table),
        ("rejected_unknown_sender", sec.rejected_unknown_sender),
        ("rejected_no_session", sec.rejected_no_session),
        ("handshake_timeouts", sec.handshake_timeouts),
        ("handshakes", sec.handshakes),
    ]
}

/// Everything this system threw away (or, for duplicates, did not deliver twice), from its
/// counters, and the sessions its security layers made.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct Drops {
    malformed: u64,
    unknown_origin: u64,
    misrouted: u64,
    unknown_module: u64,
    duplicates: u64,
    /// Data frames older than the duplicate filter remembers: neither delivered nor
    /// acknowledged (`RouterStats::too_old`).
    too_old: u64,
    /// Lost to full inboxes, whatever the policy.
    inbox: u64,
    /// Dropped by the links (frames they could not make sense of, failed batch flushes).
    links: u64,
    /// Datagrams the kernel dropped because a socket's receive buffer was full (UDP links
    /// count them; `LinkStats::kernel_drops`); None while there were none, so the summary
    /// names them only when they happened.
    kernel: Option<u64>,
    /// Refused by the links' security layers, summed over links (`LinkStats::security`).
    security: hetcomm::SecurityStats,
}

impl Drops {
    fn of(s: &SystemStats) -> Drops {
        Drops {
            malformed: s.router.malformed,
            unknown_origin: s.router.unknown_origin,
            misrouted: s.router.misrouted,
            unknown_module: s.unknown_module,
            duplicates: s.router.duplicates,
            too_old: s.router.too_old,
            inbox: s.inboxes.iter().map(|(_, i)| i.dropped()).sum(),
            links: s.links.iter().map(|(_, l)| l.frames_dropped).sum(),
            kernel: kernel_drops(s),
            security: s.links.iter().fold(Default::default(), |mut sum, (_, l)| {
                let x = &l.security;
                sum.rejected_auth += x.rejected_auth;
                sum.rejected_replay += x.rejected_replay;
                sum.rejected_table += x.rejected_table;
                sum.rejected_unknown_sender += x.rejected_unknown_sender;
                sum.rejected_no_session += x.rejected_no_session;
                sum.handshake_timeouts += x.handshake_timeouts;
                sum.handshakes += x.handshakes;
                sum.enabled |= x.enabled;
                sum
            }),
        }
    }

    /// Each counter with its label, in the order they are printed. The security layer's are
    /// labelled with their names (`LinkStats::security`, docs/security.md's table), so a
    /// reader can look them up.
    fn labelled(&self) -> [(&'static str, u64); 16] {
        let sec = &self.security;
        [
            ("malformed", self.malformed),
            ("unknown origin", self.unknown_origin),
            ("misrouted", self.misrouted),
            ("unknown module", self.unknown_module),
            ("duplicates", self.duplicates),
            ("too old", self.too_old),
            ("inbox full", self.inbox),
            ("dropped by links", self.links),
            ("dropped by the kernel", self.kernel.unwrap_or(0)),
        ]
        .into_iter()
        .chain(security_counters(sec))
        .collect::<Vec<_>>()
        .try_into()
        .expect("9 drop counters and 7 security counters")
    }

    /// The status line: the messages printed so far and every counter that is not zero.
    fn status(&self, seen: usize) -> String {
        let mut parts = vec![format!(
            "{seen} message{} so far",
            if seen == 1 { "" } else { "s" }
        )];
        parts.extend(
            self.labelled()
                .iter()
                .filter(|(_, n)| *n > 0)
                .map(|(label, n)| format!("{n} {label}")),
        );
        parts.join(", ")
    }

    /// One line per counter that moved since `before` (`--verbose`).
    fn changes_since(&self, before: &Drops) -> Vec<String> {
        self.labelled()
            .iter()
            .zip(before.labelled())
            .filter(|((_, now), (_, then))| now > then)
            .map(|((label, now), (_, then))| format!("+{} {label} ({now} in all)", now - then))
            .collect()
    }
}

/// Datagrams the kernel dropped for this system's sockets (`LinkStats::kernel_drops`, read
/// from the socket's drop counter where the OS keeps one), when there were any.
fn kernel_drops(stats: &SystemStats) -> Option<u64> {
    let n: u64 = stats.links.iter().map(|(_, l)| l.kernel_drops).sum();
    (n > 0).then_some(n)
}

/// Waits (at most `limit`) until the acknowledgements of the `owed` messages printed are on
/// the wire. The router acknowledges a message on the link's receive thread only after it is
/// in the module's inbox, so the message can be printed — and with `--count` this process
/// exit — before its acknowledgement went out; the sender would then report a failure for a
/// message that arrived. This system sends nothing but acknowledgements, so every frame its
/// links sent is one; a link still connecting keeps frames queued (`buffered_bytes`), so
/// those must have left too.
fn wait_for_acks(comm: &Comm, owed: u64, limit: Duration) {
    let give_up = Instant::now() + limit;
    loop {
        let s = comm.stats();
        let on_wire: u64 = s.links.iter().map(|(_, l)| l.frames_sent).sum();
        let queued: u64 = s.links.iter().map(|(_, l)| l.buffered_bytes).sum();
        if (s.router.acks_sent >= owed && on_wire >= s.router.ack_frames_sent && queued == 0)
            || Instant::now() >= give_up
        {
            return;
        }
        std::thread::sleep(Duration::from_millis(1));
    }
}

/// How times are printed: seconds since the listener started (`+1.234 s`), or with
/// `--raw-times` the clock's microseconds since the UNIX epoch (`1732432042123456us`).
struct Clock {
    start: Time,
    raw: bool,
}

impl Clock {
    fn format(&self, t: Time) -> String {
        if self.raw {
            return format!("{}us", t.as_micros());
        }
        let (sign, us) = match t.as_micros().checked_sub(self.start.as_micros()) {
            Some(after) => ('+', after),
            None => ('-', self.start.as_micros() - t.as_micros()),
        };
        format!("{sign}{}.{:03} s", us / 1_000_000, us % 1_000_000 / 1_000)
    }
}

/// One message as a line: text, or a JSON object (times always as raw microseconds there).
fn describe(module: &str, raw: &RawMessage, json: bool, clock: &Clock) -> String {
    let e = &raw.envelope;
    let payload = decode_payload(&raw.payload);
    if json {
        let mut line = serde_json::json!({
            "to_module": module,
            "from_system": e.source_system,
            "from_module": e.source_module,
            // Unique per message: a restarted sender numbers from 1 again under a new
            // incarnation, and its broadcasts count in a space of their own.
            "id": {
                "origin": e.id().origin.0,
                "incarnation": e.header.incarnation,
                "seq": e.id().seq,
                "broadcast_space": e.header.broadcast_seq(),
            },
            "type": e.message_type().0,
            "priority": e.priority().0,
            "timestamp_us": e.timestamp().as_micros(),
            "received_us": e.received_at.as_micros(),
            "broadcast": e.is_broadcast(),
            "size": raw.payload.len(),
        });
        // `payload` is present only when the bytes decoded; a decoded nil (`null`) also
        // carries its bytes, so it can never be mistaken for a payload that did not decode.
        match payload {
            Ok(value) => {
                if value.is_null() {
                    line["payload_hex"] = hex(&raw.payload).into();
                }
                line["payload"] = value;
            }
            Err(why) => {
                line["payload_error"] = why.into();
                line["payload_hex"] = hex(&raw.payload).into();
            }
        }
        line.to_string()
    } else {
        let body = match payload {
            Ok(value) => value.to_string(),
            Err(why) => format!("undecodable ({why}): hex:{}", hex(&raw.payload)),
        };
        let sent = if clock.raw { "ts=" } else { "sent=" };
        format!(
            "{}  {}.{} -> {module}  type={} prio={} {sent}{} size={}{}  {body}",
            clock.format(e.received_at),
            e.source_system,
            e.source_module,
            e.message_type(),
            e.priority(),
            clock.format(e.timestamp()).replace(' ', ""),
            raw.payload.len(),
            if e.is_broadcast() { " broadcast" } else { "" },
        )
    }
}

/// The payload as JSON, or why it is not one MessagePack value.
fn decode_payload(bytes: &[u8]) -> Result<serde_json::Value, String> {
    if let Some(value) = hetcomm::payload::to_json(bytes) {
        // The decoder reads the one byte MessagePack never uses, 0xc1, as nil.
        if value.is_null() && bytes != [0xc0] {
            return Err(format!(
                "not MessagePack: 0x{:02x} is no MessagePack value",
                bytes[0]
            ));
        }
        return Ok(value);
    }
    if bytes.is_empty() {
        return Err("empty: no MessagePack value".into());
    }
    let mut cursor = io::Cursor::new(bytes);
    match rmpv::decode::read_value(&mut cursor) {
        Err(
            rmpv::decode::Error::InvalidMarkerRead(e) | rmpv::decode::Error::InvalidDataRead(e),
        ) if e.kind() == io::ErrorKind::UnexpectedEof => Err(format!(
            "not MessagePack: the value is cut short after {} byte{}",
            bytes.len(),
            if bytes.len() == 1 { "" } else { "s" }
        )),
        Err(e) => Err(format!("not MessagePack: {e}")),
        Ok(_) if (cursor.position() as usize) < bytes.len() => {
            let left = bytes.len() - cursor.position() as usize;
            Err(format!(
                "{left} byte{} after the first MessagePack value",
                if left == 1 { "" } else { "s" }
            ))
        }
        Ok(_) => Err("MessagePack that has no JSON form".into()),
    }
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// What a reload of the fleet file did (SIGHUP), as lines for stderr.
fn reload_lines(comm: &Comm, fleet: &Path) -> Vec<String> {
    hetcomm::describe_reload(fleet, &comm.reload(fleet))
}

pub use hetcomm::signals::StopSignals;

/// SIGINT's or SIGTERM's name.
fn signal_name(signal: libc::c_int) -> &'static str {
    if signal == libc::SIGINT {
        "SIGINT"
    } else {
        "SIGTERM"
    }
}

#[cfg(test)]
mod tests {
    use hetcomm::LinkStats;

    fn stats_with_kernel_drops(per_link: &[u64]) -> SystemStats {
        SystemStats {
            router: Default::default(),
            inboxes: Vec::new(),
            links: per_link
                .iter()
                .map(|&k| {
                    let l = LinkStats {
                        kernel_drops: k,
                        ..LinkStats::default()
                    };
                    ("lan".to_string(), l)
                })
                .collect(),
            callback_failures: 0,
            held_frames: 0,
            path_switches: Vec::new(),
            unknown_module: 0,
        }
    }

    #[test]
    fn kernel_drops_are_summed_over_links_and_shown_once_they_happen() {
        assert_eq!(Drops::of(&stats_with_kernel_drops(&[0, 0])).kernel, None);
        let d = Drops::of(&stats_with_kernel_drops(&[3, 4]));
        assert_eq!(d.kernel, Some(7));
        assert!(
            d.status(2).contains("7 dropped by the kernel"),
            "{}",
            d.status(2)
        );
        let s = summary(2, &stats_with_kernel_drops(&[3, 4]));
        assert!(s.ends_with("; kernel dropped 7"), "{s}");
    }

    use super::*;

    #[test]
    fn times_relative_to_the_start_or_raw() {
        let clock = Clock {
            start: Time::from_micros(10_000_000),
            raw: false,
        };
        assert_eq!(clock.format(Time::from_micros(11_234_567)), "+1.234 s");
        assert_eq!(clock.format(Time::from_micros(9_500_000)), "-0.500 s");
        let raw = Clock { raw: true, ..clock };
        assert_eq!(raw.format(Time::from_micros(11_234_567)), "11234567us");
    }

    #[test]
    fn payload_errors_say_why() {
        assert_eq!(decode_payload(&[0xc0]), Ok(serde_json::Value::Null));
        assert!(decode_payload(&[]).unwrap_err().contains("empty"));
        assert!(decode_payload(&[0xc1])
            .unwrap_err()
            .contains("not MessagePack"));
        assert_eq!(
            decode_payload(&[0xa5, b'h']).unwrap_err(),
            "not MessagePack: the value is cut short after 2 bytes"
        );
        assert_eq!(
            decode_payload(&[0x01, 0x02]).unwrap_err(),
            "1 byte after the first MessagePack value"
        );
    }

    #[test]
    fn verbose_lines_name_what_moved() {
        let before = Drops {
            malformed: 2,
            ..Drops::default()
        };
        let now = Drops {
            malformed: 5,
            misrouted: 1,
            ..Drops::default()
        };
        assert_eq!(
            now.changes_since(&before),
            ["+3 malformed (5 in all)", "+1 misrouted (1 in all)"]
        );
        assert_eq!(now.status(1), "1 message so far, 5 malformed, 1 misrouted");
    }
}
