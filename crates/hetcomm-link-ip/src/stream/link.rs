//! [`StreamLink`]'s sending side and its [`Link`] implementation: opening the link,
//! one cached outgoing connection per peer made by a connector thread, batching of held
//! frames, write failures, driven reading ([`Readable`]) and shutdown.

use parking_lot::{Condvar, Mutex};
use std::collections::{BTreeMap, HashMap};
use std::fmt;
use std::io::{self, Write};
use std::os::fd::{AsFd, AsRawFd};
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use hetcomm_core::{FrameBuf, SystemId};
use hetcomm_link::readiness::WakeFd;
use hetcomm_link::{FrameSink, Link, LinkCaps, LinkError, LinkEvent, LinkStats, Readable};

use super::connection::accept_loop;
use super::framing::{append_record, encode_hello, record_header, write_parts, FrameParts};
use super::poller::{ConnSet, Poller};
use super::{
    add, bump, lock, raise, Backoff, IdentityMode, PeerEntry, PeerSlot, Shared, StreamConfig,
    StreamCounters, StreamLink, StreamListener, StreamSocket, StreamStats, StreamTransport,
    RECORD_HEADER_LEN,
};

impl<T: StreamTransport> StreamLink<T> {
    /// Starts a link for system `local` that accepts on `listener` and connects to the
    /// addresses in `peers` (an entry for `local` itself is ignored). Received frames go to
    /// `sink`. Fails only if the receiving thread (or its `epoll` instance) cannot be set up.
    pub fn new(
        transport: T,
        local: SystemId,
        listener: T::Listener,
        peers: BTreeMap<SystemId, T::Addr>,
        sink: Arc<dyn FrameSink>,
        config: StreamConfig,
    ) -> io::Result<StreamLink<T>> {
        let peers: BTreeMap<_, _> = peers
            .into_iter()
            .filter(|(id, _)| *id != local)
            .map(|(id, addr)| {
                let entry = PeerEntry {
                    addr,
                    slot: Mutex::new(PeerSlot::new()),
                    held: AtomicBool::new(false),
                    room: Condvar::new(),
                };
                (id, entry)
            })
            .collect();
        let polled = listener.raw_fd().is_some() && listener.set_nonblocking(true).is_ok();
        let conns = if config.driven || polled {
            Some(ConnSet::new()?)
        } else {
            None
        };
        let shared = Arc::new(Shared {
            transport,
            sink,
            conns,
            config,
            fleet: peers.keys().map(|id| (*id, ())).collect(),
            closing: AtomicBool::new(false),
            counters: StreamCounters::default(),
            open: Arc::new(AtomicUsize::new(0)),
            readers: Mutex::new(HashMap::new()),
            finished_readers: Mutex::new(Vec::new()),
            next_reader: AtomicU64::new(1),
        });
        let listener = Arc::new(listener);
        let (accept_thread, waker) = {
            let shared = shared.clone();
            let listener = listener.clone();
            let thread = std::thread::Builder::new();
            if polled {
                let waker = Arc::new(WakeFd::new()?);
                let poller = Poller::new(shared, listener, waker.clone())?;
                let handle = thread
                    .name(format!("hetcomm-{}-rx-{local}", T::NAME))
                    .spawn(move || poller.run())?;
                (handle, Some(waker))
            } else {
                let handle = thread
                    .name(format!("hetcomm-{}-accept-{local}", T::NAME))
                    .spawn(move || accept_loop(&shared, &listener))?;
                (handle, None)
            }
        };
        Ok(StreamLink {
            local,
            shared,
            listener,
            peers: Arc::new(peers),
            held_any: AtomicBool::new(false),
            accept_thread: Some(accept_thread),
            waker,
            writer: Arc::default(),
        })
    }

    /// The system this link belongs to.
    pub fn local(&self) -> SystemId {
        self.local
    }

    /// The listener this link accepts on (e.g. to read its bound address).
    pub fn listener(&self) -> &T::Listener {
        &self.listener
    }

    /// The connections a driving thread reads, with [`StreamConfig::driven`].
    fn driven(&self) -> Option<&ConnSet<T::Socket>> {
        self.shared
            .conns
            .as_ref()
            .filter(|_| self.shared.config.driven)
    }

