//! Unit tests of the stream layer: hellos and record headers, the [`RecordReader`] (any
//! chunking, non-blocking resumption, handed-out and reused buffers), held frames and the
//! connect queue, and resumed partial vectored writes.

use std::io::IoSlice;

use hetcomm_core::BufferPool;
use hetcomm_link::{Link, LinkError, Peer};

use super::framing::{append_record, record_header, write_parts, FrameParts};
use super::reader::{FrameAt, RecordReader, RecordSource, StreamEnd};
use super::*;

#[test]
fn hello_round_trips_and_rejects_noise() {
    let h = encode_hello(SystemId(513));
    assert_eq!(decode_hello(&h), Some(SystemId(513)));
    let mut bad = h;
    bad[0] = b'X';
    assert_eq!(decode_hello(&bad), None);
    let mut bad = h;
    bad[2] = 9;
    assert_eq!(decode_hello(&bad), None);
    let mut bad = h;
    bad[7] = 1;
    assert_eq!(decode_hello(&bad), None);
}

#[test]
fn record_header_is_checked_before_use() {
    let mut h = [0u8; RECORD_HEADER_LEN];
    h[0..2].copy_from_slice(&RECORD_MAGIC);
    h[2] = STREAM_VERSION;
    h[4..8].copy_from_slice(&100u32.to_le_bytes());
    assert_eq!(decode_record_header(&h, 100), Some(100));
    assert_eq!(decode_record_header(&h, 99), None);
    assert_eq!(record_header(100), h);
    h[4..8].copy_from_slice(&u32::MAX.to_le_bytes());
    assert_eq!(
        decode_record_header(&h, StreamConfig::default().max_frame()),
        None
    );
    h[0] = b'H';
    h[1] = b'C';
    assert_eq!(decode_record_header(&h, usize::MAX), None);
}

#[test]
fn max_frame_follows_max_message_bytes() {
    let mut c = StreamConfig::default();
    assert_eq!(c.max_frame(), HEADER_LEN + MAX_PAYLOAD);
    c.max_message_bytes = Some(1000);
    assert_eq!(c.max_frame(), HEADER_LEN + 1000);
    c.max_message_bytes = Some(usize::MAX);
    assert_eq!(c.max_frame(), HEADER_LEN + MAX_PAYLOAD);
}

/// A stream that hands out its bytes in pieces of varying size (at most `max` per call),
/// filling only the first buffer of a vectored read, as many sockets do. A blocking one is
/// interrupted now and then; a `non_blocking` one would block between most pieces (in the
/// middle of large frames too) and once it has nothing left.
struct Chunky<'a> {
    data: &'a [u8],
    max: usize,
    calls: usize,
    non_blocking: bool,
}

impl<'a> Chunky<'a> {
    fn new(data: &'a [u8], max: usize) -> Self {
        Chunky {
            data,
            max,
            calls: 0,
            non_blocking: false,
        }
    }

    fn non_blocking(data: &'a [u8], max: usize) -> Self {
        Chunky {
            non_blocking: true,
            ..Chunky::new(data, max)
        }
    }
}

impl Read for Chunky<'_> {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        self.calls += 1;
        if self.non_blocking && (!self.calls.is_multiple_of(3) || self.data.is_empty()) {
            return Err(io::ErrorKind::WouldBlock.into());
        }
        if !self.non_blocking && self.calls % 5 == 4 {
            return Err(io::ErrorKind::Interrupted.into());
        }
        // 1, 2, … max, 1, 2, …: every split point shows up sooner or later.
        let n = (self.calls % self.max + 1)
            .min(buf.len())
            .min(self.data.len());
        buf[..n].copy_from_slice(&self.data[..n]);
        self.data = &self.data[n..];
        Ok(n)
    }
}

impl RecordSource for Chunky<'_> {}

fn frame_of(len: usize, seed: u8) -> Vec<u8> {
    (0..len)
        .map(|i| (i as u8).wrapping_mul(31).wrapping_add(seed))
        .collect()
}

