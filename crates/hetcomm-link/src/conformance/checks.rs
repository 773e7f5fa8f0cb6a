//! The checks of the suite, one public function each ([`super::run_all`] runs them all).

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use hetcomm_core::{FrameBuf, SystemId};

use crate::layer::{LayerContext, LayerStack, Tap, TapLayer};
use crate::{FrameSink, Link, LinkError, Peer};

use super::sinks::{open, poll_readable, Endpoint};
use super::{CollectSink, Harness, Received, WAIT};

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

fn check_from(r: &Received, sender: SystemId) {
    if let Peer::System(s) = r.from {
        assert_eq!(s, sender, "link labelled a frame from {sender} as from {s}");
    }
}

/// A frame each way arrives byte-for-byte, labelled with the right sender.
pub fn delivers_both_ways(h: &mut dyn Harness) {
    let (sa, sb) = (CollectSink::new(), CollectSink::new());
    let a = open(h, A, sa.clone());
    let b = open(h, B, sb.clone());
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
/// arrive intact: every one on a reliable link, all but those counted as lost on an unreliable
/// one.
pub fn preserves_sizes(h: &mut dyn Harness) {
    let sb = CollectSink::new();
    let a = open(h, A, CollectSink::new());
    let b = open(h, B, sb.clone());
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
    Delivery::of(h, &*a, &*b).wait(&sb, sizes.len(), "sizes");
    for r in sb.frames() {
        let index = u32::from_le_bytes([r.bytes[1], r.bytes[2], r.bytes[3], r.bytes[4]]) as usize;
        assert_eq!(
            r.bytes,
            frame(3, index as u32, sizes[index]),
            "frame {index} corrupted"
        );
    }
}

/// 1000 frames: all arrive on a reliable link, all but those counted as lost (within the
/// configured loss, if any) on an unreliable one, in order on an ordered one, and none is
/// duplicated or invented on any link.
pub fn many_frames_respect_caps(h: &mut dyn Harness) {
    const N: u32 = 1000;
    let sb = CollectSink::new();
    let a = open(h, A, CollectSink::new());
    let b = open(h, B, sb.clone());
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
    Delivery::of(h, &*a, &*b).wait(&sb, N as usize, "many frames");
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
    let a = open(h, A, CollectSink::new());
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
    let a = open(h, A, CollectSink::new());
    let _b = open(h, B, CollectSink::new());
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
    let a = open(h, A, CollectSink::new());
    let sb1 = CollectSink::new();
    let b = open(h, B, sb1.clone());
    a.send(B, &frame(6, 0, 32)).expect("first send");
    assert_eq!(sb1.wait_for(1, WAIT), 1);
    drop(b);
    let _ = a.send(B, &frame(6, 1, 32)); // may fail: the peer is gone
    let sb2 = CollectSink::new();
    let _b2 = open(h, B, sb2.clone());
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

/// The frame index [`frame`] wrote.
fn index_of(bytes: &[u8]) -> u32 {
    u32::from_le_bytes([bytes[1], bytes[2], bytes[3], bytes[4]])
}

/// What a check requires of the frames it sent from one link to another.
struct Delivery<'a> {
    reliable: bool,
    /// [`Harness::configured_loss`].
    loss: f64,
    sender: &'a dyn Link,
    receiver: &'a dyn Link,
}

impl<'a> Delivery<'a> {
    fn of(h: &dyn Harness, sender: &'a dyn Link, receiver: &'a dyn Link) -> Self {
        Delivery {
            reliable: sender.caps().reliable,
            loss: h.configured_loss(),
            sender,
            receiver,
        }
    }

    /// Frames the two ends counted as lost: dropped by either (an emulation counts what it
    /// loses at the sender), or by the receiver's operating system. Counted in datagrams
    /// there, so a fragmented frame may count more than once: an upper bound.
    fn counted_losses(&self) -> usize {
        let (s, r) = (self.sender.stats(), self.receiver.stats());
        (s.frames_dropped + r.frames_dropped + r.kernel_drops) as usize
    }

    /// Whether every one of `n` frames arrived in `sink` or was counted as lost.
    fn settled(&self, sink: &CollectSink, n: usize) -> bool {
        sink.len() >= n || (!self.reliable && sink.len() + self.counted_losses() >= n)
    }

    /// Waits (up to [`WAIT`]) until the `n` frames sent are in `sink` or counted as lost,
    /// then checks them ([`Delivery::check`]).
    fn wait(&self, sink: &CollectSink, n: usize, what: &str) {
        let deadline = Instant::now() + WAIT;
        while !self.settled(sink, n) && Instant::now() < deadline {
            sink.wait_for(sink.len() + 1, Duration::from_millis(20));
        }
        self.check(sink, n, what);
    }

    /// A reliable link delivered all `n` frames. An unreliable one delivered all but frames
    /// the links counted as lost; and, with loss configured, at least what the loss leaves
    /// with five standard deviations to spare (a link losing far more than configured fails;
    /// one run in millions of a healthy one would).
    fn check(&self, sink: &CollectSink, n: usize, what: &str) {
        let got = sink.len();
        if self.reliable {
            assert!(
                got >= n,
                "{what}: a reliable link delivered {got} of {n} frames"
            );
            return;
        }
        let counted = self.counted_losses();
        assert!(
            got + counted >= n,
            "{what}: an unreliable link delivered {got} of {n} frames and counted {counted} \
             lost; the other {} vanished",
            n - got - counted
        );
        if self.loss > 0.0 {
            let p = self.loss.min(1.0);
            let expected = n as f64 * (1.0 - p);
            let spread = 5.0 * (n as f64 * p * (1.0 - p)).sqrt();
            let least = (expected - spread).floor().max(0.0) as usize;
            assert!(
                got >= least,
                "{what}: {got} of {n} frames arrived with {:.1}% loss configured; at least \
                 {least} should have",
                p * 100.0
            );
        }
    }
}

/// Checks what arrived against what was sent, by index: nothing corrupted, duplicated or
/// invented, and in order on an ordered link.
fn check_against(got: &[Received], sent: &[Vec<u8>], sender: SystemId, ordered: bool, what: &str) {
    let mut seen = Vec::with_capacity(got.len());
    for r in got {
        let i = index_of(&r.bytes) as usize;
        assert!(i < sent.len(), "{what}: invented frame {i}");
        assert_eq!(r.bytes, sent[i], "{what}: frame {i} corrupted");
        check_from(r, sender);
        seen.push(i);
    }
    let mut unique = seen.clone();
    unique.sort_unstable();
    unique.dedup();
    assert_eq!(unique.len(), seen.len(), "{what}: duplicated frames");
    if ordered {
        assert!(
            seen.windows(2).all(|w| w[0] < w[1]),
            "{what}: ordered link reordered frames: {seen:?}"
        );
    }
}

/// Frames arrive through the link's receive side, a frame larger than its MTU among them:
///
/// - a link with a receive side ([`Link::readable`]) starts no reader of its own: its frames
///   arrive when, and because, someone polls its descriptor and calls `read_ready`. This check
///   reads the receiver itself (no other reader), through `readable()` only;
/// - a link without one delivers on its own (a receive thread, or the sender's thread for an
///   in-process link): the frames arrive with nobody reading it.
pub fn receive_side_delivers(h: &mut dyn Harness) {
    let sb = CollectSink::new();
    let a = open(h, A, CollectSink::new());
    // Not an `Endpoint`: nobody but this check reads it.
    let b = h.open(B, sb.clone());
    let caps = a.caps();
    let big = (caps.mtu + 1000).min(caps.max_frame).min(256 * 1024);
    let sent: Vec<Vec<u8>> = (0..10)
        .map(|i| frame(8, i, if i == 5 { big } else { 100 }))
        .collect();
    let delivery = Delivery::of(h, &*a, &*b);
    let Some(rx) = b.readable() else {
        for f in &sent {
            a.send(B, f)
                .expect("send to a link that receives on its own");
        }
        delivery.wait(&sb, sent.len(), "receive on the link's own");
        check_against(
            &sb.frames(),
            &sent,
            A,
            caps.ordered,
            "receive on the link's own",
        );
        return;
    };
    assert!(rx.fd() >= 0, "a receive side needs a descriptor to poll");
    let deadline = Instant::now() + WAIT;
    // Read while sending: a large frame may not fit the socket buffers until the receiver
    // reads, and a driven link's receiver is whoever calls `read_ready`.
    let handed_on = std::thread::scope(|scope| {
        let reader = scope.spawn(|| {
            let mut handed_on = 0;
            while !delivery.settled(&sb, sent.len()) && Instant::now() < deadline {
                poll_readable(rx, 20);
                handed_on += rx.read_ready(64).expect("read_ready");
            }
            handed_on
        });
        for f in &sent {
            a.send(B, f).expect("send to a driven link");
        }
        reader.join().expect("the reader")
    });
    delivery.check(&sb, sent.len(), "driven receive");
    let got = sb.frames();
    // Not `==`: a link may read some connections with threads of its own even so (the stream
    // links do for sockets that cannot be polled).
    assert!(
        handed_on <= got.len(),
        "read_ready reported {handed_on} frames handed on, the sink got {}",
        got.len()
    );
    check_against(&got, &sent, A, caps.ordered, "driven receive");
}

/// Frames sent with [`Link::send_held`] go out at [`Link::flush`], and before a later plain
/// [`Link::send`] to the same peer (links that do not batch send them at once).
pub fn held_frames_are_flushed(h: &mut dyn Harness) {
    let sb = CollectSink::new();
    let a = open(h, A, CollectSink::new());
    let b = open(h, B, sb.clone());
    let caps = a.caps();
    let delivery = Delivery::of(h, &*a, &*b);
    let sent: Vec<Vec<u8>> = (0..24).map(|i| frame(9, i, 64 + i as usize)).collect();
    for f in &sent[..20] {
        a.send_held(B, f).expect("send_held");
    }
    a.flush().expect("flush");
    delivery.wait(&sb, 20, "held frames after flush");
    // Held frames, then a plain send: the held ones go first.
    for f in &sent[20..23] {
        a.send_held(B, f).expect("send_held");
    }
    a.send(B, &sent[23]).expect("send after held frames");
    delivery.wait(&sb, 24, "held frames before a plain send");
    a.flush().expect("flush with nothing held");
    check_against(&sb.frames(), &sent, A, caps.ordered, "held frames");
}

/// [`Link::send_parts`] delivers `head` followed by `body` as one frame, whatever the split
/// (an empty body, a body past the MTU, up to 1 MiB), and refuses parts over `max_frame`.
pub fn send_parts_arrive_as_one_frame(h: &mut dyn Harness) {
    let sb = CollectSink::new();
    let a = open(h, A, CollectSink::new());
    let b = open(h, B, sb.clone());
    let caps = a.caps();
    let delivery = Delivery::of(h, &*a, &*b);
    let head_len = 48;
    let lens = [
        head_len,
        head_len + 1,
        1000,
        caps.mtu.min(caps.max_frame),
        (caps.mtu + 1).min(caps.max_frame),
        (1024 * 1024).min(caps.max_frame),
    ];
    let sent: Vec<Vec<u8>> = lens
        .iter()
        .enumerate()
        .map(|(i, &len)| frame(10, i as u32, len))
        .collect();
    for (i, f) in sent.iter().enumerate() {
        let (head, body) = f.split_at(head_len.min(f.len()));
        a.send_parts(B, head, body)
            .unwrap_or_else(|e| panic!("send_parts of {} + {} bytes: {e}", head.len(), body.len()));
        delivery.wait(&sb, i + 1, "send_parts");
    }
    check_against(&sb.frames(), &sent, A, caps.ordered, "send_parts");
    if caps.max_frame <= 64 * 1024 * 1024 {
        let body = vec![0u8; caps.max_frame + 1 - head_len];
        let result = a.send_parts(B, &sent[0][..head_len], &body);
        assert!(
            matches!(result, Err(LinkError::TooLarge { .. })),
            "oversize send_parts: {result:?}"
        );
    }
}

/// A sink that keeps frames handed over to it ([`FrameSink::takes_frames`]), recording which
/// came as owned buffers.
#[derive(Default)]
struct TakingSink {
    collect: CollectSink,
    owned: AtomicU64,
}

impl FrameSink for TakingSink {
    fn on_frame(&self, frame: &[u8], from: Peer) {
        self.collect.on_frame(frame, from);
    }
    fn on_frame_owned(&self, frame: FrameBuf, from: Peer) {
        self.owned.fetch_add(1, Ordering::Relaxed);
        self.collect.on_frame(&frame, from);
    }
    fn takes_frames(&self) -> bool {
        true
    }
}

/// Frames given away ([`Link::send_owned`]) in a fast stream, which a link may write behind
/// the sender, keep their place among frames sent with `send`, `send_parts` and `send_held`
/// and a `flush`: every one arrives once, intact, in order on an ordered link. Their buffers
/// go back to their pool once the link is done with them.
pub fn given_frames_keep_their_place(h: &mut dyn Harness) {
    let sb = CollectSink::new();
    let a = open(h, A, CollectSink::new());
    let b = open(h, B, sb.clone());
    let caps = a.caps();
    let delivery = Delivery::of(h, &*a, &*b);
    let pool = hetcomm_core::BufferPool::new(16 << 20);
    let large = (40 << 10).min(caps.max_frame);
    let sent: Vec<Vec<u8>> = (0..240)
        .map(|i| frame(12, i, if i % 8 == 7 { 100 } else { large }))
        .collect();
    for (i, f) in sent.iter().enumerate() {
        let result = match i % 40 {
            7 => a.send(B, f),
            15 => a.send_parts(B, &f[..48], &f[48..]),
            23 | 31 => a.send_held(B, f),
            39 => a.send_held(B, f).and_then(|()| a.flush()),
            _ => {
                let mut buf = pool.take(f.len());
                buf.extend_from_slice(f);
                a.send_owned(B, pool.wrap(buf))
            }
        };
        result.unwrap_or_else(|e| panic!("frame {i} of {} bytes: {e}", f.len()));
    }
    a.flush().expect("flush");
    delivery.wait(&sb, sent.len(), "given frames");
    check_against(&sb.frames(), &sent, A, caps.ordered, "given frames");
    let deadline = std::time::Instant::now() + WAIT;
    while pool.kept_bytes() == 0 && std::time::Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(5));
    }
    assert!(
        pool.kept_bytes() > 0,
        "given frames: no buffer came back to its pool"
    );
}

