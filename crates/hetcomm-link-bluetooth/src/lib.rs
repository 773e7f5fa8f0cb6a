//! # hetcomm-link-bluetooth — the `bluetooth` transport kind (RFCOMM)
//!
//! A [`Link`](hetcomm_link::Link) over Bluetooth Classic RFCOMM sockets, as the thesis's `BlueComm` class (§4.3.1):
//! each system listens on one RFCOMM channel, and sends to a peer over one connection to that
//! peer's device address, opened on first send. The fleet's `bluetooth` transport gives the
//! channel and each system's adapter address (Tables 3 and 8).
//!
//! All the stream logic is the shared [`stream`](hetcomm_link_ip::stream) layer's, the same
//! code TCP and Unix-socket links run: framing, one cached connection per peer, reconnection
//! with backoff, write deadlines (backpressure), the listener thread and clean shutdown. This
//! crate adds only the socket family and the identity rule:
//!
//! - **Identity by address** ([`IdentityMode::Address`]): there is no hello; the receiver maps
//!   the accepted connection's remote device address to the fleet system with that address.
//!   A connection from an address that is not in the fleet is closed before anything is read,
//!   and counted as one dropped frame and one rejected connection
//!   ([`StreamStats::rejected_connections`]).
//! - **Sockets** ([`socket`]): outgoing connections bind to this system's own fleet address,
//!   so peers can recognise it; the listener binds to any local adapter on the fleet's
//!   channel.
//!
//! ## Without Bluetooth
//!
//! On a kernel without Bluetooth support (no `AF_BLUETOOTH`, errno 97 `EAFNOSUPPORT`, as on
//! most CI machines and containers) [`BluetoothLink::open`] fails at once with
//! [`BluetoothOpenError::NoKernelSupport`], whose message suggests the `emulated` transport with
//! `profile = "bluetooth-classic"` for simulation.
//!
//! ## Why raw sockets rather than `bluer`
//!
//! `bluer`'s RFCOMM sockets (`default-features = false, features = ["rfcomm"]`) are
//! tokio-async only: every socket is created inside a tokio `AsyncFd`, whose constructor
//! panics outside a tokio runtime, and `Stream` has no way to give its descriptor back. Fitting
//! that to the synchronous stream layer would mean owning a tokio runtime inside the transport,
//! `dup`ing each connected descriptor out of a `Stream`, switching it back to blocking mode,
//! and then using `socket2` for the timeouts, clones and shutdowns the stream layer needs
//! anyway; the listener would need an async select to be woken. What `bluer` would really
//! contribute is one `socket()` call and the 10-byte `sockaddr_rc` layout (its `sys` module
//! is private). So this crate creates the socket with `socket2`
//! (`AF_BLUETOOTH` = 31, `SOCK_STREAM`, `BTPROTO_RFCOMM` = 3), builds `sockaddr_rc` itself
//! ([`socket::sockaddr_rc_bytes`], unit-tested), and uses `poll(2)` (through `rustix`) for a wakeable
//! listener: no async runtime, no extra threads, no D-Bus, and the same blocking model as the
//! TCP and Unix links. Pairing, trusting and adapter power stay with BlueZ (`bluetoothctl`,
//! see `docs/bluetooth.md`).
//!
//! ## What is tested without hardware
//!
//! The address family is the only part not exercised on a machine without Bluetooth. The
//! socket and listener code is generic over [`AddressFamily`]; the tests run this crate's
//! [`BluetoothLink`] — identity by address, rejection of unknown addresses, validation, the
//! conformance suite — over a Unix-socket family whose paths stand for device addresses, and
//! check the `sockaddr_rc` encoding byte by byte.
//!
//! ```
//! use std::collections::BTreeMap;
//! use hetcomm_core::SystemId;
//! use hetcomm_link::conformance::CollectSink;
//! use hetcomm_link_bluetooth::{BdAddr, BluetoothLink, BluetoothSettings, BluetoothOpenError};
//!
//! let settings = BluetoothSettings {
//!     channel: 1,
//!     addresses: BTreeMap::from([
//!         (SystemId(1), BdAddr([0x68, 0xA3, 0xC4, 0x4A, 0xB3, 0xBA])),
//!         (SystemId(2), BdAddr([0xE4, 0xB3, 0x18, 0x09, 0x09, 0x06])),
//!     ]),
//!     addresses_file: None,
//! };
//! let config = BluetoothLink::default_config();
//! match BluetoothLink::open(SystemId(1), &settings, CollectSink::new(), config) {
//!     Ok(link) => println!("listening on RFCOMM channel {}", link.channel()),
//!     Err(e @ BluetoothOpenError::NoKernelSupport { .. }) => println!("{e}"),
//!     Err(e) => println!("cannot open: {e}"),
//! }
//! ```

