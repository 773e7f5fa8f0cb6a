//! Sockets: the RFCOMM address family, the connected stream and the wakeable listener the
//! [`stream`](hetcomm_link_ip::stream) layer runs on.
//!
//! Everything here is written against [`AddressFamily`], so the same stream and listener code
//! runs over RFCOMM in production and over Unix stream sockets in this crate's tests. The
//! family decides only how sockets are created and what addresses look like.

use std::io::{self, IoSlice, Read, Write};
use std::os::unix::net::UnixStream;
use std::time::Duration;

use hetcomm_config::BdAddr;
use hetcomm_link_ip::stream::{StreamListener, StreamSocket};
use rustix::event::{poll, PollFd, PollFlags};
use socket2::{Domain, Protocol, SockAddr, Socket, Type};

/// Linux's address family number for Bluetooth sockets (`AF_BLUETOOTH`).
pub const AF_BLUETOOTH: i32 = 31;
/// Linux's protocol number for RFCOMM within [`AF_BLUETOOTH`] (`BTPROTO_RFCOMM`).
pub const BTPROTO_RFCOMM: i32 = 3;
/// Size of the kernel's `struct sockaddr_rc`: family (2), device address (6), channel (1),
/// padding (1).
pub const SOCKADDR_RC_LEN: usize = 10;
/// The lowest RFCOMM server channel.
pub const MIN_CHANNEL: u8 = 1;
/// The highest RFCOMM server channel.
pub const MAX_CHANNEL: u8 = 30;

/// How a [`BluetoothLink`](crate::BluetoothLink) creates sockets and reads addresses: the one
/// seam between the link and the kernel's socket family.
///
/// [`Rfcomm`] is the real family. Tests implement this trait over Unix stream sockets (device
/// addresses become socket paths), which is how everything above the address family is
/// exercised on machines without Bluetooth.
pub trait AddressFamily: Send + Sync + 'static {
    /// Creates a new, unconnected, blocking stream socket of this family.
    fn stream_socket(&self) -> io::Result<Socket>;

    /// The address this system's listener binds to, given its own device address and the
    /// fleet's channel.
    fn listen_addr(&self, local: BdAddr, channel: u8) -> io::Result<SockAddr>;

    /// The address an outgoing connection binds to before connecting, so that the receiver
    /// sees `local` as its source (`None`: do not bind, let the kernel choose).
    fn source_addr(&self, local: BdAddr) -> io::Result<Option<SockAddr>>;

    /// The address to connect to for `device`'s listener on `channel`.
    fn connect_addr(&self, device: BdAddr, channel: u8) -> io::Result<SockAddr>;

    /// The device behind an accepted connection's remote address (`None`: not a device
    /// address; the connection will be refused).
    fn device_of(&self, remote: &SockAddr) -> Option<BdAddr>;
}

/// The real address family: Bluetooth Classic RFCOMM sockets (`AF_BLUETOOTH`,
/// `SOCK_STREAM`, `BTPROTO_RFCOMM`).
///
/// The listener binds to any local adapter on the fleet's channel; outgoing connections bind
/// to this system's own fleet address (channel 0, "any free"), so the kernel routes them
/// through that adapter and a wrong local address fails at the sender, loudly, instead of
/// being refused silently by every receiver.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Rfcomm;

impl Rfcomm {
    /// Checks that this kernel can create RFCOMM sockets by creating (and closing) one.
    /// Fails with the operating system's error: `EAFNOSUPPORT` (errno 97) when the kernel
    /// has no Bluetooth support at all, `EPROTONOSUPPORT` when RFCOMM is missing.
    pub fn probe() -> io::Result<()> {
        Rfcomm.stream_socket().map(drop)
    }
}

impl AddressFamily for Rfcomm {
    fn stream_socket(&self) -> io::Result<Socket> {
        Socket::new(
            Domain::from(AF_BLUETOOTH),
            Type::STREAM,
            Some(Protocol::from(BTPROTO_RFCOMM)),
        )
    }

