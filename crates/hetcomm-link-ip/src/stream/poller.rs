//! Receiving without a thread per connection: the link's poller thread and the set of
//! identified connections (see "Receiving" in the [module docs](super)).
//!
//! When the listener can be polled ([`StreamListener::raw_fd`]), one thread per link waits in
//! `epoll` on the listener, on every connection that has not sent its hello yet and (unless
//! the link is [driven](super::StreamConfig::driven)) on the [`ConnSet`] of identified
//! connections, and does all of the link's receiving: it accepts (refusing connections over
//! [`max_connections`](super::StreamConfig::max_connections)), reads hellos without blocking
//! (closing connections whose hello is late), and reads records. A driven link's identified
//! connections are read by whoever calls [`Readable::read_ready`](hetcomm_link::Readable)
//! instead. Either way the number of threads does not grow with the number of connections,
//! and a connection's descriptor is closed as soon as its peer's end of stream is read.

use parking_lot::Mutex;
use std::collections::{HashMap, VecDeque};
use std::io::{self, Read};
use std::os::fd::{AsFd, BorrowedFd, OwnedFd};
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use hetcomm_core::SystemId;
use hetcomm_link::readiness::{timespec, WakeFd};
use hetcomm_link::Peer;
use rustix::event::epoll::{self, EventData, EventFlags};

use super::connection::{identify, new_reader, spawn_conn_reader, spawn_reader, Connection};
use super::framing::decode_hello;
use super::reader::StreamEnd;
use super::{bump, lock, Shared, StreamListener, StreamSocket, StreamTransport, HELLO_LEN};

/// Records read per connection per turn of the poller thread, so that one busy connection
/// does not starve the others.
const BUDGET: usize = 64;
/// Connections accepted per turn before the poller looks at its other descriptors again.
const ACCEPTS_PER_TURN: usize = 64;
/// How long accepting pauses after an error such as running out of descriptors (the
/// connection waits in the listen backlog meanwhile), so that the poller does not spin.
const ACCEPT_PAUSE: Duration = Duration::from_millis(10);
/// The longest the poller blocks in one wait, so that a lost wake-up costs little.
const MAX_WAIT: Duration = Duration::from_millis(500);

/// An `epoll` instance, level-triggered: a descriptor that still has bytes after a turn's
/// budget is reported again on the next wait.
pub(super) struct Epoll(OwnedFd);

impl Epoll {
    pub(super) fn new() -> io::Result<Epoll> {
        Ok(Epoll(epoll::create(epoll::CreateFlags::CLOEXEC)?))
    }

    /// Watches `fd` for `events`, reported with `token`.
    pub(super) fn add(&self, fd: impl AsFd, token: u64, events: EventFlags) -> io::Result<()> {
        Ok(epoll::add(&self.0, fd, EventData::new_u64(token), events)?)
    }

    /// Changes what `fd` is watched for.
    fn modify(&self, fd: impl AsFd, token: u64, events: EventFlags) -> io::Result<()> {
        Ok(epoll::modify(
            &self.0,
            fd,
            EventData::new_u64(token),
            events,
        )?)
    }

    /// Stops watching `fd` (closing it would too; this is for descriptors that stay open).
    pub(super) fn delete(&self, fd: impl AsFd) {
        let _ = epoll::delete(&self.0, fd);
    }

    /// Waits up to `timeout` (zero: not at all) for events; an interrupted wait returns none.
    pub(super) fn wait(&self, events: &mut [epoll::Event], timeout: Duration) -> io::Result<usize> {
        // Whole milliseconds, rounded up, as `epoll_wait` takes them: a short timeout waits.
        let ms = timeout.as_nanos().div_ceil(1_000_000).min(i32::MAX as u128) as u64;
        match epoll::wait(&self.0, events, Some(&timespec(Duration::from_millis(ms)))) {
            Ok(n) => Ok(n),
            Err(rustix::io::Errno::INTR) => Ok(0),
            Err(e) => Err(e.into()),
        }
    }
}

impl AsFd for Epoll {
    fn as_fd(&self) -> BorrowedFd<'_> {
        self.0.as_fd()
    }
}

/// An event slot for [`Epoll::wait`] to fill.
const NO_EVENT: epoll::Event = epoll::Event {
    flags: EventFlags::empty(),
    data: EventData::new_u64(0),
};

/// One accepted connection's share of [`StreamConfig::max_connections`](super::StreamConfig):
/// taken when it is accepted, given back when it is closed (dropped), whatever the path.
pub(super) struct Permit(Arc<AtomicUsize>);

