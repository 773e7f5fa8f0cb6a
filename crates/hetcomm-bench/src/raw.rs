//! Baselines: raw UDP, raw TCP (TCP_NODELAY, length-prefixed) and Unix datagram sockets,
//! ping-pong and one-way between two processes, measured by the same code as hetcomm.
//!
//! Datagram paths send a message larger than [`CHUNK`] as several datagrams (the receiver
//! counts bytes until the message is complete), as hetcomm's UDP link splits large frames; a
//! lost datagram in ping-pong is a lost round trip (counted, not timed). Socket buffers are
//! raised to 4 MiB on both ends.

use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream, UdpSocket};
use std::os::fd::AsRawFd;
use std::os::unix::net::UnixDatagram;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use crate::child::Peer;
use crate::stats::{parse_sink_line, Latency, Recorder, Throughput};

/// Largest datagram sent (a message above it is split).
pub const CHUNK: usize = 65_000;

/// Which raw socket.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RawKind {
    /// UDP on 127.0.0.1.
    Udp,
    /// TCP on 127.0.0.1 with TCP_NODELAY, 4-byte length prefix.
    Tcp,
    /// Unix datagram sockets in a temporary directory.
    Unix,
}

impl RawKind {
    /// The row name.
    pub fn name(self) -> &'static str {
        match self {
            RawKind::Udp => "raw-udp",
            RawKind::Tcp => "raw-tcp",
            RawKind::Unix => "raw-unix",
        }
    }
}

/// A datagram socket of either family.
pub enum Dgram {
    /// UDP.
    Udp(UdpSocket),
    /// Unix datagram.
    Unix(UnixDatagram),
}

/// Where a datagram came from.
pub enum Source {
    /// A UDP address.
    Udp(SocketAddr),
    /// A Unix socket path.
    Unix(PathBuf),
}

/// What a message receive got.
pub enum Got {
    /// A whole message, from this sender.
    Message(Option<Source>),
    /// A one-byte stop marker.
    Stop,
    /// Nothing before the read timeout (or a partial message that was abandoned).
    Nothing,
}

impl Dgram {
    /// Sets the read timeout.
    pub fn set_read_timeout(&self, t: Option<Duration>) {
        let _ = match self {
            Dgram::Udp(s) => s.set_read_timeout(t),
            Dgram::Unix(s) => s.set_read_timeout(t),
        };
    }

    /// Receives one datagram: its length and sender, None on timeout or error.
    pub fn recv_from(&self, buf: &mut [u8]) -> Option<(usize, Option<Source>)> {
        match self {
            Dgram::Udp(s) => s
                .recv_from(buf)
                .ok()
                .map(|(n, a)| (n, Some(Source::Udp(a)))),
            Dgram::Unix(s) => s
                .recv_from(buf)
                .ok()
                .map(|(n, a)| (n, a.as_pathname().map(|p| Source::Unix(p.to_path_buf())))),
        }
    }

    fn send_to(&self, buf: &[u8], to: Option<&Source>) -> std::io::Result<usize> {
        match (self, to) {
            (Dgram::Udp(s), Some(Source::Udp(a))) => s.send_to(buf, a),
            (Dgram::Udp(s), _) => s.send(buf),
            (Dgram::Unix(s), Some(Source::Unix(p))) => s.send_to(buf, p),
            (Dgram::Unix(s), _) => s.send(buf),
        }
    }
}

/// Raises a socket's send and receive buffers to 4 MiB (forcing past the sysctl limit when
/// allowed); failures are ignored.
pub fn big_buffers(sock: &impl AsRawFd) {
    let size: libc::c_int = 4 * 1024 * 1024;
    let fd = sock.as_raw_fd();
    for (force, plain) in [
        (libc::SO_RCVBUFFORCE, libc::SO_RCVBUF),
        (libc::SO_SNDBUFFORCE, libc::SO_SNDBUF),
    ] {
        // SAFETY: setsockopt on a valid fd with a pointer to a c_int and its size.
        unsafe {
            let p = &size as *const libc::c_int as *const libc::c_void;
            let len = std::mem::size_of::<libc::c_int>() as libc::socklen_t;
            if libc::setsockopt(fd, libc::SOL_SOCKET, force, p, len) != 0 {
                libc::setsockopt(fd, libc::SOL_SOCKET, plain, p, len);
            }
        }
    }
}