    fn listen_addr(&self, _local: BdAddr, channel: u8) -> io::Result<SockAddr> {
        // BDADDR_ANY: accept through whichever adapter the peer reaches.
        Ok(rfcomm_sockaddr(BdAddr([0; 6]), channel))
    }

    fn source_addr(&self, local: BdAddr) -> io::Result<Option<SockAddr>> {
        Ok(Some(rfcomm_sockaddr(local, 0)))
    }

    fn connect_addr(&self, device: BdAddr, channel: u8) -> io::Result<SockAddr> {
        Ok(rfcomm_sockaddr(device, channel))
    }

    fn device_of(&self, remote: &SockAddr) -> Option<BdAddr> {
        parse_rfcomm_sockaddr(remote).map(|(device, _channel)| device)
    }
}

/// The bytes of a `struct sockaddr_rc` for `device` and `channel`. The kernel stores a
/// device address least significant byte first, the reverse of how it is written
/// (`68:A3:C4:4A:B3:BA` is stored `BA B3 4A C4 A3 68`).
pub fn sockaddr_rc_bytes(device: BdAddr, channel: u8) -> [u8; SOCKADDR_RC_LEN] {
    let mut bytes = [0u8; SOCKADDR_RC_LEN];
    // AF_BLUETOOTH fits in sa_family_t (u16), which is in native byte order.
    bytes[0..2].copy_from_slice(&(AF_BLUETOOTH as u16).to_ne_bytes());
    let mut b = device.0;
    b.reverse();
    bytes[2..8].copy_from_slice(&b);
    bytes[8] = channel;
    bytes
}

/// Reads a `struct sockaddr_rc`'s bytes back into a device address and channel; `None` if
/// the family is not `AF_BLUETOOTH` or the bytes are too short.
pub fn parse_sockaddr_rc_bytes(bytes: &[u8]) -> Option<(BdAddr, u8)> {
    if bytes.len() < SOCKADDR_RC_LEN - 1 {
        return None;
    }
    let family = u16::from_ne_bytes([bytes[0], bytes[1]]);
    if i32::from(family) != AF_BLUETOOTH {
        return None;
    }
    let mut device = [0u8; 6];
    device.copy_from_slice(&bytes[2..8]);
    device.reverse();
    Some((BdAddr(device), bytes[8]))
}

/// An RFCOMM socket address for `device` and `channel`, ready for `bind` or `connect`.
pub fn rfcomm_sockaddr(device: BdAddr, channel: u8) -> SockAddr {
    let bytes = sockaddr_rc_bytes(device, channel);
    // SAFETY: `sockaddr_storage` is plain old data, for which all-zero bytes are valid.
    let mut storage: libc::sockaddr_storage = unsafe { std::mem::zeroed() };
    // SAFETY: the storage is 128 bytes, larger than the 10 copied into its start; the two
    // regions do not overlap.
    unsafe {
        std::ptr::copy_nonoverlapping(
            bytes.as_ptr(),
            (&mut storage as *mut libc::sockaddr_storage).cast::<u8>(),
            bytes.len(),
        );
    }
    // SAFETY: the storage now holds a complete `sockaddr_rc` of `SOCKADDR_RC_LEN` bytes.
    unsafe { SockAddr::new(storage, SOCKADDR_RC_LEN as libc::socklen_t) }
}

/// The device address and channel of an RFCOMM socket address (as `accept` returns it);
/// `None` for any other kind of address.
pub fn parse_rfcomm_sockaddr(addr: &SockAddr) -> Option<(BdAddr, u8)> {
    if i32::from(addr.family()) != AF_BLUETOOTH {
        return None;
    }
    let len = (addr.len() as usize).min(SOCKADDR_RC_LEN);
    let storage = addr.clone().as_storage();
    let mut bytes = [0u8; SOCKADDR_RC_LEN];
    // SAFETY: `len` is at most 10 and the storage is 128 bytes; the regions do not overlap.
    unsafe {
        std::ptr::copy_nonoverlapping(
            (&storage as *const libc::sockaddr_storage).cast::<u8>(),
            bytes.as_mut_ptr(),
            len,
        );
    }
    parse_sockaddr_rc_bytes(&bytes[..len])
}