/// Frames around every size boundary of the reader, in an order that exercises the switch
/// between buffered and direct reads both ways.
fn mixed_frames() -> Vec<Vec<u8>> {
    let sizes = [
        0,
        1,
        64,
        DIRECT_READ_MIN,
        DIRECT_READ_MIN + 1,
        64,
        READ_BUF_LEN - RECORD_HEADER_LEN,
        READ_BUF_LEN + 48,
        READ_BUF_LEN + 48,
        3,
        1 << 20,
        READ_AHEAD_AFTER_LARGE,
        70_000,
        5,
    ];
    sizes
        .iter()
        .enumerate()
        .map(|(i, &n)| frame_of(n, i as u8))
        .collect()
}

fn stream_of(frames: &[Vec<u8>]) -> Vec<u8> {
    let mut s = Vec::new();
    for f in frames {
        append_record(&mut s, FrameParts::whole(f));
    }
    s
}

fn read_all<R: RecordSource>(r: &mut R, max_frame: usize) -> (Vec<Vec<u8>>, StreamEnd) {
    let mut reader = RecordReader::new(max_frame);
    let mut got = Vec::new();
    loop {
        match reader.next_record(r) {
            Ok(at) => got.push(reader.frame(at).to_vec()),
            Err(end) => return (got, end),
        }
    }
}

/// Like [`read_all`] with a reader that hands large frames out; also says which frames
/// came out as their own buffer (with less than a step of spare capacity).
fn read_all_handed_out<R: RecordSource>(
    r: &mut R,
    max_frame: usize,
) -> (Vec<(Vec<u8>, bool)>, StreamEnd) {
    let mut reader = RecordReader::handing_out(max_frame, BufferPool::new(1 << 20));
    let mut got = Vec::new();
    loop {
        match reader.next_record(r) {
            Ok(FrameAt::Large(len)) => {
                let frame = reader.take_large();
                assert!(frame.is_pooled());
                // Kept, so none came back to the pool: each is a new buffer.
                let frame = frame.into_vec();
                assert_eq!(frame.len(), len);
                assert!(
                    frame.capacity() < len + POOLED_BUF_STEP,
                    "a buffer of about the frame"
                );
                got.push((frame, true));
            }
            Ok(at) => got.push((reader.frame(at).to_vec(), false)),
            Err(end) => return (got, end),
        }
    }
}

#[test]
fn a_reader_resumes_where_a_non_blocking_socket_left_it() {
    let frames = mixed_frames();
    let stream = stream_of(&frames);
    for hand_out in [false, true] {
        for max in [7, 5000, 200_000] {
            let mut reader = if hand_out {
                RecordReader::handing_out(2 << 20, BufferPool::new(1 << 20))
            } else {
                RecordReader::new(2 << 20)
            };
            let mut r = Chunky::non_blocking(&stream, max);
            let (mut got, mut pending) = (Vec::new(), 0);
            while got.len() < frames.len() {
                match reader.next_record(&mut r) {
                    Ok(FrameAt::Large(len)) if hand_out => {
                        got.push(reader.take_large().into_vec());
                        assert_eq!(got.last().unwrap().len(), len);
                    }
                    Ok(at) => got.push(reader.frame(at).to_vec()),
                    Err(StreamEnd::Pending) => pending += 1,
                    Err(end) => panic!("hand_out {hand_out}, max {max}: ended with {end:?}"),
                }
                assert!(pending < 10_000_000, "no progress");
            }
            assert!(pending > 0);
            for (i, (g, f)) in got.iter().zip(&frames).enumerate() {
                assert!(g == f, "hand_out {hand_out}, max {max}: frame {i}");
            }
            assert!(!reader.has_buffered_record());
            assert_eq!(reader.next_record(&mut r), Err(StreamEnd::Pending));
        }
    }
}

#[test]
fn buffered_records_are_seen_without_reading() {
    let stream = stream_of(&[vec![1; 10], vec![2; 20], vec![3; 100_000]]);
    let mut reader = RecordReader::new(1 << 20);
    let mut r = &stream[..];
    // One read fills the buffer: the first record comes from it, the second is whole in
    // it, the third (large) is not.
    assert_eq!(reader.next_record(&mut r), Ok(FrameAt::Buffered(8, 18)));
    assert!(reader.has_buffered_record());
    assert!(matches!(
        reader.next_record(&mut r),
        Ok(FrameAt::Buffered(..))
    ));
    assert!(!reader.has_buffered_record());
    // A bad header counts as "there is something to report".
    let mut bad = stream_of(&[vec![1; 10], vec![2; 10]]);
    bad[18] = b'X';
    let mut reader = RecordReader::new(1 << 20);
    let mut r = &bad[..];
    assert!(reader.next_record(&mut r).is_ok());
    assert!(reader.has_buffered_record());
    assert_eq!(reader.next_record(&mut r), Err(StreamEnd::Bad));
}

