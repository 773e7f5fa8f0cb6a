//! `shm` links between real processes (the `shm-test-peer` program): a peer killed with
//! SIGKILL mid-stream is found dead, cleaned up and reported down, the survivor's sends to it
//! end truthfully, and a restarted peer works; a peer that never reads fills its queue and
//! every refused send is counted; a foreign service under a transport's name is a clear
//! error, and a foreign publisher's oversize samples are counted, not delivered.

mod common;

use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use common::{config, unique_fleet};
use hetcomm_core::SystemId;
use hetcomm_link::{FrameSink, Link, LinkError, LinkEvent, Peer};
use hetcomm_link_shm::{ShmLink, ShmSettings};

const A: SystemId = SystemId(1);
const B: SystemId = SystemId(2);

/// Frames and link events, as they came.
#[derive(Default)]
struct Recorder {
    frames: Mutex<Vec<Vec<u8>>>,
    events: Mutex<Vec<LinkEvent>>,
}

impl FrameSink for Recorder {
    fn on_frame(&self, frame: &[u8], _from: Peer) {
        self.frames.lock().unwrap().push(frame.to_vec());
    }
    fn on_event(&self, event: LinkEvent) {
        self.events.lock().unwrap().push(event);
    }
}

impl Recorder {
    fn has_event(&self, e: LinkEvent) -> bool {
        self.events.lock().unwrap().contains(&e)
    }
    fn frames(&self) -> usize {
        self.frames.lock().unwrap().len()
    }
}

