//! [`UdpLink`]'s opening and sending side and its [`Link`] implementation: resolving peers,
//! sending frames whole, batched or fragmented, the kernel's drop counter, and shutdown.

use parking_lot::{Condvar, Mutex};
use std::collections::BTreeMap;
use std::io::{self, IoSlice};
use std::net::{IpAddr, Ipv4Addr, Ipv6Addr, SocketAddr, ToSocketAddrs, UdpSocket};
use std::os::fd::AsRawFd;
use std::sync::atomic::{AtomicBool, AtomicU32, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;

use hetcomm_core::wire::HEADER_LEN;
use hetcomm_core::{FrameBuf, SystemId};
use hetcomm_link::{FrameSink, Link, LinkCaps, LinkError, LinkStats, Readable};

use super::batch::{batchable, misread_alone, push_record};
use super::behind::Behind;
use super::fragment::FragmentHeader;
use super::reassembly::Reassembler;
use super::receive::{receive_pool, DrivenReceiver, Receiver, RxState, RECV_BUF_LEN};
use super::{
    add, lock, Batch, KernelDrops, RxSide, SendSide, Shared, UdpConfig, UdpCounters, UdpLink,
    UdpPeer, UdpStats, BATCH_HEADER_LEN, BATCH_LENGTH_LEN, FRAGMENT_HEADER_LEN,
};
use crate::IpOpenError;

impl UdpLink {
    /// Binds `local`'s endpoint from `endpoints` (port 0 picks a free port; see
    /// [`UdpLink::local_addr`]) and starts the receive thread (unless [`UdpConfig::driven`]).
    /// The other entries are the peers; they are resolved now, since their addresses also
    /// identify senders.
    pub fn bind(
        local: SystemId,
        endpoints: &BTreeMap<SystemId, String>,
        sink: Arc<dyn FrameSink>,
        config: UdpConfig,
    ) -> Result<UdpLink, IpOpenError> {
        let endpoint = endpoints
            .get(&local)
            .ok_or(IpOpenError::NoLocalEndpoint { system: local })?;
        let socket = UdpSocket::bind(endpoint.as_str()).map_err(|source| IpOpenError::Bind {
            endpoint: endpoint.clone(),
            source,
        })?;
        UdpLink::with_socket(local, socket, endpoints, sink, config)
    }

    /// Starts the link on an already-bound `socket` (tests bind port 0 for every system first).
    /// `local`'s own entry in `endpoints`, if any, is not used.
    pub fn with_socket(
        local: SystemId,
        socket: UdpSocket,
        endpoints: &BTreeMap<SystemId, String>,
        sink: Arc<dyn FrameSink>,
        config: UdpConfig,
    ) -> Result<UdpLink, IpOpenError> {
        config.check()?;
        let local_addr = socket.local_addr()?;
        let mut peer_addrs = BTreeMap::new();
        for (&id, endpoint) in endpoints.iter().filter(|(id, _)| **id != local) {
            peer_addrs.insert(id, resolve(id, endpoint, local_addr.is_ipv4())?);
        }
        // Best effort: the kernel may cap these (net.core.rmem_max / wmem_max).
        let sock = socket2::SockRef::from(&socket);
        let _ = sock.set_recv_buffer_size(config.socket_buffer_bytes);
        let _ = sock.set_send_buffer_size(config.socket_buffer_bytes);
        if !config.driven {
            // The receive thread wakes at least this often to expire incomplete messages and
            // to notice shutdown should the wake-up datagram be lost.
            let tick = (config.reassembly_timeout / 4)
                .clamp(Duration::from_millis(10), Duration::from_millis(250));
            socket.set_read_timeout(Some(tick))?;
        }
        let socket = Arc::new(socket);
        let shared = Arc::new(Shared {
            closing: AtomicBool::new(false),
            counters: UdpCounters::default(),
        });
        let max_frame = config.max_frame();
        let takes_frames = sink.takes_frames();
        let pool = receive_pool(takes_frames);
        let receiver = Receiver {
            socket: socket.clone(),
            buf: vec![0; RECV_BUF_LEN],
            state: RxState {
                shared: shared.clone(),
                sink,
                takes_frames,
                pool: pool.clone(),
                senders: peer_addrs.iter().map(|(id, addr)| (*addr, *id)).collect(),
                reassembler: Reassembler::new(
                    config.reassembly_limit_bytes,
                    config.reassembly_timeout,
                    max_frame,
                )
                .with_fleet(peer_addrs.keys().copied())
                .with_pool(pool),
            },
        };
        let rx = if config.driven {
            RxSide::Driven(Box::new(DrivenReceiver {
                fd: socket.as_raw_fd(),
                receiver: Mutex::new(receiver),
            }))
        } else {
            let thread = std::thread::Builder::new()
                .name(format!("hetcomm-udp-rx-{local}"))
                .spawn(move || receiver.run())?;
            RxSide::Thread(Some(thread))
        };
        let peers = peer_addrs
            .into_iter()
            .map(|(id, addr)| {
                let peer = UdpPeer {
                    addr,
                    batch: Mutex::new(Batch::default()),
                    behind: Mutex::new(Behind::default()),
                    room: Condvar::new(),
                };
                (id, peer)
            })
            .collect();
        let tx = SendSide {
            local,
            socket,
            peers,
            mtu: config.datagram_payload,
            max_frame,
            // Start from a value tied to the clock so that a restarted sender is unlikely to
            // reuse the ids of its previous incarnation's half-delivered messages.
            next_message_id: AtomicU32::new(clock_seed()),
            shared,
            writer: Arc::default(),
            write_behind: config.write_behind,
        };
        Ok(UdpLink {
            tx: Arc::new(tx),
            local_addr,
            config,
            rx,
            kernel_drops: Mutex::new(KernelDrops::default()),
        })
    }

    /// The address the socket is bound to (with the real port when the endpoint said 0).
    pub fn local_addr(&self) -> SocketAddr {
        self.local_addr
    }

    /// All counters, including those [`LinkStats`] has no field for.
    pub fn udp_stats(&self) -> UdpStats {
        let c = &self.tx.shared.counters;
        let get = |a: &AtomicU64| a.load(Ordering::Relaxed);
        let bad = get(&c.bad_datagrams);
        let timeouts = get(&c.reassembly_timeouts);
        let evictions = get(&c.reassembly_evictions);
        let held_dropped = get(&c.held_frames_dropped);
        UdpStats {
            frames_sent: get(&c.frames_sent),
            datagrams_sent: get(&c.datagrams_sent),
            batches_sent: get(&c.batches_sent),
            fragments_sent: get(&c.fragments_sent),
            held_frames_dropped: held_dropped,
            frames_written_behind: get(&c.frames_written_behind),
            frames_received: get(&c.frames_received),
            batches_received: get(&c.batches_received),
            frames_dropped: bad + timeouts + evictions + held_dropped,
            bad_datagrams: bad,
            reassembly_timeouts: timeouts,
            reassembly_evictions: evictions,
            duplicate_fragments: get(&c.duplicate_fragments),
            oversize_fragments: get(&c.oversize_fragments),
            from_unknown_address: get(&c.from_unknown_address),
            buffered_bytes: get(&c.buffered_bytes) + self.tx.behind_bytes(),
            kernel_drops: self.kernel_drops(),
        }
    }

    /// Datagrams the kernel dropped at the socket so far (0 where the OS does not say).
    fn kernel_drops(&self) -> u64 {
        // Read under the lock, so that the reads are in order and each adds what is new.
        let mut drops = lock(&self.kernel_drops);
        if let Some(now) = socket_drops(&self.tx.socket) {
            drops.update(now);
        }
        drops.total
    }
}

impl SendSide {
    pub(super) fn check_size(&self, frame: &[u8]) -> Result<(), LinkError> {
        if frame.len() > self.max_frame {
            return Err(LinkError::TooLarge {
                len: frame.len(),
                max: self.max_frame,
            });
        }
        Ok(())
    }

    pub(super) fn peer(&self, to: SystemId) -> Result<&UdpPeer, LinkError> {
        self.peers.get(&to).ok_or_else(|| {
            let reason = if to == self.local {
                "it is this system itself".to_string()
            } else {
                format!("system {to} has no endpoint on this udp link")
            };
            LinkError::Unreachable { peer: to, reason }
        })
    }

    /// Sends `frame` on its own: as one datagram, or as fragments.
    pub(super) fn send_now(
        &self,
        to: SystemId,
        addr: SocketAddr,
        frame: &[u8],
    ) -> Result<(), LinkError> {
        let counters = &self.shared.counters;
        let mtu = self.mtu;
        if frame.len() <= mtu && !misread_alone(frame) {
            self.socket
                .send_to(frame, addr)
                .map_err(|e| self.send_error(to, addr, e))?;
            add(&counters.datagrams_sent, 1);
            add(&counters.frames_sent, 1);
            return Ok(());
        }
        let too_large = || LinkError::TooLarge {
            len: frame.len(),
            max: self.max_frame,
        };
        let piece_max = mtu - FRAGMENT_HEADER_LEN;
        let count = frame.len().div_ceil(piece_max).max(1);
        let count = u16::try_from(count).map_err(|_| too_large())?;
        let total = u32::try_from(frame.len()).map_err(|_| too_large())?;
        let message_id = self.next_message_id.fetch_add(1, Ordering::Relaxed);
        let dest = socket2::SockAddr::from(addr);
        let sock = socket2::SockRef::from(&*self.socket);
        for index in 0..count {
            let h = FragmentHeader {
                sender: self.local,
                index,
                count,
                message_id,
                total,
            };
            let head = h.encode();
            let piece = &frame[h.piece_range()];
            sock.send_to_vectored(&[IoSlice::new(&head), IoSlice::new(piece)], &dest)
                .map_err(|e| self.send_error(to, addr, e))?;
            add(&counters.fragments_sent, 1);
            add(&counters.datagrams_sent, 1);
        }
        add(&counters.frames_sent, 1);
        Ok(())
    }

    /// Sends the held frames `b` towards `to` as one datagram and empties the batch. `own` of
    /// them (0 or 1, the last) are the caller's, who gets the error; should the send fail, the
    /// others are counted as dropped.
    pub(super) fn send_batch(
        &self,
        to: SystemId,
        addr: SocketAddr,
        b: &mut Batch,
        own: u64,
    ) -> Result<(), LinkError> {
        if b.frames == 0 {
            return Ok(());
        }
        // One frame goes out bare, as `send` would send it (readable by receivers that predate
        // batch records, and 8 bytes shorter), unless it would be misread alone.
        let first = BATCH_HEADER_LEN + BATCH_LENGTH_LEN;
        let alone = b.frames == 1 && !misread_alone(&b.buf[first..]);
        let datagram = if alone { &b.buf[first..] } else { &b.buf[..] };
        let result = self.socket.send_to(datagram, addr);
        let frames = b.frames;
        b.buf.clear();
        b.frames = 0;
        let c = &self.shared.counters;
        match result {
            Ok(_) => {
                add(&c.frames_sent, frames);
                add(&c.datagrams_sent, 1);
                add(&c.batches_sent, u64::from(!alone));
                Ok(())
            }
            Err(e) => {
                add(&c.held_frames_dropped, frames.saturating_sub(own));
                Err(self.send_error(to, addr, e))
            }
        }
    }

    fn send_error(&self, to: SystemId, addr: SocketAddr, e: io::Error) -> LinkError {
        if e.kind() == io::ErrorKind::WouldBlock || e.raw_os_error() == Some(libc::ENOBUFS) {
            return LinkError::Congested {
                peer: to,
                reason: format!("socket send buffer full sending to {addr}: {e}"),
            };
        }
        match e.kind() {
            io::ErrorKind::ConnectionRefused
            | io::ErrorKind::HostUnreachable
            | io::ErrorKind::NetworkUnreachable
            | io::ErrorKind::AddrNotAvailable
            | io::ErrorKind::NetworkDown => LinkError::Unreachable {
                peer: to,
                reason: format!("send_to {addr} failed: {e}"),
            },
            _ => LinkError::Io(e),
        }
    }
}

/// The kernel's count of datagrams dropped at `socket` since it was opened (`SO_MEMINFO`,
/// Linux 4.12 and later), a 32-bit counter that wraps; `None` where it is not reported.
#[cfg(target_os = "linux")]
fn socket_drops(socket: &UdpSocket) -> Option<u32> {
    /// `SO_MEMINFO` (`asm-generic/socket.h`; sparc numbers it differently). The libc crate
    /// does not export it for every target.
    const SO_MEMINFO: libc::c_int = if cfg!(any(target_arch = "sparc", target_arch = "sparc64")) {
        0x39
    } else {
        55
    };
    let drops = libc::SK_MEMINFO_DROPS as usize;
    // The kernel fills as much of its `SK_MEMINFO_VARS` counters (9 today) as fits.
    let mut info = [0u32; 16];
    let mut len = std::mem::size_of_val(&info) as libc::socklen_t;
    // SAFETY: `socket` is open for the whole call; `info` is a live, writable buffer of `len`
    // bytes, and the kernel writes at most `len` bytes into it and the length into `len`.
    let r = unsafe {
        libc::getsockopt(
            socket.as_raw_fd(),
            libc::SOL_SOCKET,
            SO_MEMINFO,
            info.as_mut_ptr().cast(),
            &mut len,
        )
    };
    let filled = (len as usize) / std::mem::size_of::<u32>();
    (r == 0 && filled > drops).then(|| info[drops])
}

/// Not reported on this OS.
#[cfg(not(target_os = "linux"))]
fn socket_drops(_socket: &UdpSocket) -> Option<u32> {
    None
}

fn clock_seed() -> u32 {
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.subsec_nanos() ^ (d.as_secs() as u32).rotate_left(16))
        .unwrap_or(0);
    nanos ^ std::process::id().rotate_left(8)
}