impl Permit {
    /// A permit, unless `max` connections already hold one.
    pub(super) fn take(open: &Arc<AtomicUsize>, max: usize) -> Option<Permit> {
        open.fetch_update(Ordering::AcqRel, Ordering::Acquire, |n| {
            (n < max).then_some(n + 1)
        })
        .ok()
        .map(|_| Permit(open.clone()))
    }
}

impl Drop for Permit {
    fn drop(&mut self) {
        self.0.fetch_sub(1, Ordering::AcqRel);
    }
}

/// Identified connections, registered with one epoll instance and read, without blocking, by
/// whoever calls [`ConnSet::read_ready`]: the driving thread of a driven link (whose
/// [`Readable::fd`](hetcomm_link::Readable::fd) is this epoll), otherwise the poller thread.
pub(super) struct ConnSet<S> {
    pub(super) epoll: Epoll,
    /// Keyed by the token registered with epoll. Locked while a reader reads them (one
    /// reader at a time; a new connection's registration waits for it).
    conns: Mutex<HashMap<u64, Connection<S>>>,
    next_token: AtomicU64,
}

impl<S: StreamSocket> ConnSet<S> {
    pub(super) fn new() -> io::Result<Self> {
        Ok(ConnSet {
            epoll: Epoll::new()?,
            conns: Mutex::new(HashMap::new()),
            next_token: AtomicU64::new(1),
        })
    }

    /// Makes `conn` readable through [`ConnSet::read_ready`]; gives it back if its socket
    /// cannot be read without blocking (the caller then reads it on a thread).
    pub(super) fn register(&self, conn: Connection<S>) -> Result<(), Connection<S>> {
        let Some(fd) = conn.socket.raw_fd() else {
            return Err(conn);
        };
        if conn.socket.set_nonblocking(true).is_err() {
            return Err(conn);
        }
        let token = self.next_token.fetch_add(1, Ordering::Relaxed);
        // Registered and inserted under the map's lock: a reader that epoll tells about the
        // token finds the connection.
        let mut conns = lock(&self.conns);
        if self
            .epoll
            .add(fd, token, EventFlags::IN | EventFlags::RDHUP)
            .is_err()
        {
            drop(conns);
            let _ = conn.socket.set_nonblocking(false);
            return Err(conn);
        }
        conns.insert(token, conn);
        Ok(())
    }

    /// Reads up to `budget` records from each connection epoll reports ready (and then
    /// whatever records are already buffered), handing them to the sink; closes connections
    /// that ended. Returns the number of frames handed on.
    pub(super) fn read_ready<T>(&self, shared: &Shared<T>, budget: usize) -> io::Result<usize>
    where
        T: StreamTransport<Socket = S>,
    {
        const EVENTS: usize = 16;
        let mut events = [NO_EVENT; EVENTS];
        let n = self.epoll.wait(&mut events, Duration::ZERO)?;
        let mut frames = 0;
        let mut conns = lock(&self.conns);
        for ev in &events[..n] {
            let token = ev.data.u64();
            let Some(conn) = conns.get_mut(&token) else {
                continue;
            };
            let (got, result) = conn.read_records(shared, budget);
            frames += got;
            match result {
                Ok(()) | Err(StreamEnd::Pending) => {}
                Err(end) => {
                    if let Some(conn) = conns.remove(&token) {
                        if let Some(fd) = conn.socket.raw_fd() {
                            self.epoll.delete(fd);
                        }
                        // Closes the descriptor: the peer's end is not kept waiting.
                        conn.end(shared, end);
                    }
                }
            }
        }
        Ok(frames)
    }

    /// Closes every connection (the link is closing).
    pub(super) fn shutdown(&self) {
        for conn in std::mem::take(&mut *lock(&self.conns)).into_values() {
            let _ = conn.socket.shutdown_both();
        }
    }
}

/// Tokens of the poller's own descriptors; connections waiting for their hello get the
/// tokens above them.
const LISTENER: u64 = 0;
const WAKER: u64 = 1;
const CONNS: u64 = 2;
const FIRST_HELLO: u64 = 3;

/// An accepted connection whose hello has not arrived in full yet.
struct Hello<S> {
    socket: S,
    hello: [u8; HELLO_LEN],
    got: usize,
    permit: Permit,
}

/// What a hello's read came to.
enum HelloRead {
    /// More bytes are needed; the socket has none now.
    Waiting,
    /// The whole hello is in.
    Complete,
    /// End of stream or an error before the whole hello.
    Failed,
}

