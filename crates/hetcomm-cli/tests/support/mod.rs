//! Helpers shared by the integration tests of the `hetcomm` binary: free ports, temporary
//! fleet files, child processes that are killed on drop and whose output is read line by line
//! with deadlines.
//!
//! Nothing here sleeps to wait for readiness: a listener is ready when it has printed its
//! `listening as ...` line on stderr; everything else waits for output lines or exits, always
//! bounded by the test's [`Deadline`].

#![allow(dead_code)] // each test binary uses a different subset

use parking_lot::Mutex;
use std::io::{BufRead, BufReader, Read};
use std::net::{TcpListener, UdpSocket};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, Command, ExitStatus, Stdio};
use std::sync::mpsc::{self, Receiver, RecvTimeoutError};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// The `hetcomm` binary under test.
pub const HETCOMM: &str = env!("CARGO_BIN_EXE_hetcomm");

/// A test's hard deadline: every wait is bounded by it, so no test can hang.
#[derive(Clone, Copy, Debug)]
pub struct Deadline(Instant);

impl Deadline {
    pub fn after(secs: u64) -> Deadline {
        Deadline(Instant::now() + Duration::from_secs(secs))
    }

    /// Time left (zero once passed).
    pub fn left(&self) -> Duration {
        self.0.saturating_duration_since(Instant::now())
    }

    /// The earlier of this deadline and `d` from now.
    pub fn within(&self, d: Duration) -> Deadline {
        Deadline(self.0.min(Instant::now() + d))
    }

    pub fn passed(&self) -> bool {
        self.left().is_zero()
    }
}

/// A free UDP port on 127.0.0.1: bind port 0, read it, close. Another process could take the
/// port between this and the child binding it; that tiny race is accepted in exchange for
/// never using fixed ports. Within this process no port is handed out twice (the kernel can
/// return a just-closed port again, and two systems of one fleet then share an endpoint).
pub fn free_udp_port() -> u16 {
    not_given_before(|| {
        UdpSocket::bind("127.0.0.1:0")
            .and_then(|s| s.local_addr())
            .expect("bind udp port 0")
            .port()
    })
}

/// Calls `pick` until it returns a port this process has not handed out yet.
fn not_given_before(pick: impl Fn() -> u16) -> u16 {
    static GIVEN: parking_lot::Mutex<std::collections::BTreeSet<u16>> =
        parking_lot::Mutex::new(std::collections::BTreeSet::new());
    loop {
        let port = pick();
        if GIVEN.lock().insert(port) {
            return port;
        }
    }
}

/// A free TCP port on 127.0.0.1 (same accepted race as [`free_udp_port`]).
pub fn free_tcp_port() -> u16 {
    not_given_before(|| {
        TcpListener::bind("127.0.0.1:0")
            .and_then(|s| s.local_addr())
            .expect("bind tcp port 0")
            .port()
    })
}

/// A free port for a transport kind (`udp` or `tcp`).
pub fn free_port(kind: &str) -> u16 {
    match kind {
        "udp" => free_udp_port(),
        "tcp" => free_tcp_port(),
        other => panic!("no free-port rule for {other}"),
    }
}

/// A directory under the system temp dir, removed on drop.
pub struct TempDir(PathBuf);

impl TempDir {
    pub fn new(tag: &str) -> TempDir {
        use std::sync::atomic::{AtomicU32, Ordering};
        static N: AtomicU32 = AtomicU32::new(0);
        let path = std::env::temp_dir().join(format!(
            "hetcomm-test-{tag}-{}-{}",
            std::process::id(),
            N.fetch_add(1, Ordering::Relaxed)
        ));
        let _ = std::fs::remove_dir_all(&path);
        std::fs::create_dir_all(&path).expect("create temp dir");
        TempDir(path)
    }

    pub fn path(&self) -> &Path {
        &self.0
    }