fn resolve(id: SystemId, endpoint: &str, prefer_v4: bool) -> Result<SocketAddr, IpOpenError> {
    let bad = |reason: String| IpOpenError::BadEndpoint {
        system: id,
        endpoint: endpoint.to_string(),
        reason,
    };
    let addrs: Vec<SocketAddr> = endpoint
        .to_socket_addrs()
        .map_err(|e| bad(e.to_string()))?
        .collect();
    addrs
        .iter()
        .find(|a| a.is_ipv4() == prefer_v4)
        .or(addrs.first())
        .copied()
        .ok_or_else(|| bad("resolves to no address".into()))
}

impl SendSide {
    /// [`Link::send`].
    fn send(&self, to: SystemId, frame: &[u8]) -> Result<(), LinkError> {
        self.check_size(frame)?;
        let peer = self.peer(to)?;
        self.wait_for_writer(to, peer)?;
        {
            let mut b = lock(&peer.batch);
            if b.frames > 0 {
                if b.buf.len() + BATCH_LENGTH_LEN + frame.len() <= self.mtu {
                    // Joins the held frames: one datagram for all of them.
                    push_record(&mut b, frame);
                    return self.send_batch(to, peer.addr, &mut b, 1);
                }
                // Held frames go first. Their failure is counted; the result is this frame's.
                let _ = self.send_batch(to, peer.addr, &mut b, 0);
            }
        }
        self.send_now(to, peer.addr, frame)
    }