/// The poller thread's state: see the module docs.
pub(super) struct Poller<T: StreamTransport> {
    shared: Arc<Shared<T>>,
    listener: Arc<T::Listener>,
    waker: Arc<WakeFd>,
    epoll: Epoll,
    hellos: HashMap<u64, Hello<T::Socket>>,
    /// When each waiting hello is due, in order (hellos all get the same timeout). Entries of
    /// hellos that arrived are skipped when they reach the front.
    deadlines: VecDeque<(Instant, u64)>,
    next_token: u64,
    /// Accepting is paused until then after an accept error.
    accept_paused_until: Option<Instant>,
}

impl<T: StreamTransport> Poller<T> {
    /// The poller of a link whose listener is polled ([`StreamListener::raw_fd`]) and
    /// already non-blocking. The poller reads the link's [`ConnSet`] itself unless the link
    /// is driven.
    pub(super) fn new(
        shared: Arc<Shared<T>>,
        listener: Arc<T::Listener>,
        waker: Arc<WakeFd>,
    ) -> io::Result<Self> {
        let epoll = Epoll::new()?;
        let listener_fd = listener.raw_fd().ok_or(io::ErrorKind::Unsupported)?;
        epoll.add(listener_fd, LISTENER, EventFlags::IN)?;
        epoll.add(&*waker, WAKER, EventFlags::IN)?;
        if !shared.config.driven {
            if let Some(set) = &shared.conns {
                epoll.add(&set.epoll, CONNS, EventFlags::IN)?;
            }
        }
        Ok(Poller {
            shared,
            listener,
            waker,
            epoll,
            hellos: HashMap::new(),
            deadlines: VecDeque::new(),
            next_token: FIRST_HELLO,
            accept_paused_until: None,
        })
    }

    /// Runs until the link closes.
    pub(super) fn run(mut self) {
        const EVENTS: usize = 64;
        let mut events = [NO_EVENT; EVENTS];
        while !self.shared.closing.load(Ordering::SeqCst) {
            let now = Instant::now();
            let next = [
                self.deadlines.front().map(|d| d.0),
                self.accept_paused_until,
            ]
            .into_iter()
            .flatten()
            .min();
            let timeout = next.map_or(MAX_WAIT, |t| t.saturating_duration_since(now).min(MAX_WAIT));
            let n = match self.epoll.wait(&mut events, timeout) {
                Ok(n) => n,
                Err(_) => {
                    // Not expected with valid arguments; do not spin if it happens.
                    std::thread::park_timeout(ACCEPT_PAUSE);
                    0
                }
            };
            if self.shared.closing.load(Ordering::SeqCst) {
                break;
            }
            for ev in &events[..n] {
                match ev.data.u64() {
                    LISTENER => self.accept(),
                    WAKER => self.waker.drain(),
                    CONNS => {
                        if let Some(set) = &self.shared.conns {
                            let _ = set.read_ready(&self.shared, BUDGET);
                        }
                    }
                    token => self.read_hello(token),
                }
            }
            self.upkeep(Instant::now());
        }
        // Waiting hellos are dropped (closed) with `self`, uncounted: the link is closing.
    }

    /// Accepts what the listen backlog holds, up to a turn's worth.
    fn accept(&mut self) {
        for _ in 0..ACCEPTS_PER_TURN {
            match self.listener.accept() {
                Ok((socket, addr)) => self.admit(socket, addr),
                Err(e) => match e.kind() {
                    io::ErrorKind::WouldBlock => return,
                    io::ErrorKind::Interrupted | io::ErrorKind::ConnectionAborted => {}
                    _ => {
                        // Typically EMFILE: the connection stays in the backlog; try again
                        // shortly rather than spin on a listener that stays readable.
                        self.pause_accepting();
                        return;
                    }
                },
            }
        }
    }

    fn pause_accepting(&mut self) {
        if let Some(fd) = self.listener.raw_fd() {
            if self.epoll.modify(fd, LISTENER, EventFlags::empty()).is_ok() {
                self.accept_paused_until = Some(Instant::now() + ACCEPT_PAUSE);
            }
        }
    }