    /// Writes `name` in the directory and returns its path. A fleet file (`.toml`) with a
    /// transport that leaves the process and no word on security is secured the way a user
    /// would: a key pair per system in `keys/` (what `hetcomm keygen` writes) and
    /// `[security] keys = "keys"` appended. Tests about unsecured links say
    /// `security = "none"` in the transport's section.
    pub fn write(&self, name: &str, text: &str) -> PathBuf {
        let p = self.0.join(name);
        let mut text = text.to_string();
        let leaves_process = ["\"udp\"", "\"tcp\"", "\"ros1\"", "\"ros2\""]
            .iter()
            .any(|k| text.contains(&format!("kind = {k}")));
        // A fleet that already names `keys = "keys"` (a shipped example) gets its keys made,
        // as its user would with `hetcomm keygen`.
        let names_keys_dir = text.contains("[security]\nkeys = \"keys\"");
        if names_keys_dir {
            let unkeyed = text.replace("[security]\nkeys = \"keys\"", "");
            text = unkeyed;
        }
        if name.ends_with(".toml") && leaves_process && !text.contains("security = ") {
            if let Ok(fleet) = hetcomm::parse_fleet(&text, name, None) {
                let keys = self.0.join("keys");
                std::fs::create_dir_all(&keys).expect("create keys dir");
                for system in &fleet.systems {
                    hetcomm::security::Keypair::generate()
                        .and_then(|k| k.write(&keys, &system.name))
                        .expect("write keys");
                }
                text.push_str("\n[security]\nkeys = \"keys\"\n");
            }
        }
        std::fs::write(&p, text).expect("write temp file");
        p
    }

    /// Writes `name` in the directory exactly as given (no keys added), creating its folder.
    #[allow(dead_code)]
    pub fn write_plain(&self, name: &str, text: &str) -> PathBuf {
        let p = self.0.join(name);
        if let Some(parent) = p.parent() {
            std::fs::create_dir_all(parent).expect("create folder");
        }
        std::fs::write(&p, text).expect("write temp file");
        p
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// A fleet file text: `systems` as (name, id, endpoint); modules Plan = 0 and Act = 1; one
/// transport `net` of `kind` (`udp` / `tcp`) carrying every pair.
pub fn fleet_text(kind: &str, systems: &[(&str, u16, String)]) -> String {
    let mut s = String::from("name = \"test\"\n[systems]\n");
    for (name, id, _) in systems {
        s.push_str(&format!("{name} = {id}\n"));
    }
    s.push_str("\n[modules]\nPlan = 0\nAct = 1\n\n[transports.net]\n");
    s.push_str(&format!("kind = \"{kind}\"\n"));
    let eps: Vec<String> = systems
        .iter()
        .map(|(name, _, ep)| format!("{name} = \"{ep}\""))
        .collect();
    s.push_str(&format!(
        "endpoints = {{ {} }}\n\n[table]\n",
        eps.join(", ")
    ));
    let cols: Vec<String> = systems.iter().map(|(n, _, _)| format!("\"{n}\"")).collect();
    s.push_str(&format!("columns = [{}]\n", cols.join(", ")));
    for (i, (row, _, _)) in systems.iter().enumerate() {
        let cells: Vec<&str> = (0..systems.len())
            .map(|j| if i == j { "\"X\"" } else { "\"net\"" })
            .collect();
        s.push_str(&format!("{row} = [{}]\n", cells.join(", ")));
    }
    s
}

/// `text` with its `udp`/`tcp` transports unsecured (`security = "none"`): for tests that
/// speak to a system with hand-made frames from a raw socket, as an unsecured peer would.
pub fn unsecured(text: &str) -> String {
    let mut out = String::new();
    for line in text.lines() {
        out.push_str(line);
        out.push('\n');
        if line == "kind = \"udp\"" || line == "kind = \"tcp\"" {
            out.push_str("security = \"none\"\n");
        }
    }
    out
}

/// [`loopback_fleet`] with its transport unsecured ([`unsecured`]).
pub fn loopback_fleet_unsecured(
    kind: &str,
    systems: &[(&str, u16)],
) -> (TempDir, PathBuf, Vec<u16>) {
    let (dir, _, ports) = loopback_fleet(kind, systems);
    let full: Vec<(&str, u16, String)> = systems
        .iter()
        .zip(&ports)
        .map(|(&(n, id), p)| (n, id, format!("127.0.0.1:{p}")))
        .collect();
    let path = dir.write("fleet.toml", &unsecured(&fleet_text(kind, &full)));
    (dir, path, ports)
}

/// A fleet on 127.0.0.1 with a free port per system: (temp dir holding `fleet.toml`, its
/// path, the ports by system in the order given). Secured with keys in the directory (see
/// [`TempDir::write`]).
pub fn loopback_fleet(kind: &str, systems: &[(&str, u16)]) -> (TempDir, PathBuf, Vec<u16>) {
    let ports: Vec<u16> = systems.iter().map(|_| free_port(kind)).collect();
    let full: Vec<(&str, u16, String)> = systems
        .iter()
        .zip(&ports)
        .map(|(&(n, id), p)| (n, id, format!("127.0.0.1:{p}")))
        .collect();
    let dir = TempDir::new(kind);
    let path = dir.write("fleet.toml", &fleet_text(kind, &full));
    (dir, path, ports)
}

/// One line of a child's output, or the end of that stream.
enum Line {
    Text(String),
    Eof,
}

/// Reads `r` line by line on a thread; every line also goes to `log`.
fn pump(r: impl Read + Send + 'static, log: Arc<Mutex<Vec<String>>>) -> Receiver<Line> {
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        let mut r = BufReader::new(r);
        let mut buf = Vec::new();
        loop {
            buf.clear();
            match r.read_until(b'\n', &mut buf) {
                Ok(0) | Err(_) => break,
                Ok(_) => {
                    let line = String::from_utf8_lossy(&buf)
                        .trim_end_matches(['\n', '\r'])
                        .to_string();
                    log.lock().push(line.clone());
                    // Nobody may wait for lines any more: keep draining into the log.
                    let _ = tx.send(Line::Text(line));
                }
            }
        }
        let _ = tx.send(Line::Eof);
    });
    rx
}

