//! Helpers shared by the integration tests: conformance harnesses that pre-bind port 0 (or a
//! fresh socket path) for every system, and a deadline-bounded condition wait.

#![allow(dead_code)] // each test binary uses a different subset

pub mod driven;

use std::collections::{BTreeMap, HashMap};
use std::io::Read;
use std::net::{TcpListener, TcpStream, UdpSocket};
use std::path::PathBuf;
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use hetcomm_core::SystemId;
use hetcomm_link::conformance::Harness;
use hetcomm_link::{FrameSink, Link};
use hetcomm_link_ip::stream::{StreamConfig, RECORD_MAGIC, STREAM_VERSION};
use hetcomm_link_ip::{TcpLink, UdpConfig, UdpLink, UnixLink};

/// How long a test waits for something that should happen promptly.
pub const DEADLINE: Duration = Duration::from_secs(10);

/// Waits until `cond` holds, checking every millisecond, and fails the test naming `what`
/// if `timeout` passes first. Used for effects with no event to wait on (counters kept by a
/// link's threads); it returns as soon as the condition holds.
pub fn wait_until(what: &str, timeout: Duration, mut cond: impl FnMut() -> bool) {
    let deadline = Instant::now() + timeout;
    while !cond() {
        assert!(Instant::now() < deadline, "timed out waiting for {what}");
        std::thread::park_timeout(Duration::from_millis(1));
    }
}

/// The systems the conformance suite uses.
pub const SYSTEMS: [SystemId; 2] = [SystemId(1), SystemId(2)];

/// Binds a TCP listener on a free loopback port for each system.
pub fn tcp_listeners(
    systems: &[SystemId],
) -> (BTreeMap<SystemId, String>, HashMap<SystemId, TcpListener>) {
    let mut endpoints = BTreeMap::new();
    let mut listeners = HashMap::new();
    for &s in systems {
        let l = TcpListener::bind("127.0.0.1:0").expect("bind port 0");
        endpoints.insert(s, l.local_addr().expect("local addr").to_string());
        listeners.insert(s, l);
    }
    (endpoints, listeners)
}

/// Opens TCP links on pre-bound listeners; reopening a system rebinds its port (a restart).
pub struct TcpHarness {
    pub endpoints: BTreeMap<SystemId, String>,
    pub listeners: HashMap<SystemId, TcpListener>,
    pub config: StreamConfig,
}

impl TcpHarness {
    pub fn new(config: StreamConfig) -> Self {
        let (endpoints, listeners) = tcp_listeners(&SYSTEMS);
        TcpHarness {
            endpoints,
            listeners,
            config,
        }
    }

    pub fn open_tcp(&mut self, system: SystemId, sink: Arc<dyn FrameSink>) -> TcpLink {
        let listener = match self.listeners.remove(&system) {
            Some(l) => l,
            None => {
                TcpListener::bind(self.endpoints[&system].as_str()).expect("rebind the same port")
            }
        };
        TcpLink::with_listener(system, listener, &self.endpoints, sink, self.config.clone())
            .expect("open tcp link")
    }
}

impl Harness for TcpHarness {
    fn open(&mut self, system: SystemId, sink: Arc<dyn FrameSink>) -> Box<dyn Link> {
        Box::new(self.open_tcp(system, sink))
    }
}

/// Binds a UDP socket on a free loopback port for each system.
pub fn udp_sockets(
    systems: &[SystemId],
) -> (BTreeMap<SystemId, String>, HashMap<SystemId, UdpSocket>) {
    let mut endpoints = BTreeMap::new();
    let mut sockets = HashMap::new();
    for &s in systems {
        let u = UdpSocket::bind("127.0.0.1:0").expect("bind port 0");
        endpoints.insert(s, u.local_addr().expect("local addr").to_string());
        sockets.insert(s, u);
    }
    (endpoints, sockets)
}

/// Opens UDP links on pre-bound sockets; reopening a system rebinds its port (a restart).
pub struct UdpHarness {
    pub endpoints: BTreeMap<SystemId, String>,
    pub sockets: HashMap<SystemId, UdpSocket>,
    pub config: UdpConfig,
}

impl UdpHarness {
    pub fn new(config: UdpConfig) -> Self {
        let (endpoints, sockets) = udp_sockets(&SYSTEMS);
        UdpHarness {
            endpoints,
            sockets,
            config,
        }
    }

    pub fn open_udp(&mut self, system: SystemId, sink: Arc<dyn FrameSink>) -> UdpLink {
        let socket = match self.sockets.remove(&system) {
            Some(s) => s,
            None => {
                UdpSocket::bind(self.endpoints[&system].as_str()).expect("rebind the same port")
            }
        };
        UdpLink::with_socket(system, socket, &self.endpoints, sink, self.config.clone())
            .expect("open udp link")
    }
}

impl Harness for UdpHarness {
    fn open(&mut self, system: SystemId, sink: Arc<dyn FrameSink>) -> Box<dyn Link> {
        Box::new(self.open_udp(system, sink))
    }
}

/// A fresh, empty directory for socket files, removed when dropped.
pub struct TempDir(pub PathBuf);

impl TempDir {
    pub fn new(tag: &str) -> TempDir {
        static NEXT: AtomicU32 = AtomicU32::new(0);
        let n = NEXT.fetch_add(1, Ordering::Relaxed);
        let dir = std::env::temp_dir().join(format!("hetcomm-{tag}-{}-{n}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).expect("create temp dir");
        TempDir(dir)
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// Opens Unix-socket links on paths in a temporary directory.
pub struct UnixHarness {
    pub dir: TempDir,
    pub paths: BTreeMap<SystemId, PathBuf>,
    pub config: StreamConfig,
}

impl UnixHarness {
    pub fn new(config: StreamConfig) -> Self {
        let dir = TempDir::new("unix");
        let paths = SYSTEMS
            .iter()
            .map(|s| (*s, dir.0.join(format!("system-{}.sock", s.0))))
            .collect();
        UnixHarness { dir, paths, config }
    }
}

impl Harness for UnixHarness {
    fn open(&mut self, system: SystemId, sink: Arc<dyn FrameSink>) -> Box<dyn Link> {
        Box::new(
            UnixLink::bind(system, &self.paths, sink, self.config.clone()).expect("open unix link"),
        )
    }
}

/// Waits until the server closes `s` (a read returns end-of-stream or an error).
pub fn assert_closed_by_peer(s: &mut TcpStream) {
    s.set_read_timeout(Some(DEADLINE)).unwrap();
    let started = Instant::now();
    let mut buf = [0u8; 64];
    loop {
        match s.read(&mut buf) {
            Ok(0) | Err(_) => break,
            Ok(_) => {}
        }
    }
    assert!(
        started.elapsed() < DEADLINE,
        "the link did not close the connection"
    );
}

/// `frame` as one stream record (header and bytes).
pub fn record(frame: &[u8]) -> Vec<u8> {
    let mut r = RECORD_MAGIC.to_vec();
    r.extend_from_slice(&[STREAM_VERSION, 0]);
    r.extend_from_slice(&(frame.len() as u32).to_le_bytes());
    r.extend_from_slice(frame);
    r
}
