//! hetcomm itself, through the public API only: a fleet file written to a temporary
//! directory, `Comm::open` in this process (system A) and in a peer process (system B),
//! `send_raw` with a payload of the given size, `recv_raw_timeout`. In-process runs use a
//! `LocalFleet` and two threads.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use hetcomm::{Comm, LocalFleet, Module, RouterStats};

use crate::child::{Peer, DATA, PROBE, STOP};
use crate::raw::TempDir;
use crate::stats::{parse_sink_line, Latency, Outcomes, Recorder, SinkCounter, Throughput};

/// A transport kind hetcomm is measured over.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    /// `udp`.
    Udp,
    /// `tcp`.
    Tcp,
    /// `inproc` (one process, two threads).
    Inproc,
    /// `udp`, secured (keys per system, every frame sealed: `docs/security.md`). The plain
    /// `Udp` and `Tcp` rows say `security = "none"`, so the two stand side by side.
    UdpSecured,
    /// `tcp`, secured.
    TcpSecured,
    /// `zenoh`: two Zenoh peers (TCP on loopback, multicast scouting off) that find each other
    /// through a Zenoh router in the measuring process, then talk directly.
    Zenoh,
}

impl Kind {
    /// The fleet file's kind name.
    pub fn name(self) -> &'static str {
        match self {
            Kind::Udp | Kind::UdpSecured => "udp",
            Kind::Tcp | Kind::TcpSecured => "tcp",
            Kind::Inproc => "inproc",
            Kind::Zenoh => "zenoh",
        }
    }

    /// Whether frames are sealed.
    pub fn secured(self) -> bool {
        matches!(self, Kind::UdpSecured | Kind::TcpSecured)
    }
}

/// The row name of a kind and delivery mode (`hetcomm-udp-unack`,
/// `hetcomm-udp-secured-ack`, …).
pub fn path_name(kind: Kind, acked: bool) -> String {
    format!(
        "hetcomm-{}{}-{}",
        kind.name(),
        if kind.secured() { "-secured" } else { "" },
        if acked { "ack" } else { "unack" }
    )
}

/// Two distinct free loopback ports for `kind`: both sockets stay bound until both are read,
/// so the kernel cannot hand out the same port twice (two systems would share an endpoint).
pub fn free_port_pair(kind: Kind) -> Result<(u16, u16), String> {
    use std::net::{TcpListener, UdpSocket};
    let pair = if matches!(kind, Kind::Udp | Kind::UdpSecured) {
        UdpSocket::bind("127.0.0.1:0").and_then(|a| {
            let b = UdpSocket::bind("127.0.0.1:0")?;
            Ok((a.local_addr()?.port(), b.local_addr()?.port()))
        })
    } else {
        TcpListener::bind("127.0.0.1:0").and_then(|a| {
            let b = TcpListener::bind("127.0.0.1:0")?;
            Ok((a.local_addr()?.port(), b.local_addr()?.port()))
        })
    };
    pair.map_err(|e| format!("finding free ports: {e}"))
}

/// The fleet file text: systems A and B, module M, one transport `t`. A secured kind reads
/// its keys from `keys/` beside the file (see [`write_keys`]); the plain network kinds say
/// `security = "none"`. For `zenoh`, `ports` is the router's port (twice).
pub fn fleet_text(kind: Kind, acked: bool, ports: Option<(u16, u16)>) -> String {
    let endpoints = match ports {
        Some((r, _)) if kind == Kind::Zenoh => format!(
            "mode = \"peer\"\nconnect = [\"tcp/127.0.0.1:{r}\"]\nlisten = [\"tcp/127.0.0.1:0\"]\n\
             multicast_scouting = false\nprefix = \"hetcomm-bench/{}\"\n",
            std::process::id()
        ),
        Some((a, b)) => format!("endpoints = {{ A = \"127.0.0.1:{a}\", B = \"127.0.0.1:{b}\" }}\n"),
        None => String::new(),
    };
    let security = match kind {
        // Unsecured, to stand beside raw sockets and raw Zenoh; the secured rows are UdpSecured
        // and TcpSecured.
        Kind::Udp | Kind::Tcp | Kind::Zenoh => "security = \"none\"\n",
        _ => "",
    };
    let keys = if kind.secured() {
        "[security]\nkeys = \"keys\"\n"
    } else {
        ""
    };
    format!(
        r#"[systems]
A = 0
B = 1
[modules]
M = 0
[inbox]
capacity = 65536
overflow = "block"
block_timeout_ms = 1000
[transports.t]
kind = "{}"
delivery = "{}"
{security}{endpoints}[table]
columns = ["A", "B"]
A = ["X", "t"]
B = ["t", "X"]
{keys}"#,
        kind.name(),
        if acked {
            "acknowledged"
        } else {
            "unacknowledged"
        }
    )
}

