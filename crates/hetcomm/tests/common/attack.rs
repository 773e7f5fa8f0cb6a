//! An attacker for the security tests: keys and fleets for systems A, B and C on one network
//! transport (udp, tcp or ros1), raw endpoints that speak the wire format without any
//! security ([`Station`]), and a relay that sits between A and B and records what passes
//! ([`Relay`]).
//!
//! Nothing here goes through hetcomm's runtime or security layer: frames are built with
//! `hetcomm::wire` (the unsecured frame of `docs/wire-format.md`) or copied off the wire, and
//! written to sockets (or a ROS topic) directly.
#![allow(dead_code)] // each test binary uses its own subset

use std::collections::BTreeMap;
use std::io::{Read, Write};
use std::net::{SocketAddr, TcpListener, TcpStream, UdpSocket};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{channel, Receiver};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use hetcomm::config::Fleet;
use hetcomm::security::Keypair;
use hetcomm::wire::{self, FrameKind, Header};
use hetcomm::{Address, MessageType, ModuleId, Priority, SecurityStats, SystemId};

/// The three systems of every attack fleet, by name and id.
pub const SYSTEMS: [(&str, u16); 3] = [("A", 0), ("B", 1), ("C", 2)];
/// Module ids: `Plan` sends, `Act` receives.
pub const PLAN: u16 = 0;
pub const ACT: u16 = 1;
/// A system id no fleet here has.
pub const STRANGER: u16 = 9;
/// The transport's name in every fleet.
pub const TRANSPORT: &str = "t";
/// Transmissions per message: more than the default 3, so that a handshake delayed by a
/// loaded machine (after a restart) does not outlast a message's retransmissions.
pub const ATTEMPTS: u32 = 5;

/// The default table: A ↔ B, B → C; C → B and anything to or from A and C is `X`.
pub const TABLE: [&str; 3] = [
    r#"A = ["X", "t", "X"]"#,
    r#"B = ["t", "X", "t"]"#,
    r#"C = ["X", "X", "X"]"#,
];

/// The transport kind an attack runs over.
#[derive(Clone, Debug)]
pub enum Kind {
    Udp,
    Tcp,
    /// A ROS 1 transport through the master at this URI.
    Ros1(String),
}

impl Kind {
    pub fn name(&self) -> &'static str {
        match self {
            Kind::Udp => "udp",
            Kind::Tcp => "tcp",
            Kind::Ros1(_) => "ros1",
        }
    }
}

pub fn id(name: &str) -> u16 {
    SYSTEMS
        .iter()
        .find(|(n, _)| *n == name)
        .map(|(_, i)| *i)
        .unwrap_or_else(|| panic!("no system {name}"))
}

fn free_port(kind: &Kind) -> u16 {
    match kind {
        Kind::Tcp => super::not_given_before(|| {
            TcpListener::bind("127.0.0.1:0")
                .and_then(|l| l.local_addr())
                .map(|a| a.port())
                .expect("a free TCP port")
        }),
        _ => super::free_udp_port(),
    }
}

