//! The security layer's handshakes over a link whose frames the test holds, drops, replays
//! and delivers by hand: restarts of either side, an initiation replayed after the responder
//! restarted, responses that come late or not at all; and held frames leaving as one data
//! batch.

use parking_lot::Mutex;
use std::collections::{HashMap, HashSet, VecDeque};
use std::sync::Arc;
use std::time::{Duration, Instant};

use hetcomm_core::wire::{self, Header};
use hetcomm_core::{Address, MessageType, ModuleId, SystemId};
use hetcomm_link::layer::{LayerContext, LinkLayer};
use hetcomm_link::{FrameSink, Link, LinkCaps, LinkError, LinkEvent, Peer};
use hetcomm_security::{Handshakes, Keypair, Policy, SecurityLayer};

const A: SystemId = SystemId(0);
const B: SystemId = SystemId(1);

/// Frames in flight: queued by `send`, delivered when the test says.
#[derive(Default)]
struct Net {
    queue: Mutex<VecDeque<(SystemId, Vec<u8>)>>,
    sinks: Mutex<HashMap<SystemId, Arc<dyn FrameSink>>>,
}

impl Net {
    /// Delivers everything in flight, and what that sends, until nothing is left.
    fn run(&self) {
        while let Some((to, frame)) = self.pop() {
            self.deliver(to, &frame);
        }
    }

    /// Delivers what is in flight until a frame of `kind` is at the front (or nothing is
    /// left).
    fn run_until_kind(&self, kind: u8) {
        loop {
            let next = {
                let mut q = self.queue.lock();
                match q.front() {
                    Some((_, f)) if f[3] != kind => q.pop_front(),
                    _ => None,
                }
            };
            match next {
                Some((to, f)) => self.deliver(to, &f),
                None => return,
            }
        }
    }

    fn pop(&self) -> Option<(SystemId, Vec<u8>)> {
        self.queue.lock().pop_front()
    }

    fn deliver(&self, to: SystemId, frame: &[u8]) {
        let sink = self.sinks.lock().get(&to).cloned();
        if let Some(sink) = sink {
            sink.on_frame(frame, Peer::Unknown);
        }
    }

    /// Takes the next frame in flight of secured message type `kind` (1 init, 2 response,
    /// 3 data), waiting for it at most a second.
    fn take(&self, kind: u8) -> Option<(SystemId, Vec<u8>)> {
        let deadline = Instant::now() + Duration::from_secs(1);
        loop {
            {
                let mut q = self.queue.lock();
                if let Some(i) = q.iter().position(|(_, f)| f[3] == kind) {
                    return q.remove(i);
                }
            }
            if Instant::now() >= deadline {
                return None;
            }
            std::thread::sleep(Duration::from_millis(5));
        }
    }
}

struct Pipe {
    net: Arc<Net>,
}

impl Link for Pipe {
    fn caps(&self) -> LinkCaps {
        LinkCaps {
            max_frame: 1 << 20,
            mtu: 1 << 20,
            reliable: false,
            ordered: true,
            broadcast: false,
        }
    }

    fn send(&self, to: SystemId, frame: &[u8]) -> Result<(), LinkError> {
        self.net.queue.lock().push_back((to, frame.to_vec()));
        Ok(())
    }
}

/// What a node's layer hands its router, and the peers it said are up.
#[derive(Default)]
struct Router(Mutex<Vec<Vec<u8>>>, Mutex<Vec<SystemId>>);

impl FrameSink for Router {
    fn on_frame(&self, frame: &[u8], _from: Peer) {
        self.0.lock().push(frame.to_vec());
    }
    fn on_event(&self, event: LinkEvent) {
        if let LinkEvent::PeerUp(peer) = event {
            self.1.lock().push(peer);
        }
    }
}

/// One system's secured link on the net (opening it again is a restart: same keys, nothing
/// else kept).
struct Node {
    link: Arc<dyn Link>,
    router: Arc<Router>,
    local: SystemId,
    peer: SystemId,
}

