//! A link's frames into the system: the sink each link delivers to, and the frames held for
//! the router while the system opens.

use super::*;

/// Most frames held while a system opens ([`Opening`]); later ones are dropped and counted.
pub(crate) const OPENING_BACKLOG_FRAMES: usize = 4096;
/// Most bytes held while a system opens ([`Opening`]); frames past it are dropped and
/// counted.
pub(crate) const OPENING_BACKLOG_BYTES: usize = 16 << 20;

/// Frames that arrive between a link's opening and the system's start.
///
/// Links are opened with their sink and may deliver at once (a receive thread, or another
/// system of this process sending in-process), but the router is built only after every link
/// is open (its routes need the links' frame limits). Frames that arrive meanwhile are held
/// here, bounded, and handed to the router when the system starts ([`SystemCore::start`]);
/// what does not fit is counted per link, in that link's `frames_dropped`
/// ([`crate::SystemStats::links`]).
#[derive(Default)]
pub(crate) struct Opening {
    /// Set once the held frames went to the router: from then on frames go there directly.
    ready: AtomicBool,
    backlog: Mutex<Backlog>,
}

#[derive(Default)]
struct Backlog {
    frames: Vec<HeldFrame>,
    bytes: usize,
    /// Per link index: frames dropped because the backlog was full.
    dropped: Vec<u64>,
}

/// A frame held while the system opens, with when it arrived.
struct HeldFrame {
    link: usize,
    peer: Option<SystemId>,
    at: Time,
    bytes: Held,
}

enum Held {
    Copied(Vec<u8>),
    Owned(FrameBuf),
}

impl Held {
    fn len(&self) -> usize {
        match self {
            Held::Copied(v) => v.len(),
            Held::Owned(f) => f.len(),
        }
    }
}

impl Opening {
    /// Whether frames go to the router now.
    fn is_ready(&self) -> bool {
        self.ready.load(Ordering::Acquire)
    }

    /// Frames dropped on link `link` because they arrived while the system opened and did
    /// not fit the backlog.
    pub(crate) fn dropped(&self, link: usize) -> u64 {
        let backlog = self.backlog.lock();
        backlog.dropped.get(link).copied().unwrap_or(0)
    }

    /// Holds the frames `make` gives unless the system is ready; false (and nothing held) if
    /// it is, so the caller hands them to the router itself.
    fn hold(
        &self,
        link: usize,
        peer: Option<SystemId>,
        at: Time,
        make: impl FnOnce(&mut dyn FnMut(Held)),
    ) -> bool {
        let mut backlog = self.backlog.lock();
        // Checked again under the lock: `release` sets `ready` under it, once it is empty.
        if self.is_ready() {
            return false;
        }
        let backlog = &mut *backlog;
        make(&mut |bytes: Held| {
            let len = bytes.len();
            if backlog.frames.len() < OPENING_BACKLOG_FRAMES
                && backlog.bytes + len <= OPENING_BACKLOG_BYTES
            {
                backlog.bytes += len;
                backlog.frames.push(HeldFrame {
                    link,
                    peer,
                    at,
                    bytes,
                });
            } else {
                if backlog.dropped.len() <= link {
                    backlog.dropped.resize(link + 1, 0);
                }
                backlog.dropped[link] += 1;
            }
        });
        true
    }
}

impl SystemCore {
    /// Hands the frames held while the system opened to its router, in the order they came,
    /// and from then on lets frames go to the router directly. Called by `start` once the
    /// router and the links are in place.
    pub(super) fn release_opening_backlog(&self) {
        loop {
            let held = {
                let mut backlog = self.opening.backlog.lock();
                if backlog.frames.is_empty() {
                    // Under the lock, so no frame can be held after the last batch was taken.
                    self.opening.ready.store(true, Ordering::Release);
                    return;
                }
                backlog.bytes = 0;
                std::mem::take(&mut backlog.frames)
            };
            // Not under the backlog lock: what these frames cause may send, and an in-process
            // peer's answer may come back into this system's sink on this thread.
            let mut router = self.router();
            for f in held {
                match f.bytes {
                    Held::Copied(bytes) => router.handle_frame_from(f.at, f.link, f.peer, &bytes),
                    Held::Owned(frame) => {
                        router.handle_frame_owned_from(f.at, f.link, f.peer, frame)
                    }
                }
            }
            self.pump(router);
        }
    }
}

/// What link number `link` of a system hands its frames to.
pub(super) struct SystemSink {
    pub(super) core: Weak<SystemCore>,
    pub(super) link: usize,
}

