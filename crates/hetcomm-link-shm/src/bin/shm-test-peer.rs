//! A peer process for the `shm` crate's tests: opens one system's link of a fleet and echoes,
//! ignores, or streams frames, so that tests can kill it, restart it and starve it.
//!
//! `shm-test-peer FLEET LOCAL_ID PEER_ID MODE [QUEUE_DEPTH]`, systems 1 `A`, 2 `B`, 3 `C`:
//! - `echo`: sends every frame it receives back to PEER_ID;
//! - `idle`: never reads (its queue fills);
//!
//! It prints `ready` on stdout once its link is open, then runs until killed.

use std::io::Write;
use std::sync::{Arc, Mutex, OnceLock};

use hetcomm_core::SystemId;
use hetcomm_link::{FrameSink, Link, Peer};
use hetcomm_link_shm::{ShmLink, ShmLinkConfig, ShmSettings};

/// Echoes every frame to the peer, through the link it is set to once that is open.
struct Echo {
    link: OnceLock<Arc<ShmLink>>,
    to: SystemId,
    pending: Mutex<Vec<Vec<u8>>>,
}

impl FrameSink for Echo {
    fn on_frame(&self, frame: &[u8], _from: Peer) {
        // On the reading thread: a send never waits there, so keep what the queue refuses
        // and send it on the next frame or turn.
        let mut pending = self.pending.lock().unwrap();
        pending.push(frame.to_vec());
        if let Some(link) = self.link.get() {
            while let Some(f) = pending.first() {
                if link.send(self.to, f).is_err() {
                    break;
                }
                pending.remove(0);
            }
        }
    }
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if args.len() < 5 {
        eprintln!("usage: shm-test-peer FLEET LOCAL_ID PEER_ID echo|idle [QUEUE_DEPTH]");
        std::process::exit(2);
    }
    let id = |s: &str| SystemId(s.parse().expect("a system id"));
    let (local, peer, mode) = (id(&args[2]), id(&args[3]), args[4].as_str());
    let mut settings = ShmSettings::default();
    if let Some(q) = args.get(5) {
        settings.queue_depth = q.parse().expect("a queue depth");
    }
    let config = ShmLinkConfig {
        local,
        systems: vec![
            (SystemId(1), "A".into()),
            (SystemId(2), "B".into()),
            (SystemId(3), "C".into()),
        ],
        fleet: args[1].clone(),
        settings,
    };
    let echo = Arc::new(Echo {
        link: OnceLock::new(),
        to: peer,
        pending: Mutex::new(Vec::new()),
    });
    let link = match ShmLink::open(config, echo.clone()) {
        Ok(l) => Arc::new(l),
        Err(e) => {
            eprintln!("shm-test-peer: {e}");
            std::process::exit(1);
        }
    };
    let _ = echo.link.set(link.clone());
    println!("ready");
    let _ = std::io::stdout().flush();
    let rx = link.readable().expect("an shm link is driven");
    loop {
        if mode == "idle" {
            std::thread::sleep(std::time::Duration::from_secs(1));
            continue;
        }
        let mut fds = libc::pollfd {
            fd: rx.fd(),
            events: libc::POLLIN,
            revents: 0,
        };
        // SAFETY: one valid pollfd.
        unsafe { libc::poll(&mut fds, 1, 20) };
        let _ = rx.read_ready(64);
        echo.on_frame_flush();
    }
}

impl Echo {
    /// Sends what the queue refused earlier.
    fn on_frame_flush(&self) {
        let mut pending = self.pending.lock().unwrap();
        if let Some(link) = self.link.get() {
            while let Some(f) = pending.first() {
                if link.send(self.to, f).is_err() {
                    break;
                }
                pending.remove(0);
            }
        }
    }
}
