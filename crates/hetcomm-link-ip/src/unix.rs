//! Unix stream sockets: the [`stream`](crate::stream) layer between processes of one machine
//! (e.g. a robot's driver process and its planner), addressed by socket paths.
//!
//! Identity is by hello and small frames are batched with `send_held`, as for TCP. The link
//! removes its socket file when dropped.

use std::collections::BTreeMap;
use std::io;
use std::net::Shutdown;
use std::os::unix::net::{SocketAddr, UnixListener, UnixStream};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use hetcomm_core::{FrameBuf, SystemId};
use hetcomm_link::{FrameSink, Link, LinkCaps, LinkError, LinkStats, Readable};

use crate::stream::{
    StreamConfig, StreamLink, StreamListener, StreamSocket, StreamStats, StreamTransport,
};
use crate::IpOpenError;

impl StreamSocket for UnixStream {
    fn try_clone(&self) -> io::Result<Self> {
        UnixStream::try_clone(self)
    }
    fn shutdown_both(&self) -> io::Result<()> {
        self.shutdown(Shutdown::Both)
    }
    fn set_write_timeout(&self, timeout: Option<Duration>) -> io::Result<()> {
        UnixStream::set_write_timeout(self, timeout)
    }
    fn set_read_timeout(&self, timeout: Option<Duration>) -> io::Result<()> {
        UnixStream::set_read_timeout(self, timeout)
    }
    fn raw_fd(&self) -> Option<std::os::fd::BorrowedFd<'_>> {
        // Reading the socket through `Read` is exactly `read(2)` on this descriptor.
        Some(std::os::fd::AsFd::as_fd(self))
    }
    fn set_nonblocking(&self, on: bool) -> io::Result<()> {
        UnixStream::set_nonblocking(self, on)
    }
}

impl StreamListener for UnixListener {
    type Socket = UnixStream;
    type PeerAddr = SocketAddr;

    fn accept(&self) -> io::Result<(UnixStream, SocketAddr)> {
        UnixListener::accept(self)
    }

    fn raw_fd(&self) -> Option<std::os::fd::BorrowedFd<'_>> {
        Some(std::os::fd::AsFd::as_fd(self))
    }

    fn set_nonblocking(&self, on: bool) -> io::Result<()> {
        UnixListener::set_nonblocking(self, on)
    }

    fn wake(&self) {
        // As for TCP: shutdown works on Linux, a connection to ourselves elsewhere.
        let _ = socket2::SockRef::from(self).shutdown(Shutdown::Both);
        if let Some(path) = self
            .local_addr()
            .ok()
            .and_then(|a| a.as_pathname().map(Path::to_owned))
        {
            let _ = UnixStream::connect(path);
        }
    }
}

/// The Unix-socket [`StreamTransport`]: connects to socket paths, identifies by hello.
#[derive(Clone, Copy, Debug, Default)]
pub struct UnixTransport;

/// A socket path, shown in error reasons.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct UnixAddr(pub PathBuf);

impl std::fmt::Display for UnixAddr {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}", self.0.display())
    }
}

impl StreamTransport for UnixTransport {
    type Socket = UnixStream;
    type Listener = UnixListener;
    type Addr = UnixAddr;
    const NAME: &'static str = "unix";

    fn connect(&self, addr: &UnixAddr, _timeout: Duration) -> io::Result<UnixStream> {
        // A local connect either succeeds or fails at once (no handshake to wait for).
        UnixStream::connect(&addr.0)
    }

    /// A Unix socket's bytes never leave the kernel: they arrive unaltered or not at all.
    fn checksums_payload(&self) -> bool {
        true
    }
}

/// A system's endpoint on Unix stream sockets.
pub struct UnixLink {
    /// Always `Some` until `drop`, which must stop the link before removing the file.
    inner: Option<StreamLink<UnixTransport>>,
    path: PathBuf,
}

