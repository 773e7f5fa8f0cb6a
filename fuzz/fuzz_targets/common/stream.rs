//! The stream targets' shared part: the model of `docs/wire-format.md`'s stream format, a
//! sink that checks frames against it, and two ways of feeding a real `StreamLink` — an
//! in-memory connection read by the link's reader thread (`stream_records`) and a Unix socket
//! pair read by a driven link through `Readable::read_ready` (`stream_driven`).
#![allow(dead_code)]

use std::collections::BTreeMap;
use std::io::{self, Read, Write};
use std::marker::PhantomData;
use std::os::fd::AsFd;
use std::os::unix::net::UnixStream;
use std::sync::{Arc, Condvar, Mutex};
use std::time::Duration;
use std::time::Instant;

use crate::common::{self, Cursor};
use hetcomm_core::wire::MAX_PAYLOAD;
use hetcomm_core::{FrameBuf, SystemId};
use hetcomm_link::{FrameSink, Link, Peer};
use hetcomm_link_ip::stream::{
    decode_hello, decode_record_header, encode_hello, IdentityMode, StreamConfig, StreamLink,
    StreamListener, StreamSocket, StreamTransport, HELLO_LEN, RECORD_HEADER_LEN,
};

/// The reader's buffer for small records (`READ_BUF_LEN` in stream/mod.rs, private).
const READ_BUF_LEN: usize = 64 * 1024;
/// Pooled buffers are allocated in multiples of this (`POOLED_BUF_STEP`, private).
const POOL_STEP: usize = 4096;
/// Threads, their names, the sink's bookkeeping.
const SLACK: usize = 64 * 1024;
/// The fleet as the receiving link sees it: its peers (the local system 0 is not one).
const FLEET: [SystemId; 2] = [SystemId(1), SystemId(2)];
const LOCAL: SystemId = SystemId(0);

// ---------------------------------------------------------------------------------------------
// The model, from docs/wire-format.md.

#[derive(Debug, Default, PartialEq, Eq)]
pub struct Outcome {
    frames: Vec<Vec<u8>>,
    dropped: u64,
    rejected: u64,
    from: Option<Peer>,
}

fn model_hello(h: &[u8]) -> Option<SystemId> {
    (h[0..2] == *b"HL" && h[2] == 1 && h[3] == 0 && h[6] == 0 && h[7] == 0)
        .then(|| SystemId(u16::from_le_bytes([h[4], h[5]])))
}

fn model_record_header(h: &[u8], max_frame: usize) -> Option<usize> {
    let len = u32::from_le_bytes([h[4], h[5], h[6], h[7]]) as usize;
    (h[0..2] == *b"HR" && h[2] == 1 && h[3] == 0 && len <= max_frame).then_some(len)
}

/// What the receiver must make of `stream`; also returns the longest record length it reads a
/// valid header for.
fn model(stream: &[u8], t: &Input, max_frame: usize) -> (Outcome, usize) {
    let mut out = Outcome::default();
    let mut largest = 0;
    let mut rest = stream;
    let from = match t.mode {
        IdentityMode::Anonymous => Some(Peer::Unknown),
        IdentityMode::Address => t.address_system.map(Peer::System),
        IdentityMode::Hello => {
            if rest.len() < HELLO_LEN {
                None
            } else {
                let h: [u8; HELLO_LEN] = rest[..HELLO_LEN].try_into().unwrap();
                let id = model_hello(&h);
                assert_eq!(decode_hello(&h), id, "decode_hello on {h:02x?}");
                rest = &rest[HELLO_LEN..];
                id.map(Peer::System)
            }
        }
    };
    let from = from.filter(|p| match p {
        Peer::System(id) => FLEET.contains(id),
        Peer::Unknown => true,
    });
    if from.is_none() {
        out.dropped = 1;
        out.rejected = 1;
        return (out, 0);
    }
    out.from = from;
    loop {
        if rest.is_empty() {
            break;
        }
        if rest.len() < RECORD_HEADER_LEN {
            out.dropped = 1; // cut inside a record header
            break;
        }
        let h: [u8; RECORD_HEADER_LEN] = rest[..RECORD_HEADER_LEN].try_into().unwrap();
        let len = model_record_header(&h, max_frame);
        assert_eq!(
            decode_record_header(&h, max_frame),
            len,
            "decode_record_header on {h:02x?} (max_frame {max_frame})"
        );
        let Some(len) = len else {
            out.dropped = 1; // desynchronised or oversized
            break;
        };
        largest = largest.max(len);
        rest = &rest[RECORD_HEADER_LEN..];
        if rest.len() < len {
            out.dropped = 1; // cut inside a frame
            break;
        }
        out.frames.push(rest[..len].to_vec());
        rest = &rest[len..];
    }
    (out, largest)
}

