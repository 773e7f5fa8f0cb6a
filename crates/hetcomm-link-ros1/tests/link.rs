//! The `ros1` link against a real ROS master: conformance, an unreachable master, a master
//! restart, and `rostopic` seeing our frames.

mod common;

use std::collections::{BTreeMap, HashSet};
use std::process::{Command, Stdio};
use std::sync::{Arc, Condvar, Mutex, Weak};
use std::time::{Duration, Instant};

use common::Master;
use hetcomm_core::SystemId;
use hetcomm_link::conformance::{self, CollectSink, Harness, Layered};
use hetcomm_link::{FrameSink, Link, LinkError, Peer};
use hetcomm_link_ros1::Ros1Settings;
use hetcomm_link_ros1::{MasterState, Ros1Config, Ros1Link, Ros1OpenError};

const WAIT: Duration = Duration::from_secs(15);

fn names(list: &[(u16, &str)]) -> BTreeMap<SystemId, String> {
    list.iter()
        .map(|&(id, n)| (SystemId(id), n.to_string()))
        .collect()
}

fn settings(master: &Master, namespace: &str) -> Ros1Settings {
    Ros1Settings {
        master_uri: master.uri(),
        namespace: Some(namespace.to_string()),
        connect_timeout_ms: None,
    }
}

/// A 3-byte probe frame `EE src_lo src_hi` (conformance frames start with tags 1..=6).
fn probe(from: SystemId) -> Vec<u8> {
    let b = from.0.to_le_bytes();
    vec![0xEE, b[0], b[1]]
}

/// Passes frames on to `inner`, except probes, which it records by sender.
struct ProbeFilter {
    inner: Arc<dyn FrameSink>,
    seen: Mutex<HashSet<u16>>,
    arrived: Condvar,
}

impl ProbeFilter {
    fn wait_for(&self, from: SystemId, timeout: Duration) -> bool {
        let deadline = Instant::now() + timeout;
        let mut seen = self.seen.lock().unwrap();
        while !seen.contains(&from.0) {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return false;
            }
            seen = self.arrived.wait_timeout(seen, left).unwrap().0;
        }
        true
    }
}

impl FrameSink for ProbeFilter {
    fn on_frame(&self, frame: &[u8], from: Peer) {
        if frame.len() == 3 && frame[0] == 0xEE {
            self.seen
                .lock()
                .unwrap()
                .insert(u16::from_le_bytes([frame[1], frame[2]]));
            self.arrived.notify_all();
        } else {
            self.inner.on_frame(frame, from);
        }
    }
}

/// Opens endpoints on a real master. ROS 1 connects a subscriber to a publisher
/// asynchronously after registration (frames published before that are lost, as in any ROS
/// program), so after opening an endpoint the harness exchanges probe frames with every live
/// endpoint until both directions are connected; the checks then start on a connected graph.
struct RosHarness {
    master: Master,
    systems: BTreeMap<SystemId, String>,
    live: Vec<(SystemId, Weak<Ros1Link>, Arc<ProbeFilter>)>,
}

impl Harness for RosHarness {
    fn open(&mut self, system: SystemId, sink: Arc<dyn FrameSink>) -> Box<dyn Link> {
        let filter = Arc::new(ProbeFilter {
            inner: sink,
            seen: Mutex::new(HashSet::new()),
            arrived: Condvar::new(),
        });
        let link = Arc::new(
            Ros1Link::open(
                system,
                &self.systems,
                &settings(&self.master, "conformance"),
                filter.clone(),
                Ros1Config::default(),
            )
            .expect("open"),
        );
        self.live.retain(|(_, w, _)| w.strong_count() > 0);
        for (peer, weak, peer_filter) in &self.live {
            let Some(peer_link) = weak.upgrade() else {
                continue;
            };
            let deadline = Instant::now() + WAIT;
            loop {
                let _ = link.send(*peer, &probe(system));
                let _ = peer_link.send(system, &probe(*peer));
                let ok = peer_filter.wait_for(system, Duration::from_millis(50))
                    & filter.wait_for(*peer, Duration::from_millis(50));
                if ok {
                    break;
                }
                assert!(
                    Instant::now() < deadline,
                    "{system} and {peer} never connected"
                );
            }
        }
        self.live.push((system, Arc::downgrade(&link), filter));
        Box::new(link)
    }
}

/// System `id` of the fleet A (1), B (2), with the default configuration, in `namespace`.
fn open_ab(master: &Master, namespace: &str, id: u16, sink: Arc<CollectSink>) -> Ros1Link {
    Ros1Link::open(
        SystemId(id),
        &names(&[(1, "A"), (2, "B")]),
        &settings(master, namespace),
        sink,
        Ros1Config::default(),
    )
    .expect("open")
}