/// System A of a two-process pair plus its peer process (system B in role `role`).
struct Pair {
    _dir: TempDir,
    /// The Zenoh router the peers find each other through (`zenoh` only).
    #[cfg(feature = "hetcomm-zenoh")]
    _router: Option<hetcomm_link_zenoh::router::ZenohRouter>,
    peer: Peer,
    comm: Comm,
    m: Module,
}

/// Writes a key pair for A and B in `dir/keys` (what `hetcomm keygen` writes).
pub fn write_keys(dir: &std::path::Path) -> Result<(), String> {
    let keys = dir.join("keys");
    std::fs::create_dir_all(&keys).map_err(|e| format!("{}: {e}", keys.display()))?;
    for name in ["A", "B"] {
        hetcomm::security::Keypair::generate()
            .and_then(|k| k.write(&keys, name))
            .map_err(|e| e.to_string())?;
    }
    Ok(())
}

fn open_pair(kind: Kind, acked: bool, role: &str) -> Result<Pair, String> {
    let dir = TempDir::new()?;
    let ports = free_port_pair(kind)?;
    if kind.secured() {
        write_keys(&dir.0)?;
    }
    #[cfg(feature = "hetcomm-zenoh")]
    let router = match kind {
        Kind::Zenoh => Some(
            hetcomm_link_zenoh::router::ZenohRouter::start(
                &[format!("tcp/127.0.0.1:{}", ports.0)],
                false,
            )
            .map_err(|e| format!("zenoh router: {e}"))?,
        ),
        _ => None,
    };
    let path = dir.0.join("fleet.toml");
    std::fs::write(&path, fleet_text(kind, acked, Some(ports)))
        .map_err(|e| format!("{}: {e}", path.display()))?;
    let peer = Peer::spawn(None, &[format!("hc-{role}"), path.display().to_string()])?;
    peer.expect("ready", Duration::from_secs(20))?;
    let comm = Comm::open(&path, "A").map_err(|e| e.to_string())?;
    let m = comm.module("M").map_err(|e| e.to_string())?;
    Ok(Pair {
        _dir: dir,
        #[cfg(feature = "hetcomm-zenoh")]
        _router: router,
        peer,
        comm,
        m,
    })
}

/// Round trips that may go unanswered before a measurement is abandoned.
pub const MAX_LOST: u64 = 10;

/// Round trips from `m` to B's `M` and back (B echoes), after a probe that waits for the echo.
pub(crate) fn round_trips(
    m: &Module,
    size: usize,
    warmup: u64,
    iters: u64,
) -> Result<Latency, String> {
    let msg = vec![7u8; size];
    let mut rec = Recorder::new();
    probe_echo(m, &msg)?;
    for i in 0..warmup + iters {
        let t = Instant::now();
        // An acknowledged ping whose answer came back before its acknowledgement still counts
        // against the send window: with large pings the window can be full, and a program
        // then waits for room (an earlier outcome), as here, within the round trip.
        send_with_room(m, "B", DATA, &msg, t + ROOM_WAIT).map_err(|e| e.to_string())?;
        match m.recv_raw_timeout(Some(Duration::from_secs(1))) {
            Ok(_) if i >= warmup => rec.record(t.elapsed()),
            Ok(_) => {}
            Err(_) => {
                rec.lost();
                if rec.summary().lost > MAX_LOST {
                    return Err(format!("more than {MAX_LOST} round trips lost"));
                }
                while m.try_recv_raw().is_some() {}
            }
        }
    }
    Ok(rec.summary())
}