    /// All counters, including those [`LinkStats`] has no field for.
    pub fn stream_stats(&self) -> StreamStats {
        let c = &self.shared.counters;
        let get = |a: &AtomicU64| a.load(Ordering::Relaxed);
        StreamStats {
            frames_sent: get(&c.frames_sent),
            frames_received: get(&c.frames_received),
            frames_dropped: get(&c.frames_dropped),
            connects: get(&c.connects),
            accepted: get(&c.accepted),
            rejected_connections: get(&c.rejected_connections),
            refused_connections: get(&c.refused_connections),
            open_connections: self.shared.open.load(Ordering::Relaxed) as u64,
            frames_written_behind: get(&c.frames_written_behind),
            write_failures: get(&c.write_failures),
            frames_lost_connecting: get(&c.frames_lost_connecting),
            held_frames_dropped: get(&c.held_frames_dropped),
            oversize_records: get(&c.oversize_records),
        }
    }

    /// Bytes of frames queued for connections, held in batches or written behind, over all
    /// peers.
    pub fn pending_bytes(&self) -> usize {
        self.peers
            .values()
            .map(|p| {
                let slot = lock(&p.slot);
                slot.out.len() + slot.behind.bytes()
            })
            .sum()
    }

    /// Starts a connector thread for `to` (its slot is already marked `connecting`).
    fn start_connector(&self, to: SystemId) -> io::Result<()> {
        let shared = self.shared.clone();
        let peers = self.peers.clone();
        let local = self.local;
        std::thread::Builder::new()
            .name(format!("hetcomm-{}-connect-{to}", T::NAME))
            .spawn(move || {
                if let Some(entry) = peers.get(&to) {
                    // Told after the peer's lock is released: the sink may send at once.
                    if let Some(event) = run_connector(&shared, local, entry, to) {
                        shared.sink.on_event(event);
                    }
                }
            })
            .map(|_| ())
    }

    /// The peer entry of `to`, after checking the size of a frame of `len` bytes.
    pub(super) fn entry_for(&self, to: SystemId, len: usize) -> Result<&PeerEntry<T>, LinkError> {
        let max = self.shared.config.max_frame();
        if len > max {
            return Err(LinkError::TooLarge { len, max });
        }
        self.peers.get(&to).ok_or_else(|| {
            let reason = if to == self.local {
                "it is this system itself".to_string()
            } else {
                format!("system {to} has no endpoint on this {} link", T::NAME)
            };
            LinkError::Unreachable { peer: to, reason }
        })
    }

    /// [`Link::send`] of a frame in one or two pieces.
    fn send_frame(&self, to: SystemId, frame: FrameParts<'_>) -> Result<(), LinkError> {
        let entry = self.entry_for(to, frame.len())?;
        let mut slot = lock(&entry.slot);
        if slot.behind.active() {
            return self.copy_behind(to, entry, slot, Some(frame));
        }
        if slot.conn.is_none() {
            return self.queue_for_connection(to, entry, &mut slot, frame, true);
        }
        // Held frames first, in the same write: order kept, one syscall for both.
        self.write_batch(to, entry, &mut slot, Some(frame))
    }

    fn mark_held(&self, entry: &PeerEntry<T>) {
        raise(&entry.held);
        raise(&self.held_any);
    }

    /// Queues `frame` for `to`'s connection, which is not up, starting a connector if none
    /// runs. `release`: the frame (and everything held before it) goes out as soon as the
    /// connection is up; otherwise it is held like the batch of a live connection.
    pub(super) fn queue_for_connection(
        &self,
        to: SystemId,
        entry: &PeerEntry<T>,
        slot: &mut PeerSlot<T::Socket>,
        frame: FrameParts<'_>,
        release: bool,
    ) -> Result<(), LinkError> {
        let now = Instant::now();
        if let Some(b) = &slot.backoff {
            if now < b.retry_at {
                let left = b.retry_at - now;
                return Err(LinkError::Unreachable {
                    peer: to,
                    reason: format!(
                        "reconnecting in {} ms after: {}",
                        left.as_millis().max(1),
                        b.reason
                    ),
                });
            }
        }
        // Never wait for a connect on the caller's thread: queue behind a connector.
        if slot.pending_frames() >= self.shared.config.connect_queue_frames {
            return Err(LinkError::Congested {
                peer: to,
                reason: format!(
                    "{} frames already wait for the connection to {}",
                    slot.pending_frames(),
                    entry.addr
                ),
            });
        }
        append_record(&mut slot.out, frame);
        slot.held_frames += 1;
        if release {
            slot.release_all();
        } else {
            self.mark_held(entry);
        }
        if !slot.connecting {
            slot.connecting = true;
            if let Err(e) = self.start_connector(to) {
                slot.connecting = false;
                // Only this frame can be pending here (no connection and no connector means
                // nothing was queued), and it is refused rather than lost.
                slot.clear_pending(self.shared.config.batch_bytes);
                return Err(LinkError::Io(e));
            }
        }
        Ok(())
    }