    /// Takes a freshly accepted connection in, or refuses it when the link has
    /// `max_connections` open.
    fn admit(&mut self, mut socket: T::Socket, addr: <T::Listener as StreamListener>::PeerAddr) {
        let shared = &self.shared;
        bump(&shared.counters.accepted);
        let Some(permit) = Permit::take(&shared.open, shared.config.max_connections) else {
            refuse(shared, socket);
            return;
        };
        let _ = shared.transport.configure(&socket);
        if shared.transport.identity_mode() != super::IdentityMode::Hello {
            // Known from the address (or not at all): nothing to wait for.
            match identify(shared, &mut socket, &addr) {
                Some(from) => self.identified(socket, from, permit),
                None => reject(shared, socket),
            }
            return;
        }
        let Some(fd) = socket.raw_fd() else {
            spawn_reader(shared, socket, addr, permit);
            return;
        };
        if socket.set_nonblocking(true).is_err() {
            spawn_reader(shared, socket, addr, permit);
            return;
        }
        let token = self.next_token;
        self.next_token += 1;
        if self
            .epoll
            .add(fd, token, EventFlags::IN | EventFlags::RDHUP)
            .is_err()
        {
            let _ = socket.set_nonblocking(false);
            spawn_reader(shared, socket, addr, permit);
            return;
        }
        let hello = Hello {
            socket,
            hello: [0; HELLO_LEN],
            got: 0,
            permit,
        };
        self.hellos.insert(token, hello);
        let due = Instant::now() + shared.config.hello_timeout;
        self.deadlines.push_back((due, token));
    }

    /// Reads what has arrived of the hello of connection `token`.
    fn read_hello(&mut self, token: u64) {
        let Some(h) = self.hellos.get_mut(&token) else {
            return;
        };
        let outcome = loop {
            // Exactly the hello: the records behind it belong to the record reader.
            match h.socket.read(&mut h.hello[h.got..]) {
                Ok(0) => break HelloRead::Failed,
                Ok(n) => {
                    h.got += n;
                    if h.got == HELLO_LEN {
                        break HelloRead::Complete;
                    }
                }
                Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                Err(e) if e.kind() == io::ErrorKind::WouldBlock => break HelloRead::Waiting,
                Err(_) => break HelloRead::Failed,
            }
        };
        if matches!(outcome, HelloRead::Waiting) {
            return;
        }
        let Some(h) = self.hellos.remove(&token) else {
            return;
        };
        if let Some(fd) = h.socket.raw_fd() {
            self.epoll.delete(fd);
        }
        let from = match outcome {
            HelloRead::Complete => decode_hello(&h.hello).filter(|id| self.in_fleet(*id)),
            _ => None,
        };
        match from {
            Some(id) => self.identified(h.socket, Peer::System(id), h.permit),
            None => reject(&self.shared, h.socket),
        }
    }

    fn in_fleet(&self, id: SystemId) -> bool {
        self.shared.fleet.contains_key(&id)
    }

    /// Hands an identified connection to the [`ConnSet`] (or, if its socket cannot be read
    /// without blocking, to a thread of its own).
    fn identified(&mut self, socket: T::Socket, from: Peer, permit: Permit) {
        let conn = Connection {
            reader: new_reader(&self.shared),
            socket,
            from,
            _permit: permit,
        };
        let conn = match &self.shared.conns {
            Some(set) => match set.register(conn) {
                Ok(()) => return,
                Err(back) => back,
            },
            None => conn,
        };
        spawn_conn_reader(&self.shared, conn);
    }

    /// Closes connections whose hello is overdue and resumes accepting after a pause.
    fn upkeep(&mut self, now: Instant) {
        while let Some(&(due, token)) = self.deadlines.front() {
            if !self.hellos.contains_key(&token) {
                self.deadlines.pop_front();
                continue;
            }
            if due > now {
                break;
            }
            self.deadlines.pop_front();
            if let Some(h) = self.hellos.remove(&token) {
                if let Some(fd) = h.socket.raw_fd() {
                    self.epoll.delete(fd);
                }
                reject(&self.shared, h.socket);
            }
        }
        if self.accept_paused_until.is_some_and(|t| t <= now) {
            if let Some(fd) = self.listener.raw_fd() {
                if self.epoll.modify(fd, LISTENER, EventFlags::IN).is_ok() {
                    self.accept_paused_until = None;
                }
            }
        }
    }
}

/// Closes a connection refused because the link has `max_connections` open: counted, and
/// as one dropped frame (what its sender sends on it is lost).
pub(super) fn refuse<T: StreamTransport>(shared: &Shared<T>, socket: T::Socket) {
    bump(&shared.counters.refused_connections);
    bump(&shared.counters.frames_dropped);
    let _ = socket.shutdown_both();
}

/// Closes a connection whose sender is not a fleet system, or whose hello was malformed,
/// late or cut short: one rejected connection and one dropped frame (unless the link is
/// closing).
pub(super) fn reject<T: StreamTransport>(shared: &Shared<T>, socket: T::Socket) {
    if !shared.closing.load(Ordering::SeqCst) {
        bump(&shared.counters.rejected_connections);
        bump(&shared.counters.frames_dropped);
    }
    let _ = socket.shutdown_both();
}