/// [`round_trips`] the way `ddsperf` measures in its listener mode: once the echo answers,
/// `m`'s callbacks run inline ([`Module::set_inline_callbacks`]) and each reply's callback,
/// on the thread that delivered it, records the round trip and sends the next ping; this
/// thread only waits for the end. The peer must echo from inline callbacks too.
#[cfg(feature = "ros2-cyclone")]
pub(crate) fn round_trips_inline(
    comm: &Comm,
    m: &Module,
    size: usize,
    warmup: u64,
    iters: u64,
) -> Result<Latency, String> {
    let msg = vec![7u8; size];
    probe_echo(m, &msg)?;
    struct Run {
        rec: Recorder,
        sent_at: Instant,
        done: u64,
        /// Taken when the run ends: the callback holds the system open while it has one.
        sender: Option<Module>,
    }
    let total = warmup + iters;
    let run = Arc::new((
        parking_lot::Mutex::new(Run {
            rec: Recorder::new(),
            sent_at: Instant::now(),
            done: 0,
            sender: Some(comm.module("M").map_err(|e| e.to_string())?),
        }),
        parking_lot::Condvar::new(),
    ));
    m.set_inline_callbacks(true);
    let cb = run.clone();
    m.on_any(move |_reply| {
        let now = Instant::now();
        let (lock, ended) = &*cb;
        let mut r = lock.lock();
        if r.done >= warmup {
            let rtt = now - r.sent_at;
            r.rec.record(rtt);
        }
        r.done += 1;
        if r.done >= total {
            r.sender = None;
            ended.notify_all();
            return;
        }
        r.sent_at = Instant::now();
        if let Some(sender) = &r.sender {
            let _ = sender.send_raw("B", "M", DATA, &msg, Default::default());
        }
    });
    let (lock, ended) = &*run;
    let mut r = lock.lock();
    r.sent_at = Instant::now();
    m.send_raw("B", "M", DATA, &vec![7u8; size], Default::default())
        .map_err(|e| e.to_string())?;
    // No retries here (unlike `round_trips`): a lost ping or pong ends the chain.
    let deadline = Instant::now() + Duration::from_secs(60);
    while r.done < total {
        let left = deadline.saturating_duration_since(Instant::now());
        if left.is_zero() {
            let done = r.done;
            r.sender = None;
            return Err(format!(
                "the ping–pong chain stopped after {done} of {total}"
            ));
        }
        ended.wait_for(&mut r, left);
    }
    Ok(r.rec.summary())
}

/// Sends `msg` until the echo comes back (links may still be connecting), then drains.
fn probe_echo(m: &Module, msg: &[u8]) -> Result<(), String> {
    let deadline = Instant::now() + Duration::from_secs(20);
    loop {
        m.send_raw("B", "M", DATA, msg, Default::default())
            .map_err(|e| e.to_string())?;
        if m.recv_raw_timeout(Some(Duration::from_millis(200))).is_ok() {
            break;
        }
        if Instant::now() > deadline {
            return Err("no echo within 20 s".into());
        }
    }
    while m.try_recv_raw().is_some() {}
    Ok(())
}

/// Ping-pong round trips between two processes (udp, tcp) or two threads (inproc).
pub fn rtt(
    kind: Kind,
    acked: bool,
    size: usize,
    warmup: u64,
    iters: u64,
) -> Result<Latency, String> {
    if kind == Kind::Inproc {
        return inproc_rtt(acked, size, warmup, iters);
    }
    let pair = open_pair(kind, acked, "echo")?;
    let result = round_trips(&pair.m, size, warmup, iters);
    let Pair { peer, .. } = pair;
    peer.finish(Duration::from_secs(3));
    result
}

/// How long both ends of [`rtt_spinning`] spin before they sleep.
pub const WAIT_SPIN: Duration = Duration::from_micros(50);

/// [`rtt`] between two processes whose waiting modules spin [`WAIT_SPIN`] before they
/// sleep ([`Module::set_wait_spin`]), reading their links meanwhile.
pub fn rtt_spinning(kind: Kind, size: usize, warmup: u64, iters: u64) -> Result<Latency, String> {
    let pair = open_pair(kind, false, "echo-spin")?;
    pair.m.set_wait_spin(WAIT_SPIN);
    let result = round_trips(&pair.m, size, warmup, iters);
    let Pair { peer, .. } = pair;
    peer.finish(Duration::from_secs(3));
    result
}