    /// Writes `slot`'s held records followed by `frame`, if any, on its live connection in one
    /// vectored write. On failure the connection is dropped and the held frames are counted
    /// as dropped (the caller learns about `frame` from the error).
    pub(super) fn write_batch(
        &self,
        to: SystemId,
        entry: &PeerEntry<T>,
        slot: &mut PeerSlot<T::Socket>,
        frame: Option<FrameParts<'_>>,
    ) -> Result<(), LinkError> {
        let cfg = &self.shared.config;
        let counters = &self.shared.counters;
        let PeerSlot {
            conn,
            out,
            held_frames,
            ..
        } = slot;
        let Some(socket) = conn.as_mut() else {
            // Callers check the connection first; fail soft rather than panic.
            return Err(LinkError::Closed);
        };
        let head = frame.map_or([0; RECORD_HEADER_LEN], |f| record_header(f.len()));
        let parts: [&[u8]; 4] = match frame {
            Some(f) => [&out[..], &head, f.head, f.body],
            None => [&out[..], &[], &[], &[]],
        };
        let result = write_parts(socket, &parts, cfg.write_timeout);
        let held = std::mem::take(held_frames);
        out.clear();
        if held > 0 && entry.held.load(Ordering::Relaxed) {
            // Nothing is held any more (we hold the lock), so the next flush can skip this peer.
            entry.held.store(false, Ordering::Release);
        }
        match result {
            Ok(()) => {
                add(&counters.frames_sent, held + usize::from(frame.is_some()));
                Ok(())
            }
            Err(e) => {
                slot.drop_connection();
                bump(&counters.write_failures);
                add(&counters.held_frames_dropped, held);
                Err(write_error(to, &entry.addr, &e, cfg.write_timeout))
            }
        }
    }
}

/// The error a failed write on a live connection is reported as.
fn write_error(
    to: SystemId,
    addr: &impl fmt::Display,
    e: &io::Error,
    timeout: Duration,
) -> LinkError {
    let ms = timeout.as_millis();
    if matches!(
        e.kind(),
        io::ErrorKind::WouldBlock | io::ErrorKind::TimedOut
    ) {
        LinkError::Congested {
            peer: to,
            reason: format!(
                "{addr} did not take the data within the {ms} ms write timeout; \
                 connection dropped"
            ),
        }
    } else {
        LinkError::Unreachable {
            peer: to,
            reason: format!(
                "write to {addr} failed: {e}; connection dropped, the next send reconnects"
            ),
        }
    }
}

/// Opens a connection to `addr` and sends the hello if the transport uses one.
fn connect<T: StreamTransport>(
    shared: &Shared<T>,
    local: SystemId,
    addr: &T::Addr,
) -> io::Result<T::Socket> {
    let cfg = &shared.config;
    let mut socket = shared.transport.connect(addr, cfg.connect_timeout)?;
    shared.transport.configure(&socket)?;
    socket.set_write_timeout(Some(cfg.write_timeout))?;
    if shared.transport.identity_mode() == IdentityMode::Hello {
        socket.write_all(&encode_hello(local))?;
    }
    Ok(socket)
}

