//! Who is on the Zenoh network, from liveliness tokens: the table sends consult, and a feed of
//! joins and leaves for tools.

use parking_lot::{Condvar, Mutex};
use std::collections::HashMap;
use std::sync::mpsc;
use std::time::{Duration, Instant};

use hetcomm_core::SystemId;

/// What a link knows of a system's presence.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Seen {
    /// Its token has never been seen.
    Never,
    /// Its token is there.
    Present,
    /// Its token was there and has gone.
    Left,
}

/// A system joining or leaving the Zenoh network.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PresenceEvent {
    /// Its liveliness token appeared.
    Joined(SystemId),
    /// Its liveliness token went away (it closed, or Zenoh lost it).
    Left(SystemId),
}

/// Joins and leaves, in the order the link saw them ([`crate::ZenohLink::presence_events`]).
pub struct PresenceEvents {
    rx: mpsc::Receiver<PresenceEvent>,
}

impl PresenceEvents {
    /// The next event, waiting at most `timeout`; None if there was none (or the link closed).
    pub fn recv_timeout(&self, timeout: Duration) -> Option<PresenceEvent> {
        self.rx.recv_timeout(timeout).ok()
    }

    /// The next event if one is waiting.
    pub fn try_recv(&self) -> Option<PresenceEvent> {
        self.rx.try_recv().ok()
    }
}

/// Feeds of every link of the process ([`watch_all`]): the local system and the change.
static EVERY_LINK: Mutex<Vec<mpsc::Sender<(SystemId, PresenceEvent)>>> = Mutex::new(Vec::new());

/// Joins and leaves seen by every `zenoh` link of this process from now on, each with the
/// system whose link saw it (what `hetcomm listen` prints).
pub fn watch_all() -> mpsc::Receiver<(SystemId, PresenceEvent)> {
    let (tx, rx) = mpsc::channel();
    EVERY_LINK.lock().push(tx);
    rx
}

#[derive(Default)]
struct State {
    seen: HashMap<SystemId, Seen>,
    /// When a send first waited for a system never seen.
    first_wait: HashMap<SystemId, Instant>,
    joins: u64,
    listeners: Vec<mpsc::Sender<PresenceEvent>>,
    closed: bool,
}

/// The presence table of one link, written by its liveliness subscriber.
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

    /// Records a token appearing (`Present`) or going (`Left`); what changed, if anything.
    pub(crate) fn set(&self, id: SystemId, now: Seen) -> Option<PresenceEvent> {
        let mut st = self.lock();
        let before = st.seen.insert(id, now).unwrap_or(Seen::Never);
        if before == now {
            return None;
        }
        let event = match now {
            Seen::Present => {
                st.joins += 1;
                PresenceEvent::Joined(id)
            }
            _ => PresenceEvent::Left(id),
        };
        st.listeners.retain(|l| l.send(event).is_ok());
        drop(st);
        EVERY_LINK
            .lock()
            .retain(|l| l.send((self.local, event)).is_ok());
        self.changed.notify_all();
        Some(event)
    }

    /// `id`'s presence. A token never seen is waited for until `grace` after the first send
    /// that asked (discovery may still be going on); after that, not seen means absent at
    /// once, so a system that is not there holds a caller (or the router's timer) only once.
    pub(crate) fn wait_present(&self, id: SystemId, grace: Duration) -> Seen {
        let mut st = self.lock();
        let deadline = *st.first_wait.entry(id).or_insert_with(Instant::now) + grace;
        loop {
            let seen = st.seen.get(&id).copied().unwrap_or(Seen::Never);
            if seen != Seen::Never || st.closed {
                return seen;
            }
            let now = Instant::now();
            if now >= deadline {
                return Seen::Never;
            }
            self.changed.wait_for(&mut st, deadline - now);
        }
    }

    /// `id`'s presence now, without waiting or starting a wait.
    pub(crate) fn peek(&self, id: SystemId) -> Seen {
        self.lock().seen.get(&id).copied().unwrap_or(Seen::Never)
    }

    /// The systems present now, by id.
    pub(crate) fn present(&self) -> Vec<SystemId> {
        let mut ids: Vec<SystemId> = self
            .lock()
            .seen
            .iter()
            .filter(|(_, s)| **s == Seen::Present)
            .map(|(id, _)| *id)
            .collect();
        ids.sort_unstable();
        ids
    }

    /// Times a system's token appeared.
    pub(crate) fn joins(&self) -> u64 {
        self.lock().joins
    }

    /// A feed of the changes from now on.
    pub(crate) fn events(&self) -> PresenceEvents {
        let (tx, rx) = mpsc::channel();
        self.lock().listeners.push(tx);
        PresenceEvents { rx }
    }

    /// Wakes waiting sends (the link is closing) and ends the feeds.
    pub(crate) fn close(&self) {
        let mut st = self.lock();
        st.closed = true;
        st.listeners.clear();
        drop(st);
        self.changed.notify_all();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_token_seen_then_gone_is_left_and_events_follow() {
        let p = Presence::new(SystemId(0));
        let events = p.events();
        assert_eq!(p.wait_present(SystemId(1), Duration::ZERO), Seen::Never);
        p.set(SystemId(1), Seen::Present);
        p.set(SystemId(1), Seen::Present); // a duplicate report changes nothing
        assert_eq!(p.present(), [SystemId(1)]);
        p.set(SystemId(1), Seen::Left);
        assert_eq!(p.wait_present(SystemId(1), Duration::ZERO), Seen::Left);
        assert_eq!(p.present(), []);
        assert_eq!(events.try_recv(), Some(PresenceEvent::Joined(SystemId(1))));
        assert_eq!(events.try_recv(), Some(PresenceEvent::Left(SystemId(1))));
        assert_eq!(events.try_recv(), None);
        assert_eq!(p.joins(), 1);
    }

    #[test]
    fn a_token_never_seen_is_waited_for_once() {
        let p = Presence::new(SystemId(0));
        let started = Instant::now();
        assert_eq!(
            p.wait_present(SystemId(3), Duration::from_millis(30)),
            Seen::Never
        );
        assert!(started.elapsed() >= Duration::from_millis(30));
        let again = Instant::now();
        assert_eq!(
            p.wait_present(SystemId(3), Duration::from_millis(30)),
            Seen::Never
        );
        assert!(again.elapsed() < Duration::from_millis(10));
    }

    #[test]
    fn a_waiting_send_wakes_when_the_token_appears() {
        let p = std::sync::Arc::new(Presence::new(SystemId(0)));
        let q = p.clone();
        let t = std::thread::spawn(move || q.wait_present(SystemId(2), Duration::from_secs(10)));
        std::thread::sleep(Duration::from_millis(20));
        p.set(SystemId(2), Seen::Present);
        assert_eq!(t.join().unwrap(), Seen::Present);
    }
}