/// The longest wait for the outcomes of acknowledged sends after a one-way run: well beyond
/// what the retransmissions of the default 3 attempts take (each timeout is the measured RTO,
/// backed off per attempt, at most 5 s).
pub const OUTCOME_WAIT: Duration = Duration::from_secs(30);

/// How the sends made since `before` (the router's counters then) ended, once none is in
/// flight any more, or at `limit` with the rest counted as pending.
fn wait_for_outcomes(comm: &Comm, before: &RouterStats, limit: Duration) -> Outcomes {
    let deadline = Instant::now() + limit;
    loop {
        let r = comm.stats().router;
        let o = Outcomes {
            delivered: r.delivered.saturating_sub(before.delivered),
            unconfirmed: r.unconfirmed.saturating_sub(before.unconfirmed),
            failed: r.failed.saturating_sub(before.failed),
            // Not `in_flight()`: counters read one by one may be a send apart.
            pending: r
                .sends
                .saturating_sub(r.delivered + r.sent + r.unconfirmed + r.failed),
        };
        if o.pending == 0 || Instant::now() >= deadline {
            return o;
        }
        std::thread::sleep(Duration::from_millis(1));
    }
}

/// One-way: A sends as fast as `send_raw` returns for `duration`; B counts. Acknowledged: A
/// then waits until every send has its outcome (retransmissions included) before it stops B,
/// so that B counts every message that arrives, and the outcomes explain those that did not.
pub fn oneway(
    kind: Kind,
    acked: bool,
    size: usize,
    duration: Duration,
) -> Result<Throughput, String> {
    if kind == Kind::Inproc {
        return inproc_oneway(acked, size, duration, false).map(|(t, _)| t);
    }
    let mut pair = open_pair(kind, acked, "sink")?;
    let msg = vec![7u8; size];
    // Make sure B is there (and a secured link's handshake done): a probe, acknowledged or
    // not, which B does not count, then the timed run. B's clock starts at the first timed
    // message, so that its rate is the timed run's alone.
    let _ = pair.m.send_raw("B", "M", PROBE, &msg, Default::default());
    std::thread::sleep(Duration::from_millis(50));
    let before = pair.comm.stats().router;
    let mut sent = 0;
    let cpu_before = crate::child::cpu_us(libc::RUSAGE_THREAD);
    let process_before = crate::child::cpu_us(libc::RUSAGE_SELF);
    let end = Instant::now() + duration;
    while Instant::now() < end {
        for _ in 0..16 {
            if send_with_room(&pair.m, "B", DATA, &msg, end).is_ok() {
                sent += 1;
            }
        }
    }
    if crate::child::cpu_report_wanted() && sent > 0 {
        // The sending thread's own CPU time: what limits how fast one thread sends. Then the
        // whole process's (the link's writer and receive threads too), as the sink's line
        // gives the receiver's.
        let after = crate::child::cpu_us(libc::RUSAGE_THREAD);
        let process_after = crate::child::cpu_us(libc::RUSAGE_SELF);
        let path = path_name(kind, acked);
        let who = format!("sender {path} {size} B, sending thread");
        crate::child::print_cpu(&who, sent, (after.0 - cpu_before.0, after.1 - cpu_before.1));
        let who = format!("sender {path} {size} B, whole process");
        let process = (
            process_after.0 - process_before.0,
            process_after.1 - process_before.1,
        );
        crate::child::print_cpu(&who, sent, process);
    }
    // Counted before STOP is sent: the outcomes are those of the measured messages.
    let outcomes = acked.then(|| wait_for_outcomes(&pair.comm, &before, OUTCOME_WAIT));
    if std::env::var_os("HETCOMM_BENCH_DIAG").is_some() {
        eprintln!("sender stats: {:#?}", pair.comm.stats());
    }
    for _ in 0..3 {
        let stop_by = Instant::now() + Duration::from_secs(5);
        let _ = send_with_room(&pair.m, "B", STOP, &[0], stop_by);
        std::thread::sleep(Duration::from_millis(5));
    }
    pair.peer.close_input();
    let line = pair.peer.expect("result", Duration::from_secs(40))?;
    let Pair { peer, .. } = pair;
    peer.finish(Duration::from_secs(3));
    let mut t = parse_sink_line(&line, sent).ok_or(format!("bad sink line {line:?}"))?;
    t.outcomes = outcomes;
    Ok(t)
}