/// Waits until `cond` holds (polling), at most `timeout`; whether it did.
pub fn wait_until(timeout: Duration, mut cond: impl FnMut() -> bool) -> bool {
    let deadline = Instant::now() + timeout;
    loop {
        if cond() {
            return true;
        }
        if Instant::now() >= deadline {
            return false;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
}

/// A directory of key files, removed on drop.
pub struct KeyDir {
    pub dir: PathBuf,
    pub pairs: BTreeMap<String, Keypair>,
}

impl KeyDir {
    /// A fresh key pair per name, written as `<name>.key` (0600) and `<name>.pub`.
    pub fn new(names: &[&str]) -> KeyDir {
        static N: AtomicU64 = AtomicU64::new(0);
        let dir = std::env::temp_dir().join(format!(
            "hc-attack-{}-{}",
            std::process::id(),
            N.fetch_add(1, Ordering::Relaxed)
        ));
        std::fs::create_dir_all(&dir).expect("key dir");
        let mut pairs = BTreeMap::new();
        for name in names {
            let pair = Keypair::generate().expect("a key pair");
            pair.write(&dir, name).expect("writing keys");
            pairs.insert(name.to_string(), pair);
        }
        KeyDir { dir, pairs }
    }

    pub fn private_file(&self, name: &str) -> PathBuf {
        self.dir.join(format!("{name}.key"))
    }
}

impl Drop for KeyDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

/// One attack's world: the transport, the systems' real endpoints and their keys.
pub struct Setup {
    pub kind: Kind,
    /// Where each system listens (udp, tcp).
    pub endpoints: BTreeMap<String, SocketAddr>,
    /// The ROS namespace (ros1): unique per setup, so tests on one master do not meet.
    pub namespace: String,
    pub keys: KeyDir,
}

impl Setup {
    pub fn new(kind: Kind) -> Setup {
        static N: AtomicU64 = AtomicU64::new(0);
        let endpoints = SYSTEMS
            .iter()
            .map(|(n, _)| {
                let addr: SocketAddr = format!("127.0.0.1:{}", free_port(&kind)).parse().unwrap();
                (n.to_string(), addr)
            })
            .collect();
        Setup {
            namespace: format!(
                "attack_{}_{}",
                std::process::id(),
                N.fetch_add(1, Ordering::Relaxed)
            ),
            kind,
            endpoints,
            keys: KeyDir::new(&["A", "B", "C"]),
        }
    }

    pub fn endpoint(&self, name: &str) -> SocketAddr {
        self.endpoints[name]
    }

    /// The fleet text, with some systems' endpoints replaced (`moved`: a relay in between)
    /// and the table's rows (`rows`).
    pub fn text(&self, moved: &[(&str, SocketAddr)], rows: [&str; 3]) -> String {
        let settings = match &self.kind {
            Kind::Udp | Kind::Tcp => {
                let eps: Vec<String> = SYSTEMS
                    .iter()
                    .map(|(n, _)| {
                        let addr = moved
                            .iter()
                            .find(|(m, _)| m == n)
                            .map(|(_, a)| *a)
                            .unwrap_or(self.endpoints[*n]);
                        format!("{n} = \"{addr}\"")
                    })
                    .collect();
                format!("endpoints = {{ {} }}", eps.join(", "))
            }
            Kind::Ros1(uri) => {
                format!("master_uri = \"{uri}\"\nnamespace = \"{}\"", self.namespace)
            }
        };
        format!(
            r#"[systems]
A = 0
B = 1
C = 2
[modules]
Plan = {PLAN}
Act = {ACT}
[transports.{TRANSPORT}]
kind = "{}"
attempts = {ATTEMPTS}
{settings}
[table]
columns = ["A", "B", "C"]
{}
{}
{}
"#,
            self.kind.name(),
            rows[0],
            rows[1],
            rows[2]
        )
    }

    /// The fleet as system `who` sees it: every system's public key, and `who`'s own private
    /// key file (the other systems' private keys are not in its process).
    pub fn fleet_for(&self, who: &str, moved: &[(&str, SocketAddr)], rows: [&str; 3]) -> Fleet {
        let text = self.text(moved, rows);
        let mut fleet = hetcomm::parse_fleet(&text, "attack.toml", None)
            .unwrap_or_else(|e| panic!("attack fleet does not parse: {e}\n{text}"));
        for s in &mut fleet.systems {
            s.public_key = Some(self.keys.pairs[&s.name].public.0);
            s.private_key_file = (s.name == who).then(|| self.keys.private_file(who));
        }
        fleet
    }

    /// Opens `who` with the default table, its own endpoints, and a relay for B (if given)
    /// in A's fleet.
    pub fn open(&self, who: &str, moved: &[(&str, SocketAddr)]) -> hetcomm::Comm {
        open_retrying(&self.fleet_for(who, moved, TABLE), who)
    }
}

/// Opens `who`, retrying for a while if its port is still held by a system that just closed.
pub fn open_retrying(fleet: &Fleet, who: &str) -> hetcomm::Comm {
    let deadline = Instant::now() + Duration::from_secs(10);
    loop {
        match hetcomm::Comm::open_fleet(fleet, who) {
            Ok(c) => return c,
            Err(e) if Instant::now() < deadline && e.to_string().contains("in use") => {
                std::thread::sleep(Duration::from_millis(20))
            }
            Err(e) => panic!("opening {who}: {e}"),
        }
    }
}

/// The security counters of `comm`'s link on the attack transport.
pub fn security(comm: &hetcomm::Comm) -> SecurityStats {
    comm.stats()
        .links
        .iter()
        .find(|(n, _)| n == TRANSPORT)
        .map(|(_, l)| l.security)
        .expect("a link on the attack transport")
}

// ---- frames ----------------------------------------------------------------------------

/// An unsecured data frame (exactly what a system without security sends).
pub fn plain_data(
    from: (u16, u16),
    to: (u16, u16),
    priority: u8,
    incarnation: u32,
    seq: u64,
    payload: &[u8],
) -> Vec<u8> {
    let mut h = Header::data(addr(from), addr(to), MessageType(1));
    h.flags = wire::FLAG_ACK_REQUESTED;
    h.priority = Priority(priority);
    h.incarnation = incarnation;
    h.seq = seq;
    wire::encode(&h, payload)
}

/// An unsecured acknowledgement ("delivered") of `(incarnation, seq)` from `from` to `to`.
pub fn plain_ack(from: (u16, u16), to: (u16, u16), incarnation: u32, seq: u64) -> Vec<u8> {
    let mut h = Header::data(addr(from), addr(to), MessageType(1));
    h.kind = FrameKind::Ack;
    h.incarnation = incarnation;
    h.seq = seq;
    wire::encode(&h, &[0])
}

fn addr((system, module): (u16, u16)) -> Address {
    Address {
        system: SystemId(system),
        module: ModuleId(module),
    }
}

/// A frame in the secured format (`"HS"`, version 1) of `kind` (1 init, 2 response, 3
/// data) from `sender` to `receiver`, whose body the attacker cannot make authentic:
/// `index` is the session index field, then `body`.
pub fn forged_secured(kind: u8, sender: u16, receiver: u16, index: u32, body: &[u8]) -> Vec<u8> {
    let mut f = b"HS\x01".to_vec();
    f.push(kind);
    f.extend_from_slice(&sender.to_le_bytes());
    f.extend_from_slice(&receiver.to_le_bytes());
    f.extend_from_slice(&index.to_le_bytes());
    f.extend_from_slice(body);
    f
}

/// A forged secured data frame: a guessed session index and counter, 48 + 8 bytes of
/// "ciphertext" and a 16-byte "tag".
pub fn forged_data(sender: u16, receiver: u16, index: u32, counter: u64) -> Vec<u8> {
    let mut body = counter.to_le_bytes().to_vec();
    body.extend(std::iter::repeat_n(0xA5, 48 + 8 + 16));
    forged_secured(3, sender, receiver, index, &body)
}

/// The secured message type of a captured frame (1 init, 2 response, 3 data), if it is one.
pub fn secured_kind(frame: &[u8]) -> Option<u8> {
    (frame.len() >= 8 && frame.starts_with(b"HS\x01")).then(|| frame[3])
}

/// (sender, receiver) of a secured frame.
pub fn secured_pair(frame: &[u8]) -> (u16, u16) {
    (
        u16::from_le_bytes([frame[4], frame[5]]),
        u16::from_le_bytes([frame[6], frame[7]]),
    )
}

/// The frames of one UDP datagram: a batch (`"HB"`) split into its records, anything else
/// whole.
pub fn datagram_frames(d: &[u8]) -> Vec<Vec<u8>> {
    if !d.starts_with(b"HB") || d.len() < 4 {
        return vec![d.to_vec()];
    }
    let mut out = Vec::new();
    let mut at = 4;
    while at + 4 <= d.len() {
        let len = u32::from_le_bytes(d[at..at + 4].try_into().unwrap()) as usize;
        at += 4;
        if at + len > d.len() {
            break;
        }
        out.push(d[at..at + len].to_vec());
        at += len;
    }
    out
}

fn hello(system: u16) -> [u8; 8] {
    let s = system.to_le_bytes();
    [b'H', b'L', 1, 0, s[0], s[1], 0, 0]
}

fn record(frame: &[u8]) -> Vec<u8> {
    let mut r = vec![b'H', b'R', 1, 0];
    r.extend_from_slice(&(frame.len() as u32).to_le_bytes());
    r.extend_from_slice(frame);
    r
}

/// Reads one connection's hello and records, sending each frame to `out` (and the hello's
/// system first, as the only `Err`).
fn read_stream(mut s: TcpStream, on_hello: impl FnOnce(u16), out: impl Fn(Vec<u8>)) {
    let mut h = [0u8; 8];
    if s.read_exact(&mut h).is_err() {
        return;
    }
    on_hello(u16::from_le_bytes([h[4], h[5]]));
    loop {
        let mut rh = [0u8; 8];
        if s.read_exact(&mut rh).is_err() {
            return;
        }
        let len = u32::from_le_bytes(rh[4..8].try_into().unwrap()) as usize;
        let mut frame = vec![0; len];
        if s.read_exact(&mut frame).is_err() {
            return;
        }
        out(frame);
    }
}

// ---- raw endpoints ---------------------------------------------------------------------

/// A raw endpoint on the attack transport, claiming to be system `claim`: it sends bytes
/// to systems' endpoints (TCP: after a hello naming `claim`), and, when placed at a
/// system's endpoint ([`Station::at`]), receives what is sent there.
pub struct Station {
    claim: u16,
    endpoints: BTreeMap<String, SocketAddr>,
    frames: Mutex<Receiver<Vec<u8>>>,
    inner: StationKind,
    stop: Arc<AtomicBool>,
}

enum StationKind {
    Udp(UdpSocket),
    Tcp(Mutex<BTreeMap<String, TcpStream>>),
    /// A rospy node, and the namespace of the fleet's topics.
    Ros1(Mutex<RosNode>, String),
}

impl Station {
    /// An endpoint anywhere (an ephemeral port; ROS: a rospy node of its own), claiming to be
    /// `claim` (in the TCP hello; UDP and ROS carry no claim but the frames').
    pub fn anywhere(setup: &Setup, claim: u16) -> Station {
        Self::open(setup, claim, None)
    }

    /// An endpoint in the place of system `name`: its UDP or TCP endpoint (which must be
    /// free: the system is not running), or a rospy subscriber of its ROS topic (beside it,
    /// if it runs: ROS gives every subscriber a copy).
    pub fn at(setup: &Setup, name: &str) -> Station {
        Self::open(setup, id(name), Some(name))
    }

    fn open(setup: &Setup, claim: u16, at: Option<&str>) -> Station {
        let (tx, rx) = channel();
        let stop = Arc::new(AtomicBool::new(false));
        let inner = match &setup.kind {
            Kind::Udp => {
                let bind = at.map_or("127.0.0.1:0".parse().unwrap(), |n| setup.endpoint(n));
                let sock = UdpSocket::bind(bind).expect("binding the attacker's socket");
                sock.set_read_timeout(Some(Duration::from_millis(20)))
                    .unwrap();
                let reader = sock.try_clone().unwrap();
                let stop = stop.clone();
                std::thread::spawn(move || {
                    let mut buf = vec![0; 65536];
                    while !stop.load(Ordering::Relaxed) {
                        if let Ok((n, _)) = reader.recv_from(&mut buf) {
                            for f in datagram_frames(&buf[..n]) {
                                let _ = tx.send(f);
                            }
                        }
                    }
                });
                StationKind::Udp(sock)
            }
            Kind::Tcp => {
                if let Some(n) = at {
                    let listener = TcpListener::bind(setup.endpoint(n)).expect("binding");
                    spawn_acceptor(listener, stop.clone(), move |s| {
                        let tx = tx.clone();
                        read_stream(s, |_| {}, move |f| drop(tx.send(f)))
                    });
                }
                StationKind::Tcp(Mutex::new(BTreeMap::new()))
            }
            Kind::Ros1(uri) => {
                let mut node = RosNode::start(uri, tx);
                if let Some(n) = at {
                    node.command(&format!("sub /{}/{n}", setup.namespace));
                }
                StationKind::Ros1(Mutex::new(node), setup.namespace.clone())
            }
        };
        Station {
            claim,
            endpoints: setup.endpoints.clone(),
            frames: Mutex::new(rx),
            inner,
            stop,
        }
    }

    /// Sends `frames` to system `to`, in order; with none, only connects to it (TCP: the
    /// hello; ROS: a publisher on its topic that it has subscribed to).
    pub fn send(&self, to: &str, frames: &[Vec<u8>]) {
        match &self.inner {
            StationKind::Udp(sock) => {
                for f in frames {
                    sock.send_to(f, self.endpoints[to]).expect("send_to");
                }
            }
            StationKind::Tcp(conns) => {
                let mut conns = conns.lock().unwrap();
                let s = conns.entry(to.to_string()).or_insert_with(|| {
                    let mut s = TcpStream::connect(self.endpoints[to]).expect("connecting");
                    s.set_nodelay(true).unwrap();
                    s.write_all(&hello(self.claim)).expect("hello");
                    s
                });
                let mut bytes = Vec::new();
                for f in frames {
                    bytes.extend_from_slice(&record(f));
                }
                s.write_all(&bytes).expect("writing records");
            }
            StationKind::Ros1(node, namespace) => {
                let mut node = node.lock().unwrap();
                // At most 200 frames a command, so a line stays short; none: only connect.
                let none: [Vec<u8>; 0] = [];
                let chunks = frames.chunks(200);
                for chunk in chunks.chain((frames.is_empty()).then_some(&none[..])) {
                    let list: Vec<String> = chunk.iter().map(|f| hex(f)).collect();
                    node.command(&format!("pub /{namespace}/{to} {}", list.join(" ")));
                }
            }
        }
    }

    /// The next frame that arrived here, waiting at most `timeout`.
    pub fn recv(&self, timeout: Duration) -> Option<Vec<u8>> {
        self.frames.lock().unwrap().recv_timeout(timeout).ok()
    }

    /// The next secured frame of kind `kind` that arrived here (others are skipped).
    pub fn recv_secured(&self, kind: u8, timeout: Duration) -> Option<Vec<u8>> {
        let deadline = Instant::now() + timeout;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            let f = self.recv(left)?;
            if secured_kind(&f) == Some(kind) {
                return Some(f);
            }
        }
    }

    /// Every frame received so far.
    pub fn drain(&self) -> Vec<Vec<u8>> {
        self.frames.lock().unwrap().try_iter().collect()
    }
}

impl Drop for Station {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
    }
}

