//! Accepted connections: establishing who is on the other end (hello, address or anonymous),
//! the [`Connection`] that reads an identified connection's records and closes it when its
//! stream ends, and the thread per connection used for listeners and sockets that cannot be
//! polled.

use std::io;
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::{Duration, Instant};

use hetcomm_core::{BufferPool, SystemId};
use hetcomm_link::{LinkEvent, Peer};

use super::framing::decode_hello;
use super::poller::{refuse, reject, Permit};
use super::reader::{FrameAt, RecordReader, StreamEnd};
use super::{
    bump, lock, IdentityMode, Reader, Shared, StreamListener, StreamSocket, StreamTransport,
    HELLO_LEN, RECEIVE_POOL_BYTES,
};

/// The accept thread of a listener that cannot be polled: a reader thread per connection.
pub(super) fn accept_loop<T: StreamTransport>(shared: &Arc<Shared<T>>, listener: &T::Listener) {
    loop {
        let accepted = listener.accept();
        if shared.closing.load(Ordering::SeqCst) {
            return;
        }
        let (socket, addr) = match accepted {
            Ok(x) => x,
            Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
            Err(_) => {
                // Typically EMFILE or an aborted handshake. Pause briefly so a persistent error
                // (out of file descriptors) does not spin a core; the error is per attempt.
                std::thread::sleep(Duration::from_millis(10));
                continue;
            }
        };
        bump(&shared.counters.accepted);
        match Permit::take(&shared.open, shared.config.max_connections) {
            Some(permit) => spawn_reader(shared, socket, addr, permit),
            None => refuse(shared, socket),
        }
    }
}

/// Identifies and reads an accepted connection on a thread of its own.
pub(super) fn spawn_reader<T: StreamTransport>(
    shared: &Arc<Shared<T>>,
    socket: T::Socket,
    addr: <T::Listener as StreamListener>::PeerAddr,
    permit: Permit,
) {
    let Ok(handle) = socket.try_clone() else {
        refuse(shared, socket);
        return;
    };
    spawn_thread(shared, handle, move |shared| {
        serve_connection(shared, socket, addr, permit)
    });
}

/// Reads an identified connection whose socket cannot be polled on a thread of its own.
pub(super) fn spawn_conn_reader<T: StreamTransport>(
    shared: &Arc<Shared<T>>,
    conn: Connection<T::Socket>,
) {
    let Ok(handle) = conn.socket.try_clone() else {
        refuse(shared, conn.socket);
        return;
    };
    spawn_thread(shared, handle, move |shared| read_on_thread(shared, conn));
}

/// Starts a reader thread running `run`, with `handle` (a second handle to its connection)
/// kept to shut the connection down when the link closes. The thread forgets its entry, and
/// so closes `handle`, when `run` returns. If no thread can be started the connection is
/// closed (with `run`) and counted as refused.
fn spawn_thread<T: StreamTransport>(
    shared: &Arc<Shared<T>>,
    handle: T::Socket,
    run: impl FnOnce(&Shared<T>) + Send + 'static,
) {
    // Threads that finished their connections are ending (or have ended): join them.
    for h in std::mem::take(&mut *lock(&shared.finished_readers)) {
        let _ = h.join();
    }
    let id = shared.next_reader.fetch_add(1, Ordering::Relaxed);
    let thread_shared = shared.clone();
    // Locked until the entry is in: a thread that ends at once waits to remove it.
    let mut readers = lock(&shared.readers);
    let spawned = std::thread::Builder::new()
        .name(format!("hetcomm-{}-rx-{id}", T::NAME))
        .spawn(move || {
            run(&thread_shared);
            // Its handle goes where the next reader's start or the link's drop joins it.
            if let Some(done) = lock(&thread_shared.readers).remove(&id) {
                lock(&thread_shared.finished_readers).push(done.handle);
            }
        });
    match spawned {
        Ok(thread) => {
            readers.insert(
                id,
                Reader {
                    socket: handle,
                    handle: thread,
                },
            );
        }
        Err(_) => {
            drop(readers);
            refuse(shared, handle);
        }
    }
}