// ---------------------------------------------------------------------------------------------
// An in-memory transport: one connection, serving the stream in the given reads.

struct Conn {
    data: Vec<u8>,
    /// Sizes of successive reads; 0 is an `Interrupted` error. Past the end: as much as asked.
    reads: Vec<usize>,
    state: Mutex<ConnState>,
    closed: Condvar,
}

#[derive(Default)]
struct ConnState {
    pos: usize,
    read_no: usize,
    shut: bool,
}

struct MemSocket(Arc<Conn>);

impl Read for MemSocket {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        let c = &self.0;
        let mut s = c.state.lock().unwrap();
        if s.shut || buf.is_empty() {
            return Ok(0);
        }
        let want = match c.reads.get(s.read_no) {
            Some(0) => {
                s.read_no += 1;
                return Err(io::ErrorKind::Interrupted.into());
            }
            Some(&n) => n,
            None => usize::MAX,
        };
        s.read_no += 1;
        let n = want.min(buf.len()).min(c.data.len() - s.pos);
        buf[..n].copy_from_slice(&c.data[s.pos..s.pos + n]);
        s.pos += n;
        Ok(n)
    }
}

impl Write for MemSocket {
    fn write(&mut self, _: &[u8]) -> io::Result<usize> {
        Err(io::ErrorKind::Unsupported.into())
    }
    fn flush(&mut self) -> io::Result<()> {
        Ok(())
    }
}

impl StreamSocket for MemSocket {
    fn try_clone(&self) -> io::Result<Self> {
        Ok(MemSocket(self.0.clone()))
    }
    fn shutdown_both(&self) -> io::Result<()> {
        self.0.state.lock().unwrap().shut = true;
        self.0.closed.notify_all();
        Ok(())
    }
    fn set_write_timeout(&self, _: Option<Duration>) -> io::Result<()> {
        Ok(())
    }
    fn set_read_timeout(&self, _: Option<Duration>) -> io::Result<()> {
        Ok(())
    }
}

/// Hands out one connection, then waits for `wake`.
struct OneListener<S> {
    next: Mutex<(Option<S>, bool)>,
    cv: Condvar,
}

impl<S> OneListener<S> {
    fn new() -> Self {
        OneListener {
            next: Mutex::new((None, false)),
            cv: Condvar::new(),
        }
    }

    fn hand_over(&self, s: S) {
        self.next.lock().unwrap().0 = Some(s);
        self.cv.notify_all();
    }
}

impl<S: StreamSocket> StreamListener for OneListener<S> {
    type Socket = S;
    type PeerAddr = ();

    fn accept(&self) -> io::Result<(S, ())> {
        let mut g = self.next.lock().unwrap();
        loop {
            if let Some(s) = g.0.take() {
                return Ok((s, ()));
            }
            if g.1 {
                return Err(io::ErrorKind::Other.into());
            }
            g = self.cv.wait(g).unwrap();
        }
    }

    fn wake(&self) {
        self.next.lock().unwrap().1 = true;
        self.cv.notify_all();
    }
}

/// A transport over sockets of type `S` that never connects anywhere: only its receive side
/// is used.
struct TestTransport<S> {
    mode: IdentityMode,
    /// In `IdentityMode::Address`, who the accepted connection is.
    address_system: Option<SystemId>,
    socket: PhantomData<fn() -> S>,
}

impl<S: StreamSocket> StreamTransport for TestTransport<S> {
    type Socket = S;
    type Listener = OneListener<S>;
    type Addr = String;
    const NAME: &'static str = "test";

