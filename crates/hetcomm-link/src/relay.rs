//! Relay receipts: what an intermediary between two systems (an MQTT broker) said about a
//! frame a link took.
//!
//! On most links `Ok` from [`Link::send`](crate::Link::send) is all a sender of an
//! unacknowledged message can learn. A link whose frames pass through an intermediary that
//! confirms taking them (a broker's PUBACK at MQTT QoS 1) can say more, a broker round trip
//! later: [`Link::send_relayed`](crate::Link::send_relayed) sends the frame and hands back a
//! [`RelayReceipt`]; the link keeps the matching [`RelayPromise`] and keeps it when the
//! intermediary answers, or breaks it when it cannot (within a bound of its own). A layer that
//! holds a frame before it leaves (the security layer, during a handshake) gives a receipt of
//! its own, kept with the link below's receipt when the frame leaves, or refused when it
//! never does.
//! The runtime turns the [`RelayVerdict`] into the send's outcome. A receipt may be cloned:
//! a broadcast's one frame carries the share of every destination, each of which learns the
//! one verdict.

use parking_lot::Mutex;
use std::sync::Arc;

/// What the intermediary said about one frame.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum RelayVerdict {
    /// It confirmed it has the frame (and will pass it on): not that the destination got it.
    Confirmed,
    /// It said nobody will get the frame: it refused it, or no one is subscribed to its
    /// destination. The text says which, naming the intermediary.
    Refused(String),
    /// No answer came in time, or the connection to it was lost before one did: the frame may
    /// or may not have arrived. The text says why, naming the intermediary.
    Unanswered(String),
    /// The frame left later than the send returned (a layer held it, e.g. for a security
    /// handshake) on a link that confirms nothing: the send is sent without confirmation.
    Left,
}

type Callback = Box<dyn FnOnce(RelayVerdict) + Send>;

enum State {
    /// What the holders of the receipt (and its clones) asked for, in order.
    Waiting(Vec<Callback>),
    Done(RelayVerdict),
}

struct Shared {
    state: Mutex<State>,
}

/// The sender's end: learns the verdict once (each clone once).
#[derive(Clone)]
pub struct RelayReceipt {
    shared: Arc<Shared>,
}

/// The link's end: gives the verdict once. Dropped without one (the link closed), it
/// gives [`RelayVerdict::Unanswered`].
pub struct RelayPromise {
    shared: Option<Arc<Shared>>,
}

/// A receipt and the promise that completes it.
pub fn relay_receipt() -> (RelayReceipt, RelayPromise) {
    let shared = Arc::new(Shared {
        state: Mutex::new(State::Waiting(Vec::new())),
    });
    (
        RelayReceipt {
            shared: shared.clone(),
        },
        RelayPromise {
            shared: Some(shared),
        },
    )
}

impl RelayReceipt {
    /// Calls `then` with the verdict: at once (on this thread) when it is known already,
    /// else on the thread that gives it (the link's).
    pub fn then(self, then: impl FnOnce(RelayVerdict) + Send + 'static) {
        let mut state = self.shared.state.lock();
        match &mut *state {
            State::Done(verdict) => {
                let verdict = verdict.clone();
                drop(state);
                then(verdict);
            }
            State::Waiting(callbacks) => callbacks.push(Box::new(then)),
        }
    }

    /// The verdict, if it is known.
    pub fn verdict(&self) -> Option<RelayVerdict> {
        match &*self.shared.state.lock() {
            State::Done(v) => Some(v.clone()),
            State::Waiting(_) => None,
        }
    }
}

impl RelayPromise {
    /// Gives the verdict (and runs what the receipt's holder asked for, on this thread).
    pub fn keep(mut self, verdict: RelayVerdict) {
        self.give(verdict);
    }

    fn give(&mut self, verdict: RelayVerdict) {
        let Some(shared) = self.shared.take() else {
            return;
        };
        let mut state = shared.state.lock();
        let callbacks = match std::mem::replace(&mut *state, State::Done(verdict.clone())) {
            State::Waiting(callbacks) => callbacks,
            State::Done(_) => Vec::new(),
        };
        drop(state);
        for callback in callbacks {
            callback(verdict.clone());
        }
    }
}

impl Drop for RelayPromise {
    fn drop(&mut self) {
        self.give(RelayVerdict::Unanswered(
            "the link closed before the frame's receipt came".into(),
        ));
    }
}

impl std::fmt::Debug for RelayReceipt {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RelayReceipt")
            .field("verdict", &self.verdict())
            .finish()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::mpsc;

    #[test]
    fn a_verdict_given_before_or_after_the_callback_reaches_it_once() {
        let (receipt, promise) = relay_receipt();
        promise.keep(RelayVerdict::Confirmed);
        let (tx, rx) = mpsc::channel();
        receipt.then(move |v| tx.send(v).unwrap());
        assert_eq!(rx.try_recv().unwrap(), RelayVerdict::Confirmed);

        let (receipt, promise) = relay_receipt();
        let (tx, rx) = mpsc::channel();
        receipt.then(move |v| tx.send(v).unwrap());
        assert!(rx.try_recv().is_err(), "no verdict yet");
        promise.keep(RelayVerdict::Refused("no subscribers".into()));
        assert_eq!(
            rx.try_recv().unwrap(),
            RelayVerdict::Refused("no subscribers".into())
        );
        assert!(rx.try_recv().is_err(), "given once");
    }

    #[test]
    fn every_clone_of_a_receipt_learns_the_one_verdict() {
        let (receipt, promise) = relay_receipt();
        let (tx, rx) = mpsc::channel();
        for share in 0..3 {
            let tx = tx.clone();
            receipt.clone().then(move |v| tx.send((share, v)).unwrap());
        }
        drop(receipt);
        assert!(rx.try_recv().is_err(), "no verdict yet");
        promise.keep(RelayVerdict::Confirmed);
        let got: Vec<_> = rx.try_iter().collect();
        assert_eq!(
            got,
            (0..3)
                .map(|s| (s, RelayVerdict::Confirmed))
                .collect::<Vec<_>>()
        );
    }

    #[test]
    fn a_promise_dropped_unkept_says_unanswered() {
        let (receipt, promise) = relay_receipt();
        drop(promise);
        assert!(matches!(
            receipt.verdict(),
            Some(RelayVerdict::Unanswered(_))
        ));
    }
}