/// Reads exactly `buf.len()` bytes by `deadline` in total, however the peer spreads them over
/// its writes: the socket's read timeout is set to what is left before each read. An error if
/// the stream ends first (`UnexpectedEof`) or the deadline passes (`TimedOut`).
fn read_by<S: StreamSocket>(socket: &mut S, buf: &mut [u8], deadline: Instant) -> io::Result<()> {
    let mut got = 0;
    while got < buf.len() {
        let left = deadline.saturating_duration_since(Instant::now());
        if left.is_zero() {
            return Err(io::ErrorKind::TimedOut.into());
        }
        socket.set_read_timeout(Some(left))?;
        match socket.read(&mut buf[got..]) {
            Ok(0) => return Err(io::ErrorKind::UnexpectedEof.into()),
            Ok(n) => got += n,
            Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
            Err(e) => return Err(e),
        }
    }
    Ok(())
}

/// Establishes who is on the other end of an accepted connection, per the identity mode.
pub(super) fn identify<T: StreamTransport>(
    shared: &Shared<T>,
    socket: &mut T::Socket,
    addr: &<T::Listener as StreamListener>::PeerAddr,
) -> Option<Peer> {
    let in_fleet = |id: SystemId| shared.fleet.contains_key(&id).then_some(Peer::System(id));
    match shared.transport.identity_mode() {
        IdentityMode::Anonymous => Some(Peer::Unknown),
        IdentityMode::Address => shared.transport.peer_identity(addr).and_then(in_fleet),
        IdentityMode::Hello => {
            // Exactly the hello: the records behind it belong to the record reader.
            let mut hello = [0u8; HELLO_LEN];
            read_by(
                socket,
                &mut hello,
                Instant::now() + shared.config.hello_timeout,
            )
            .ok()?;
            socket.set_read_timeout(None).ok()?;
            decode_hello(&hello).and_then(in_fleet)
        }
    }
}

/// The reader thread of one accepted connection.
fn serve_connection<T: StreamTransport>(
    shared: &Shared<T>,
    mut socket: T::Socket,
    addr: <T::Listener as StreamListener>::PeerAddr,
    permit: Permit,
) {
    let _ = shared.transport.configure(&socket);
    let Some(from) = identify(shared, &mut socket, &addr) else {
        reject(shared, socket);
        return;
    };
    let mut conn = Connection {
        reader: new_reader(shared),
        socket,
        from,
        _permit: permit,
    };
    if let Some(conns) = &shared.conns {
        // From here on whoever drives the link reads this connection.
        match conns.register(conn) {
            Ok(()) => return,
            Err(back) => conn = back,
        }
    }
    read_on_thread(shared, conn);
}

/// Reads an identified connection with blocking reads until it ends, then closes it.
fn read_on_thread<T: StreamTransport>(shared: &Shared<T>, mut conn: Connection<T::Socket>) {
    let end = loop {
        match conn.read_records(shared, usize::MAX).1 {
            Ok(()) => continue,
            // A blocking socket has no "later": treat it as cut.
            Err(StreamEnd::Pending) => break StreamEnd::Cut,
            Err(end) => break end,
        }
    };
    conn.end(shared, end);
}

/// A reader for a new connection. A sink that keeps frames gets each large one in a buffer of
/// its own (its payload then needs no copy); others borrow from the reader's reused buffers.
pub(super) fn new_reader<T: StreamTransport>(shared: &Shared<T>) -> RecordReader {
    if shared.sink.takes_frames() {
        RecordReader::handing_out(
            shared.config.max_frame(),
            BufferPool::new(RECEIVE_POOL_BYTES),
        )
    } else {
        RecordReader::new(shared.config.max_frame())
    }
}

/// The most records handed to the sink in one `on_frames` call.
const RUN_MAX: usize = 64;

/// An accepted, identified connection and its record reader.
pub(super) struct Connection<S> {
    pub(super) socket: S,
    pub(super) reader: RecordReader,
    pub(super) from: Peer,
    /// Its share of `max_connections`, given back when the connection is dropped (closed).
    pub(super) _permit: Permit,
}

