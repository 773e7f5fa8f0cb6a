//! What the IP links tell the router about frame integrity ([`Link::checksums_payload`]), and
//! how the stream links hand large frames over to a sink that keeps them
//! ([`FrameSink::on_frame_owned`]). Real sockets on 127.0.0.1 (port 0) and in a temporary
//! directory.

mod common;

use parking_lot::Mutex;
use std::sync::Arc;

use common::{wait_until, TcpHarness, UdpHarness, UnixHarness, DEADLINE};
use hetcomm_core::{FrameBuf, SystemId};
use hetcomm_link::conformance::{CollectSink, Harness};
use hetcomm_link::emulation::{EmulatedLink, LinkModel, ModelParams, PositionTable};
use hetcomm_link::{FrameSink, Link, Peer};
use hetcomm_link_ip::stream::StreamConfig;
use hetcomm_link_ip::UdpConfig;

const A: SystemId = SystemId(1);
const B: SystemId = SystemId(2);

#[test]
fn stream_links_check_the_payload_datagram_and_emulated_links_do_not() {
    let mut tcp = TcpHarness::new(StreamConfig::default());
    let mut unix = UnixHarness::new(StreamConfig::default());
    let mut udp = UdpHarness::new(UdpConfig::default());
    let tcp_link = tcp.open(A, CollectSink::new());
    let unix_link = unix.open(A, CollectSink::new());
    let udp_link = udp.open(A, CollectSink::new());
    assert!(tcp_link.checksums_payload(), "tcp");
    assert!(unix_link.checksums_payload(), "unix");
    assert!(!udp_link.checksums_payload(), "udp");
    // Through an Arc, as the runtime holds links.
    let shared: Arc<dyn Link> = Arc::from(tcp_link);
    assert!(Arc::clone(&shared).checksums_payload());
    // An emulated link may corrupt bytes on purpose, whatever it runs over.
    let model = LinkModel::new(ModelParams::default(), 1).expect("model");
    let emulated = EmulatedLink::new(shared, A, model, PositionTable::new()).expect("emulated");
    assert!(!emulated.checksums_payload(), "emulated over tcp");
}

/// Records each frame and whether it came as an owned buffer.
#[derive(Default)]
struct OwningSink {
    frames: Mutex<Vec<(Vec<u8>, bool, Peer)>>,
}

impl FrameSink for OwningSink {
    fn on_frame(&self, frame: &[u8], from: Peer) {
        self.frames.lock().push((frame.to_vec(), false, from));
    }
    fn on_frame_owned(&self, frame: FrameBuf, from: Peer) {
        self.frames.lock().push((frame.into_vec(), true, from));
    }
    fn takes_frames(&self) -> bool {
        true
    }
}

fn frame(tag: u8, len: usize) -> Vec<u8> {
    (0..len).map(|i| (i as u8).wrapping_mul(7) ^ tag).collect()
}

/// Small frames are lent, large ones handed over in a buffer of their own; all arrive intact,
/// in order, labelled with their sender.
fn hands_over_large_frames(h: &mut dyn Harness) {
    let sink = Arc::new(OwningSink::default());
    let _b = h.open(B, sink.clone());
    let a = h.open(A, CollectSink::new());
    let sent: Vec<Vec<u8>> = [10, 65_584, 100, 1 << 20, 20_000, 65_584, 3]
        .iter()
        .enumerate()
        .map(|(i, &len)| frame(i as u8, len))
        .collect();
    for f in &sent {
        a.send(B, f).expect("send");
    }
    wait_until("every frame", DEADLINE, || {
        sink.frames.lock().len() == sent.len()
    });
    let got = sink.frames.lock();
    for (i, ((bytes, owned, from), f)) in got.iter().zip(&sent).enumerate() {
        assert!(bytes == f, "frame {i} differs");
        assert_eq!(*from, Peer::System(A), "frame {i}");
        if f.len() <= 100 {
            assert!(!owned, "small frame {i} handed over");
        }
    }
    // The megabyte frame cannot have been in the 64 KiB read buffer.
    assert!(got[3].1, "the 1 MiB frame was not handed over");
}

