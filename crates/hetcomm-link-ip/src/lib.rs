//! # hetcomm-link-ip — IP and local-socket transports
//!
//! The transport layer below the router: [`Link`](hetcomm_link::Link) implementations that
//! move whole frames between systems over the network, using only `std` threads and sockets.
//!
//! - [`stream`]: a stream-link layer generic over a connector/listener pair — framing, one
//!   cached connection per peer, reconnect with backoff, write deadlines, receiving on one
//!   poller thread per link with a bound on accepted connections, clean shutdown. TCP and Unix sockets are built on it; Bluetooth RFCOMM can be.
//! - [`tcp`]: [`TcpLink`], reliable and ordered while connected.
//! - [`udp`]: [`UdpLink`], unreliable and unordered, fragmenting frames larger than one
//!   datagram and reassembling them with bounded memory and a timeout.
//! - [`unix`]: [`UnixLink`], the stream layer over Unix stream sockets.
//!
//! What this crate does **not** do: acknowledgements, retries, duplicate suppression and
//! routing are the router's. A link hands every frame it reads to its
//! [`FrameSink`](hetcomm_link::FrameSink) without looking inside it, and reports failures to
//! send as [`LinkError`](hetcomm_link::LinkError)s; it never resends on its own.
//!
//! ```
//! use std::collections::BTreeMap;
//! use std::net::TcpListener;
//! use std::time::Duration;
//! use hetcomm_core::SystemId;
//! use hetcomm_link::{conformance::CollectSink, Link};
//! use hetcomm_link_ip::{stream::StreamConfig, TcpLink};
//!
//! // Bind both systems' listeners on free ports first, then share the endpoint map.
//! let (la, lb) = (TcpListener::bind("127.0.0.1:0")?, TcpListener::bind("127.0.0.1:0")?);
//! let endpoints = BTreeMap::from([
//!     (SystemId(1), la.local_addr()?.to_string()),
//!     (SystemId(2), lb.local_addr()?.to_string()),
//! ]);
//! let sink_b = CollectSink::new();
//! let a = TcpLink::with_listener(SystemId(1), la, &endpoints, CollectSink::new(), StreamConfig::default())?;
//! let _b = TcpLink::with_listener(SystemId(2), lb, &endpoints, sink_b.clone(), StreamConfig::default())?;
//! a.send(SystemId(2), b"a frame")?;
//! assert_eq!(sink_b.wait_for(1, Duration::from_secs(10)), 1);
//! assert_eq!(sink_b.frames()[0].bytes, b"a frame");
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

mod common;
pub mod factory;
pub mod settings;
pub mod stream;
pub mod tcp;
pub mod udp;
#[cfg(unix)]
pub mod unix;

pub use common::WriteBehind;
pub use settings::IpSettings;
pub use tcp::TcpLink;
pub use udp::{UdpConfig, UdpLink};
#[cfg(unix)]
pub use unix::UnixLink;

use hetcomm_core::SystemId;

/// Registers the `udp` and `tcp` transport factories ([`factory`]).
pub fn register_transports(registry: &mut hetcomm_link::registry::Registry) {
    registry.register(factory::UdpFactory);
    registry.register(factory::TcpFactory);
}

/// Why a link could not be opened.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum IpOpenError {
    /// The endpoint map has no entry for the system being opened.
    #[error("system {system} has no endpoint in the endpoint map")]
    NoLocalEndpoint {
        /// The system being opened.
        system: SystemId,
    },
    /// A peer's endpoint does not resolve to an address.
    #[error("endpoint {endpoint:?} of system {system} does not resolve: {reason}")]
    BadEndpoint {
        /// The peer.
        system: SystemId,
        /// The endpoint as written.
        endpoint: String,
        /// What the resolver said.
        reason: String,
    },
    /// The local endpoint could not be bound.
    #[error("cannot bind {endpoint}: {source}")]
    Bind {
        /// The endpoint as written.
        endpoint: String,
        /// The operating system's error.
        source: std::io::Error,
    },
    /// A configuration value is out of range.
    #[error("invalid link configuration: {field}: {reason}")]
    BadConfig {
        /// The field's name.
        field: &'static str,
        /// What is wrong with it.
        reason: String,
    },
    /// Another operating-system error (reading the bound address, starting a thread).
    #[error("i/o error while opening the link: {0}")]
    Io(#[from] std::io::Error),
}