impl Node {
    fn open(net: &Arc<Net>, keys: &HashMap<SystemId, Keypair>, local: SystemId) -> Node {
        let peer = if local == A { B } else { A };
        let policy = Policy {
            local,
            keypair: keys[&local].clone(),
            peers: HashMap::from([(peer, keys[&peer].public)]),
            data_from: HashSet::from([peer]),
            acks_from: HashSet::from([peer]),
        };
        let layer = SecurityLayer::new("t", policy, Handshakes::OverTheLink);
        let ctx = LayerContext::new(local);
        let router = Arc::new(Router::default());
        let link = layer
            .wrap(&ctx, router.clone(), &mut |sink| {
                net.sinks.lock().insert(local, sink);
                Ok(Arc::new(Pipe { net: net.clone() }))
            })
            .unwrap();
        Node {
            link,
            router,
            local,
            peer,
        }
    }

    /// A data frame numbered `seq` to the peer.
    fn frame(&self, seq: u64) -> Vec<u8> {
        self.frame_with(seq, 0)
    }

    /// A data frame numbered `seq` to the peer, with header `flags`.
    fn frame_with(&self, seq: u64, flags: u8) -> Vec<u8> {
        let at = |system| Address {
            system,
            module: ModuleId(0),
        };
        let mut h = Header::data(at(self.local), at(self.peer), MessageType(1));
        h.seq = seq;
        h.flags = flags;
        wire::encode(&h, b"x")
    }

    /// Sends a data frame numbered `seq` to the peer.
    fn send(&self, seq: u64) {
        self.link.send(self.peer, &self.frame(seq)).unwrap();
    }

    /// Sends a data frame numbered `seq` to the peer, letting it wait for the next ones.
    fn send_held(&self, seq: u64) {
        self.link.send_held(self.peer, &self.frame(seq)).unwrap();
    }

    /// The sequence numbers the router got.
    fn got(&self) -> Vec<u64> {
        self.router
            .0
            .lock()
            .iter()
            .map(|f| wire::decode(f).unwrap().header.seq)
            .collect()
    }
}

fn keys() -> HashMap<SystemId, Keypair> {
    [A, B]
        .into_iter()
        .map(|s| (s, Keypair::generate().unwrap()))
        .collect()
}

/// B restarts and starts a handshake with A (A sent it a frame of the old session); an
/// attacker replays A's initiation of the old session to the new B before A's response
/// arrives. The new B answers it (it cannot tell it from a fresh one), but that session waits
/// for A to use it, which A cannot: B's own handshake still completes and both ways work.
#[test]
fn an_initiation_replayed_after_the_responder_restarted_displaces_nothing() {
    let (net, keys) = (Arc::new(Net::default()), keys());
    let a = Node::open(&net, &keys, A);
    let b = Node::open(&net, &keys, B);
    a.send(1);
    let (_, old_init) = net.take(1).expect("A's initiation");
    net.deliver(B, &old_init);
    net.run();
    assert_eq!(b.got(), [1]);

    let b = Node::open(&net, &keys, B); // restarted
    a.send(2); // in the old session: the new B starts a handshake
    net.run_until_kind(1);
    let (_, b_init) = net.take(1).expect("the new B's initiation");
    net.deliver(A, &b_init);
    let (_, response) = net.take(2).expect("A's response");
    net.deliver(B, &old_init); // the replay, before A's response
    net.run(); // B's response to the replay reaches A, which has no handshake under way
    net.deliver(B, &response);
    net.run();
    b.send(1);
    a.send(3);
    net.run();
    assert_eq!(a.got(), [1], "B's frame reached A");
    assert_eq!(b.got(), [3], "A's frame reached the new B");
}

/// A's initiation waits longer than the retry interval for its response (a slow link): A
/// sends another, and the response to the first still completes the handshake.
#[test]
fn a_response_to_an_initiation_since_retried_completes_the_handshake() {
    let (net, keys) = (Arc::new(Net::default()), keys());
    let a = Node::open(&net, &keys, A);
    let b = Node::open(&net, &keys, B);
    a.send(1);
    let (_, first) = net.take(1).expect("A's initiation");
    let (_, retry) = net
        .take(1)
        .expect("A's initiation again, after the retry interval");
    assert_ne!(first, retry);
    net.deliver(B, &first);
    let (_, response) = net.take(2).expect("B's response to the first");
    net.deliver(A, &response);
    net.run();
    assert_eq!(b.got(), [1]);
    b.send(1);
    net.run();
    assert_eq!(a.got(), [1]);
}