#[test]
fn tcp_hands_over_large_frames() {
    hands_over_large_frames(&mut TcpHarness::new(StreamConfig::default()));
}

#[test]
fn unix_hands_over_large_frames() {
    hands_over_large_frames(&mut UnixHarness::new(StreamConfig::default()));
}

/// A sink that does not keep frames gets every frame lent, large ones included.
#[test]
fn sinks_that_do_not_keep_frames_borrow_them() {
    let mut h = TcpHarness::new(StreamConfig::default());
    let sink = CollectSink::new();
    let _b = h.open(B, sink.clone());
    let a = h.open(A, CollectSink::new());
    let big = frame(1, 1 << 20);
    a.send(B, &big).expect("send");
    assert_eq!(sink.wait_for(1, DEADLINE), 1);
    assert!(sink.frames()[0].bytes == big);
}

/// What a [`DroppingSink`] saw of one frame.
struct Seen {
    bytes: Vec<u8>,
    /// Handed over (`on_frame_owned`) rather than lent.
    owned: bool,
    /// Its buffer belongs to the link's pool.
    pooled: bool,
    /// Where its bytes lay.
    at: usize,
}

/// Keeps a copy of each frame and drops the buffer of a handed-over one at once, as a module
/// done with the message would: a pooled buffer is then back in the link's pool before the
/// next frame arrives.
#[derive(Default)]
struct DroppingSink {
    seen: Mutex<Vec<Seen>>,
}

impl FrameSink for DroppingSink {
    fn on_frame(&self, frame: &[u8], _from: Peer) {
        self.seen.lock().push(Seen {
            bytes: frame.to_vec(),
            owned: false,
            pooled: false,
            at: frame.as_ptr() as usize,
        });
    }
    fn on_frame_owned(&self, frame: FrameBuf, _from: Peer) {
        self.seen.lock().push(Seen {
            bytes: frame.to_vec(),
            owned: true,
            pooled: frame.is_pooled(),
            at: frame.as_ptr() as usize,
        });
    }
    fn takes_frames(&self) -> bool {
        true
    }
}

/// Over UDP a frame reassembled from fragments, or a large one that came in one datagram, is
/// handed over intact in a buffer of the link's pool; once the sink drops it, the next frame
/// of that size arrives in the same buffer (no allocation per frame). Small frames are lent.
#[test]
fn udp_hands_over_large_frames_in_buffers_that_come_back() {
    let mut h = UdpHarness::new(UdpConfig::loopback());
    let sink = Arc::new(DroppingSink::default());
    let _b = h.open(B, sink.clone());
    let a = h.open(A, CollectSink::new());
    // 65 584 bytes: two fragments of a 65 000-byte datagram; 30 000: one datagram.
    let lens = [65_584, 65_584, 30_000, 30_000, 100, 1 << 20, 65_584, 10];
    let sent: Vec<Vec<u8>> = lens
        .iter()
        .enumerate()
        .map(|(i, &len)| frame(i as u8, len))
        .collect();
    // One at a time: each is dropped by the sink before the next is sent.
    for (i, f) in sent.iter().enumerate() {
        a.send(B, f).expect("send");
        wait_until("the frame", DEADLINE, || sink.seen.lock().len() == i + 1);
    }
    let seen = sink.seen.lock();
    for (i, (s, f)) in seen.iter().zip(&sent).enumerate() {
        assert!(s.bytes == *f, "frame {i} differs");
        let large = f.len() >= 16 * 1024;
        assert_eq!((s.owned, s.pooled), (large, large), "frame {i}");
    }
    assert_eq!(seen[1].at, seen[0].at, "the second 65 584-byte frame");
    assert_eq!(seen[3].at, seen[2].at, "the second 30 000-byte frame");
}
