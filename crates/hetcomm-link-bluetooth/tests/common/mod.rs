//! Helpers shared by the integration tests: a Unix-socket stand-in for the RFCOMM address
//! family, a temporary directory and a deadline-bounded wait.
//!
//! [`UnixFamily`] turns device addresses into socket paths: a system with address
//! `68:A3:C4:4A:B3:BA` listens on `<dir>/68A3C44AB3BA-ch<channel>.listen`, and its outgoing
//! connections bind to `<dir>/68A3C44AB3BA.<n>.src`, so the receiver's `accept` sees the
//! sender's "device address" in the peer path just as RFCOMM shows the remote adapter address.

#![allow(dead_code)] // each test binary uses a different subset

use std::collections::BTreeMap;
use std::io;
use std::os::unix::net::UnixStream;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use hetcomm_core::SystemId;
use hetcomm_link::conformance::Harness;
use hetcomm_link::{FrameSink, Link};
use hetcomm_link_bluetooth::{AddressFamily, BluetoothLink};
use hetcomm_link_bluetooth::{BdAddr, BluetoothSettings};
use hetcomm_link_ip::stream::StreamConfig;
use socket2::{Domain, SockAddr, Socket, Type};

/// How long a test waits for something that should happen promptly.
pub const DEADLINE: Duration = Duration::from_secs(10);

/// Table 8's addresses: system 1 (Charlie) and system 2 (Tango).
pub const CHARLIE: BdAddr = BdAddr([0x68, 0xA3, 0xC4, 0x4A, 0xB3, 0xBA]);
/// Tango's address in Table 8.
pub const TANGO: BdAddr = BdAddr([0xE4, 0xB3, 0x18, 0x09, 0x09, 0x06]);
/// An address that is in no fleet.
pub const STRANGER: BdAddr = BdAddr([0x00, 0x1A, 0x7D, 0xDA, 0x71, 0x13]);

/// Waits until `cond` holds, failing the test naming `what` if `timeout` passes first.
pub fn wait_until(what: &str, timeout: Duration, mut cond: impl FnMut() -> bool) {
    let deadline = Instant::now() + timeout;
    while !cond() {
        assert!(Instant::now() < deadline, "timed out waiting for {what}");
        std::thread::sleep(Duration::from_millis(1));
    }
}

/// A fresh, empty directory for socket files, removed when dropped.
pub struct TempDir(pub PathBuf);

impl TempDir {
    pub fn new(tag: &str) -> TempDir {
        static NEXT: AtomicU32 = AtomicU32::new(0);
        let n = NEXT.fetch_add(1, Ordering::Relaxed);
        let dir = std::env::temp_dir().join(format!("hetcomm-bt-{tag}-{}-{n}", std::process::id()));
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

/// Twelve hex digits, as the stand-in family writes a device address in a path.
pub fn hex(addr: BdAddr) -> String {
    addr.0.iter().map(|b| format!("{b:02X}")).collect()
}

fn unhex(s: &str) -> Option<BdAddr> {
    if s.len() != 12 || !s.is_ascii() {
        return None;
    }
    let mut out = [0u8; 6];
    for (i, o) in out.iter_mut().enumerate() {
        *o = u8::from_str_radix(&s[2 * i..2 * i + 2], 16).ok()?;
    }
    Some(BdAddr(out))
}

/// The RFCOMM address family's stand-in: Unix stream sockets in one directory.
#[derive(Clone)]
pub struct UnixFamily {
    pub dir: PathBuf,
    next: Arc<AtomicU32>,
}

impl UnixFamily {
    pub fn new(dir: &Path) -> UnixFamily {
        UnixFamily {
            dir: dir.to_path_buf(),
            next: Arc::new(AtomicU32::new(0)),
        }
    }

    /// Where the system with `device` listens on `channel`.
    pub fn listen_path(&self, device: BdAddr, channel: u8) -> PathBuf {
        self.dir.join(format!("{}-ch{channel}.listen", hex(device)))
    }

    /// A fresh source path for a connection from `device`.
    pub fn source_path(&self, device: BdAddr) -> PathBuf {
        let n = self.next.fetch_add(1, Ordering::Relaxed);
        self.dir.join(format!("{}.{n}.src", hex(device)))
    }

    /// A raw connection to `to`'s listener on `channel` that claims to come from `from`
    /// (`None`: an unnamed socket with no address at all).
    pub fn raw_connect(&self, from: Option<BdAddr>, to: BdAddr, channel: u8) -> Socket {
        let s = self.stream_socket().expect("unix socket");
        if let Some(from) = from {
            s.bind(&SockAddr::unix(self.source_path(from)).unwrap())
                .expect("bind source path");
        }
        s.connect(&SockAddr::unix(self.listen_path(to, channel)).unwrap())
            .expect("connect to listener");
        s
    }
}

impl AddressFamily for UnixFamily {
    fn stream_socket(&self) -> io::Result<Socket> {
        Socket::new(Domain::UNIX, Type::STREAM, None)
    }

    fn listen_addr(&self, local: BdAddr, channel: u8) -> io::Result<SockAddr> {
        let path = self.listen_path(local, channel);
        // A file left by a listener that was dropped (a restart) is stale; a live one is a
        // busy channel and must make bind fail.
        if path.exists() && UnixStream::connect(&path).is_err() {
            std::fs::remove_file(&path)?;
        }
        SockAddr::unix(path)
    }

    fn source_addr(&self, local: BdAddr) -> io::Result<Option<SockAddr>> {
        SockAddr::unix(self.source_path(local)).map(Some)
    }

    fn connect_addr(&self, device: BdAddr, channel: u8) -> io::Result<SockAddr> {
        SockAddr::unix(self.listen_path(device, channel))
    }

    fn device_of(&self, remote: &SockAddr) -> Option<BdAddr> {
        let name = remote.as_pathname()?.file_name()?.to_str()?;
        unhex(name.split('.').next()?)
    }
}

/// Bluetooth settings with `channel` and the given systems' addresses.
pub fn settings(channel: u8, addresses: &[(SystemId, BdAddr)]) -> BluetoothSettings {
    BluetoothSettings {
        channel,
        addresses: addresses.iter().copied().collect::<BTreeMap<_, _>>(),
        addresses_file: None,
    }
}

/// Opens Bluetooth links over [`UnixFamily`] for the conformance suite's systems 1 and 2,
/// with Table 8's addresses.
pub struct UnixBtHarness {
    pub dir: TempDir,
    pub family: UnixFamily,
    pub settings: BluetoothSettings,
    pub config: StreamConfig,
}

impl UnixBtHarness {
    pub fn new(config: StreamConfig) -> Self {
        let dir = TempDir::new("harness");
        let family = UnixFamily::new(&dir.0);
        UnixBtHarness {
            dir,
            family,
            settings: settings(1, &[(SystemId(1), CHARLIE), (SystemId(2), TANGO)]),
            config,
        }
    }

    pub fn open_bt(
        &mut self,
        system: SystemId,
        sink: Arc<dyn FrameSink>,
    ) -> BluetoothLink<UnixFamily> {
        BluetoothLink::open_with_family(
            self.family.clone(),
            system,
            &self.settings,
            sink,
            self.config.clone(),
        )
        .expect("open bluetooth link over unix sockets")
    }
}

impl Harness for UnixBtHarness {
    fn open(&mut self, system: SystemId, sink: Arc<dyn FrameSink>) -> Box<dyn Link> {
        Box::new(self.open_bt(system, sink))
    }
}