/// How long a round trip's ping (or its echo) waits for room in a full send window.
pub(crate) const ROOM_WAIT: Duration = Duration::from_secs(5);

/// Sends to system `to`'s `M`; while the acknowledged window is full (backpressure), gives
/// the CPU to the threads that handle acknowledgements and tries again, until `deadline`.
pub(crate) fn send_with_room(
    m: &Module,
    to: &str,
    ty: hetcomm::MessageType,
    payload: &[u8],
    deadline: Instant,
) -> Result<hetcomm::Ticket, hetcomm::SendError> {
    loop {
        match m.send_raw(to, "M", ty, payload, Default::default()) {
            Err(hetcomm::SendError::Backpressure { .. }) if Instant::now() < deadline => {
                std::thread::yield_now()
            }
            other => return other,
        }
    }
}

fn local(acked: bool) -> Result<(LocalFleet, Module, Module), String> {
    let text = fleet_text(Kind::Inproc, acked, None);
    let fleet =
        hetcomm::config::parse_str(&text, "bench-inproc.toml", None).map_err(|e| e.to_string())?;
    let f = LocalFleet::open(fleet).map_err(|e| e.to_string())?;
    let a = f
        .system("A")
        .and_then(|s| s.module("M"))
        .map_err(|e| e.to_string())?;
    let b = f
        .system("B")
        .and_then(|s| s.module("M"))
        .map_err(|e| e.to_string())?;
    Ok((f, a, b))
}

fn inproc_rtt(acked: bool, size: usize, warmup: u64, iters: u64) -> Result<Latency, String> {
    let (_f, a, b) = local(acked)?;
    let stop = Arc::new(AtomicBool::new(false));
    let s2 = stop.clone();
    let echo = std::thread::spawn(move || {
        while !s2.load(Ordering::Relaxed) {
            if let Ok(m) = b.recv_raw_timeout(Some(Duration::from_millis(20))) {
                let _ = b.send_raw("A", "M", DATA, &m.payload, Default::default());
            }
        }
    });
    let r = round_trips(&a, size, warmup, iters);
    stop.store(true, Ordering::Relaxed);
    let _ = echo.join();
    r
}

/// The first 8 bytes of a payload that carries no send time.
const UNSTAMPED: u64 = u64::MAX;

fn stamp(buf: &mut [u8], epoch: Instant) {
    let ns = epoch.elapsed().as_nanos() as u64;
    write_stamp(buf, ns);
}

fn write_stamp(buf: &mut [u8], ns: u64) {
    if buf.len() >= 8 {
        buf[..8].copy_from_slice(&ns.to_le_bytes());
    }
}

fn age_ns(buf: &[u8], epoch: Instant) -> Option<u64> {
    let b: [u8; 8] = buf.get(..8)?.try_into().ok()?;
    let sent = u64::from_le_bytes(b);
    (sent != UNSTAMPED).then(|| (epoch.elapsed().as_nanos() as u64).saturating_sub(sent))
}

/// Messages a benchmark receiver takes per call at most.
pub(crate) const RECV_BATCH: usize = 256;