    fn connect(&self, _: &String, _: Duration) -> io::Result<S> {
        Err(io::ErrorKind::ConnectionRefused.into())
    }
    fn identity_mode(&self) -> IdentityMode {
        self.mode
    }
    fn peer_identity(&self, _: &()) -> Option<SystemId> {
        self.address_system
    }
}

/// One end of a Unix socket pair, offering its descriptor and non-blocking mode, so that a
/// driven link reads it with epoll (and, handing out, with `readv` into uninitialised memory).
struct UnixSocket(UnixStream);

impl Read for UnixSocket {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        self.0.read(buf)
    }
    fn read_vectored(&mut self, bufs: &mut [io::IoSliceMut<'_>]) -> io::Result<usize> {
        self.0.read_vectored(bufs)
    }
}

impl Write for UnixSocket {
    fn write(&mut self, b: &[u8]) -> io::Result<usize> {
        self.0.write(b)
    }
    fn flush(&mut self) -> io::Result<()> {
        Ok(())
    }
}

impl StreamSocket for UnixSocket {
    fn try_clone(&self) -> io::Result<Self> {
        self.0.try_clone().map(UnixSocket)
    }
    fn shutdown_both(&self) -> io::Result<()> {
        self.0.shutdown(std::net::Shutdown::Both)
    }
    fn set_write_timeout(&self, t: Option<Duration>) -> io::Result<()> {
        self.0.set_write_timeout(t)
    }
    fn set_read_timeout(&self, t: Option<Duration>) -> io::Result<()> {
        self.0.set_read_timeout(t)
    }
    fn raw_fd(&self) -> Option<std::os::fd::BorrowedFd<'_>> {
        Some(self.0.as_fd())
    }
    fn set_nonblocking(&self, on: bool) -> io::Result<()> {
        self.0.set_nonblocking(on)
    }
}

/// Compares what the link hands up with the model's frames as they arrive (so that it holds
/// no copies on the heap being measured).
struct CheckSink {
    expected: Vec<Vec<u8>>,
    from: Option<Peer>,
    takes: bool,
    got: Mutex<(usize, Option<String>)>,
}

impl CheckSink {
    fn check(&self, frame: &[u8], from: Peer) {
        let mut g = self.got.lock().unwrap();
        let n = g.0;
        g.0 += 1;
        if g.1.is_some() {
            return;
        }
        if Some(from) != self.from {
            g.1 = Some(format!(
                "frame {n} labelled {from:?}, expected {:?}",
                self.from
            ));
        } else if self.expected.get(n).map(|e| &e[..]) != Some(frame) {
            g.1 = Some(format!(
                "frame {n} ({} bytes) is not the model's ({:?} bytes)",
                frame.len(),
                self.expected.get(n).map(|e| e.len())
            ));
        }
    }
}

impl FrameSink for CheckSink {
    fn on_frame(&self, frame: &[u8], from: Peer) {
        self.check(frame, from);
    }
    fn on_frame_owned(&self, frame: FrameBuf, from: Peer) {
        self.check(&frame, from);
    }
    fn takes_frames(&self) -> bool {
        self.takes
    }
}

// ---------------------------------------------------------------------------------------------

pub struct Input {
    mode: IdentityMode,
    address_system: Option<SystemId>,
    config: StreamConfig,
    takes_frames: bool,
    pub reads: Vec<usize>,
    stream: Vec<u8>,
}

/// Expands a compact stream description, so that short inputs reach records over the
/// reader's 16 KiB direct-read threshold: a tag below 0x80 is followed by `tag + 1` literal
/// bytes; a tag `0x80 | k` by one byte repeated `(k + 1) * 512` times.
fn expand(mut c: Cursor) -> Vec<u8> {
    let mut out = Vec::new();
    while !c.is_empty() {
        let tag = c.u8();
        if tag < 0x80 {
            out.extend_from_slice(c.bytes(usize::from(tag) + 1));
        } else {
            let fill = c.u8();
            out.resize(out.len() + (usize::from(tag & 0x7f) + 1) * 512, fill);
        }
    }
    out
}

