//! The conformance suite every transport runs: one set of behaviours, checked the same way on
//! every [`Link`] implementation (as iceoryx2 does for its backends).
//!
//! A transport's tests implement [`Harness`] (how to open an endpoint for a system) and call
//! [`run_all`]. Checks adapt to the link's declared [`LinkCaps`](crate::LinkCaps): an unreliable link is not
//! required to deliver everything, but must never corrupt, invent or mislabel a frame.

use std::sync::{Arc, Condvar, Mutex};
use std::time::{Duration, Instant};

use hetcomm_core::SystemId;

use crate::{FrameSink, Link, LinkError, Peer};

/// How long a check waits for frames to arrive before it fails.
pub const WAIT: Duration = Duration::from_secs(10);

/// Opens link endpoints for the suite.
pub trait Harness {
    /// Opens an endpoint for `system` whose received frames go to `sink`. Opening a system that
    /// was opened before (and whose link was dropped) must work: that is a peer restart.
    fn open(&mut self, system: SystemId, sink: Arc<dyn FrameSink>) -> Box<dyn Link>;
}

/// A frame as a sink saw it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Received {
    /// The bytes.
    pub bytes: Vec<u8>,
    /// Who the link said sent it.
    pub from: Peer,
}

/// A sink that keeps every frame and lets a test wait for a count.
#[derive(Default)]
pub struct CollectSink {
    frames: Mutex<Vec<Received>>,
    arrived: Condvar,
}

impl CollectSink {
    /// A new, empty sink.
    pub fn new() -> Arc<CollectSink> {
        Arc::new(CollectSink::default())
    }

    /// Everything received so far.
    pub fn frames(&self) -> Vec<Received> {
        self.frames
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .clone()
    }

    /// Waits until at least `n` frames arrived or `timeout` passed; returns how many arrived.
    pub fn wait_for(&self, n: usize, timeout: Duration) -> usize {
        let deadline = Instant::now() + timeout;
        let mut frames = self.frames.lock().unwrap_or_else(|e| e.into_inner());
        while frames.len() < n {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                break;
            }
            frames = self
                .arrived
                .wait_timeout(frames, left)
                .unwrap_or_else(|e| e.into_inner())
                .0;
        }
        frames.len()
    }
}

impl FrameSink for CollectSink {
    fn on_frame(&self, frame: &[u8], from: Peer) {
        self.frames
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .push(Received {
                bytes: frame.to_vec(),
                from,
            });
        self.arrived.notify_all();
    }
}

const A: SystemId = SystemId(1);
const B: SystemId = SystemId(2);

/// A recognisable test frame: `tag` and an index, padded with a pattern to `len` bytes.
fn frame(tag: u8, index: u32, len: usize) -> Vec<u8> {
    let mut f = Vec::with_capacity(len.max(5));
    f.push(tag);
    f.extend_from_slice(&index.to_le_bytes());
    while f.len() < len {
        f.push((f.len() % 251) as u8);
    }
    f
}

/// Runs every check, each with fresh endpoints.
pub fn run_all(h: &mut dyn Harness) {
    delivers_both_ways(h);
    preserves_sizes(h);
    many_frames_respect_caps(h);
    unknown_destination_is_an_error(h);
    oversize_frame_is_refused(h);
    traffic_resumes_after_peer_restart(h);
}

fn check_from(r: &Received, sender: SystemId) {
    if let Peer::System(s) = r.from {
        assert_eq!(s, sender, "link labelled a frame from {sender} as from {s}");
    }
}

/// A frame each way arrives byte-for-byte, labelled with the right sender.
pub fn delivers_both_ways(h: &mut dyn Harness) {
    let (sa, sb) = (CollectSink::new(), CollectSink::new());
    let a = h.open(A, sa.clone());
    let b = h.open(B, sb.clone());
    a.send(B, &frame(1, 0, 100)).expect("A -> B send");
    assert_eq!(sb.wait_for(1, WAIT), 1, "A -> B frame did not arrive");
    b.send(A, &frame(2, 0, 100)).expect("B -> A send");
    assert_eq!(sa.wait_for(1, WAIT), 1, "B -> A frame did not arrive");
    assert_eq!(sb.frames()[0].bytes, frame(1, 0, 100));
    assert_eq!(sa.frames()[0].bytes, frame(2, 0, 100));
    check_from(&sb.frames()[0], A);
    check_from(&sa.frames()[0], B);
}