    /// [`Link::send_held`].
    fn send_held(&self, to: SystemId, frame: &[u8]) -> Result<(), LinkError> {
        self.check_size(frame)?;
        let peer = self.peer(to)?;
        let mtu = self.mtu;
        let mut b = lock(&peer.batch);
        if !batchable(frame, mtu) {
            self.wait_for_writer(to, peer)?;
            // Held frames go first. Their failure is counted; the result is this frame's.
            let _ = self.send_batch(to, peer.addr, &mut b, 0);
            drop(b);
            return self.send_now(to, peer.addr, frame);
        }
        if b.buf.len() + BATCH_LENGTH_LEN + frame.len() > mtu {
            self.wait_for_writer(to, peer)?;
            let _ = self.send_batch(to, peer.addr, &mut b, 0);
        }
        if b.buf.capacity() < mtu {
            // Once per peer: afterwards holding a frame never allocates.
            b.buf.reserve_exact(mtu);
        }
        push_record(&mut b, frame);
        if mtu - b.buf.len() < BATCH_LENGTH_LEN + HEADER_LEN {
            // No further frame can fit: holding these longer would only add latency. Should
            // the writer not finish in time, the frame stays held for the next send.
            self.wait_for_writer(to, peer)?;
            return self.send_batch(to, peer.addr, &mut b, 1);
        }
        Ok(())
    }