#[test]
fn handed_out_frames_come_back_to_the_readers_pool() {
    let frames: Vec<Vec<u8>> = (0..6u8)
        .map(|i| vec![i; 100_000 + usize::from(i)])
        .collect();
    let stream = stream_of(&frames);
    let pool = BufferPool::new(1 << 20);
    let mut reader = RecordReader::handing_out(2 << 20, pool.clone());
    let mut r = &stream[..];
    let mut first_ptr = None;
    for (i, f) in frames.iter().enumerate() {
        assert!(matches!(reader.next_record(&mut r), Ok(FrameAt::Large(_))));
        let frame = reader.take_large();
        assert_eq!(frame.as_slice(), &f[..], "frame {i}");
        // Each frame is dropped before the next is read: one buffer serves them all.
        let ptr = frame.as_ptr();
        assert_eq!(*first_ptr.get_or_insert(ptr), ptr, "frame {i}");
        drop(frame);
        assert!(pool.kept_bytes() >= f.len());
    }
    assert_eq!(reader.next_record(&mut r), Err(StreamEnd::Clean));
}

#[test]
fn handing_out_reader_gives_each_large_frame_its_own_buffer() {
    let frames = mixed_frames();
    let stream = stream_of(&frames);
    let check = |got: &[(Vec<u8>, bool)], what: &str| {
        assert_eq!(got.len(), frames.len(), "{what}");
        for (i, ((g, own), f)) in got.iter().zip(&frames).enumerate() {
            assert!(g == f, "{what}: frame {i}");
            // Only frames read directly (large, not already buffered) are handed out.
            if *own {
                assert!(f.len() > DIRECT_READ_MIN, "{what}: frame {i}");
            }
        }
        assert!(got.iter().any(|(_, own)| *own), "{what}: none handed out");
    };
    // No descriptor: the zero-filled path, whole reads and odd pieces.
    let (got, end) = read_all_handed_out(&mut &stream[..], 2 << 20);
    assert_eq!(end, StreamEnd::Clean);
    check(&got, "whole reads");
    for max in [1, 4096, 100_000] {
        let mut r = Chunky::new(&stream, max);
        let (got, end) = read_all_handed_out(&mut r, 2 << 20);
        assert_eq!(end, StreamEnd::Clean, "chunks of up to {max}");
        check(&got, &format!("chunks of up to {max}"));
    }
    // A real socket: read with readv(2) into uninitialised buffers.
    let (mut tx, mut rx) = std::os::unix::net::UnixStream::pair().unwrap();
    assert!(rx.raw_fd().is_some());
    let writer = std::thread::spawn(move || {
        tx.write_all(&stream).unwrap();
        // Cut in the middle of a large frame at the end.
        let mut last = Vec::new();
        append_record(&mut last, FrameParts::whole(&frame_of(100_000, 9)));
        tx.write_all(&last[..50_000]).unwrap();
    });
    let (got, end) = read_all_handed_out(&mut rx, 2 << 20);
    writer.join().unwrap();
    assert_eq!(end, StreamEnd::Cut);
    check(&got, "unix socket");
}

#[test]
fn record_reader_splits_any_chunking_into_the_frames_sent() {
    let frames = mixed_frames();
    let stream = stream_of(&frames);
    // Whole reads (a slice fills every buffer of a vectored read), then odd pieces.
    let (got, end) = read_all(&mut &stream[..], 2 << 20);
    assert_eq!(end, StreamEnd::Clean);
    assert!(got == frames, "whole reads");
    for max in [1, 7, 4096, 100_000] {
        let mut r = Chunky::new(&stream, max);
        let (got, end) = read_all(&mut r, 2 << 20);
        assert_eq!(end, StreamEnd::Clean, "chunks of up to {max}");
        assert!(got == frames, "chunks of up to {max}");
    }
}