pub mod factory;
pub mod settings;
pub mod socket;

/// Registers the `bluetooth` transport factory ([`factory::BluetoothFactory`]).
pub fn register_transports(registry: &mut hetcomm_link::registry::Registry) {
    registry.register(factory::BluetoothFactory);
}

use std::collections::BTreeMap;
use std::io;
use std::sync::Arc;
use std::time::Duration;

pub use hetcomm_config::BdAddr;
use hetcomm_core::SystemId;
use hetcomm_link::FrameSink;
use hetcomm_link_ip::stream::{
    IdentityMode, StreamConfig, StreamLink, StreamStats, StreamTransport,
};
pub use settings::BluetoothSettings;
use socket2::SockAddr;

pub use socket::{AddressFamily, Rfcomm, RfcommListener, RfcommStream};
use socket::{MAX_CHANNEL, MIN_CHANNEL};

/// The hint every "no Bluetooth here" message ends with.
pub const SIMULATION_HINT: &str =
    "to simulate a Bluetooth link, use an `emulated` transport with profile = \"bluetooth-classic\"";

/// Why a Bluetooth link could not be opened.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum BluetoothOpenError {
    /// The kernel cannot create Bluetooth sockets at all (`EAFNOSUPPORT`).
    #[error(
        "this kernel has no Bluetooth (AF_BLUETOOTH) support: creating an RFCOMM socket failed \
         with {source}; RFCOMM links cannot run on this machine ({SIMULATION_HINT})"
    )]
    NoKernelSupport {
        /// The operating system's error.
        source: io::Error,
    },
    /// The kernel has Bluetooth sockets but no RFCOMM protocol (`EPROTONOSUPPORT`).
    #[error(
        "this kernel's Bluetooth stack has no RFCOMM support ({source}): load it with \
         `modprobe rfcomm`, or {SIMULATION_HINT}"
    )]
    NoRfcomm {
        /// The operating system's error.
        source: io::Error,
    },
    /// The operating system refused to create a Bluetooth socket (`EPERM`, `EACCES`).
    #[error(
        "not permitted to create a Bluetooth socket ({source}): a container or sandbox may \
         block AF_BLUETOOTH (a container needs the host's network namespace), or a security \
         module denies it"
    )]
    Permission {
        /// The operating system's error.
        source: io::Error,
    },
    /// The system being opened has no address in the settings, so peers could not tell its
    /// connections from a stranger's.
    #[error(
        "system {system} has no Bluetooth address in the transport's `addresses`: add this \
         machine's adapter address (the `Controller` line of `bluetoothctl show`)"
    )]
    NoLocalAddress {
        /// The system being opened.
        system: SystemId,
    },
    /// A setting is out of range or inconsistent.
    #[error("invalid Bluetooth settings: {field}: {reason}")]
    BadConfig {
        /// The setting's name.
        field: &'static str,
        /// What is wrong with it.
        reason: String,
    },
    /// Another socket on this machine already listens on the channel.
    #[error(
        "RFCOMM channel {channel} is already in use on this machine ({source}): stop the other \
         listener (another hetcomm process, `rfcomm listen`, or a BlueZ profile such as the \
         serial port service) or choose another `channel` for the whole fleet"
    )]
    ChannelBusy {
        /// The fleet's channel.
        channel: u8,
        /// The operating system's error.
        source: io::Error,
    },
    /// The listener could not be bound or could not listen.
    #[error("cannot listen on RFCOMM channel {channel}: {source}")]
    Listen {
        /// The fleet's channel.
        channel: u8,
        /// The operating system's error.
        source: io::Error,
    },
    /// Another operating-system error (creating the wake-up pair, starting a thread).
    #[error("i/o error while opening the Bluetooth link: {0}")]
    Io(#[from] io::Error),
}