    /// [`Link::flush`].
    fn flush(&self) -> Result<(), LinkError> {
        let mut first = Ok(());
        for (&to, peer) in &self.peers {
            let mut b = lock(&peer.batch);
            let sent = self
                .wait_for_writer(to, peer)
                .and_then(|()| self.send_batch(to, peer.addr, &mut b, 0));
            if let Err(e) = sent {
                if first.is_ok() {
                    first = Err(e);
                }
            }
        }
        first
    }
}

impl Link for UdpLink {
    fn caps(&self) -> LinkCaps {
        LinkCaps {
            max_frame: self.tx.max_frame,
            mtu: self.config.datagram_payload,
            reliable: false,
            ordered: false,
            broadcast: false,
        }
    }

    fn send(&self, to: SystemId, frame: &[u8]) -> Result<(), LinkError> {
        self.tx.send(to, frame)
    }

    /// Sent behind a streaming sender by the link's writer thread (see "Write-behind" in the
    /// module docs), on the caller's thread otherwise.
    fn send_owned(&self, to: SystemId, frame: FrameBuf) -> Result<(), LinkError> {
        self.tx.send_given(to, frame)
    }

    fn stats(&self) -> LinkStats {
        let s = self.udp_stats();
        LinkStats {
            frames_sent: s.frames_sent,
            frames_received: s.frames_received,
            frames_dropped: s.frames_dropped,
            connects: 0,
            buffered_bytes: s.buffered_bytes,
            kernel_drops: s.kernel_drops,
            security: Default::default(),
        }
    }

