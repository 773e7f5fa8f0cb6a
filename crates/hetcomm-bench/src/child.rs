//! The peer process: `hetcomm-bench __peer ROLE ARGS…` (the binary re-executes itself), and
//! the parent's handle to it.
//!
//! Every role ends when its standard input closes (the parent dropping its handle), so a
//! parent that fails half-way never leaves a peer behind. Echo roles answer each message with
//! the same bytes; sink roles count what arrives and print `result COUNT BYTES ELAPSED_NS`
//! (the hetcomm sink adds `kernel_drops=N`: datagrams its kernel dropped at its sockets).

use std::io::{BufRead, BufReader, Read, Write};
use std::net::{TcpListener, UdpSocket};
use std::os::unix::net::UnixDatagram;
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{self, Receiver};
use std::sync::Arc;
use std::time::{Duration, Instant};

use crate::raw::{recv_dgram_msg, send_dgram_msg, Dgram, Got};
use crate::stats::SinkCounter;

/// The message type of benchmark payloads.
pub const DATA: hetcomm::MessageType = hetcomm::MessageType(1);
/// The message type that ends a sink.
pub const STOP: hetcomm::MessageType = hetcomm::MessageType(2);
/// The message type of the probe a one-way run sends before its timed part (it makes sure
/// the receiver is there, and starts a secured link's handshake): not counted, so that the
/// receiver's window starts with the timed messages.
pub const PROBE: hetcomm::MessageType = hetcomm::MessageType(3);

/// How long a sink that is still receiving keeps counting once its parent has closed its
/// input; well within [`EXIT_AFTER_CLOSE`].
const SINK_GRACE: Duration = Duration::from_secs(1);

/// How long a peer lives after its parent closed its input (or went away).
const EXIT_AFTER_CLOSE: Duration = Duration::from_secs(3);

/// A running peer process.
pub struct Peer {
    child: Child,
    stdin: Option<ChildStdin>,
    lines: Receiver<String>,
}