/// Input layout: flags (bit 0: the sink takes frames, i.e. hand-out mode; bits 1-2: identity
/// mode; bits 3-4: how `max_message_bytes` is made from the parameter; bits 5-6: the system
/// behind the address in address mode; bit 7: the stream is `expand`ed), a u16 parameter, a
/// count of read sizes and that many u16 read sizes, then the stream.
pub fn parse(data: &[u8]) -> Input {
    let mut c = Cursor::new(data);
    let flags = c.u8();
    let param = usize::from(c.u16());
    let mode = match (flags >> 1) & 3 {
        1 => IdentityMode::Anonymous,
        2 => IdentityMode::Address,
        _ => IdentityMode::Hello,
    };
    let address_system = match (flags >> 5) & 3 {
        0 => Some(SystemId(1)),
        1 => Some(SystemId(2)),
        2 => Some(LOCAL),
        _ => None,
    };
    let max_message_bytes = match (flags >> 3) & 3 {
        0 => None,
        1 => Some(param),
        2 => Some(param << 4),
        _ => Some(param % 64),
    };
    let n_reads = usize::from(c.u8());
    let reads = (0..n_reads).map(|_| usize::from(c.u16())).collect();
    Input {
        mode,
        address_system,
        config: StreamConfig {
            max_message_bytes,
            ..StreamConfig::default()
        },
        takes_frames: flags & 1 == 1,
        reads,
        stream: if flags & 0x80 != 0 {
            expand(c)
        } else {
            c.rest().to_vec()
        },
    }
}

fn transport<S>(input: &Input) -> TestTransport<S> {
    TestTransport {
        mode: input.mode,
        address_system: input.address_system,
        socket: PhantomData,
    }
}

fn check_sink(input: &Input, expected: &Outcome) -> Arc<CheckSink> {
    Arc::new(CheckSink {
        expected: expected.frames.clone(),
        from: expected.from,
        takes: input.takes_frames,
        got: Mutex::new((0, None)),
    })
}

fn peers() -> BTreeMap<SystemId, String> {
    [LOCAL, FLEET[0], FLEET[1]]
        .into_iter()
        .map(|id| (id, format!("test:{}", id.0)))
        .collect()
}

/// What the link did, from its sink and counters, once the connection is closed.
fn outcome<T: StreamTransport>(
    link: StreamLink<T>,
    sink: &CheckSink,
    expected: &Outcome,
) -> Outcome {
    let stats = link.stream_stats();
    drop(link);
    let got = sink.got.lock().unwrap();
    if let Some(e) = &got.1 {
        panic!("{e}");
    }
    assert_eq!(got.0 as u64, stats.frames_received, "sink calls vs counter");
    assert_eq!(stats.accepted, 1);
    assert_eq!(
        got.0,
        expected.frames.len(),
        "frames handed up vs the model"
    );
    Outcome {
        frames: expected.frames.clone(),
        dropped: stats.frames_dropped,
        rejected: stats.rejected_connections,
        from: expected.from,
    }
}

/// Runs one in-memory connection carrying the stream in `reads` through a fresh link (a
/// reader thread per connection); returns what the link did and the peak heap it took while
/// reading.
pub fn run_threads(input: &Input, reads: Vec<usize>, expected: &Outcome) -> (Outcome, usize) {
    let conn = Arc::new(Conn {
        data: input.stream.clone(),
        reads,
        state: Mutex::new(ConnState::default()),
        closed: Condvar::new(),
    });
    let sink = check_sink(input, expected);
    let link = StreamLink::new(
        transport::<MemSocket>(input),
        LOCAL,
        OneListener::new(),
        peers(),
        sink.clone(),
        input.config.clone(),
    )
    .expect("link starts");
    let base = common::reset_peak();
    link.listener().hand_over(MemSocket(conn.clone()));
    {
        let mut s = conn.state.lock().unwrap();
        while !s.shut {
            let (g, t) = conn
                .closed
                .wait_timeout(s, Duration::from_secs(20))
                .unwrap();
            s = g;
            assert!(
                !t.timed_out() || s.shut,
                "the link neither finished nor closed the connection (hang)"
            );
        }
    }
    let peak = common::peak().saturating_sub(base);
    (outcome(link, &sink, expected), peak)
}

