//! TCP: the [`stream`](crate::stream) layer over `std::net` sockets.
//!
//! Each system listens on its endpoint from the fleet's endpoint map; a sender opens one
//! connection per peer on first send, identifies itself with a hello, and reuses the
//! connection (`TCP_NODELAY` set, so the kernel never holds small frames back; the link
//! batches frames itself when the runtime asks it to, with `send_held`). See the
//! [`stream`](crate::stream) module for the byte format, batching, identity, backoff and
//! timeouts.
//!
//! Peer endpoints are resolved (`host:port`, DNS allowed) on each connect attempt, so a peer
//! whose name does not resolve yet is simply unreachable until it does.

use std::collections::BTreeMap;
use std::io;
use std::net::{Shutdown, SocketAddr, TcpListener, TcpStream, ToSocketAddrs};
use std::sync::Arc;
use std::time::Duration;

use hetcomm_core::SystemId;
use hetcomm_link::FrameSink;

use crate::stream::{
    StreamConfig, StreamLink, StreamListener, StreamSocket, StreamStats, StreamTransport,
};
use crate::IpOpenError;

impl StreamSocket for TcpStream {
    fn try_clone(&self) -> io::Result<Self> {
        TcpStream::try_clone(self)
    }
    fn shutdown_both(&self) -> io::Result<()> {
        self.shutdown(Shutdown::Both)
    }
    fn set_write_timeout(&self, timeout: Option<Duration>) -> io::Result<()> {
        TcpStream::set_write_timeout(self, timeout)
    }
    fn set_read_timeout(&self, timeout: Option<Duration>) -> io::Result<()> {
        TcpStream::set_read_timeout(self, timeout)
    }
    fn raw_fd(&self) -> Option<std::os::fd::BorrowedFd<'_>> {
        // Reading the socket through `Read` is exactly `read(2)` on this descriptor.
        Some(std::os::fd::AsFd::as_fd(self))
    }
    fn set_nonblocking(&self, on: bool) -> io::Result<()> {
        TcpStream::set_nonblocking(self, on)
    }
}

impl StreamListener for TcpListener {
    type Socket = TcpStream;
    type PeerAddr = SocketAddr;

    fn accept(&self) -> io::Result<(TcpStream, SocketAddr)> {
        TcpListener::accept(self)
    }

    fn raw_fd(&self) -> Option<std::os::fd::BorrowedFd<'_>> {
        Some(std::os::fd::AsFd::as_fd(self))
    }

    fn set_nonblocking(&self, on: bool) -> io::Result<()> {
        TcpListener::set_nonblocking(self, on)
    }

    fn wake(&self) {
        // On Linux, shutting a listening socket down makes a blocked accept fail at once. Where
        // that is not supported, a connection to ourselves wakes it instead.
        let _ = socket2::SockRef::from(self).shutdown(Shutdown::Both);
        if let Ok(mut addr) = self.local_addr() {
            if addr.ip().is_unspecified() {
                let loopback: std::net::IpAddr = if addr.is_ipv4() {
                    std::net::Ipv4Addr::LOCALHOST.into()
                } else {
                    std::net::Ipv6Addr::LOCALHOST.into()
                };
                addr.set_ip(loopback);
            }
            let _ = TcpStream::connect_timeout(&addr, Duration::from_millis(500));
        }
    }
}

/// The TCP [`StreamTransport`]: connects to `host:port` strings, identifies by hello.
#[derive(Clone, Copy, Debug, Default)]
pub struct TcpTransport;

impl StreamTransport for TcpTransport {
    type Socket = TcpStream;
    type Listener = TcpListener;
    type Addr = String;
    const NAME: &'static str = "tcp";

    fn connect(&self, addr: &String, timeout: Duration) -> io::Result<TcpStream> {
        let mut last = None;
        for a in addr.to_socket_addrs()? {
            match TcpStream::connect_timeout(&a, timeout) {
                Ok(s) => return Ok(s),
                Err(e) => last = Some(e),
            }
        }
        Err(last.unwrap_or_else(|| {
            io::Error::new(io::ErrorKind::NotFound, "endpoint resolved to no address")
        }))
    }

    fn configure(&self, socket: &TcpStream) -> io::Result<()> {
        socket.set_nodelay(true)
    }

    /// TCP checksums every segment and retransmits what is lost or damaged.
    fn checksums_payload(&self) -> bool {
        true
    }
}

/// A system's TCP endpoint: a [`StreamLink`] over [`TcpTransport`] that also knows the
/// address it is bound to.
pub struct TcpLink {
    inner: StreamLink<TcpTransport>,
    local_addr: SocketAddr,
}

impl TcpLink {
    /// Binds `local`'s endpoint from `endpoints` (port 0 picks a free port; see
    /// [`TcpLink::local_addr`]) and starts the link. Every other entry of `endpoints` is a peer
    /// this link can send to; frames received go to `sink`.
    ///
    /// `std` sets `SO_REUSEADDR` on the listener, so a restarted system can bind the same port
    /// again while old connections linger in `TIME_WAIT`.
    pub fn bind(
        local: SystemId,
        endpoints: &BTreeMap<SystemId, String>,
        sink: Arc<dyn FrameSink>,
        config: StreamConfig,
    ) -> Result<TcpLink, IpOpenError> {
        let endpoint = endpoints
            .get(&local)
            .ok_or(IpOpenError::NoLocalEndpoint { system: local })?;
        let listener =
            TcpListener::bind(endpoint.as_str()).map_err(|source| IpOpenError::Bind {
                endpoint: endpoint.clone(),
                source,
            })?;
        TcpLink::with_listener(local, listener, endpoints, sink, config)
    }

    /// Starts the link on an already-bound `listener` (tests bind port 0 for every system
    /// first, then build `endpoints` from the bound ports). `local`'s own entry in
    /// `endpoints`, if any, is not used. The listen backlog is raised to
    /// [`StreamConfig::max_connections`] (at least 128; the kernel caps it at
    /// `net.core.somaxconn`).
    pub fn with_listener(
        local: SystemId,
        listener: TcpListener,
        endpoints: &BTreeMap<SystemId, String>,
        sink: Arc<dyn FrameSink>,
        config: StreamConfig,
    ) -> Result<TcpLink, IpOpenError> {
        let local_addr = listener.local_addr()?;
        // A burst of connects must not overflow the listen backlog (std's is 128), or the
        // connects that do wait for SYN retries. Listening again only changes the backlog.
        let backlog = config.max_connections.clamp(128, i32::MAX as usize) as i32;
        let _ = socket2::SockRef::from(&listener).listen(backlog);
        let inner = StreamLink::new(
            TcpTransport,
            local,
            listener,
            endpoints.clone(),
            sink,
            config,
        )?;
        Ok(TcpLink { inner, local_addr })
    }

    /// The address the listener is bound to (with the real port when the endpoint said 0).
    pub fn local_addr(&self) -> SocketAddr {
        self.local_addr
    }

    /// All counters of the underlying stream link.
    pub fn stream_stats(&self) -> StreamStats {
        self.inner.stream_stats()
    }
}

hetcomm_link::forward_link!(TcpLink, inner);