impl BluetoothOpenError {
    /// Classifies a failure to create a socket: no kernel support, no RFCOMM, no permission,
    /// or another error.
    pub fn from_socket_error(source: io::Error) -> BluetoothOpenError {
        match source.raw_os_error() {
            Some(libc::EAFNOSUPPORT) => BluetoothOpenError::NoKernelSupport { source },
            Some(libc::EPROTONOSUPPORT) | Some(libc::ESOCKTNOSUPPORT) => {
                BluetoothOpenError::NoRfcomm { source }
            }
            Some(libc::EPERM) | Some(libc::EACCES) => BluetoothOpenError::Permission { source },
            _ => BluetoothOpenError::Io(source),
        }
    }
}

/// Checks `settings` for system `local` without touching any socket: the channel is 1–30,
/// `local` has an address, no address is used twice, and no address is reserved
/// (`00:00:00:00:00:00` "any", `00:00:00:FF:FF:FF` "local", `FF:FF:FF:FF:FF:FF` "all").
pub fn validate(local: SystemId, settings: &BluetoothSettings) -> Result<(), BluetoothOpenError> {
    if !(MIN_CHANNEL..=MAX_CHANNEL).contains(&settings.channel) {
        return Err(BluetoothOpenError::BadConfig {
            field: "channel",
            reason: format!(
                "RFCOMM channels are {MIN_CHANNEL} to {MAX_CHANNEL}, got {}",
                settings.channel
            ),
        });
    }
    let mut by_addr: BTreeMap<BdAddr, SystemId> = BTreeMap::new();
    for (&system, &addr) in &settings.addresses {
        if is_reserved(addr) {
            return Err(BluetoothOpenError::BadConfig {
                field: "addresses",
                reason: format!(
                    "system {system} has the reserved address {addr}, which no adapter has"
                ),
            });
        }
        if let Some(other) = by_addr.insert(addr, system) {
            return Err(BluetoothOpenError::BadConfig {
                field: "addresses",
                reason: format!(
                    "systems {other} and {system} both have address {addr}, so a connection \
                     from it could not be attributed"
                ),
            });
        }
    }
    if !settings.addresses.contains_key(&local) {
        return Err(BluetoothOpenError::NoLocalAddress { system: local });
    }
    Ok(())
}

fn is_reserved(addr: BdAddr) -> bool {
    matches!(
        addr.0,
        [0, 0, 0, 0, 0, 0] | [0, 0, 0, 0xFF, 0xFF, 0xFF] | [0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF]
    )
}

/// A short explanation of a common RFCOMM connect error, for error reasons; `None` when the
/// operating system's own message says enough.
pub fn connect_hint(e: &io::Error, channel: u8) -> Option<String> {
    let hint = match e.raw_os_error()? {
        libc::EHOSTDOWN => "the device is off, out of range, or its adapter is not connectable \
             (on the peer: `bluetoothctl power on`, and is its hetcomm link running?)"
            .to_string(),
        libc::ECONNREFUSED => format!(
            "the device answered but nothing listens on RFCOMM channel {channel}: both ends must \
             use the fleet's `channel`, and the peer's link must be open"
        ),
        libc::EHOSTUNREACH => "no local adapter has this system's fleet address: check \
             `bluetoothctl show` against the fleet file, and that the adapter is powered"
            .to_string(),
        libc::EACCES | libc::EPERM => "the connection was refused for security reasons: pair \
             and trust the two devices with `bluetoothctl` (see docs/bluetooth.md)"
            .to_string(),
        libc::ECONNRESET | libc::ECONNABORTED => "the peer dropped the connection during set-up \
             (pairing rejected, or the peer is not trusted)"
            .to_string(),
        libc::ETIMEDOUT => "no answer in time: the device may be out of range or busy".to_string(),
        _ => return None,
    };
    Some(hint)
}