/// With a sink that takes frames ([`FrameSink::on_frame_owned`]), small and large frames
/// (up to 1 MiB + 1) arrive intact and in order, lent or handed over as the link chooses.
pub fn owned_frames_arrive_intact(h: &mut dyn Harness) {
    let sink = Arc::new(TakingSink::default());
    let a = open(h, A, CollectSink::new());
    let b = open(h, B, sink.clone());
    let caps = a.caps();
    let delivery = Delivery::of(h, &*a, &*b);
    let lens = [10, 70_000, 100, 1024 * 1024 + 1, 3000, 70_000];
    let sent: Vec<Vec<u8>> = lens
        .iter()
        .enumerate()
        .map(|(i, &len)| frame(11, i as u32, len.min(caps.max_frame)))
        .collect();
    for (i, f) in sent.iter().enumerate() {
        a.send(B, f)
            .unwrap_or_else(|e| panic!("send of {} bytes: {e}", f.len()));
        delivery.wait(&sink.collect, i + 1, "frames to a taking sink");
    }
    check_against(
        &sink.collect.frames(),
        &sent,
        A,
        caps.ordered,
        "owned frames",
    );
    let owned = sink.owned.load(Ordering::Relaxed) as usize;
    assert!(owned <= sink.collect.frames().len());
}