impl SystemSink {
    /// Gives arriving frames to the open system's router (`handle`, with one clock reading),
    /// then carries out what they caused; while the system is still opening, `hold` keeps
    /// them for the router instead ([`Opening`]).
    fn handle(
        &self,
        peer: Option<SystemId>,
        hold: impl FnOnce(&mut dyn FnMut(Held)),
        handle: impl FnOnce(&mut Router<Arc<OutcomeSlot>>, Time),
    ) {
        let Some(core) = self.core.upgrade() else {
            return;
        };
        if core.is_closed() {
            return;
        }
        let now = core.clock.now();
        if !core.opening.is_ready() && core.opening.hold(self.link, peer, now, hold) {
            return;
        }
        let mut router = core.router();
        handle(&mut router, now);
        core.pump_at(router, now);
    }
}

/// The system a link saw a frame come from, as the router takes it.
fn peer_system(from: Peer) -> Option<SystemId> {
    match from {
        Peer::System(id) => Some(id),
        Peer::Unknown => None,
    }
}

impl FrameSink for SystemSink {
    fn on_frame(&self, frame: &[u8], from: Peer) {
        self.on_frames(&mut std::iter::once(frame), from);
    }

    /// The frames of one batch datagram: one clock reading, one router lock and one pump for
    /// all of them instead of one each (they arrived at the same moment).
    fn on_frames(&self, frames: &mut dyn Iterator<Item = &[u8]>, from: Peer) {
        let peer = peer_system(from);
        // One of the two closures runs; both need the frames.
        let frames = std::cell::RefCell::new(frames);
        self.handle(
            peer,
            |keep| {
                for frame in &mut *frames.borrow_mut() {
                    keep(Held::Copied(frame.to_vec()));
                }
            },
            |router, now| {
                for frame in &mut *frames.borrow_mut() {
                    router.handle_frame_from(now, self.link, peer, frame);
                }
            },
        );
    }

    /// A large frame in a buffer of its own: the router delivers its payload in that buffer.
    fn on_frame_owned(&self, frame: FrameBuf, from: Peer) {
        let peer = peer_system(from);
        let frame = std::cell::Cell::new(Some(frame));
        self.handle(
            peer,
            |keep| {
                if let Some(f) = frame.take() {
                    keep(Held::Owned(f));
                }
            },
            |router, now| {
                if let Some(f) = frame.take() {
                    router.handle_frame_owned_from(now, self.link, peer, f);
                }
            },
        );
    }

    fn takes_frames(&self) -> bool {
        true
    }

    /// What the link knows of a peer, for the router: a peer up (a connection, or a security
    /// session: sends that waited for it go now) or lost (its sends fail over to the pair's
    /// next transport, docs/failover.md).
    fn on_event(&self, event: hetcomm_link::LinkEvent) {
        let Some(core) = self.core.upgrade() else {
            return;
        };
        // Before the system starts nothing can wait for a session (no send was made yet),
        // and every path starts up: the event has nothing to tell.
        if core.is_closed() || !core.opening.is_ready() {
            return;
        }
        let now = core.clock.now();
        let mut router = core.router();
        let link = self.link;
        let event = match event {
            hetcomm_link::LinkEvent::PeerUp(peer) => {
                hetcomm_router::LinkEvent::PeerUp { link, peer }
            }
            hetcomm_link::LinkEvent::PeerDown(peer) => {
                hetcomm_router::LinkEvent::PeerDown { link, peer }
            }
            _ => return,
        };
        router.handle_link_event(now, event);
        core.pump_at(router, now);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Holds `n` copied frames of `len` bytes on `link` while not ready.
    fn hold_copies(opening: &Opening, link: usize, n: usize, len: usize) {
        for _ in 0..n {
            assert!(
                opening.hold(link, None, Time::ZERO, |keep| keep(Held::Copied(vec![
                    0;
                    len
                ])))
            );
        }
    }

    #[test]
    fn the_backlog_holds_its_bound_and_counts_the_rest_per_link() {
        let opening = Opening::default();
        hold_copies(&opening, 1, OPENING_BACKLOG_FRAMES - 1, 10);
        hold_copies(&opening, 0, 3, 10);
        assert_eq!(opening.dropped(0), 2, "one fitted, two did not");
        assert_eq!(opening.dropped(1), 0);
        // Bytes bound: a frame past it is dropped however few frames are held.
        let opening = Opening::default();
        hold_copies(&opening, 0, 1, OPENING_BACKLOG_BYTES);
        hold_copies(&opening, 0, 1, 1);
        assert_eq!(opening.dropped(0), 1);
    }

    #[test]
    fn once_ready_nothing_is_held() {
        let opening = Opening::default();
        opening.ready.store(true, Ordering::Release);
        let mut made = false;
        assert!(!opening.hold(0, None, Time::ZERO, |_| made = true));
        assert!(!made, "frames for the router were taken by the backlog");
    }
}