/// The connector thread: makes the connection without holding the peer's lock (senders keep
/// queueing meanwhile), then installs it and writes the released frames in order (held ones
/// stay in the batch), or drops them all and starts the backoff. Returns what the sink is to
/// be told: the peer up (connected) or lost (the connect or its first write failed).
fn run_connector<T: StreamTransport>(
    shared: &Shared<T>,
    local: SystemId,
    entry: &PeerEntry<T>,
    to: SystemId,
) -> Option<LinkEvent> {
    let result = connect(shared, local, &entry.addr);
    let mut slot = lock(&entry.slot);
    slot.connecting = false;
    if shared.closing.load(Ordering::SeqCst) {
        // The link closed while connecting: what waited for the connection is lost, counted.
        let lost = slot.clear_pending(shared.config.batch_bytes);
        add(&shared.counters.frames_lost_connecting, lost);
        return None;
    }
    let cfg = &shared.config;
    let error = match result {
        Ok(mut socket) => {
            bump(&shared.counters.connects);
            let released = slot.released;
            match write_parts(&mut socket, &[&slot.out[..released]], cfg.write_timeout) {
                Ok(()) => {
                    add(&shared.counters.frames_sent, slot.released_frames);
                    slot.out.drain(..released);
                    slot.out.shrink_to(cfg.batch_bytes);
                    slot.released = 0;
                    slot.released_frames = 0;
                    slot.conn = Some(socket);
                    slot.backoff = None;
                    return Some(LinkEvent::PeerUp(to));
                }
                Err(e) => {
                    bump(&shared.counters.write_failures);
                    let _ = socket.shutdown_both();
                    e
                }
            }
        }
        Err(e) => e,
    };
    let lost = slot.clear_pending(cfg.batch_bytes);
    add(&shared.counters.frames_lost_connecting, lost);
    let delay = match &slot.backoff {
        Some(b) => (b.delay * 2).min(cfg.backoff_max),
        None => cfg.backoff_initial,
    };
    slot.backoff = Some(Backoff {
        retry_at: Instant::now() + delay,
        delay,
        reason: format!("{} connect to {} failed: {error}", T::NAME, entry.addr),
    });
    Some(LinkEvent::PeerDown(to))
}

impl<T: StreamTransport> StreamLink<T> {
    /// The capabilities a stream link with `config` declares.
    pub fn caps_for(config: &StreamConfig) -> LinkCaps {
        let max = config.max_frame();
        LinkCaps {
            max_frame: max,
            mtu: max,
            reliable: true,
            ordered: true,
            broadcast: false,
        }
    }
}

impl<T: StreamTransport> Link for StreamLink<T> {
    fn caps(&self) -> LinkCaps {
        Self::caps_for(&self.shared.config)
    }

    fn send(&self, to: SystemId, frame: &[u8]) -> Result<(), LinkError> {
        self.send_frame(to, FrameParts::whole(frame))
    }

    /// Writes the record header, `head` and `body` with one vectored write: a large payload
    /// goes from the caller's buffer to the socket without a copy in user space.
    fn send_parts(&self, to: SystemId, head: &[u8], body: &[u8]) -> Result<(), LinkError> {
        self.send_frame(to, FrameParts { head, body })
    }

    /// Written behind a streaming sender by the link's writer thread (see "Write-behind" in
    /// the module docs), on the caller's thread otherwise.
    fn send_owned(&self, to: SystemId, frame: FrameBuf) -> Result<(), LinkError> {
        self.send_given(to, frame)
    }

    fn readable(&self) -> Option<&dyn Readable> {
        self.driven().map(|_| self as &dyn Readable)
    }

    fn send_held(&self, to: SystemId, frame: &[u8]) -> Result<(), LinkError> {
        let entry = self.entry_for(to, frame.len())?;
        let frame = FrameParts::whole(frame);
        let cap = self.shared.config.batch_bytes;
        let mut slot = lock(&entry.slot);
        if slot.behind.active() {
            // The writer is busy with this peer: the frame leaves with its next write.
            return self.copy_behind(to, entry, slot, Some(frame));
        }
        if slot.conn.is_none() {
            return self.queue_for_connection(to, entry, &mut slot, frame, false);
        }
        let record = RECORD_HEADER_LEN + frame.len();
        if record > cap {
            // Too big to hold: write it now, right behind what is held.
            return self.write_batch(to, entry, &mut slot, Some(frame));
        }
        if slot.out.len() + record > cap {
            self.write_batch(to, entry, &mut slot, None)?;
        }
        if slot.out.capacity() < cap {
            // Grow to the full batch once, rather than by doubling.
            let more = cap - slot.out.len();
            slot.out.reserve_exact(more);
        }
        append_record(&mut slot.out, frame);
        slot.held_frames += 1;
        self.mark_held(entry);
        Ok(())
    }