/// Frames from 1 byte up to the link's MTU and beyond it (up to 1 MiB + 1, or `max_frame`)
/// arrive intact on a reliable link.
pub fn preserves_sizes(h: &mut dyn Harness) {
    let sb = CollectSink::new();
    let a = h.open(A, CollectSink::new());
    let _b = h.open(B, sb.clone());
    let caps = a.caps();
    let mut sizes = vec![1, 48, 1000, caps.mtu.min(caps.max_frame)];
    sizes.push((1024 * 1024 + 1).min(caps.max_frame));
    for (i, &len) in sizes.iter().enumerate() {
        a.send(B, &frame(3, i as u32, len))
            .unwrap_or_else(|e| panic!("send of {len} bytes: {e}"));
        if caps.reliable {
            assert_eq!(sb.wait_for(i + 1, WAIT), i + 1, "{len}-byte frame lost");
        }
    }
    for r in sb.frames() {
        let index = u32::from_le_bytes([r.bytes[1], r.bytes[2], r.bytes[3], r.bytes[4]]) as usize;
        assert_eq!(
            r.bytes,
            frame(3, index as u32, sizes[index]),
            "frame {index} corrupted"
        );
    }
}

/// 1000 frames: all arrive on a reliable link, in order on an ordered one, and none is
/// duplicated or invented on any link.
pub fn many_frames_respect_caps(h: &mut dyn Harness) {
    const N: u32 = 1000;
    let sb = CollectSink::new();
    let a = h.open(A, CollectSink::new());
    let _b = h.open(B, sb.clone());
    let caps = a.caps();
    for i in 0..N {
        loop {
            match a.send(B, &frame(4, i, 64)) {
                Ok(()) => break,
                // Backpressure is allowed; the caller retries.
                Err(LinkError::Congested { .. }) => std::thread::sleep(Duration::from_micros(100)),
                Err(e) => panic!("send {i}: {e}"),
            }
        }
    }
    if caps.reliable {
        assert_eq!(
            sb.wait_for(N as usize, WAIT),
            N as usize,
            "reliable link lost frames"
        );
    } else {
        sb.wait_for(N as usize, Duration::from_millis(500));
    }
    let got: Vec<u32> = sb
        .frames()
        .iter()
        .map(|r| {
            assert_eq!(r.bytes.len(), 64);
            u32::from_le_bytes([r.bytes[1], r.bytes[2], r.bytes[3], r.bytes[4]])
        })
        .collect();
    let mut sorted = got.clone();
    sorted.sort_unstable();
    sorted.dedup();
    assert_eq!(sorted.len(), got.len(), "link duplicated frames");
    assert!(got.iter().all(|&i| i < N), "link invented frames");
    if caps.ordered {
        assert!(
            got.windows(2).all(|w| w[0] < w[1]),
            "ordered link reordered frames"
        );
    }
}

/// Sending to a system with no endpoint is an error, not a panic or a hang.
pub fn unknown_destination_is_an_error(h: &mut dyn Harness) {
    let a = h.open(A, CollectSink::new());
    let started = Instant::now();
    let result = a.send(SystemId(999), &frame(5, 0, 10));
    assert!(
        matches!(result, Err(LinkError::Unreachable { .. })),
        "send to unknown system: {result:?}"
    );
    assert!(
        started.elapsed() < WAIT,
        "send to unknown system took too long"
    );
}

/// A frame over `max_frame` is refused with `TooLarge` (skipped for links whose limit is over
/// 64 MiB, where building such a frame is itself the problem).
pub fn oversize_frame_is_refused(h: &mut dyn Harness) {
    let a = h.open(A, CollectSink::new());
    let _b = h.open(B, CollectSink::new());
    let max = a.caps().max_frame;
    if max > 64 * 1024 * 1024 {
        return;
    }
    let result = a.send(B, &vec![0u8; max + 1]);
    assert!(
        matches!(result, Err(LinkError::TooLarge { .. })),
        "oversize: {result:?}"
    );
}

/// After the receiver's endpoint is dropped and opened again, frames flow again (sends in
/// between may fail, but must not hang or panic).
pub fn traffic_resumes_after_peer_restart(h: &mut dyn Harness) {
    let a = h.open(A, CollectSink::new());
    let sb1 = CollectSink::new();
    let b = h.open(B, sb1.clone());
    a.send(B, &frame(6, 0, 32)).expect("first send");
    assert_eq!(sb1.wait_for(1, WAIT), 1);
    drop(b);
    let _ = a.send(B, &frame(6, 1, 32)); // may fail: the peer is gone
    let sb2 = CollectSink::new();
    let _b2 = h.open(B, sb2.clone());
    let deadline = Instant::now() + WAIT;
    let mut i = 2;
    while sb2.frames().is_empty() {
        assert!(
            Instant::now() < deadline,
            "traffic did not resume after restart"
        );
        let _ = a.send(B, &frame(6, i, 32));
        i += 1;
        sb2.wait_for(1, Duration::from_millis(50));
    }
}