    fn send_held(&self, to: SystemId, frame: &[u8]) -> Result<(), LinkError> {
        self.tx.send_held(to, frame)
    }

    fn flush(&self) -> Result<(), LinkError> {
        self.tx.flush()
    }

    fn batches(&self) -> bool {
        true
    }

    fn readable(&self) -> Option<&dyn Readable> {
        match &self.rx {
            RxSide::Driven(d) => Some(&**d),
            RxSide::Thread(_) => None,
        }
    }
}

impl Drop for UdpLink {
    fn drop(&mut self) {
        // Best effort: held frames would otherwise be lost without a trace. The writer sends
        // what it has queued before it stops.
        let _ = self.tx.flush();
        self.tx.writer.stop();
        self.tx.shared.closing.store(true, Ordering::SeqCst);
        let RxSide::Thread(thread) = &mut self.rx else {
            return; // driven: no thread to stop
        };
        // Wake the receive thread with an empty datagram to ourselves; the read timeout is the
        // fallback should it be lost.
        let mut me = self.local_addr;
        if me.ip().is_unspecified() {
            me.set_ip(match me.ip() {
                IpAddr::V4(_) => Ipv4Addr::LOCALHOST.into(),
                IpAddr::V6(_) => Ipv6Addr::LOCALHOST.into(),
            });
        }
        let _ = self.tx.socket.send_to(&[], me);
        if let Some(t) = thread.take() {
            let _ = t.join();
        }
    }
}