/// Counts what a [`TapLayer`] shows, per direction.
#[derive(Default)]
struct CountTap {
    sent: AtomicU64,
    sent_bytes: AtomicU64,
    received: AtomicU64,
}

impl Tap for CountTap {
    fn on_send(&self, _to: SystemId, head: &[u8], body: &[u8]) {
        self.sent.fetch_add(1, Ordering::Relaxed);
        self.sent_bytes
            .fetch_add((head.len() + body.len()) as u64, Ordering::Relaxed);
    }
    fn on_receive(&self, _frame: &[u8], _from: Peer) {
        self.received.fetch_add(1, Ordering::Relaxed);
    }
}

/// A layer stack over the link (a tap on both sides, as the runtime puts layers where it
/// opens links) keeps everything the link offers: its receive side, batching, the sink's
/// taking of frames. Every frame, however sent (`send`, `send_parts`, `send_held` + `flush`)
/// and however received (lent, handed over or in a batch), passes through the layer and
/// arrives intact.
pub fn layers_see_and_pass_every_frame(h: &mut dyn Harness) {
    let loss = h.configured_loss();
    let tap = Arc::new(CountTap::default());
    let stack = LayerStack::new().with(Arc::new(TapLayer::new(tap.clone())));
    let mut open_layered = |system: SystemId, sink: Arc<dyn FrameSink>| {
        let ctx = LayerContext::new(system);
        let (mut driven, mut batches) = (false, false);
        let wrapped = stack
            .open(&ctx, sink.clone(), &mut |wrapped_sink| {
                assert_eq!(
                    wrapped_sink.takes_frames(),
                    sink.takes_frames(),
                    "the layered sink changed takes_frames"
                );
                let link: Arc<dyn Link> = Arc::from(h.open(system, wrapped_sink));
                (driven, batches) = (link.readable().is_some(), link.batches());
                Ok(link)
            })
            .expect("wrap the link");
        assert_eq!(
            wrapped.readable().is_some(),
            driven,
            "the layered link lost its receive side"
        );
        assert_eq!(
            wrapped.batches(),
            batches,
            "the layered link changed batches"
        );
        Endpoint::new(Box::new(wrapped))
    };
    let sink = Arc::new(TakingSink::default());
    let a = open_layered(A, CollectSink::new());
    let b = open_layered(B, sink.clone());
    let caps = a.caps();
    let big = (1024 * 1024 + 1).min(caps.max_frame);
    let sent: Vec<Vec<u8>> = [100, 2000, 300, 400, big]
        .iter()
        .enumerate()
        .map(|(i, &len)| frame(12, i as u32, len))
        .collect();
    a.send(B, &sent[0]).expect("layered send");
    let (head, body) = sent[1].split_at(48);
    a.send_parts(B, head, body).expect("layered send_parts");
    a.send_held(B, &sent[2]).expect("layered send_held");
    a.send_held(B, &sent[3]).expect("layered send_held");
    a.flush().expect("layered flush");
    a.send(B, &sent[4]).expect("layered large send");
    let n = sent.len();
    let delivery = Delivery {
        reliable: caps.reliable,
        loss,
        sender: &*a,
        receiver: &*b,
    };
    delivery.wait(&sink.collect, n, "layered link");
    check_against(
        &sink.collect.frames(),
        &sent,
        A,
        caps.ordered,
        "layered link",
    );
    assert_eq!(
        tap.sent.load(Ordering::Relaxed),
        n as u64,
        "the layer did not see every send"
    );
    let bytes: usize = sent.iter().map(Vec::len).sum();
    assert_eq!(tap.sent_bytes.load(Ordering::Relaxed), bytes as u64);
    assert_eq!(
        tap.received.load(Ordering::Relaxed),
        sink.collect.frames().len() as u64,
        "the layer did not see every frame received"
    );
}