impl UnixLink {
    /// Listens on `local`'s path from `paths` and starts the link; the other entries are the
    /// peers. A stale socket file left by a crashed process (nobody accepting on it) is
    /// replaced; a live one is an [`IpOpenError::Bind`] error.
    pub fn bind(
        local: SystemId,
        paths: &BTreeMap<SystemId, PathBuf>,
        sink: Arc<dyn FrameSink>,
        config: StreamConfig,
    ) -> Result<UnixLink, IpOpenError> {
        let path = paths
            .get(&local)
            .ok_or(IpOpenError::NoLocalEndpoint { system: local })?
            .clone();
        let bind_err = |source| IpOpenError::Bind {
            endpoint: path.display().to_string(),
            source,
        };
        let listener = match UnixListener::bind(&path) {
            Ok(l) => l,
            Err(e) if e.kind() == io::ErrorKind::AddrInUse => {
                if UnixStream::connect(&path).is_ok() {
                    return Err(bind_err(e));
                }
                std::fs::remove_file(&path).map_err(bind_err)?;
                UnixListener::bind(&path).map_err(bind_err)?
            }
            Err(e) => return Err(bind_err(e)),
        };
        let peers = paths
            .iter()
            .map(|(id, p)| (*id, UnixAddr(p.clone())))
            .collect();
        // As for TCP: a burst of connects must not overflow std's backlog of 128.
        let backlog = config.max_connections.clamp(128, i32::MAX as usize) as i32;
        let _ = socket2::SockRef::from(&listener).listen(backlog);
        let inner = StreamLink::new(UnixTransport, local, listener, peers, sink, config)?;
        Ok(UnixLink {
            inner: Some(inner),
            path,
        })
    }

    /// The path this link listens on.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// All counters of the underlying stream link.
    pub fn stream_stats(&self) -> StreamStats {
        self.inner
            .as_ref()
            .map(StreamLink::stream_stats)
            .unwrap_or_default()
    }
}

impl Link for UnixLink {
    fn caps(&self) -> LinkCaps {
        match &self.inner {
            Some(l) => l.caps(),
            None => StreamLink::<UnixTransport>::caps_for(&StreamConfig::default()),
        }
    }
    fn send(&self, to: SystemId, frame: &[u8]) -> Result<(), LinkError> {
        self.inner
            .as_ref()
            .ok_or(LinkError::Closed)?
            .send(to, frame)
    }
    fn send_parts(&self, to: SystemId, head: &[u8], body: &[u8]) -> Result<(), LinkError> {
        self.inner
            .as_ref()
            .ok_or(LinkError::Closed)?
            .send_parts(to, head, body)
    }
    fn send_owned(&self, to: SystemId, frame: FrameBuf) -> Result<(), LinkError> {
        self.inner
            .as_ref()
            .ok_or(LinkError::Closed)?
            .send_owned(to, frame)
    }
    fn stats(&self) -> LinkStats {
        self.inner.as_ref().map(Link::stats).unwrap_or_default()
    }
    fn send_held(&self, to: SystemId, frame: &[u8]) -> Result<(), LinkError> {
        self.inner
            .as_ref()
            .ok_or(LinkError::Closed)?
            .send_held(to, frame)
    }
    fn flush(&self) -> Result<(), LinkError> {
        self.inner.as_ref().map_or(Ok(()), Link::flush)
    }
    fn batches(&self) -> bool {
        self.inner.as_ref().is_some_and(Link::batches)
    }
    fn checksums_payload(&self) -> bool {
        self.inner.as_ref().is_some_and(Link::checksums_payload)
    }
    fn readable(&self) -> Option<&dyn Readable> {
        self.inner.as_ref().and_then(|l| l.readable())
    }
}

impl Drop for UnixLink {
    fn drop(&mut self) {
        // Stop the link first (its wake-up may connect to the path), then remove the file.
        drop(self.inner.take());
        let _ = std::fs::remove_file(&self.path);
    }
}