/// Where a peer listens: its device address and the fleet's channel.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RfcommAddr {
    /// The peer's adapter address.
    pub device: BdAddr,
    /// The RFCOMM channel it listens on.
    pub channel: u8,
}

impl std::fmt::Display for RfcommAddr {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "[{}]:{}", self.device, self.channel)
    }
}

/// The Bluetooth [`StreamTransport`]: connects from this system's address to peers' addresses
/// and identifies accepted connections by their remote address.
pub struct BluetoothTransport<F: AddressFamily = Rfcomm> {
    family: F,
    local: BdAddr,
    systems: BTreeMap<BdAddr, SystemId>,
}

impl<F: AddressFamily> BluetoothTransport<F> {
    /// A transport for the system whose address is `local`, with `systems` giving the fleet
    /// system behind each address.
    pub fn new(family: F, local: BdAddr, systems: BTreeMap<BdAddr, SystemId>) -> Self {
        BluetoothTransport {
            family,
            local,
            systems,
        }
    }

    /// The system with device address `device`, if it is in the fleet.
    pub fn system_of(&self, device: BdAddr) -> Option<SystemId> {
        self.systems.get(&device).copied()
    }
}

impl<F: AddressFamily> StreamTransport for BluetoothTransport<F> {
    type Socket = RfcommStream;
    type Listener = RfcommListener;
    type Addr = RfcommAddr;
    const NAME: &'static str = "bluetooth";

    fn connect(&self, addr: &RfcommAddr, timeout: Duration) -> io::Result<RfcommStream> {
        let explain = |e: io::Error| match connect_hint(&e, addr.channel) {
            Some(hint) => io::Error::new(e.kind(), format!("{e}: {hint}")),
            None => e,
        };
        let socket = self.family.stream_socket()?;
        if let Some(source) = self.family.source_addr(self.local)? {
            socket.bind(&source).map_err(|e| {
                io::Error::new(
                    e.kind(),
                    format!("binding to this system's address {}: {e}", self.local),
                )
            })?;
        }
        let target = self.family.connect_addr(addr.device, addr.channel)?;
        socket.connect_timeout(&target, timeout).map_err(explain)?;
        socket.set_nonblocking(false)?;
        Ok(RfcommStream(socket))
    }

    fn identity_mode(&self) -> IdentityMode {
        IdentityMode::Address
    }

    fn peer_identity(&self, addr: &SockAddr) -> Option<SystemId> {
        self.family
            .device_of(addr)
            .and_then(|device| self.system_of(device))
    }

    /// RFCOMM is a reliable stream over L2CAP, whose frames the baseband checks (CRC) and
    /// retransmits: bytes arrive unaltered or not at all.
    fn checksums_payload(&self) -> bool {
        true
    }
}

/// A system's Bluetooth endpoint: a [`StreamLink`] over [`BluetoothTransport`].
///
/// `F` is the socket family: [`Rfcomm`] on real hardware; tests substitute a Unix-socket
/// family through [`BluetoothLink::open_with_family`].
pub struct BluetoothLink<F: AddressFamily = Rfcomm> {
    inner: StreamLink<BluetoothTransport<F>>,
    device: BdAddr,
    channel: u8,
}