/// A restarts; B's next frame (of the old session) makes A start a handshake, whose
/// response is lost. A tries again (it used to wait for ever, refusing every frame of B's),
/// and B's later frames reach it.
#[test]
fn a_handshake_started_by_an_unknown_session_is_retried_when_its_response_is_lost() {
    let (net, keys) = (Arc::new(Net::default()), keys());
    let a = Node::open(&net, &keys, A);
    let b = Node::open(&net, &keys, B);
    a.send(1);
    net.run();
    let a = Node::open(&net, &keys, A); // restarted
    b.send(1);
    net.run_until_kind(1);
    let (_, init) = net.take(1).expect("the new A's initiation");
    net.deliver(B, &init);
    net.take(2).expect("B's response, lost");
    let (_, again) = net.take(1).expect("the new A's initiation again");
    net.deliver(B, &again);
    net.run();
    b.send(2);
    net.run();
    assert_eq!(a.got(), [2], "B's frames reach the new A");
}

/// Frames the router lets wait (`send_held`) leave at `flush` as one data batch (type 4),
/// sealed once; the receiver hands every one up in order, and refuses the batch replayed as
/// one replay. A lone held frame leaves as a data message (type 3).
#[test]
fn held_frames_leave_as_one_data_batch() {
    let (net, keys) = (Arc::new(Net::default()), keys());
    let a = Node::open(&net, &keys, A);
    let b = Node::open(&net, &keys, B);
    a.send(1);
    net.run();
    assert_eq!(b.got(), [1]);
    for seq in 2..=6 {
        a.send_held(seq);
    }
    assert!(net.queue.lock().is_empty(), "held until the flush");
    a.link.flush().unwrap();
    let (to, batch) = net.take(4).expect("a data batch");
    assert_eq!(to, B);
    assert!(net.queue.lock().is_empty(), "one secured frame for five");
    net.deliver(B, &batch);
    assert_eq!(b.got(), [1, 2, 3, 4, 5, 6]);
    net.deliver(B, &batch);
    assert_eq!(b.got().len(), 6, "a replayed batch hands nothing up");
    assert_eq!(b.link.stats().security.rejected_replay, 1);
    a.send_held(7);
    a.link.flush().unwrap();
    let (_, single) = net.take(3).expect("a lone held frame, as a data message");
    net.deliver(B, &single);
    // A held frame goes before a later plain one.
    a.send_held(8);
    a.send(9);
    net.run();
    assert_eq!(b.got(), [1, 2, 3, 4, 5, 6, 7, 8, 9]);
    assert_eq!(b.link.stats().security.rejected(), 1);
}

/// Without a session, a frame that wants an acknowledgement is refused (nothing of it leaves:
/// only the initiation), however it is handed over, while an unacknowledged one waits for the
/// handshake. When the session is up the layer says so (`on_event` with `LinkEvent::PeerUp`), and the refused frame,
/// offered again, goes sealed. Nothing else is sent: the waiting frame confirmed the session.
#[test]
fn a_frame_that_wants_an_acknowledgement_is_refused_until_the_session_is_up() {
    let (net, keys) = (Arc::new(Net::default()), keys());
    let a = Node::open(&net, &keys, A);
    let b = Node::open(&net, &keys, B);
    let acked = a.frame_with(1, wire::FLAG_ACK_REQUESTED);
    let err = a.link.send(B, &acked).unwrap_err();
    assert!(
        matches!(&err, LinkError::NoSession { peer, reason } if *peer == B && reason.starts_with("handshake just started")),
        "{err:?}"
    );
    // Split anywhere, held for a batch: refused the same way.
    assert!(matches!(
        a.link.send_parts(B, &acked[..3], &acked[3..]),
        Err(LinkError::NoSession { .. })
    ));
    assert!(matches!(
        a.link.send_held(B, &acked),
        Err(LinkError::NoSession { .. })
    ));
    a.send(2); // unacknowledged: waits
    let kinds: Vec<u8> = net.queue.lock().iter().map(|(_, f)| f[3]).collect();
    assert_eq!(kinds, [1], "only A's initiation left");
    assert!(a.router.1.lock().is_empty());
    net.run_until_kind(2);
    let (_, response) = net.take(2).expect("B's response");
    net.deliver(A, &response);
    assert_eq!(*a.router.1.lock(), [B], "A's router told the session is up");
    a.link.send(B, &acked).expect("sealed in the session now");
    net.run();
    assert_eq!(
        b.got(),
        [2, 1],
        "the waiting frame, then the refused one offered again"
    );
    assert_eq!(
        *b.router.1.lock(),
        [A],
        "B's router told too, on confirmation"
    );
}