/// A harness for systems A (1) and B (2) on a fresh master.
fn two_systems() -> RosHarness {
    RosHarness {
        master: Master::start(),
        systems: names(&[(1, "A"), (2, "B")]),
        live: Vec::new(),
    }
}

#[test]
fn conformance_on_a_real_master() {
    conformance::run_all(&mut two_systems());
}

/// The same, each link inside an emulation layer (a model that changes nothing), as an
/// `emulated` transport over `ros1` opens it.
#[test]
fn conformance_on_a_real_master_wrapped_in_emulation() {
    conformance::run_all(&mut Layered::emulated(two_systems()));
}

/// The same, each link under the security layer (keys per system, Noise handshake over
/// the topics, every frame sealed), as a secured `ros1` transport opens it.
#[test]
fn conformance_on_a_real_master_secured() {
    conformance::run_all(&mut hetcomm_security::conformance::secured(
        two_systems(),
        [SystemId(1), SystemId(2)],
    ));
}

#[test]
fn unreachable_master_fails_at_once_naming_the_uri() {
    common::require_ros();
    let port = common::free_port(); // nothing listens there
    let uri = format!("http://127.0.0.1:{port}");
    let started = Instant::now();
    let result = Ros1Link::open(
        SystemId(1),
        &names(&[(1, "A"), (2, "B")]),
        &Ros1Settings {
            master_uri: uri.clone(),
            namespace: None,
            connect_timeout_ms: None,
        },
        CollectSink::new(),
        Ros1Config::default(),
    );
    let err = match result {
        Ok(_) => panic!("opened without a master"),
        Err(e) => e,
    };
    assert!(
        started.elapsed() < Duration::from_secs(5),
        "took {:?}",
        started.elapsed()
    );
    assert!(
        matches!(err, Ros1OpenError::MasterUnreachable { .. }),
        "{err:?}"
    );
    let text = err.to_string();
    assert!(text.contains(&uri), "{text}");
}

#[test]
fn bad_names_are_refused() {
    let err = hetcomm_link_ros1::topic_name(Some("ok"), "no-dash").unwrap_err();
    assert!(matches!(err, Ros1OpenError::InvalidName { .. }));
    assert_eq!(
        hetcomm_link_ros1::topic_name(Some("/a/b/"), "Charlie").unwrap(),
        "/a/b/Charlie"
    );
    assert_eq!(
        hetcomm_link_ros1::topic_name(None, "Charlie").unwrap(),
        "/Charlie"
    );
}

/// Sends `frame` from `a` to `to` until `sink` holds a frame equal to it.
fn until_arrives(a: &Ros1Link, to: SystemId, frame: &[u8], sink: &CollectSink) {
    let deadline = Instant::now() + WAIT;
    loop {
        let _ = a.send(to, frame);
        sink.wait_for(sink.frames().len() + 1, Duration::from_millis(100));
        if sink.frames().iter().any(|r| r.bytes == frame) {
            return;
        }
        assert!(Instant::now() < deadline, "frame to {to} never arrived");
    }
}

fn wait_until(what: &str, mut cond: impl FnMut() -> bool) {
    let deadline = Instant::now() + WAIT;
    while !cond() {
        assert!(Instant::now() < deadline, "timed out waiting for {what}");
        std::thread::sleep(Duration::from_millis(20));
    }
}

#[test]
fn master_restart_is_survived() {
    let mut master = Master::start();
    let systems = names(&[(1, "A"), (2, "B"), (3, "C")]);
    let config = Ros1Config {
        supervise_interval: Duration::from_millis(200),
        ..Ros1Config::default()
    };
    let open = |id: u16, sink: Arc<CollectSink>, m: &Master| {
        Ros1Link::open(
            SystemId(id),
            &systems,
            &settings(m, "restart"),
            sink,
            config.clone(),
        )
        .expect("open")
    };
    let (sa, sb) = (CollectSink::new(), CollectSink::new());
    let a = open(1, sa.clone(), &master);
    let b = open(2, sb.clone(), &master);
    until_arrives(&a, SystemId(2), b"a->b before", &sb);
    until_arrives(&b, SystemId(1), b"b->a before", &sa);
    assert_eq!(a.stats().connects, 1);

    // The master dies. Frames keep flowing over the TCPROS connections already made (the
    // master only introduces nodes); the supervisor notices the master is gone.
    master.kill();
    wait_until("A to see the master gone", || {
        matches!(a.master_state(), MasterState::Unreachable(_))
    });
    assert!(a.send(SystemId(2), b"a->b while down").is_ok());
    until_arrives(&a, SystemId(2), b"a->b while down", &sb);

    // An empty master comes back on the same port: both links re-register.
    master.restart();
    wait_until("both links to re-register", || {
        a.stats().connects == 2
            && b.stats().connects == 2
            && a.master_state() == MasterState::Registered
            && b.master_state() == MasterState::Registered
    });
    until_arrives(&a, SystemId(2), b"a->b after", &sb);
    until_arrives(&b, SystemId(1), b"b->a after", &sa);

    // A node that only the new master introduces reaches A and is reached by it: A's
    // subscriber and publishers are registered with the new master.
    let sc = CollectSink::new();
    let c = open(3, sc.clone(), &master);
    until_arrives(&c, SystemId(1), b"c->a", &sa);
    until_arrives(&a, SystemId(3), b"a->c", &sc);
}