    fn flush(&self) -> Result<(), LinkError> {
        if !self.held_any.load(Ordering::Acquire) || !self.held_any.swap(false, Ordering::AcqRel) {
            return Ok(());
        }
        let mut first_error = None;
        for (&to, entry) in self.peers.iter() {
            // Cleared before the lock is taken: a frame held after this is flagged anew.
            if !entry.held.load(Ordering::Acquire) || !entry.held.swap(false, Ordering::AcqRel) {
                continue;
            }
            let mut slot = lock(&entry.slot);
            if slot.held_frames == 0 {
                continue;
            }
            if slot.behind.active() {
                let _ = self.copy_behind(to, entry, slot, None);
                continue;
            }
            if slot.conn.is_none() {
                // The connector writes released frames as soon as the connection is up.
                slot.release_all();
                continue;
            }
            if let Err(e) = self.write_batch(to, entry, &mut slot, None) {
                first_error.get_or_insert(e);
            }
        }
        first_error.map_or(Ok(()), Err)
    }

    fn batches(&self) -> bool {
        self.shared.config.batch_bytes > 0
    }

    fn checksums_payload(&self) -> bool {
        self.shared.transport.checksums_payload()
    }

    fn stats(&self) -> LinkStats {
        let s = self.stream_stats();
        LinkStats {
            frames_sent: s.frames_sent,
            frames_received: s.frames_received,
            frames_dropped: s.frames_dropped + s.held_frames_dropped,
            connects: s.connects,
            buffered_bytes: self.pending_bytes() as u64,
            kernel_drops: 0,
            security: Default::default(),
        }
    }
}

/// With [`StreamConfig::driven`]: the receive side, read by whichever thread calls
/// `read_ready` (see "Driven receive" in the module docs).
impl<T: StreamTransport> Readable for StreamLink<T> {
    /// An epoll descriptor over every accepted connection (readable when any of them is).
    /// Without `driven`, a descriptor that never polls readable is not offered: -1.
    fn fd(&self) -> std::os::fd::RawFd {
        self.driven().map_or(-1, |d| d.epoll.as_fd().as_raw_fd())
    }

    /// Reads up to `budget` records from each connection that has bytes (and then whatever
    /// records are already buffered), handing them to the sink; closes connections that
    /// ended, counted as without `driven`.
    fn read_ready(&self, budget: usize) -> io::Result<usize> {
        match self.driven() {
            Some(d) => d.read_ready(&self.shared, budget.max(1)),
            None => Ok(0),
        }
    }
}

impl<T: StreamTransport> Drop for StreamLink<T> {
    fn drop(&mut self) {
        // Best effort: held frames would otherwise be lost without a trace (a peer that does
        // not read makes this wait up to the write timeout).
        let _ = self.flush();
        // Frames written behind go out (each write bounded by the write timeout).
        self.writer.stop();
        self.shared.closing.store(true, Ordering::SeqCst);
        match &self.waker {
            Some(w) => w.wake(),
            None => self.listener.wake(),
        }
        if let Some(h) = self.accept_thread.take() {
            let _ = h.join();
        }
        // The accepting thread is gone, so no reader can be added any more.
        let readers = std::mem::take(&mut *lock(&self.shared.readers));
        for r in readers.values() {
            let _ = r.socket.shutdown_both();
        }
        for r in readers.into_values() {
            let _ = r.handle.join();
        }
        for h in std::mem::take(&mut *lock(&self.shared.finished_readers)) {
            let _ = h.join();
        }
        if let Some(conns) = &self.shared.conns {
            conns.shutdown();
        }
        for peer in self.peers.values() {
            if let Some(s) = lock(&peer.slot).conn.take() {
                let _ = s.shutdown_both();
            }
        }
    }
}