/// In-process one-way: one thread sends as fast as it can, another receives (in batches). One payload in
/// 64 carries its send time, so the receiver also measures hand-off latency (queueing
/// included) from a sample: reading the clock for every message on both threads would cost
/// each side about 25 ns a message, a quarter of the budget of the 10 M msg/s target.
///
/// `batched`: the sender hands its messages over 64 at a time (`RawSender::send_many`)
/// instead of one by one.
pub fn inproc_oneway(
    acked: bool,
    size: usize,
    duration: Duration,
    batched: bool,
) -> Result<(Throughput, Latency), String> {
    let (f, a, b) = local(acked)?;
    let sender = f.system("A").map_err(|e| e.to_string())?;
    let before = sender.stats().router;
    let epoch = Instant::now();
    let receiver = std::thread::spawn(move || {
        let mut c = SinkCounter::default();
        let mut rec = Recorder::new();
        let mut idle = 0;
        // Taken in batches, as a consumer of a fast stream would (`recv_raw_many`).
        let mut batch = Vec::with_capacity(RECV_BATCH);
        'recv: loop {
            match b.recv_raw_many(&mut batch, RECV_BATCH, Some(Duration::from_millis(50))) {
                Ok(_) => {
                    for m in batch.drain(..) {
                        if m.envelope.message_type() == STOP {
                            break 'recv;
                        }
                        if let Some(ns) = age_ns(&m.payload, epoch) {
                            rec.record_ns(ns);
                        }
                        c.add(m.payload.len());
                    }
                    idle = 0;
                }
                Err(_) => {
                    idle += 1;
                    if idle > 100 {
                        break;
                    }
                }
            }
        }
        (c, rec)
    });
    let mut msg = vec![7u8; size.max(8)];
    let mut sent = 0u64;
    // A pre-resolved handle, as a program sending a stream of messages would use.
    let to_b = a.raw_sender("B", "M", DATA).map_err(|e| e.to_string())?;
    let end = Instant::now() + duration;
    let mut stamped = msg.clone();
    while Instant::now() < end {
        if batched {
            stamp(&mut stamped, epoch);
            write_stamp(&mut msg, UNSTAMPED);
            let mut batch: [&[u8]; 64] = [&msg; 64];
            batch[0] = &stamped;
            let tickets = to_b.send_many(&batch, Default::default());
            sent += tickets.iter().filter(|t| t.is_ok()).count() as u64;
            continue;
        }
        stamp(&mut msg, epoch);
        for _ in 0..64 {
            if to_b.send(&msg, Default::default()).is_ok() {
                sent += 1;
            }
            write_stamp(&mut msg, UNSTAMPED);
        }
    }
    let outcomes = acked.then(|| wait_for_outcomes(&sender, &before, OUTCOME_WAIT));
    let _ = a.send_raw("B", "M", STOP, &[0], Default::default());
    let (c, rec) = receiver.join().map_err(|_| "receiver thread panicked")?;
    let mut t = parse_sink_line(&c.line(), sent).ok_or("no result")?;
    t.outcomes = outcomes;
    Ok((t, rec.summary()))
}

/// In-process hand-off latency without queueing: one message at a time, the sender waits
/// until the receiving thread has taken it before sending the next. With `spin`, the
/// receiver spins that long before it sleeps ([`Module::set_wait_spin`]).
pub fn inproc_paced_handoff(
    acked: bool,
    size: usize,
    count: u64,
    spin: Option<Duration>,
) -> Result<Latency, String> {
    let (_f, a, b) = local(acked)?;
    if let Some(spin) = spin {
        b.set_wait_spin(spin);
    }
    let epoch = Instant::now();
    let taken = Arc::new(AtomicU64::new(0));
    let t2 = taken.clone();
    let receiver = std::thread::spawn(move || {
        let mut rec = Recorder::new();
        loop {
            match b.recv_raw_timeout(Some(Duration::from_millis(500))) {
                Ok(m) if m.envelope.message_type() == STOP => break,
                Ok(m) => {
                    if let Some(ns) = age_ns(&m.payload, epoch) {
                        rec.record_ns(ns);
                    }
                    t2.fetch_add(1, Ordering::Release);
                }
                Err(_) => break,
            }
        }
        rec
    });
    let mut msg = vec![7u8; size.max(8)];
    let to_b = a.raw_sender("B", "M", DATA).map_err(|e| e.to_string())?;
    for i in 0..count {
        stamp(&mut msg, epoch);
        to_b.send(&msg, Default::default())
            .map_err(|e| e.to_string())?;
        let deadline = Instant::now() + Duration::from_secs(1);
        while taken.load(Ordering::Acquire) <= i && Instant::now() < deadline {
            std::hint::spin_loop();
        }
        // Let the receiver go back to waiting, so each hand-off includes its wake-up.
        let pause = Instant::now();
        while pause.elapsed() < Duration::from_micros(20) {
            std::hint::spin_loop();
        }
    }
    let _ = a.send_raw("B", "M", STOP, &[0], Default::default());
    let rec = receiver.join().map_err(|_| "receiver thread panicked")?;
    Ok(rec.summary())
}