impl Peer {
    /// Starts `hetcomm-bench __peer ARGS…` (or `program ARGS…` for an external peer).
    pub fn spawn(program: Option<&Path>, args: &[String]) -> Result<Peer, String> {
        let mut cmd = match program {
            Some(p) => Command::new(p),
            None => {
                let exe = std::env::current_exe().map_err(|e| format!("current_exe: {e}"))?;
                let mut c = Command::new(exe);
                c.arg("__peer");
                c
            }
        };
        cmd.args(args)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit());
        let mut child = cmd.spawn().map_err(|e| format!("spawning peer: {e}"))?;
        let stdin = child.stdin.take();
        let stdout = child.stdout.take().ok_or("peer has no stdout")?;
        let (tx, rx) = mpsc::channel();
        std::thread::spawn(move || {
            for line in BufReader::new(stdout).lines() {
                match line {
                    Ok(l) => {
                        if tx.send(l).is_err() {
                            break;
                        }
                    }
                    Err(_) => break,
                }
            }
        });
        Ok(Peer {
            child,
            stdin,
            lines: rx,
        })
    }

    /// The next line the peer prints, waiting at most `timeout`.
    pub fn line(&self, timeout: Duration) -> Result<String, String> {
        match self.lines.recv_timeout(timeout) {
            Ok(l) => Ok(l),
            Err(mpsc::RecvTimeoutError::Timeout) => {
                Err(format!("peer printed nothing within {timeout:?}"))
            }
            Err(mpsc::RecvTimeoutError::Disconnected) => Err(format!(
                "peer {} exited (or closed its output) without printing the expected line",
                self.child.id()
            )),
        }
    }

    /// Waits for a line starting with `prefix` and returns the rest.
    pub fn expect(&self, prefix: &str, timeout: Duration) -> Result<String, String> {
        let deadline = Instant::now() + timeout;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            let l = self.line(left)?;
            if let Some(rest) = l.strip_prefix(prefix) {
                return Ok(rest.trim().to_string());
            }
        }
    }

    /// Closes the peer's standard input: it finishes (a sink prints its result first).
    pub fn close_input(&mut self) {
        self.stdin.take();
    }

    /// Closes its input and waits up to `timeout` for it to exit, then kills it.
    pub fn finish(mut self, timeout: Duration) {
        self.close_input();
        let deadline = Instant::now() + timeout;
        while Instant::now() < deadline {
            if let Ok(Some(_)) = self.child.try_wait() {
                return;
            }
            std::thread::sleep(Duration::from_millis(5));
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Drop for Peer {
    fn drop(&mut self) {
        if let Ok(None) = self.child.try_wait() {
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
    }
}

/// Set when standard input closes.
fn watch_stdin() -> Arc<AtomicBool> {
    let closed = Arc::new(AtomicBool::new(false));
    let flag = closed.clone();
    std::thread::spawn(move || {
        let mut buf = [0u8; 64];
        let mut stdin = std::io::stdin();
        while let Ok(n) = stdin.read(&mut buf) {
            if n == 0 {
                break;
            }
        }
        flag.store(true, Ordering::SeqCst);
    });
    closed
}

fn say(line: &str) {
    let mut out = std::io::stdout();
    let _ = writeln!(out, "{line}");
    let _ = out.flush();
}

fn arg<T: std::str::FromStr>(args: &[String], i: usize, what: &str) -> Result<T, String> {
    args.get(i)
        .ok_or(format!("missing {what}"))?
        .parse()
        .map_err(|_| format!("bad {what}: {:?}", args.get(i)))
}

/// Runs a peer role; returns the process exit status.
pub fn run_peer(args: &[String]) -> Result<(), String> {
    let role = args.first().ok_or("missing peer role")?.as_str();
    let closed = watch_stdin();
    // Exit when the parent goes away, whatever the role is doing.
    {
        let closed = closed.clone();
        std::thread::spawn(move || loop {
            if closed.load(Ordering::SeqCst) {
                std::thread::sleep(EXIT_AFTER_CLOSE);
                std::process::exit(0);
            }
            std::thread::sleep(Duration::from_millis(20));
        });
    }
    match role {
        "udp-echo" | "udp-sink" => {
            let size: usize = arg(args, 1, "size")?;
            let sock = UdpSocket::bind("127.0.0.1:0").map_err(|e| e.to_string())?;
            crate::raw::big_buffers(&sock);
            let port = sock.local_addr().map_err(|e| e.to_string())?.port();
            say(&format!("port {port}"));
            dgram_role(Dgram::Udp(sock), role.ends_with("echo"), size, &closed)
        }
        "unix-echo" | "unix-sink" => {
            let size: usize = arg(args, 1, "size")?;
            let path: PathBuf = arg(args, 2, "socket path")?;
            let sock = UnixDatagram::bind(&path).map_err(|e| e.to_string())?;
            crate::raw::big_buffers(&sock);
            say("ready");
            dgram_role(Dgram::Unix(sock), role.ends_with("echo"), size, &closed)
        }
        "tcp-echo" | "tcp-sink" => {
            let listener = TcpListener::bind("127.0.0.1:0").map_err(|e| e.to_string())?;
            let port = listener.local_addr().map_err(|e| e.to_string())?.port();
            say(&format!("port {port}"));
            let (stream, _) = listener.accept().map_err(|e| e.to_string())?;
            let _ = stream.set_nodelay(true);
            tcp_role(stream, role.ends_with("echo"))
        }
        "hc-echo-inline" => {
            // Echoes from inline callbacks, on the thread that delivers each message.
            let fleet: PathBuf = arg(args, 1, "fleet file")?;
            let comm = hetcomm::Comm::open(&fleet, "B").map_err(|e| e.to_string())?;
            let m = comm.module("M").map_err(|e| e.to_string())?;
            let sender = comm.module("M").map_err(|e| e.to_string())?;
            m.set_inline_callbacks(true);
            m.on_any(move |msg| {
                let _ = sender.send_raw("A", "M", DATA, &msg.payload, Default::default());
            });
            say("ready");
            while !closed.load(Ordering::SeqCst) {
                std::thread::sleep(Duration::from_millis(20));
            }
            Ok(())
        }
        "hc-echo" | "hc-echo-spin" | "hc-sink" => {
            let fleet: PathBuf = arg(args, 1, "fleet file")?;
            let comm = hetcomm::Comm::open(&fleet, "B").map_err(|e| e.to_string())?;
            let m = comm.module("M").map_err(|e| e.to_string())?;
            if role == "hc-echo-spin" {
                m.set_wait_spin(crate::hc::WAIT_SPIN);
            }
            say("ready");
            if role.starts_with("hc-echo") {
                while !closed.load(Ordering::SeqCst) {
                    if let Ok(msg) = m.recv_raw_timeout(Some(Duration::from_millis(50))) {
                        // The echo is acknowledged as the ping is: it waits for room too.
                        let by = Instant::now() + crate::hc::ROOM_WAIT;
                        let _ = crate::hc::send_with_room(&m, "A", DATA, &msg.payload, by);
                    }
                }
                Ok(())
            } else {
                let mut c = SinkCounter::default();
                let mut last = Instant::now();
                let mut closed_at: Option<Instant> = None;
                // Taken in batches, as a consumer of a fast stream would (`recv_raw_many`);
                // the clock is read once per batch, not per message.
                let mut batch = Vec::with_capacity(crate::hc::RECV_BATCH);
                'recv: loop {
                    let wait = Some(Duration::from_millis(20));
                    match m.recv_raw_many(&mut batch, crate::hc::RECV_BATCH, wait) {
                        Ok(_) => {
                            let (mut n, mut bytes, mut stop) = (0, 0, false);
                            for msg in batch.drain(..) {
                                match msg.envelope.message_type() {
                                    STOP => stop = true,
                                    PROBE => {}
                                    _ if !stop => {
                                        n += 1;
                                        bytes += msg.payload.len();
                                    }
                                    _ => {}
                                }
                            }
                            c.add_many(n, bytes);
                            if stop {
                                break 'recv;
                            }
                            last = Instant::now();
                            // The parent has gone on (its STOP lost or stuck behind a backlog
                            // this sink cannot drain): report before the exit watchdog fires.
                            if closed.load(Ordering::SeqCst) {
                                let since = *closed_at.get_or_insert(last);
                                if last - since > SINK_GRACE {
                                    break 'recv;
                                }
                            }
                        }
                        Err(_) => {
                            let idle = last.elapsed();
                            if (closed.load(Ordering::SeqCst) && idle > Duration::from_millis(300))
                                || idle > Duration::from_secs(20)
                            {
                                break;
                            }
                        }
                    }
                }
                report_cpu("hc-sink", c.count);
                if std::env::var_os("HETCOMM_BENCH_DIAG").is_some() {
                    eprintln!("sink stats: {:#?}", comm.stats());
                }
                // Datagrams the kernel dropped at this system's sockets (UDP on Linux).
                let drops: u64 = comm.stats().links.iter().map(|(_, l)| l.kernel_drops).sum();
                say(&format!("{} kernel_drops={drops}", c.line()));
                Ok(())
            }
        }
        other => Err(format!("unknown peer role {other}")),
    }
}

fn dgram_role(sock: Dgram, echo: bool, size: usize, closed: &AtomicBool) -> Result<(), String> {
    sock.set_read_timeout(Some(Duration::from_millis(20)));
    let mut scratch = vec![0u8; 70_000];
    let mut msg = vec![0u8; size];
    if echo {
        while !closed.load(Ordering::SeqCst) {
            match recv_dgram_msg(&sock, size, &mut scratch, Some(&mut msg)) {
                Got::Message(from) => {
                    let _ = send_dgram_msg(&sock, &msg, from.as_ref());
                }
                Got::Stop | Got::Nothing => {}
            }
        }
        return Ok(());
    }
    let mut c = SinkCounter::default();
    let mut last = Instant::now();
    let mut bytes_in_msg = 0usize;
    loop {
        match sock.recv_from(&mut scratch) {
            Some((1, _)) => break,
            Some((n, _)) => {
                // Count whole messages: a message is complete when its last chunk arrives.
                bytes_in_msg += n;
                last = Instant::now();
                if bytes_in_msg >= size {
                    c.add(size);
                    bytes_in_msg = 0;
                }
            }
            None => {
                let idle = last.elapsed();
                if (closed.load(Ordering::SeqCst) && idle > Duration::from_millis(300))
                    || idle > Duration::from_secs(20)
                {
                    break;
                }
            }
        }
    }
    say(&c.line());
    Ok(())
}

fn tcp_role(stream: std::net::TcpStream, echo: bool) -> Result<(), String> {
    let mut writer = stream.try_clone().map_err(|e| e.to_string())?;
    let mut reader = BufReader::with_capacity(256 * 1024, stream);
    let mut c = SinkCounter::default();
    let mut frame = Vec::new();
    loop {
        let mut len = [0u8; 4];
        if reader.read_exact(&mut len).is_err() {
            break;
        }
        let n = u32::from_le_bytes(len) as usize;
        if n == 0 {
            break;
        }
        frame.clear();
        frame.extend_from_slice(&len);
        frame.resize(4 + n, 0);
        if reader.read_exact(&mut frame[4..]).is_err() {
            break;
        }
        if echo {
            if writer.write_all(&frame).is_err() {
                break;
            }
        } else {
            c.add(n);
        }
    }
    if !echo {
        report_cpu("tcp-sink", c.count);
        say(&c.line());
    }
    Ok(())
}

/// Whether `HETCOMM_BENCH_SINK_CPU` is set (a developer aid, see `main.rs`).
pub(crate) fn cpu_report_wanted() -> bool {
    std::env::var_os("HETCOMM_BENCH_SINK_CPU").is_some()
}

/// CPU time (user, system) in µs used so far by this process (`libc::RUSAGE_SELF`) or by
/// the calling thread (`libc::RUSAGE_THREAD`).
pub(crate) fn cpu_us(who: libc::c_int) -> (f64, f64) {
    // SAFETY: getrusage writes into the zeroed struct we pass.
    let usage = unsafe {
        let mut u: libc::rusage = std::mem::zeroed();
        libc::getrusage(who, &mut u);
        u
    };
    let us = |t: libc::timeval| t.tv_sec as f64 * 1e6 + t.tv_usec as f64;
    (us(usage.ru_utime), us(usage.ru_stime))
}

/// Prints on standard error the CPU time (user, system; µs) `who` used per message.
pub(crate) fn print_cpu(who: &str, count: u64, (user, sys): (f64, f64)) {
    eprintln!(
        "{who}: {count} messages, CPU per message {:.2} µs (user {:.2}, sys {:.2})",
        (user + sys) / count as f64,
        user / count as f64,
        sys / count as f64
    );
}

/// With `HETCOMM_BENCH_SINK_CPU` set (a developer aid, see `main.rs`), a sink says on
/// standard error how much CPU time its whole process used per message received: the
/// receiver's cost, which throughput alone hides when the machine is busy.
fn report_cpu(role: &str, count: u64) {
    if !cpu_report_wanted() || count == 0 {
        return;
    }
    print_cpu(&format!("sink {role}"), count, cpu_us(libc::RUSAGE_SELF));
}
