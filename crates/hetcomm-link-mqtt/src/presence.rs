//! Who is online, from the retained presence messages and last wills on
//! `PREFIX/FLEET/@presence/<System>`: the table sends consult, and a feed of joins and leaves
//! for tools.

use parking_lot::{Condvar, Mutex};
use std::collections::HashMap;
use std::sync::mpsc;
use std::time::{Duration, Instant};

use hetcomm_core::SystemId;

/// A system's last presence message.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Announced {
    /// `online`: its link is open and subscribed.
    Online,
    /// `offline`: its link closed.
    Offline,
    /// `lost`: its last will, published by the broker when its connection broke.
    Lost,
}

impl Announced {
    /// The payload that says it.
    pub fn payload(self) -> &'static [u8] {
        match self {
            Announced::Online => b"online",
            Announced::Offline => b"offline",
            Announced::Lost => b"lost",
        }
    }

    /// The presence a payload says, if it is one.
    pub fn from_payload(payload: &[u8]) -> Option<Announced> {
        [Announced::Online, Announced::Offline, Announced::Lost]
            .into_iter()
            .find(|a| a.payload() == payload)
    }
}

/// A system coming or going, as one link saw it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PresenceEvent {
    /// It announced itself online.
    Joined(SystemId),
    /// It announced itself offline, or the broker published its last will.
    Left(SystemId),
}

/// Feeds of every link of the process ([`watch_all`]).
static EVERY_LINK: Mutex<Vec<mpsc::Sender<(SystemId, PresenceEvent)>>> = Mutex::new(Vec::new());

/// Joins and leaves seen by every `mqtt` link of this process from now on, each with the
/// system whose link saw it (what `hetcomm listen` prints).
pub fn watch_all() -> mpsc::Receiver<(SystemId, PresenceEvent)> {
    let (tx, rx) = mpsc::channel();
    EVERY_LINK.lock().push(tx);
    rx
}

/// What a send may do now towards a system.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Verdict {
    /// It is online.
    Go,
    /// It went away while this link watched (`Offline` or `Lost`): fail at once.
    Gone(Announced),
    /// Not online, and the wait for it ran out (never announced, or only a retained
    /// `offline`/`lost` from before this link subscribed).
    NotAnnounced(Option<Announced>),
}

#[derive(Clone, Copy)]
struct Entry {
    announced: Announced,
    /// Heard as it happened (not a retained message replayed on subscribing).
    live: bool,
}

#[derive(Default)]
struct State {
    seen: HashMap<SystemId, Entry>,
    first_wait: HashMap<SystemId, Instant>,
    closed: bool,
}

/// The presence table of one link, written by its event loop.
pub(crate) struct Presence {
    local: SystemId,
    state: Mutex<State>,
    changed: Condvar,
}

impl Presence {
    pub(crate) fn new(local: SystemId) -> Presence {
        Presence {
            local,
            state: Mutex::new(State::default()),
            changed: Condvar::new(),
        }
    }

