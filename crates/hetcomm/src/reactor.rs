//! Caller-driven receiving: the thread that waits for a message reads the socket itself.
//!
//! A link that offers a [`Readable`](hetcomm_link::Readable) receive side (UDP, TCP) starts no
//! receive thread of its own; nor does a link under layers (an `emulated` transport over UDP
//! or TCP), whose wrappers offer the receive side of the link they wrap.
//! Instead, one thread at a time *leads*: it blocks in `poll(2)` on every such link's
//! descriptor and reads what arrives, handing frames to the router, which puts messages into
//! inboxes. A module waiting in `recv` with an empty inbox becomes the leader when nobody
//! else is, so a message addressed to it is read and queued by its own thread and taken
//! without any hand-off: the only wake-up is the kernel's, as for a raw socket. (A wake-up
//! that crosses CPUs costs tens of microseconds on small VMs, more than the rest of the path.)
//!
//! When no module has led for [`LINGER`] (checked at least every 10 ms while one leads), a
//! background thread per system leads instead, so acknowledgements, callbacks and messages
//! for modules that are busy elsewhere keep flowing.
//! A module that wants to lead while the background thread does asks it to step aside
//! (through the wake descriptor) and meanwhile waits on its inbox as usual.
//!
//! A leader blocked in `poll` must also notice a message put into its inbox by another
//! thread (an in-process sender, a TCP reader thread): the runtime then writes to the wake
//! descriptor, an `eventfd` ([`WakeFd`]).

use parking_lot::{Condvar, Mutex, MutexGuard};
use std::cell::Cell;
use std::io;
use std::sync::{Arc, Weak};
use std::time::{Duration, Instant};

use hetcomm_link::readiness::{readable_fd, timespec, WakeFd};
use hetcomm_link::Link;
use rustix::event::{poll, PollFd, PollFlags};

/// How long after a module last led the background thread waits before it leads again: a
/// module that loops over `recv` comes back within microseconds and should find the
/// leadership free.
pub(crate) const LINGER: Duration = Duration::from_millis(2);

/// The longest a leader blocks in one `poll`, so that link upkeep (expiring partial messages)
/// runs and shutdown is noticed even if a wake-up were lost.
const MAX_TURN: Duration = Duration::from_millis(100);

/// Datagrams read per link per turn before the leader looks at its inbox again.
const BUDGET: usize = 64;

thread_local! {
    /// Set while this thread reads links as the leader: messages it queues need no wake-up
    /// (it checks its inbox after the turn).
    static LEADING: Cell<bool> = const { Cell::new(false) };
}