#[test]
fn record_reader_reports_cut_and_bad_records() {
    let frames = mixed_frames();
    let stream = stream_of(&frames);
    // Cut inside a header, inside a small frame, inside a large one.
    for cut in [3, RECORD_HEADER_LEN + 1 + 4, stream.len() - 2] {
        let (got, end) = read_all(&mut &stream[..cut], 2 << 20);
        assert_eq!(end, StreamEnd::Cut, "cut at {cut}");
        assert!(got.len() < frames.len());
    }
    // A frame over max_frame ends the stream before its bytes are read.
    let (got, end) = read_all(&mut &stream[..], 100_000);
    assert!(
        matches!(end, StreamEnd::Oversize(n) if n > 100_000),
        "{end:?}"
    );
    assert_eq!(got.len(), 10);
    // Garbage after a good record.
    let mut s = stream_of(&frames[..3]);
    s.extend_from_slice(b"\xde\xad\xbe\xef garbage");
    let (got, end) = read_all(&mut &s[..], 2 << 20);
    assert_eq!((got.len(), end), (3, StreamEnd::Bad));
}

#[test]
fn record_reader_reuses_its_buffers() {
    let frames: Vec<Vec<u8>> = (0..50).map(|i| frame_of(65_584, i)).collect();
    let stream = stream_of(&frames);
    let mut r = Chunky::new(&stream, 70_000);
    let mut reader = RecordReader::new(1 << 20);
    let first = reader.next_record(&mut r).unwrap();
    assert_eq!(first, FrameAt::Large(65_584));
    let ptr = reader.large.as_ptr();
    for f in &frames[1..] {
        let at = reader.next_record(&mut r).unwrap();
        assert!(reader.frame(at) == &f[..]);
    }
    assert_eq!(reader.large.as_ptr(), ptr, "large buffer reallocated");
}

/// A socket that takes at most `max` bytes per write, across buffers of a vectored write.
struct Slow {
    out: Vec<u8>,
    max: usize,
    calls: usize,
}

impl Read for Slow {
    fn read(&mut self, _: &mut [u8]) -> io::Result<usize> {
        Ok(0)
    }
}

impl Write for Slow {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        self.write_vectored(&[IoSlice::new(buf)])
    }
    fn write_vectored(&mut self, bufs: &[IoSlice<'_>]) -> io::Result<usize> {
        self.calls += 1;
        if self.calls % 4 == 3 {
            return Err(io::ErrorKind::Interrupted.into());
        }
        let mut left = self.max;
        for b in bufs {
            let n = b.len().min(left);
            self.out.extend_from_slice(&b[..n]);
            left -= n;
        }
        Ok(self.max - left)
    }
    fn flush(&mut self) -> io::Result<()> {
        Ok(())
    }
}

impl StreamSocket for Slow {
    fn try_clone(&self) -> io::Result<Self> {
        Err(io::ErrorKind::Unsupported.into())
    }
    fn shutdown_both(&self) -> io::Result<()> {
        Ok(())
    }
    fn set_write_timeout(&self, _: Option<Duration>) -> io::Result<()> {
        Ok(())
    }
    fn set_read_timeout(&self, _: Option<Duration>) -> io::Result<()> {
        Ok(())
    }
}

/// Unix sockets whose connects wait until the test opens the gate, so that a test
/// controls exactly when a connection comes up.
#[cfg(unix)]
struct GatedUnix {
    gate: Mutex<std::sync::mpsc::Receiver<()>>,
}

#[cfg(unix)]
impl StreamTransport for GatedUnix {
    type Socket = std::os::unix::net::UnixStream;
    type Listener = std::os::unix::net::UnixListener;
    type Addr = crate::unix::UnixAddr;
    const NAME: &'static str = "gated";

    fn connect(&self, addr: &Self::Addr, _: Duration) -> io::Result<Self::Socket> {
        let _ = lock(&self.gate).recv();
        std::os::unix::net::UnixStream::connect(&addr.0)
    }
}