/// Whether the link has shut the connection down (our read then sees its end).
fn peer_closed(mine: &mut UnixStream) -> bool {
    let mut b = [0u8; 1];
    match mine.read(&mut b) {
        Ok(0) => true,
        Ok(_) => panic!("the receiving side wrote to the connection"),
        Err(e) if e.kind() == io::ErrorKind::WouldBlock => false,
        Err(_) => true,
    }
}

/// Runs the stream through a fresh driven link over a Unix socket pair: the stream is written
/// in the chunks `reads` gives (0: call `read_ready` once more without writing), and after
/// each chunk the target calls `read_ready(budget)` itself, so that records are interrupted by
/// an empty socket wherever the chunks end, and resumed at the next call.
pub fn run_driven(
    input: &Input,
    reads: &[usize],
    budget: usize,
    expected: &Outcome,
) -> (Outcome, usize) {
    let (mut mine, theirs) = UnixStream::pair().expect("socket pair");
    let sink = check_sink(input, expected);
    let config = StreamConfig {
        driven: true,
        hello_timeout: Duration::from_secs(10),
        ..input.config.clone()
    };
    let link = StreamLink::new(
        transport::<UnixSocket>(input),
        LOCAL,
        OneListener::new(),
        peers(),
        sink.clone(),
        config,
    )
    .expect("link starts");
    mine.set_nonblocking(true).unwrap();
    let base = common::reset_peak();
    link.listener().hand_over(UnixSocket(theirs));
    let readable = link.readable().expect("a driven link is readable");
    let deadline = Instant::now() + Duration::from_secs(20);
    let mut closed = false;
    let data = &input.stream;
    let mut pos = 0;
    let mut chunks = reads.iter().copied();
    while pos < data.len() && !closed {
        let n = match chunks.next() {
            Some(n) => n.min(data.len() - pos),
            None => data.len() - pos,
        };
        let mut written = 0;
        while written < n {
            match mine.write(&data[pos + written..pos + n]) {
                Ok(k) => written += k,
                Err(e) if e.kind() == io::ErrorKind::WouldBlock => {
                    readable.read_ready(budget).expect("read_ready");
                    if peer_closed(&mut mine) {
                        closed = true;
                        break;
                    }
                    assert!(Instant::now() < deadline, "the link stopped reading (hang)");
                    std::thread::yield_now();
                }
                // The link closed the connection (a bad record): the rest is not read.
                Err(_) => {
                    closed = true;
                    break;
                }
            }
        }
        pos += written;
        readable.read_ready(budget).expect("read_ready");
    }
    let _ = mine.shutdown(std::net::Shutdown::Write);
    while !closed {
        readable.read_ready(budget).expect("read_ready");
        closed = peer_closed(&mut mine);
        assert!(
            Instant::now() < deadline,
            "the link neither finished nor closed the connection (hang)"
        );
        if !closed {
            std::thread::sleep(Duration::from_micros(50));
        }
    }
    let peak = common::peak().saturating_sub(base);
    (outcome(link, &sink, expected), peak)
}

/// The model's outcome for `input`, the longest record it announces, and the heap bound.
pub fn expect(input: &Input) -> (Outcome, usize, usize) {
    for id in [0, 1, 0xffff] {
        assert_eq!(
            decode_hello(&encode_hello(SystemId(id))),
            Some(SystemId(id))
        );
    }
    let max_frame = input.config.max_frame();
    assert!(max_frame <= MAX_PAYLOAD + 48);
    let (expected, largest) = model(&input.stream, input, max_frame);
    let bound = READ_BUF_LEN + 2 * largest.next_multiple_of(POOL_STEP) + SLACK;
    (expected, largest, bound)
}

/// Checks one run's outcome and peak heap against the model's.
pub fn check(
    what: &str,
    input: &Input,
    got: (Outcome, usize),
    expected: &Outcome,
    largest: usize,
    bound: usize,
) {
    let (got, peak) = got;
    assert_eq!(&got, expected, "outcome ({what})");
    assert!(
        peak <= bound,
        "{what}: reading took {peak} heap bytes; the largest record announced is {largest} \
         bytes (max_frame {}, bound {bound})",
        input.config.max_frame()
    );
}