#[test]
fn unknown_and_own_destinations_are_unreachable() {
    let master = Master::start();
    let a = Ros1Link::open(
        SystemId(1),
        &names(&[(1, "A"), (2, "B")]),
        &Ros1Settings {
            connect_timeout_ms: Some(300),
            ..settings(&master, "unknown")
        },
        CollectSink::new(),
        Ros1Config::default(),
    )
    .expect("open");
    for to in [SystemId(7), SystemId(1)] {
        let started = Instant::now();
        let r = a.send(to, b"x");
        assert!(matches!(r, Err(LinkError::Unreachable { .. })), "{r:?}");
        assert!(
            started.elapsed() < Duration::from_millis(100),
            "answered at once"
        );
    }
    // B is a system of the fleet but nothing subscribes to its topic: the send waits the
    // connect timeout (300 ms here), then says so instead of publishing into nothing.
    let started = Instant::now();
    let r = a.send(SystemId(2), b"x");
    let waited = started.elapsed();
    match r {
        Err(LinkError::Unreachable { peer, reason }) => {
            assert_eq!(peer, SystemId(2));
            assert_eq!(
                reason,
                "the subscriber of /unknown/B did not connect within 300 ms \
                 (no node subscribes to /unknown/B)"
            );
        }
        other => panic!("expected Unreachable, got {other:?}"),
    }
    assert!(
        waited >= Duration::from_millis(300) && waited < Duration::from_secs(3),
        "waited {waited:?}"
    );
    assert_eq!(a.stats().frames_sent, 0, "nothing was published");
    assert!(!a.is_connected(SystemId(2)));
}

/// ROS 1 loses what is published before the subscriber's connection is up. A send waits for
/// it: a destination that has just opened gets the very first frame sent to it, with no
/// retry, every time (ten fresh destinations in a row), and a fresh sender's first frame
/// reaches a running destination.
#[test]
fn the_first_frame_to_a_new_peer_arrives() {
    let master = Master::start();
    let open = |id: u16, sink: Arc<CollectSink>| open_ab(&master, "first", id, sink);
    let sa = CollectSink::new();
    let a = open(1, sa.clone());
    for round in 0..10u8 {
        let sb = CollectSink::new();
        let b = open(2, sb.clone());
        a.send(SystemId(2), &[0xA0, round]).expect("A to the new B");
        assert!(
            sb.wait_for(1, Duration::from_secs(5)) >= 1,
            "round {round}: the first frame to a new B was lost"
        );
        assert_eq!(sb.frames()[0].bytes, vec![0xA0, round]);
        assert!(a.is_connected(SystemId(2)));
        drop(b);
    }
    // The other way round: a new sender, a running destination.
    let sb = CollectSink::new();
    let _b = open(2, sb.clone());
    for round in 0..5u8 {
        let a2 = open(1, CollectSink::new());
        a2.send(SystemId(2), &[0xB0, round])
            .expect("a new A to the running B");
        assert!(
            sb.wait_for(usize::from(round) + 1, Duration::from_secs(5)) > usize::from(round),
            "round {round}: the first frame of a new A was lost"
        );
        assert_eq!(sb.frames()[usize::from(round)].bytes, vec![0xB0, round]);
    }
}

/// roslibrust's publisher takes subscribers one at a time and waits for each one's TCPROS
/// header without a time limit: one connection that never sends it (here a bare TCP
/// connection, held open) keeps every later subscriber out for good. The link sees that the
/// destination, alive and listed by the master, answers no probe, and registers anew (new
/// publishers on new ports): frames reach it within a few seconds all the same.
#[test]
fn a_publisher_stalled_by_a_silent_connection_is_replaced() {
    let master = Master::start();
    let open = |id: u16, sink: Arc<CollectSink>| open_ab(&master, "stall", id, sink);
    let a = open(1, CollectSink::new());
    let port = master.tcpros_port(&a.node_name(), "/stall/B");
    let silent = std::net::TcpStream::connect(("127.0.0.1", port)).expect("connecting");
    let sb = CollectSink::new();
    let _b = open(2, sb.clone());
    let started = Instant::now();
    let mut last = Ok(());
    while sb.wait_for(1, Duration::from_millis(100)) == 0 {
        assert!(
            started.elapsed() < WAIT,
            "A never reached B past a stalled publisher: {last:?}"
        );
        last = a.send(SystemId(2), b"past the stall");
    }
    assert_eq!(sb.frames()[0].bytes, b"past the stall".to_vec());
    assert!(a.stats().connects >= 2, "A did not register anew");
    drop(silent);
}