/// A connected stream socket of the link's address family (RFCOMM in production), in
/// blocking mode, as the stream layer reads and writes it.
#[derive(Debug)]
pub struct RfcommStream(pub Socket);

impl Read for RfcommStream {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        self.0.read(buf)
    }
}

impl Write for RfcommStream {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        // socket2 sends with MSG_NOSIGNAL: a dead peer is an error, not a SIGPIPE.
        self.0.write(buf)
    }
    fn write_vectored(&mut self, bufs: &[IoSlice<'_>]) -> io::Result<usize> {
        self.0.write_vectored(bufs)
    }
    fn flush(&mut self) -> io::Result<()> {
        self.0.flush()
    }
}

impl StreamSocket for RfcommStream {
    fn try_clone(&self) -> io::Result<Self> {
        self.0.try_clone().map(RfcommStream)
    }
    fn shutdown_both(&self) -> io::Result<()> {
        self.0.shutdown(std::net::Shutdown::Both)
    }
    fn set_write_timeout(&self, timeout: Option<Duration>) -> io::Result<()> {
        self.0.set_write_timeout(timeout)
    }
    fn set_read_timeout(&self, timeout: Option<Duration>) -> io::Result<()> {
        self.0.set_read_timeout(timeout)
    }
}

/// A listening socket that the link can wake from another thread.
///
/// A blocked `accept` on an RFCOMM socket is not reliably interrupted by `shutdown` the way
/// a TCP one is on Linux, so the listener waits with `poll` on both the socket and a private
/// wake-up socket pair; [`StreamListener::wake`] writes one byte to the pair.
#[derive(Debug)]
pub struct RfcommListener {
    socket: Socket,
    wake_rx: UnixStream,
    wake_tx: UnixStream,
}

impl RfcommListener {
    /// Wraps a socket that is already bound and listening. The socket is switched to
    /// non-blocking mode (accepted connections are put back in blocking mode).
    pub fn new(socket: Socket) -> io::Result<RfcommListener> {
        socket.set_nonblocking(true)?;
        let (wake_rx, wake_tx) = UnixStream::pair()?;
        wake_tx.set_nonblocking(true)?;
        Ok(RfcommListener {
            socket,
            wake_rx,
            wake_tx,
        })
    }

    /// The address the listener is bound to.
    pub fn local_addr(&self) -> io::Result<SockAddr> {
        self.socket.local_addr()
    }

    /// Waits until the listener has a connection to accept (`Ok(false)`) or was woken
    /// (`Ok(true)`).
    fn wait(&self) -> io::Result<bool> {
        loop {
            let mut fds = [
                PollFd::new(&self.socket, PollFlags::IN),
                PollFd::new(&self.wake_rx, PollFlags::IN),
            ];
            match poll(&mut fds, None) {
                Ok(_) => {}
                Err(rustix::io::Errno::INTR) => continue,
                Err(e) => return Err(e.into()),
            }
            if !fds[1].revents().is_empty() {
                return Ok(true);
            }
            if !fds[0].revents().is_empty() {
                return Ok(false);
            }
        }
    }
}

impl StreamListener for RfcommListener {
    type Socket = RfcommStream;
    type PeerAddr = SockAddr;

    fn accept(&self) -> io::Result<(RfcommStream, SockAddr)> {
        loop {
            if self.wait()? {
                return Err(io::Error::other("listener woken to shut down"));
            }
            match self.socket.accept() {
                Ok((socket, addr)) => {
                    socket.set_nonblocking(false)?;
                    return Ok((RfcommStream(socket), addr));
                }
                // The connection went away between poll and accept: wait again.
                Err(e)
                    if matches!(
                        e.kind(),
                        io::ErrorKind::WouldBlock | io::ErrorKind::Interrupted
                    ) => {}
                Err(e) => return Err(e),
            }
        }
    }

    fn wake(&self) {
        let _ = (&self.wake_tx).write(&[1]);
    }
}