/// Sends one message as datagrams of at most [`CHUNK`] bytes.
pub fn send_dgram_msg(sock: &Dgram, msg: &[u8], to: Option<&Source>) -> std::io::Result<()> {
    for c in msg.chunks(CHUNK) {
        sock.send_to(c, to)?;
    }
    Ok(())
}

/// Receives one message of `size` bytes (copied into `out` if given).
pub fn recv_dgram_msg(
    sock: &Dgram,
    size: usize,
    scratch: &mut [u8],
    mut out: Option<&mut Vec<u8>>,
) -> Got {
    let mut got = 0usize;
    let mut from = None;
    while got < size {
        match sock.recv_from(scratch) {
            Some((1, _)) if size > 1 => return Got::Stop,
            Some((n, f)) => {
                if let Some(o) = out.as_deref_mut() {
                    let end = (got + n).min(o.len());
                    if got < end {
                        o[got..end].copy_from_slice(&scratch[..end - got]);
                    }
                }
                got += n;
                from = f;
            }
            None => return Got::Nothing,
        }
    }
    Got::Message(from)
}

/// A temporary directory removed on drop.
pub struct TempDir(pub PathBuf);

impl TempDir {
    /// Creates `$TMPDIR/hetcomm-bench-PID-N`.
    pub fn new() -> Result<TempDir, String> {
        use std::sync::atomic::{AtomicU32, Ordering};
        static N: AtomicU32 = AtomicU32::new(0);
        let p = std::env::temp_dir().join(format!(
            "hetcomm-bench-{}-{}",
            std::process::id(),
            N.fetch_add(1, Ordering::Relaxed)
        ));
        std::fs::create_dir_all(&p).map_err(|e| format!("{}: {e}", p.display()))?;
        Ok(TempDir(p))
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

const START: Duration = Duration::from_secs(10);

enum Conn {
    D(Dgram),
    T(TcpStream),
}

/// Connects to a fresh peer of `kind` in role `echo` or `sink`.
fn connect(kind: RawKind, role: &str, size: usize, dir: &TempDir) -> Result<(Peer, Conn), String> {
    match kind {
        RawKind::Udp => {
            let peer = Peer::spawn(None, &[format!("udp-{role}"), size.to_string()])?;
            let port = peer.expect("port", START)?;
            let sock = UdpSocket::bind("127.0.0.1:0").map_err(|e| e.to_string())?;
            big_buffers(&sock);
            sock.connect(format!("127.0.0.1:{port}"))
                .map_err(|e| e.to_string())?;
            Ok((peer, Conn::D(Dgram::Udp(sock))))
        }
        RawKind::Unix => {
            let theirs = dir.0.join(format!("{role}-peer.sock"));
            let mine = dir.0.join(format!("{role}-me.sock"));
            let _ = std::fs::remove_file(&theirs);
            let _ = std::fs::remove_file(&mine);
            let peer = Peer::spawn(
                None,
                &[
                    format!("unix-{role}"),
                    size.to_string(),
                    theirs.display().to_string(),
                ],
            )?;
            peer.expect("ready", START)?;
            let sock = UnixDatagram::bind(&mine).map_err(|e| e.to_string())?;
            big_buffers(&sock);
            sock.connect(&theirs).map_err(|e| e.to_string())?;
            Ok((peer, Conn::D(Dgram::Unix(sock))))
        }
        RawKind::Tcp => {
            let peer = Peer::spawn(None, &[format!("tcp-{role}")])?;
            let port = peer.expect("port", START)?;
            let s = TcpStream::connect(format!("127.0.0.1:{port}")).map_err(|e| e.to_string())?;
            s.set_nodelay(true).map_err(|e| e.to_string())?;
            Ok((peer, Conn::T(s)))
        }
    }
}

/// Ping-pong round trips of `size`-byte messages.
pub fn rtt(kind: RawKind, size: usize, warmup: u64, iters: u64) -> Result<Latency, String> {
    let dir = TempDir::new()?;
    let (peer, mut conn) = connect(kind, "echo", size, &dir)?;
    let mut rec = Recorder::new();
    let mut scratch = vec![0u8; 70_000];
    match &mut conn {
        Conn::D(sock) => {
            let msg = vec![7u8; size];
            sock.set_read_timeout(Some(Duration::from_millis(500)));
            // Probe until the echo peer answers.
            let deadline = Instant::now() + START;
            loop {
                send_dgram_msg(sock, &msg, None).map_err(|e| e.to_string())?;
                if let Got::Message(_) = recv_dgram_msg(sock, size, &mut scratch, None) {
                    break;
                }
                if Instant::now() > deadline {
                    return Err("no echo".into());
                }
            }
            for i in 0..warmup + iters {
                let t = Instant::now();
                send_dgram_msg(sock, &msg, None).map_err(|e| e.to_string())?;
                match recv_dgram_msg(sock, size, &mut scratch, None) {
                    Got::Message(_) if i >= warmup => rec.record(t.elapsed()),
                    Got::Message(_) => {}
                    _ => {
                        rec.lost();
                        if rec.summary().lost > crate::hc::MAX_LOST {
                            return Err("more than 10 round trips lost".into());
                        }
                        // Drain late pieces so the next round starts clean.
                        sock.set_read_timeout(Some(Duration::from_millis(50)));
                        while sock.recv_from(&mut scratch).is_some() {}
                        sock.set_read_timeout(Some(Duration::from_millis(500)));
                    }
                }
            }
        }
        Conn::T(s) => {
            let mut frame = (size as u32).to_le_bytes().to_vec();
            frame.resize(4 + size, 7);
            let mut back = vec![0u8; 4 + size];
            for i in 0..warmup + iters {
                let t = Instant::now();
                s.write_all(&frame).map_err(|e| e.to_string())?;
                s.read_exact(&mut back).map_err(|e| e.to_string())?;
                if i >= warmup {
                    rec.record(t.elapsed());
                }
            }
        }
    }
    drop(conn);
    peer.finish(Duration::from_secs(2));
    Ok(rec.summary())
}

/// One-way: send as fast as possible for `duration`, counted at the receiving process.
pub fn oneway(kind: RawKind, size: usize, duration: Duration) -> Result<Throughput, String> {
    let dir = TempDir::new()?;
    let (mut peer, mut conn) = connect(kind, "sink", size, &dir)?;
    let mut sent = 0u64;
    let end = Instant::now() + duration;
    match &mut conn {
        Conn::D(sock) => {
            let msg = vec![7u8; size];
            while Instant::now() < end {
                for _ in 0..16 {
                    // ENOBUFS / ECONNREFUSED while the peer is busy: the message is lost.
                    let _ = send_dgram_msg(sock, &msg, None);
                    sent += 1;
                }
            }
            for _ in 0..3 {
                let _ = sock.send_to(&[0u8], None);
                std::thread::sleep(Duration::from_millis(5));
            }
        }
        Conn::T(s) => {
            let mut frame = (size as u32).to_le_bytes().to_vec();
            frame.resize(4 + size, 7);
            while Instant::now() < end {
                for _ in 0..16 {
                    s.write_all(&frame).map_err(|e| e.to_string())?;
                    sent += 1;
                }
            }
            s.write_all(&0u32.to_le_bytes())
                .map_err(|e| e.to_string())?;
            let _ = s.flush();
        }
    }
    peer.close_input();
    let line = peer.expect("result", Duration::from_secs(30))?;
    drop(conn);
    peer.finish(Duration::from_secs(2));
    parse_sink_line(&line, sent).ok_or(format!("bad sink line {line:?}"))
}