#[test]
fn rostopic_sees_our_topics_and_frames() {
    let master = Master::start();
    let systems = names(&[(0, "Alpha"), (1, "Charlie")]);
    let alpha = Ros1Link::open(
        SystemId(0),
        &systems,
        &settings(&master, "hetcomm"),
        CollectSink::new(),
        Ros1Config::default(),
    )
    .expect("open Alpha");
    let _charlie = Ros1Link::open(
        SystemId(1),
        &systems,
        &settings(&master, "hetcomm"),
        CollectSink::new(),
        Ros1Config::default(),
    )
    .expect("open Charlie");

    let list = Command::new("rostopic")
        .arg("list")
        .envs(master.env())
        .output()
        .expect("running rostopic list");
    let list = String::from_utf8_lossy(&list.stdout);
    assert!(list.lines().any(|l| l == "/hetcomm/Charlie"), "{list}");
    assert!(list.lines().any(|l| l == "/hetcomm/Alpha"), "{list}");

    let mut echo = Command::new("rostopic")
        .args(["echo", "-n", "1", "/hetcomm/Charlie"])
        .envs(master.env())
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("running rostopic echo");
    // A frame starts with the magic "HC" = 72, 67 and version 1.
    let frame = [72u8, 67, 1, 0, 0, 100, 82, 0, 9, 9];
    let deadline = Instant::now() + WAIT;
    while echo.try_wait().expect("rostopic echo").is_none() {
        if Instant::now() > deadline {
            let _ = echo.kill();
            panic!("rostopic echo saw nothing");
        }
        alpha.send(SystemId(1), &frame).expect("send");
        std::thread::sleep(Duration::from_millis(50));
    }
    let out = echo.wait_with_output().expect("rostopic output");
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        text.contains("data: [72, 67, 1, 0, 0, 100, 82, 0, 9, 9]"),
        "{text}"
    );
}

/// What `rosnode` can do with a hetcomm link's node (see docs/ros1.md, "Introspection"):
/// `list`, `ping` and `kill` work (a killed registration is replaced, as after a master
/// restart); `info` cannot list connections, because roslibrust's node answers `getBusInfo`
/// with `501 Not Implemented` (roslibrust issue #202).
#[test]
fn rosnode_lists_pings_and_kills_a_link() {
    let master = Master::start();
    let a = Ros1Link::open(
        SystemId(1),
        &names(&[(1, "A"), (2, "B")]),
        &settings(&master, "rosnode"),
        CollectSink::new(),
        Ros1Config {
            supervise_interval: Duration::from_millis(200),
            ..Ros1Config::default()
        },
    )
    .expect("open");
    let rosnode = |args: &[&str]| {
        let out = Command::new("rosnode")
            .args(args)
            .envs(master.env())
            .output()
            .expect("running rosnode");
        let text = format!(
            "{}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
        (out.status.success(), text)
    };
    let node = a.node_name();
    let (ok, list) = rosnode(&["list"]);
    assert!(ok && list.lines().any(|l| l == node), "{list}");
    let (ok, ping) = rosnode(&["ping", "-c", "1", &node]);
    assert!(
        ok && ping.contains("xmlrpc reply from http://127.0.0.1:"),
        "{ping}"
    );

    // `info` prints what the master knows, then fails asking the node for its connections.
    let (_, info) = rosnode(&["info", &node]);
    assert!(
        info.contains("Publications: \n * /rosnode/B [std_msgs/UInt8MultiArray]"),
        "{info}"
    );
    assert!(info.contains("Subscriptions: \n * /rosnode/A"), "{info}");
    assert!(info.contains("501 Not Implemented"), "{info}");

    // `kill` shuts the node down; the link registers a new one, as after a master restart.
    let (ok, kill) = rosnode(&["kill", &node]);
    assert!(ok && kill.contains("killed"), "{kill}");
    wait_until("the link to re-register", || {
        a.stats().connects == 2 && a.node_name() != node
    });
    let (_, list) = rosnode(&["list"]);
    assert!(list.lines().any(|l| l == a.node_name()), "{list}");
}