/// The ROS attacker: `ros1_attacker.py`, an ordinary rospy node (see that file).
struct RosNode {
    child: std::process::Child,
    stdin: std::process::ChildStdin,
    replies: Receiver<String>,
}

impl RosNode {
    fn start(uri: &str, frames: std::sync::mpsc::Sender<Vec<u8>>) -> RosNode {
        use std::io::BufRead;
        use std::process::{Command, Stdio};
        let script = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/common/ros1_attacker.py");
        let home = std::env::temp_dir().join(format!("hc-attack-ros-{}", std::process::id()));
        let mut child = Command::new("/usr/bin/python3")
            .arg(script)
            .env("ROS_MASTER_URI", uri)
            .env("ROS_HOSTNAME", "127.0.0.1")
            .env("ROS_LOG_DIR", &home)
            .env("ROS_HOME", &home)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .spawn()
            .expect("starting the rospy attacker (/usr/bin/python3 with rospy)");
        let stdin = child.stdin.take().unwrap();
        let stdout = std::io::BufReader::new(child.stdout.take().unwrap());
        let (tx, replies) = channel();
        std::thread::spawn(move || {
            for line in stdout.lines().map_while(Result::ok) {
                match line.strip_prefix("F ") {
                    Some(hex) => drop(frames.send(unhex(hex))),
                    None => drop(tx.send(line)),
                }
            }
        });
        let mut node = RosNode {
            child,
            stdin,
            replies,
        };
        node.expect("READY", "starting");
        node
    }