impl<S: StreamSocket> Connection<S> {
    /// Hands records to the sink: `budget` of them at most, then any more that are already
    /// buffered (a driven socket reports readable only for bytes it still holds). Returns how
    /// many, and why it stopped: `Ok` at the budget, `Err` when the stream ended or is
    /// [`StreamEnd::Pending`].
    pub(super) fn read_records<T>(
        &mut self,
        shared: &Shared<T>,
        budget: usize,
    ) -> (usize, Result<(), StreamEnd>)
    where
        T: StreamTransport<Socket = S>,
    {
        let mut n = 0;
        // Records that one read brought in together go to the sink together (`on_frames`),
        // as a UDP batch does: the router then handles them under one lock and answers them
        // with one acknowledgement range. Only records already whole in the read buffer join
        // a run (reading on could move the buffer under the ones collected).
        let mut run = [(0usize, 0usize); RUN_MAX];
        while n < budget || self.reader.has_buffered_record() {
            let at = match self.reader.next_record(&mut self.socket) {
                Ok(at) => at,
                Err(end) => return (n, Err(end)),
            };
            n += 1;
            // Counted first so that whoever the sink wakes sees the counter already updated.
            bump(&shared.counters.frames_received);
            match at {
                FrameAt::Large(_) if self.reader.hands_out() => shared
                    .sink
                    .on_frame_owned(self.reader.take_large(), self.from),
                FrameAt::Buffered(from, to) if self.reader.has_buffered_record() => {
                    run[0] = (from, to);
                    let mut k = 1;
                    let mut stop = None;
                    while k < RUN_MAX && self.reader.has_buffered_record() {
                        match self.reader.next_record(&mut self.socket) {
                            Ok(FrameAt::Buffered(from, to)) => {
                                n += 1;
                                bump(&shared.counters.frames_received);
                                run[k] = (from, to);
                                k += 1;
                            }
                            Ok(other) => {
                                // Not expected of a whole buffered record; handed on alone.
                                n += 1;
                                bump(&shared.counters.frames_received);
                                stop = Some(Ok(other));
                                break;
                            }
                            Err(end) => {
                                stop = Some(Err(end));
                                break;
                            }
                        }
                    }
                    let reader = &self.reader;
                    let mut frames = run[..k]
                        .iter()
                        .map(|&(from, to)| reader.frame(FrameAt::Buffered(from, to)));
                    shared.sink.on_frames(&mut frames, self.from);
                    match stop {
                        None => {}
                        Some(Ok(at)) => shared.sink.on_frame(self.reader.frame(at), self.from),
                        Some(Err(end)) => return (n, Err(end)),
                    }
                }
                _ => shared.sink.on_frame(self.reader.frame(at), self.from),
            }
        }
        (n, Ok(()))
    }

    /// Closes the connection after its stream ended with `end`.
    pub(super) fn end<T: StreamTransport>(self, shared: &Shared<T>, end: StreamEnd) {
        // Truncated, desynchronised or oversized: nothing after it can be trusted. A record
        // cut by our own shutdown is not the peer's fault.
        let count = match end {
            StreamEnd::Clean | StreamEnd::Pending => false,
            StreamEnd::Cut => !shared.closing.load(Ordering::SeqCst),
            StreamEnd::Bad => true,
            StreamEnd::Oversize(len) => {
                bump(&shared.counters.oversize_records);
                if !shared
                    .counters
                    .oversize_logged
                    .swap(true, Ordering::Relaxed)
                {
                    eprintln!(
                        "hetcomm {} link: closed a connection from {:?} whose record announces \
                         {len} bytes, more than this link's largest frame of {} bytes: the \
                         sender's max_message_bytes is larger than ours (further such records \
                         are only counted in oversize_records)",
                        T::NAME,
                        self.from,
                        shared.config.max_frame()
                    );
                }
                true
            }
        };
        if count {
            bump(&shared.counters.frames_dropped);
        }
        let _ = self.socket.shutdown_both();
        // The peer's connection to us ended (it closed it, or it broke): as far as this link
        // knows, the peer is gone until it connects again. Not told when we are closing, or
        // for a connection still waiting for more bytes.
        if let (Peer::System(peer), false) = (self.from, shared.closing.load(Ordering::SeqCst)) {
            if !matches!(end, StreamEnd::Pending) {
                shared.sink.on_event(LinkEvent::PeerDown(peer));
            }
        }
    }
}