#[cfg(unix)]
#[test]
fn held_frames_count_against_the_connect_queue_and_stay_held_after_connecting() {
    use std::os::unix::net::UnixListener;

    let dir = std::env::temp_dir().join(format!("hetcomm-gated-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let (path_a, path_b) = (dir.join("a.sock"), dir.join("b.sock"));
    // B is a raw listener, so the test sees the bytes A writes.
    let raw_b = UnixListener::bind(&path_b).unwrap();
    let (open, gate) = std::sync::mpsc::channel();
    let transport = GatedUnix {
        gate: Mutex::new(gate),
    };
    let config = StreamConfig {
        connect_queue_frames: 4,
        ..StreamConfig::default()
    };
    struct Nobody;
    impl FrameSink for Nobody {
        fn on_frame(&self, _: &[u8], _: Peer) {}
    }
    let (a_id, b_id) = (SystemId(1), SystemId(2));
    let a = StreamLink::new(
        transport,
        a_id,
        UnixListener::bind(&path_a).unwrap(),
        BTreeMap::from([(b_id, crate::unix::UnixAddr(path_b.clone()))]),
        Arc::new(Nobody),
        config,
    )
    .unwrap();
    let f: Vec<Vec<u8>> = (0..5).map(|i| frame_of(20 + i, i as u8)).collect();
    a.send_held(b_id, &f[0]).unwrap();
    a.send_held(b_id, &f[1]).unwrap();
    a.send(b_id, &f[2]).unwrap(); // releases 0 and 1 with it
    a.send_held(b_id, &f[3]).unwrap();
    // Four frames wait, held ones included: the fifth is refused either way.
    for result in [a.send(b_id, &f[4]), a.send_held(b_id, &f[4])] {
        assert!(
            matches!(result, Err(LinkError::Congested { .. })),
            "{result:?}"
        );
    }
    assert_eq!(a.pending_bytes(), stream_of(&f[..4]).len());

    open.send(()).unwrap();
    let (mut conn, _) = raw_b.accept().unwrap();
    let mut expected = encode_hello(a_id).to_vec();
    expected.extend_from_slice(&stream_of(&f[..3]));
    let mut got = vec![0; expected.len()];
    conn.set_read_timeout(Some(Duration::from_secs(10)))
        .unwrap();
    conn.read_exact(&mut got).unwrap();
    assert!(got == expected, "hello and the released frames, in order");
    // The frame held after the send stays held on the new connection...
    conn.set_read_timeout(Some(Duration::from_millis(150)))
        .unwrap();
    let mut more = [0u8; 1];
    assert!(conn.read(&mut more).is_err(), "a held frame went out");
    assert_eq!(a.stream_stats().frames_sent, 3);
    // ...until the flush.
    a.flush().unwrap();
    let record = stream_of(&f[3..4]);
    let mut got = vec![0; record.len()];
    conn.set_read_timeout(Some(Duration::from_secs(10)))
        .unwrap();
    conn.read_exact(&mut got).unwrap();
    assert_eq!(got, record);
    assert_eq!(a.stream_stats().frames_sent, 4);
    assert_eq!(a.pending_bytes(), 0);
    drop(a);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn partial_vectored_writes_are_resumed_exactly() {
    let held = stream_of(&mixed_frames()[..4]);
    let frame = frame_of(100_000, 9);
    let head = record_header(frame.len());
    let mut whole = held.clone();
    whole.extend_from_slice(&head);
    whole.extend_from_slice(&frame);
    for max in [1, 5, 8, 4096, 1 << 20] {
        let mut s = Slow {
            out: Vec::new(),
            max,
            calls: 0,
        };
        write_parts(&mut s, &[&held, &head, &frame], Duration::from_secs(5)).unwrap();
        assert!(s.out == whole, "writes of up to {max} bytes");
    }
    // Empty parts are skipped, and nothing to write is no write at all.
    let mut s = Slow {
        out: Vec::new(),
        max: 3,
        calls: 0,
    };
    write_parts(&mut s, &[&[], &head, &[]], Duration::from_secs(5)).unwrap();
    assert_eq!(s.out, head);
    let calls = s.calls;
    write_parts(&mut s, &[&[], &[]], Duration::from_secs(5)).unwrap();
    assert_eq!(s.calls, calls);
}