    /// Sends one command and waits for its `OK`.
    fn command(&mut self, line: &str) {
        writeln!(self.stdin, "{line}").expect("writing to the rospy attacker");
        let what = line.split(' ').take(2).collect::<Vec<_>>().join(" ");
        self.expect("OK", &what);
    }

    fn expect(&mut self, want: &str, what: &str) {
        let got = self.replies.recv_timeout(Duration::from_secs(60));
        assert_eq!(got.as_deref(), Ok(want), "rospy attacker: {what}");
    }
}

impl Drop for RosNode {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn unhex(hex: &str) -> Vec<u8> {
    (0..hex.len() / 2)
        .map(|i| u8::from_str_radix(&hex[2 * i..2 * i + 2], 16).expect("hex"))
        .collect()
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

fn spawn_acceptor(
    listener: TcpListener,
    stop: Arc<AtomicBool>,
    on_conn: impl Fn(TcpStream) + Send + Sync + 'static,
) {
    listener.set_nonblocking(true).unwrap();
    let on_conn = Arc::new(on_conn);
    std::thread::spawn(move || {
        while !stop.load(Ordering::Relaxed) {
            match listener.accept() {
                Ok((s, _)) => {
                    s.set_nonblocking(false).unwrap();
                    let f = on_conn.clone();
                    std::thread::spawn(move || f(s));
                }
                Err(_) => std::thread::sleep(Duration::from_millis(5)),
            }
        }
    });
}

// ---- a relay that records ----------------------------------------------------------------

/// Sits at `addr`, forwards every frame to a target endpoint and records it: put `addr` in
/// the sender's fleet as the receiver's endpoint. UDP batches leave as one datagram per
/// frame; TCP connections are forwarded over connections of the relay's own (with the
/// sender's hello), opened again if the target restarted.
pub struct Relay {
    pub addr: SocketAddr,
    frames: Arc<Mutex<Vec<Vec<u8>>>>,
    stop: Arc<AtomicBool>,
}

impl Relay {
    pub fn new(kind: &Kind, target: SocketAddr) -> Relay {
        let frames: Arc<Mutex<Vec<Vec<u8>>>> = Default::default();
        let stop = Arc::new(AtomicBool::new(false));
        let addr = match kind {
            Kind::Udp => {
                let sock = UdpSocket::bind("127.0.0.1:0").unwrap();
                sock.set_read_timeout(Some(Duration::from_millis(20)))
                    .unwrap();
                let addr = sock.local_addr().unwrap();
                let (frames, stop) = (frames.clone(), stop.clone());
                std::thread::spawn(move || {
                    let mut buf = vec![0; 65536];
                    while !stop.load(Ordering::Relaxed) {
                        if let Ok((n, _)) = sock.recv_from(&mut buf) {
                            for f in datagram_frames(&buf[..n]) {
                                let _ = sock.send_to(&f, target);
                                frames.lock().unwrap().push(f);
                            }
                        }
                    }
                });
                addr
            }
            Kind::Tcp => {
                let listener = TcpListener::bind("127.0.0.1:0").unwrap();
                let addr = listener.local_addr().unwrap();
                let frames = frames.clone();
                spawn_acceptor(listener, stop.clone(), move |s| {
                    let frames = frames.clone();
                    let hello_of = Arc::new(Mutex::new(0u16));
                    let h2 = hello_of.clone();
                    let up: Mutex<Option<TcpStream>> = Mutex::new(None);
                    read_stream(
                        s,
                        move |sys| *h2.lock().unwrap() = sys,
                        move |f| {
                            let rec = record(&f);
                            frames.lock().unwrap().push(f);
                            let mut up = up.lock().unwrap();
                            for _ in 0..2 {
                                if up.is_none() {
                                    *up = TcpStream::connect(target).ok().and_then(|mut c| {
                                        c.set_nodelay(true).ok()?;
                                        c.write_all(&hello(*hello_of.lock().unwrap())).ok()?;
                                        Some(c)
                                    });
                                }
                                match up.as_mut().map(|c| c.write_all(&rec)) {
                                    Some(Ok(())) => break,
                                    _ => *up = None,
                                }
                            }
                        },
                    )
                });
                addr
            }
            Kind::Ros1(_) => panic!("ROS topics reach every subscriber: sniff with a Station"),
        };
        Relay { addr, frames, stop }
    }

    /// Every frame that passed so far.
    pub fn frames(&self) -> Vec<Vec<u8>> {
        self.frames.lock().unwrap().clone()
    }
}

impl Drop for Relay {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
    }
}