/// Reads a link on a thread of its own (as the runtime's reactor would) until dropped.
struct Reader {
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Reader {
    fn start(link: Arc<ShmLink>) -> Reader {
        let stop = Arc::new(AtomicBool::new(false));
        let stopping = stop.clone();
        let thread = std::thread::spawn(move || {
            let rx = link.readable().unwrap();
            while !stopping.load(Ordering::SeqCst) {
                let mut fd = libc::pollfd {
                    fd: rx.fd(),
                    events: libc::POLLIN,
                    revents: 0,
                };
                // SAFETY: one valid pollfd.
                unsafe { libc::poll(&mut fd, 1, 20) };
                let _ = rx.read_ready(64);
            }
        });
        Reader {
            stop,
            thread: Some(thread),
        }
    }
}

impl Drop for Reader {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// A peer process, killed (SIGKILL) and reaped when dropped, also when a test fails.
struct Kid(Child);

impl Kid {
    /// SIGKILL, then reap.
    fn kill(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

impl Drop for Kid {
    fn drop(&mut self) {
        self.kill();
    }
}

/// Starts `shm-test-peer` as system B and waits for its `ready`.
fn peer(fleet: &str, mode: &str, queue_depth: usize) -> Kid {
    let mut child = Command::new(env!("CARGO_BIN_EXE_shm-test-peer"))
        .args([fleet, "2", "1", mode, &queue_depth.to_string()])
        .stdout(Stdio::piped())
        .spawn()
        .expect("start shm-test-peer");
    let mut line = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut line)
        .expect("read the peer's ready line");
    assert_eq!(line.trim(), "ready", "the peer did not open its link");
    Kid(child)
}

fn wait_until(what: &str, timeout: Duration, mut done: impl FnMut() -> bool) {
    let deadline = Instant::now() + timeout;
    while !done() {
        assert!(Instant::now() < deadline, "timed out waiting for {what}");
        std::thread::sleep(Duration::from_millis(5));
    }
}

/// Sends `frame` until the link takes it (backpressure) or refuses it otherwise.
fn send_retrying(link: &ShmLink, frame: &[u8]) -> Result<(), LinkError> {
    loop {
        match link.send(B, frame) {
            Err(LinkError::Congested { .. }) => std::thread::sleep(Duration::from_micros(200)),
            other => return other,
        }
    }
}

#[test]
fn a_killed_peer_is_found_dead_cleaned_up_and_a_restarted_one_works() {
    let fleet = unique_fleet("kill");
    let rec = Arc::new(Recorder::default());
    let a =
        Arc::new(ShmLink::open(config(&fleet, A, ShmSettings::default()), rec.clone()).unwrap());
    let _reader = Reader::start(a.clone());
    let mut child = peer(&fleet, "echo", 16);
    wait_until("B up", Duration::from_secs(5), || {
        rec.has_event(LinkEvent::PeerUp(B))
    });
    // A stream with echoes coming back; B is killed in the middle of it.
    let mut sent = 0;
    for i in 0..=100u32 {
        send_retrying(&a, &i.to_le_bytes()).expect("send to a live peer");
        sent += 1;
    }
    child.kill();
    let echoed = rec.frames();
    assert!(echoed > 0 && echoed <= sent, "{echoed} echoes of {sent}");
    // The survivor notices, cleans up and reports it down; its sends then fail, truthfully.
    wait_until("B down", Duration::from_secs(5), || {
        let _ = a.send(B, b"after");
        rec.has_event(LinkEvent::PeerDown(B))
    });
    match a.send(B, b"to the dead") {
        Err(LinkError::Unreachable { reason, .. }) => {
            assert!(reason.contains('B'), "reason: {reason}")
        }
        other => panic!("a send to a dead, cleaned-up peer: {other:?}"),
    }
    // Its node and ports are gone: nothing in iceoryx2's node list is B's any more.
    // (Its removal may be finishing in another process: any iceoryx2 process removes dead
    // nodes it comes across.)
    let b_name = hetcomm_link_shm::service_name("hetcomm", &fleet, "B");
    wait_until(
        "the dead peer's node removed",
        Duration::from_secs(5),
        || nodes_named(&b_name) == 0,
    );
    // A restarted B takes its place and echoes again.
    let _child = peer(&fleet, "echo", 16);
    wait_until("B up again", Duration::from_secs(5), || {
        rec.events
            .lock()
            .unwrap()
            .iter()
            .filter(|e| **e == LinkEvent::PeerUp(B))
            .count()
            >= 2
    });
    let before = rec.frames();
    send_retrying(&a, b"again").expect("send to the restarted peer");
    wait_until(
        "an echo from the restarted peer",
        Duration::from_secs(5),
        || rec.frames() > before,
    );
    assert_eq!(rec.frames.lock().unwrap().last().unwrap(), b"again");
}

/// Nodes in iceoryx2's list (alive or dead) named `name`.
fn nodes_named(name: &str) -> usize {
    use iceoryx2::node::NodeView;
    use iceoryx2::prelude::*;
    let mut n = 0;
    Node::<hetcomm_link_shm::IpcService>::list(Config::global_config(), |state| {
        let details = match &state {
            NodeState::Alive(v) => v.details().clone(),
            NodeState::Dead(v) => v.details().clone(),
            _ => None,
        };
        if details.is_some_and(|d| d.name().as_str() == name) {
            n += 1;
        }
        CallbackProgression::Continue
    })
    .unwrap();
    n
}

#[test]
fn a_peer_that_never_reads_fills_its_queue_and_every_refusal_is_counted() {
    let fleet = unique_fleet("idle");
    const DEPTH: usize = 8;
    let mut child = peer(&fleet, "idle", DEPTH);
    let settings = ShmSettings {
        queue_depth: DEPTH,
        send_wait_ms: 0,
        ..ShmSettings::default()
    };
    let a = ShmLink::open(config(&fleet, A, settings), Arc::new(Recorder::default())).unwrap();
    let (mut taken, mut refused) = (0, 0);
    for i in 0..(DEPTH as u32 + 20) {
        match a.send(B, &i.to_le_bytes()) {
            Ok(()) => taken += 1,
            Err(LinkError::Congested { reason, .. }) => {
                assert!(reason.contains("full"), "reason: {reason}");
                refused += 1;
            }
            Err(e) => panic!("send {i}: {e}"),
        }
    }
    assert_eq!(taken, DEPTH, "the queue holds exactly queue_depth frames");
    assert_eq!(refused, 20);
    assert_eq!(a.shm_stats().congested, 20);
    assert_eq!(a.stats().frames_dropped, 20);
    assert_eq!(a.stats().frames_sent, DEPTH as u64);
    // With a wait, a send still ends (refused after it), not hangs.
    let started = Instant::now();
    child.kill();
    let _ = a.send(B, b"x");
    assert!(started.elapsed() < Duration::from_secs(5));
}

#[test]
fn a_foreign_service_under_the_name_is_a_clear_error() {
    use iceoryx2::prelude::*;
    let fleet = unique_fleet("foreign");
    let node = NodeBuilder::new()
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<hetcomm_link_shm::IpcService>()
        .unwrap();
    let name = hetcomm_link_shm::service_name("hetcomm", &fleet, "B");
    // Something else uses B's name, with another payload type.
    let _foreign = node
        .service_builder(&ServiceName::new(&name).unwrap())
        .publish_subscribe::<u64>()
        .create()
        .unwrap();
    let err = match ShmLink::open(
        config(&fleet, A, ShmSettings::default()),
        Arc::new(Recorder::default()),
    ) {
        Ok(_) => panic!("opened over a foreign service"),
        Err(e) => e.to_string(),
    };
    assert!(err.contains(&name), "{err}");
    assert!(err.contains("another payload type"), "{err}");
}

#[test]
fn a_foreign_publishers_oversize_samples_are_counted_not_delivered() {
    use iceoryx2::prelude::*;
    let fleet = unique_fleet("oversize");
    let rec = Arc::new(Recorder::default());
    let settings = ShmSettings {
        max_frame: 256,
        initial_frame: 256,
        ..ShmSettings::default()
    };
    let a = Arc::new(ShmLink::open(config(&fleet, A, settings), rec.clone()).unwrap());
    let _reader = Reader::start(a.clone());
    let node = NodeBuilder::new()
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<hetcomm_link_shm::IpcService>()
        .unwrap();
    let sn = ServiceName::new(a.service()).unwrap();
    let service = node
        .service_builder(&sn)
        .publish_subscribe::<[u8]>()
        .open()
        .expect("open A's service as a foreign publisher");
    let publisher = service
        .publisher_builder()
        .initial_max_slice_len(4096)
        .create()
        .unwrap();
    let notifier = node
        .service_builder(&sn)
        .event()
        .open()
        .unwrap()
        .notifier_builder()
        .create()
        .unwrap();
    let big = publisher
        .loan_slice_uninit(1000)
        .unwrap()
        .write_from_fn(|i| i as u8);
    big.send().unwrap();
    let small = publisher
        .loan_slice_uninit(10)
        .unwrap()
        .write_from_fn(|i| i as u8);
    small.send().unwrap();
    notifier.notify().unwrap();
    wait_until("the small sample", Duration::from_secs(5), || {
        rec.frames() == 1
    });
    assert_eq!(rec.frames.lock().unwrap()[0].len(), 10);
    assert_eq!(a.shm_stats().oversize_received, 1);
    assert_eq!(a.stats().frames_dropped, 1);
}