impl BluetoothLink<Rfcomm> {
    /// Stream timeouts for Bluetooth Classic: connects may take up to 6 s (longer than the
    /// 5.12 s default page timeout, so an absent device is reported by the kernel as "Host
    /// is down" rather than as our timeout), writes up to 5 s (a 64 KiB frame takes about
    /// 0.7 s at the 723 kbit/s basic rate), and reconnects back off from 250 ms to 8 s.
    pub fn default_config() -> StreamConfig {
        StreamConfig {
            connect_timeout: Duration::from_secs(6),
            write_timeout: Duration::from_secs(5),
            backoff_initial: Duration::from_millis(250),
            backoff_max: Duration::from_secs(8),
            ..StreamConfig::default()
        }
    }

    /// Opens system `local`'s RFCOMM endpoint: validates `settings` ([`validate`]), listens on
    /// the fleet's channel, and sends to every other system in `settings.addresses`. Received
    /// frames go to `sink`, labelled with the sender found from its device address.
    ///
    /// On a kernel without Bluetooth this fails at once with
    /// [`BluetoothOpenError::NoKernelSupport`]. [`BluetoothLink::default_config`] gives timeouts suited
    /// to radio links.
    pub fn open(
        local: SystemId,
        settings: &BluetoothSettings,
        sink: Arc<dyn FrameSink>,
        config: StreamConfig,
    ) -> Result<BluetoothLink<Rfcomm>, BluetoothOpenError> {
        BluetoothLink::open_with_family(Rfcomm, local, settings, sink, config)
    }
}

impl<F: AddressFamily> BluetoothLink<F> {
    /// As [`BluetoothLink::open`], over the socket family `family`.
    pub fn open_with_family(
        family: F,
        local: SystemId,
        settings: &BluetoothSettings,
        sink: Arc<dyn FrameSink>,
        config: StreamConfig,
    ) -> Result<BluetoothLink<F>, BluetoothOpenError> {
        validate(local, settings)?;
        let Some(&device) = settings.addresses.get(&local) else {
            return Err(BluetoothOpenError::NoLocalAddress { system: local });
        };
        let channel = settings.channel;
        let socket = family
            .stream_socket()
            .map_err(BluetoothOpenError::from_socket_error)?;
        let listen_err = |source: io::Error| {
            if source.kind() == io::ErrorKind::AddrInUse {
                BluetoothOpenError::ChannelBusy { channel, source }
            } else {
                BluetoothOpenError::Listen { channel, source }
            }
        };
        let addr = family.listen_addr(device, channel).map_err(listen_err)?;
        socket.bind(&addr).map_err(listen_err)?;
        socket.listen(8).map_err(listen_err)?;
        let listener = RfcommListener::new(socket)?;
        let systems = settings
            .addresses
            .iter()
            .map(|(&system, &addr)| (addr, system))
            .collect();
        let peers = settings
            .addresses
            .iter()
            .map(|(&system, &device)| (system, RfcommAddr { device, channel }))
            .collect();
        let transport = BluetoothTransport::new(family, device, systems);
        let inner = StreamLink::new(transport, local, listener, peers, sink, config)?;
        Ok(BluetoothLink {
            inner,
            device,
            channel,
        })
    }

    /// This system's device address, from the settings.
    pub fn device(&self) -> BdAddr {
        self.device
    }

    /// The RFCOMM channel this link listens on and connects to.
    pub fn channel(&self) -> u8 {
        self.channel
    }

    /// The system this link belongs to.
    pub fn local(&self) -> SystemId {
        self.inner.local()
    }

    /// All counters of the underlying stream link, including rejected connections from
    /// addresses outside the fleet.
    pub fn stream_stats(&self) -> StreamStats {
        self.inner.stream_stats()
    }
}

hetcomm_link::forward_link!(impl<F: AddressFamily> BluetoothLink<F>, inner);

#[cfg(test)]
mod tests {
    use super::socket::*;
    use super::*;

    const CHARLIE: BdAddr = BdAddr([0x68, 0xA3, 0xC4, 0x4A, 0xB3, 0xBA]);