/// Whether the calling thread is reading links as a leader right now.
pub(crate) fn leading_here() -> bool {
    LEADING.with(Cell::get)
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Leader {
    Background,
    Module,
}

struct State {
    leader: Option<Leader>,
    /// A module asked the background leader to step aside.
    wanted: bool,
    /// When a module last stopped leading.
    last_module_turn: Instant,
    /// Modules waiting on their inbox while someone else leads.
    followers: usize,
    shutdown: bool,
}

/// The leader protocol of one system; see the module docs.
pub(crate) struct Reactor {
    links: Vec<Arc<dyn Link>>,
    wake: WakeFd,
    state: Mutex<State>,
    /// The background thread waits here while modules lead.
    idle: Condvar,
}

impl Reactor {
    /// A reactor over the links that offer a readable side, or None when there are none.
    pub(crate) fn new(links: &[Arc<dyn Link>]) -> io::Result<Option<Arc<Reactor>>> {
        let links: Vec<_> = links
            .iter()
            .filter(|l| l.readable().is_some())
            .cloned()
            .collect();
        if links.is_empty() {
            return Ok(None);
        }
        let wake = WakeFd::new()?;
        Ok(Some(Arc::new(Reactor {
            links,
            wake,
            state: Mutex::new(State {
                leader: None,
                wanted: false,
                last_module_turn: Instant::now(),
                followers: 0,
                shutdown: false,
            }),
            idle: Condvar::new(),
        })))
    }

    fn lock(&self) -> MutexGuard<'_, State> {
        self.state.lock()
    }

    /// Interrupts the leader's `poll`.
    pub(crate) fn kick(&self) {
        self.wake.wake();
    }

    /// A module's thread asks to lead. True: it leads until [`Reactor::end_module_turn`].
    /// False: someone else leads (if it is the background thread, it is asked to step
    /// aside); wait on the inbox and ask again.
    pub(crate) fn try_lead(&self) -> bool {
        let mut s = self.lock();
        if s.shutdown {
            return false;
        }
        match s.leader {
            None => {
                s.leader = Some(Leader::Module);
                true
            }
            Some(Leader::Background) => {
                if !s.wanted {
                    s.wanted = true;
                    drop(s);
                    self.kick();
                }
                false
            }
            Some(Leader::Module) => false,
        }
    }

    /// The leading module is done.
    pub(crate) fn end_module_turn(&self) {
        let mut s = self.lock();
        s.leader = None;
        if s.followers == 0 {
            s.last_module_turn = Instant::now();
            // The background thread notices on its own (it re-checks every LINGER): no
            // signal, since a module that loops over `recv` comes back at once.
            return;
        }
        // Other modules wait on their inboxes: the background thread must read for them now.
        s.last_module_turn = Instant::now() - LINGER;
        drop(s);
        self.idle.notify_one();
    }

    /// A module starts (`true`) or stops waiting on its inbox while someone else leads.
    pub(crate) fn follow(&self, waiting: bool) {
        let mut s = self.lock();
        if waiting {
            s.followers += 1;
        } else {
            s.followers -= 1;
        }
    }

    /// Blocks up to `timeout` in `poll` on the links and the wake descriptor, then reads
    /// whatever is ready. Only the leader calls this.
    pub(crate) fn turn(&self, timeout: Duration) {
        let timeout = timeout.min(MAX_TURN);
        // Round up so that a sub-millisecond timeout still waits rather than spins.
        let ms = timeout.as_micros().div_ceil(1000).min(i32::MAX as u128) as u64;
        self.turn_ms(ms, true);
    }

    /// A leader starts (`true`) or stops spinning over the links: each is told
    /// ([`Readable::set_spinning`](hetcomm_link::Readable::set_spinning)), so that senders
    /// that would wake it may skip that while it spins.
    pub(crate) fn set_spinning(&self, spinning: bool) {
        for l in &self.links {
            if let Some(r) = l.readable() {
                r.set_spinning(spinning);
            }
        }
    }

    /// One look of a spinning leader: reads the links that can say without a system call
    /// that something waits ([`Readable::pending`](hetcomm_link::Readable::pending)), and
    /// polls, without waiting, the descriptors of the others (none: no system call at all).
    pub(crate) fn poll_spinning(&self) {
        let mut undecided = false;
        LEADING.with(|l| l.set(true));
        for r in self.links.iter().filter_map(|l| l.readable()) {
            match r.pending() {
                Some(true) => {
                    let _ = r.read_ready(BUDGET);
                }
                Some(false) => {}
                None => undecided = true,
            }
        }
        LEADING.with(|l| l.set(false));
        if undecided {
            self.turn_filtered(0, false, true);
        }
    }

    /// Waits up to `ms` for a link to become readable and reads what is ready; with `upkeep`,
    /// a wait that ends without anything ready still lets every link do its upkeep.
    fn turn_ms(&self, ms: u64, upkeep: bool) {
        self.turn_filtered(ms, upkeep, false);
    }

    /// [`turn_ms`](Reactor::turn_ms); with `undecided_only`, over only the links that cannot
    /// tell without their descriptor whether something waits (`pending` is None).
    fn turn_filtered(&self, ms: u64, upkeep: bool, undecided_only: bool) {
        let mut fds: smallvec::SmallVec<[PollFd<'_>; 4]> = smallvec::SmallVec::new();
        let mut polled: smallvec::SmallVec<[&dyn hetcomm_link::Readable; 4]> =
            smallvec::SmallVec::new();
        fds.push(PollFd::new(&self.wake, PollFlags::IN));
        for r in self.links.iter().filter_map(|l| l.readable()) {
            if undecided_only && r.pending().is_some() {
                continue;
            }
            fds.push(PollFd::from_borrowed_fd(readable_fd(r), PollFlags::IN));
            polled.push(r);
        }
        let timeout = timespec(Duration::from_millis(ms));
        let Ok(n) = poll(&mut fds, Some(&timeout)) else {
            // EINTR and the like: the caller simply takes another turn.
            return;
        };
        if !fds[0].revents().is_empty() {
            self.wake.drain();
        }
        LEADING.with(|l| l.set(true));
        for (r, fd) in polled.iter().zip(&fds[1..]) {
            // On a timeout every link still gets its upkeep.
            if (n == 0 && upkeep) || !fd.revents().is_empty() {
                let _ = r.read_ready(BUDGET);
            }
        }
        LEADING.with(|l| l.set(false));
    }

    /// Stops the background thread and any leader.
    pub(crate) fn shutdown(&self) {
        self.lock().shutdown = true;
        self.idle.notify_all();
        self.kick();
    }

    /// The background leader: leads whenever no module has led for [`LINGER`], until
    /// shutdown or until the system is gone.
    pub(crate) fn run_background(self: Arc<Self>, alive: Weak<crate::runtime::SystemCore>) {
        loop {
            if alive.strong_count() == 0 {
                return;
            }
            let mut s = self.lock();
            if s.shutdown {
                return;
            }
            let quiet = s.last_module_turn.elapsed();
            if s.leader.is_some() || quiet < LINGER {
                // While a module leads, look back now and then (it may have gone off to do
                // other work); once it stopped, take over when the linger time is up.
                let wait = if s.leader.is_some() {
                    Duration::from_millis(10)
                } else {
                    LINGER.saturating_sub(quiet).max(Duration::from_micros(200))
                };
                self.idle.wait_for(&mut s, wait);
                drop(s);
                continue;
            }
            s.leader = Some(Leader::Background);
            s.wanted = false;
            drop(s);
            loop {
                self.turn(MAX_TURN);
                let s = self.lock();
                if s.wanted || s.shutdown || alive.strong_count() == 0 {
                    break;
                }
            }
            let mut s = self.lock();
            s.leader = None;
            s.wanted = false;
            // Give the module that asked a head start.
            s.last_module_turn = Instant::now();
        }
    }
}