    fn lock(&self) -> parking_lot::MutexGuard<'_, State> {
        self.state.lock()
    }

    /// Records `id`'s announcement; what changed, if anything: `Joined` when it came online,
    /// `Left` when it went away while this link watched (`live`, or it was online).
    pub(crate) fn set(
        &self,
        id: SystemId,
        announced: Announced,
        live: bool,
    ) -> Option<PresenceEvent> {
        let mut st = self.lock();
        let before = st.seen.insert(id, Entry { announced, live });
        let was_online = before.is_some_and(|e| e.announced == Announced::Online);
        let is_online = announced == Announced::Online;
        if was_online == is_online {
            return None;
        }
        drop(st);
        self.changed.notify_all();
        // A retained `offline` replayed on subscribing is no news of a leave.
        if !(is_online || live || was_online) {
            return None;
        }
        let event = match is_online {
            true => PresenceEvent::Joined(id),
            false => PresenceEvent::Left(id),
        };
        EVERY_LINK
            .lock()
            .retain(|l| l.send((self.local, event)).is_ok());
        Some(event)
    }

    /// Whether a send to `id` may go. One that went away while watched fails at once; one not
    /// online otherwise is waited for until `grace` after the first send that asked, then
    /// fails at once too until it announces itself.
    pub(crate) fn verdict(&self, id: SystemId, grace: Duration, wait: bool) -> Verdict {
        let mut st = self.lock();
        let deadline = *st.first_wait.entry(id).or_insert_with(Instant::now) + grace;
        loop {
            match st.seen.get(&id) {
                Some(e) if e.announced == Announced::Online => return Verdict::Go,
                Some(e) if e.live => return Verdict::Gone(e.announced),
                _ => {}
            }
            let now = Instant::now();
            if !wait || st.closed || now >= deadline {
                return Verdict::NotAnnounced(st.seen.get(&id).map(|e| e.announced));
            }
            self.changed.wait_for(&mut st, deadline - now);
        }
    }

    /// The systems online now, by id.
    pub(crate) fn online(&self) -> Vec<SystemId> {
        let mut ids: Vec<SystemId> = self
            .lock()
            .seen
            .iter()
            .filter(|(_, e)| e.announced == Announced::Online)
            .map(|(id, _)| *id)
            .collect();
        ids.sort_unstable();
        ids
    }

    /// Forgets what every system announced: the broker this link reconnected to kept no
    /// session, so its retained messages may be gone too (a restart without persistence), and
    /// each system's presence is learned again, from the retained messages replayed on
    /// subscribing or from the system announcing itself when it reconnects. Until then a send
    /// waits for it as for a system never seen, rather than publishing to a topic nobody may be
    /// subscribed to yet.
    pub(crate) fn forget_all(&self) {
        let mut st = self.lock();
        st.seen.clear();
        st.first_wait.clear();
    }

    /// Wakes waiting sends: the link is closing.
    pub(crate) fn close(&self) {
        self.lock().closed = true;
        self.changed.notify_all();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const B: SystemId = SystemId(2);

    #[test]
    fn a_live_leave_fails_at_once_and_a_retained_one_is_waited_out() {
        let p = Presence::new(SystemId(1));
        // A retained `offline` from before: no news.
        assert_eq!(p.set(B, Announced::Offline, false), None);
        let started = Instant::now();
        assert_eq!(
            p.verdict(B, Duration::from_millis(30), true),
            Verdict::NotAnnounced(Some(Announced::Offline))
        );
        assert!(started.elapsed() >= Duration::from_millis(30));
        assert_eq!(
            p.set(B, Announced::Online, true),
            Some(PresenceEvent::Joined(B))
        );
        assert_eq!(p.verdict(B, Duration::ZERO, true), Verdict::Go);
        assert_eq!(p.online(), [B]);
        assert_eq!(
            p.set(B, Announced::Lost, true),
            Some(PresenceEvent::Left(B))
        );
        let started = Instant::now();
        assert_eq!(
            p.verdict(B, Duration::from_secs(5), true),
            Verdict::Gone(Announced::Lost)
        );
        assert!(started.elapsed() < Duration::from_millis(100));
    }

    #[test]
    fn a_waiting_send_wakes_when_the_system_comes_online() {
        let p = std::sync::Arc::new(Presence::new(SystemId(1)));
        let q = p.clone();
        let t = std::thread::spawn(move || q.verdict(B, Duration::from_secs(10), true));
        std::thread::sleep(Duration::from_millis(20));
        p.set(B, Announced::Online, true);
        assert_eq!(t.join().unwrap(), Verdict::Go);
    }

    #[test]
    fn payloads_round_trip() {
        for a in [Announced::Online, Announced::Offline, Announced::Lost] {
            assert_eq!(Announced::from_payload(a.payload()), Some(a));
        }
        assert_eq!(Announced::from_payload(b"garbage"), None);
    }
}