/// A child process that is killed (and reaped) when dropped, with its stdout and stderr read
/// line by line in the background.
pub struct ChildGuard {
    pub name: String,
    child: Child,
    stdout: Receiver<Line>,
    stderr: Receiver<Line>,
    stdout_eof: bool,
    stderr_eof: bool,
    stdout_log: Arc<Mutex<Vec<String>>>,
    stderr_log: Arc<Mutex<Vec<String>>>,
    pub stdin: Option<ChildStdin>,
}

impl ChildGuard {
    /// Spawns `cmd` with piped stdout/stderr (stdin null).
    pub fn spawn(name: &str, mut cmd: Command) -> ChildGuard {
        cmd.stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped());
        let mut child = cmd
            .spawn()
            .unwrap_or_else(|e| panic!("spawn {name} ({cmd:?}): {e}"));
        let stdout_log = Arc::new(Mutex::new(Vec::new()));
        let stderr_log = Arc::new(Mutex::new(Vec::new()));
        let stdout = pump(child.stdout.take().unwrap(), stdout_log.clone());
        let stderr = pump(child.stderr.take().unwrap(), stderr_log.clone());
        ChildGuard {
            name: name.to_string(),
            child,
            stdout,
            stderr,
            stdout_eof: false,
            stderr_eof: false,
            stdout_log,
            stderr_log,
            stdin: None,
        }
    }

    pub fn id(&self) -> u32 {
        self.child.id()
    }

    /// Everything printed on stdout so far.
    pub fn stdout_lines(&self) -> Vec<String> {
        self.stdout_log.lock().clone()
    }

    /// Everything printed on stderr so far.
    pub fn stderr_lines(&self) -> Vec<String> {
        self.stderr_log.lock().clone()
    }

    fn describe(&self) -> String {
        format!(
            "{} (pid {})\n--- stdout:\n{}\n--- stderr:\n{}",
            self.name,
            self.child.id(),
            self.stdout_lines().join("\n"),
            self.stderr_lines().join("\n")
        )
    }

    fn next_line(
        rx: &Receiver<Line>,
        eof: &mut bool,
        deadline: Deadline,
    ) -> Result<String, &'static str> {
        if *eof {
            return Err("stream ended");
        }
        match rx.recv_timeout(deadline.left()) {
            Ok(Line::Text(l)) => Ok(l),
            Ok(Line::Eof) | Err(RecvTimeoutError::Disconnected) => {
                *eof = true;
                Err("stream ended")
            }
            Err(RecvTimeoutError::Timeout) => Err("deadline passed"),
        }
    }

    /// The next stdout line; panics with the child's output at the deadline or end of stream.
    pub fn next_stdout(&mut self, deadline: Deadline) -> String {
        match Self::next_line(&self.stdout, &mut self.stdout_eof, deadline) {
            Ok(l) => l,
            Err(why) => panic!("waiting for a stdout line: {why}: {}", self.describe()),
        }
    }

    /// Skips stderr lines until one contains `needle`; returns it.
    pub fn wait_stderr(&mut self, needle: &str, deadline: Deadline) -> String {
        loop {
            match Self::next_line(&self.stderr, &mut self.stderr_eof, deadline) {
                Ok(l) if l.contains(needle) => return l,
                Ok(_) => {}
                Err(why) => panic!(
                    "waiting for {needle:?} on stderr: {why}: {}",
                    self.describe()
                ),
            }
        }
    }

    /// Skips stdout lines until one contains `needle`; returns it.
    pub fn wait_stdout(&mut self, needle: &str, deadline: Deadline) -> String {
        loop {
            match Self::next_line(&self.stdout, &mut self.stdout_eof, deadline) {
                Ok(l) if l.contains(needle) => return l,
                Ok(_) => {}
                Err(why) => panic!(
                    "waiting for {needle:?} on stdout: {why}: {}",
                    self.describe()
                ),
            }
        }
    }

    /// Waits for the child to exit and for both output streams to end; returns the status.
    pub fn wait_exit(&mut self, deadline: Deadline) -> ExitStatus {
        // Both pipes close when the child exits: read them to the end first (this also makes
        // the logs complete), then reap.
        while Self::next_line(&self.stdout, &mut self.stdout_eof, deadline).is_ok() {}
        while Self::next_line(&self.stderr, &mut self.stderr_eof, deadline).is_ok() {}
        loop {
            match self.child.try_wait() {
                Ok(Some(s)) => return s,
                Ok(None) if deadline.passed() => {
                    panic!("{} did not exit in time: {}", self.name, self.describe())
                }
                // Output closed but not reaped yet: poll briefly (no blocking wait with a
                // timeout in std).
                Ok(None) => std::thread::sleep(Duration::from_millis(5)),
                Err(e) => panic!("waiting for {}: {e}", self.name),
            }
        }
    }

    /// SIGKILL and reap.
    pub fn kill(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Drop for ChildGuard {
    fn drop(&mut self) {
        if let Ok(None) = self.child.try_wait() {
            let _ = self.child.kill();
        }
        let _ = self.child.wait();
        if std::thread::panicking() {
            eprintln!("=== child {}", self.describe());
        }
    }
}

/// `hetcomm listen FLEET --as SYSTEM ARGS...` (with a `--timeout` of its own so that even an
/// orphaned listener ends), returned once it printed `listening as SYSTEM`.
pub fn listen(fleet: &Path, system: &str, args: &[&str], deadline: Deadline) -> ChildGuard {
    let mut cmd = Command::new(HETCOMM);
    cmd.arg("listen")
        .arg(fleet)
        .args(["--as", system])
        .args(args);
    if !args.contains(&"--timeout") {
        cmd.args(["--timeout", "60"]);
    }
    let mut child = ChildGuard::spawn(&format!("listen as {system}"), cmd);
    child.wait_stderr(&format!("listening as {system} "), deadline);
    child
}

/// What a finished `hetcomm send` printed.
#[derive(Debug)]
pub struct Finished {
    pub status: ExitStatus,
    pub stdout: Vec<String>,
    pub stderr: Vec<String>,
}

/// Runs a command to completion within the deadline.
pub fn run(name: &str, cmd: Command, deadline: Deadline) -> Finished {
    let mut child = ChildGuard::spawn(name, cmd);
    let status = child.wait_exit(deadline);
    Finished {
        status,
        stdout: child.stdout_lines(),
        stderr: child.stderr_lines(),
    }
}

/// The `hetcomm send` command line: as `system` to `to`'s Act module, type 7.
pub fn send_cmd(fleet: &Path, system: &str, to: &str, json: &str) -> Command {
    let mut cmd = Command::new(HETCOMM);
    cmd.arg("send")
        .arg(fleet)
        .args(["--as", system, "--to", to, "--module", "Act", "--type", "7"])
        .args(["--json", json, "--timeout", "20"]);
    cmd
}

/// Runs `hetcomm send` (see [`send_cmd`]) to completion.
pub fn send(fleet: &Path, system: &str, to: &str, json: &str, deadline: Deadline) -> Finished {
    run(
        &format!("send as {system} to {to}"),
        send_cmd(fleet, system, to, json),
        deadline,
    )
}

/// The counters line `hetcomm listen` prints on stderr when it exits.
pub fn counters_line(child: &ChildGuard) -> String {
    child
        .stderr_lines()
        .into_iter()
        .find(|l| l.starts_with("received "))
        .unwrap_or_else(|| panic!("no counters line: {:?}", child.stderr_lines()))
}

/// A `hetcomm listen` text line without its leading time column (`+1.234 s  ` by default,
/// `1732432042123456us  ` with `--raw-times`): from the sending system on.
pub fn message_text(line: &str) -> &str {
    match line.split_once("  ") {
        Some((time, rest)) if time.starts_with('+') || time.ends_with("us") => rest,
        _ => panic!("no time column at the start of {line:?}"),
    }
}

/// A data frame from system `from` (module Plan = 0) to `to`'s module `module`, type 7,
/// acknowledgement requested, carrying `payload` as given (not re-encoded).
pub fn raw_data_frame(from: u16, to: u16, module: u16, seq: u64, payload: &[u8]) -> Vec<u8> {
    use hetcomm::wire::{self, Header};
    use hetcomm::{Address, MessageType, ModuleId, SystemId, Time};
    let mut h = Header::data(
        Address {
            system: SystemId(from),
            module: ModuleId(0),
        },
        Address {
            system: SystemId(to),
            module: ModuleId(module),
        },
        MessageType(7),
    );
    h.flags = wire::FLAG_ACK_REQUESTED;
    h.incarnation = 0x5eed;
    h.seq = seq;
    h.timestamp = Time::from_micros(1_000_000);
    wire::encode(&h, payload)
}

/// Sends `signal` (e.g. `libc::SIGINT`) to the child.
pub fn signal(child: &ChildGuard, signal: i32) {
    let pid = libc::pid_t::try_from(child.id()).expect("a pid fits pid_t");
    // SAFETY: kill(2) with the pid of our own, not yet reaped, child.
    let rc = unsafe { libc::kill(pid, signal) };
    assert_eq!(rc, 0, "kill {pid}: {}", std::io::Error::last_os_error());
}

/// Alpha and a ROS robot Tango through a bridge of `kind` (`ros1_bridge`, `ros2_bridge`)
/// publishing Twist (type 40 from module Drive) on `topic`; `link` says where the ROS graph
/// is (`master_uri = "…"` or `domain_id = N`), `extra` adds keys to the transport.
pub fn twist_bridge_fleet(
    dir: &TempDir,
    kind: &str,
    link: &str,
    topic: &str,
    extra: &str,
) -> PathBuf {
    dir.write_plain(
        "fleet.toml",
        &format!(
            r#"
[systems]
Alpha = 1
Tango = 4

[modules]
Drive = 1

[transports.tango_ros]
kind = "{kind}"
robot = "Tango"
{link}
delivery = "unacknowledged"
security = "none"
{extra}

[transports.tango_ros.publish]
"{topic}" = "Drive 40 geometry_msgs/Twist"

[table]
columns = ["Alpha", "Tango"]
Alpha   = ["X",     "tango_ros"]
Tango   = ["tango_ros", "X"]
"#
        ),
    )
}

/// `hetcomm send FLEET --as Alpha --to Tango --module Drive --type 40 --json JSON`: a
/// geometry_msgs/Twist to a bridged robot Tango (the ROS bridge tests' fleets).
pub fn send_twist(fleet: &Path, json: &str, deadline: Deadline) -> Finished {
    let mut cmd = Command::new(HETCOMM);
    cmd.arg("send")
        .arg(fleet)
        .args(["--as", "Alpha", "--to", "Tango", "--module", "Drive"])
        .args(["--type", "40", "--json", json, "--timeout", "20"]);
    run("send Twist to Tango", cmd, deadline)
}

/// A Twist's JSON with `linear.x = x`.
pub fn twist(x: usize) -> String {
    format!(r#"{{"linear":{{"x":{x},"y":0,"z":0}},"angular":{{"x":0,"y":0,"z":0}}}}"#)
}

/// A payload that is not a Twist, sent to Tango through a bridge: refused at once by the link
/// with its own reason, one attempt, no wait for subscribers.
pub fn assert_a_non_twist_is_refused_at_once(fleet: &Path, deadline: Deadline) {
    let started = Instant::now();
    let sent = send_twist(fleet, r#"{"speed":1}"#, deadline);
    assert_eq!(sent.status.code(), Some(1), "{sent:?}");
    let [line] = &sent.stdout[..] else {
        panic!("one outcome line: {sent:?}");
    };
    assert!(
        line.starts_with(
            "Tango: failed: refused by the link: message type 40 for Drive does not convert to \
             geometry_msgs/Twist: "
        ) && line.ends_with("(attempts: 1)"),
        "{line}"
    );
    assert!(
        started.elapsed() < Duration::from_secs(3),
        "{:?}",
        started.elapsed()
    );
}