    #[test]
    fn sockaddr_rc_stores_the_address_reversed() {
        let b = sockaddr_rc_bytes(CHARLIE, 7);
        assert_eq!(u16::from_ne_bytes([b[0], b[1]]), 31);
        assert_eq!(&b[2..8], &[0xBA, 0xB3, 0x4A, 0xC4, 0xA3, 0x68]);
        assert_eq!(b[8], 7);
        assert_eq!(b[9], 0);
        assert_eq!(parse_sockaddr_rc_bytes(&b), Some((CHARLIE, 7)));
    }

    #[test]
    fn sockaddr_rc_round_trips_through_socket2() {
        let sa = rfcomm_sockaddr(CHARLIE, 30);
        assert_eq!(i32::from(sa.family()), AF_BLUETOOTH);
        assert_eq!(sa.len() as usize, SOCKADDR_RC_LEN);
        assert_eq!(parse_rfcomm_sockaddr(&sa), Some((CHARLIE, 30)));
        assert_eq!(Rfcomm.device_of(&sa), Some(CHARLIE));
        // Any local adapter, as the listener binds.
        let any = Rfcomm.listen_addr(CHARLIE, 3).unwrap();
        assert_eq!(parse_rfcomm_sockaddr(&any), Some((BdAddr([0; 6]), 3)));
        // The source of outgoing connections is this system's own address, channel 0.
        let src = Rfcomm.source_addr(CHARLIE).unwrap().unwrap();
        assert_eq!(parse_rfcomm_sockaddr(&src), Some((CHARLIE, 0)));
    }

    #[test]
    fn other_families_are_not_device_addresses() {
        let ip = SockAddr::from("127.0.0.1:9".parse::<std::net::SocketAddr>().unwrap());
        assert_eq!(parse_rfcomm_sockaddr(&ip), None);
        assert_eq!(Rfcomm.device_of(&ip), None);
        assert_eq!(parse_sockaddr_rc_bytes(&[31, 0, 1]), None);
        let mut wrong_family = sockaddr_rc_bytes(CHARLIE, 1);
        wrong_family[0..2].copy_from_slice(&2u16.to_ne_bytes());
        assert_eq!(parse_sockaddr_rc_bytes(&wrong_family), None);
    }

    #[test]
    fn socket_errors_are_classified() {
        let e = |n| BluetoothOpenError::from_socket_error(io::Error::from_raw_os_error(n));
        assert!(matches!(
            e(libc::EAFNOSUPPORT),
            BluetoothOpenError::NoKernelSupport { .. }
        ));
        assert!(matches!(
            e(libc::EPROTONOSUPPORT),
            BluetoothOpenError::NoRfcomm { .. }
        ));
        assert!(matches!(
            e(libc::EACCES),
            BluetoothOpenError::Permission { .. }
        ));
        assert!(matches!(e(libc::EMFILE), BluetoothOpenError::Io(_)));
        let msg = e(libc::EAFNOSUPPORT).to_string();
        assert!(msg.contains("no Bluetooth (AF_BLUETOOTH) support"), "{msg}");
        assert!(msg.contains("profile = \"bluetooth-classic\""), "{msg}");
    }

    #[test]
    fn connect_errors_get_troubleshooting_hints() {
        let hint = |n| connect_hint(&io::Error::from_raw_os_error(n), 4);
        assert!(hint(libc::EHOSTDOWN).unwrap().contains("out of range"));
        assert!(hint(libc::ECONNREFUSED).unwrap().contains("channel 4"));
        assert!(hint(libc::EHOSTUNREACH)
            .unwrap()
            .contains("bluetoothctl show"));
        assert!(hint(libc::EACCES).unwrap().contains("pair"));
        assert_eq!(hint(libc::EMFILE), None);
        assert_eq!(connect_hint(&io::Error::other("no errno"), 4), None);
    }

    #[test]
    fn rfcomm_addr_displays_like_bluer() {
        let a = RfcommAddr {
            device: CHARLIE,
            channel: 1,
        };
        assert_eq!(a.to_string(), "[68:A3:C4:4A:B3:BA]:1");
    }
}
