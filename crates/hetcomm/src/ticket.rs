//! Tickets: how a caller learns a send's outcome without being blocked by the send.

use std::sync::{Arc, Condvar, Mutex};
use std::time::{Duration, Instant};

use hetcomm_router::Outcome;

/// Where the runtime puts a send's outcome.
#[derive(Default)]
pub(crate) struct OutcomeSlot {
    outcome: Mutex<Option<Outcome>>,
    ready: Condvar,
}

impl OutcomeSlot {
    pub(crate) fn complete(&self, outcome: Outcome) {
        *self.outcome.lock().unwrap_or_else(|e| e.into_inner()) = Some(outcome);
        self.ready.notify_all();
    }
}

/// The pending outcome of one send. Dropping it is fine: the outcome is still counted in the
/// system's statistics.
#[derive(Clone)]
pub struct Ticket {
    pub(crate) slot: Arc<OutcomeSlot>,
    pub(crate) destination: String,
}

impl std::fmt::Debug for Ticket {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Ticket")
            .field("destination", &self.destination)
            .field("outcome", &self.try_outcome())
            .finish()
    }
}

impl Ticket {
    /// The destination system's name.
    pub fn destination(&self) -> &str {
        &self.destination
    }

    /// The outcome, if the send has ended.
    pub fn try_outcome(&self) -> Option<Outcome> {
        self.slot
            .outcome
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .clone()
    }

    /// Waits for the outcome. Every send ends (the retry budget bounds it), so this returns.
    pub fn wait(&self) -> Outcome {
        let mut o = self.slot.outcome.lock().unwrap_or_else(|e| e.into_inner());
        loop {
            if let Some(outcome) = o.as_ref() {
                return outcome.clone();
            }
            o = self.slot.ready.wait(o).unwrap_or_else(|e| e.into_inner());
        }
    }

    /// Waits up to `timeout` for the outcome.
    pub fn wait_timeout(&self, timeout: Duration) -> Option<Outcome> {
        let deadline = Instant::now() + timeout;
        let mut o = self.slot.outcome.lock().unwrap_or_else(|e| e.into_inner());
        loop {
            if let Some(outcome) = o.as_ref() {
                return Some(outcome.clone());
            }
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return None;
            }
            o = self
                .slot
                .ready
                .wait_timeout(o, left)
                .unwrap_or_else(|e| e.into_inner())
                .0;
        }
    }
}

/// The pending outcomes of one broadcast: one ticket per destination the table allows.
#[derive(Debug)]
pub struct BroadcastTicket {
    pub(crate) tickets: Vec<Ticket>,
}

impl BroadcastTicket {
    /// One ticket per destination.
    pub fn tickets(&self) -> &[Ticket] {
        &self.tickets
    }

    /// Waits for every destination's outcome: (destination name, outcome).
    pub fn wait(&self) -> Vec<(String, Outcome)> {
        self.tickets
            .iter()
            .map(|t| (t.destination.clone(), t.wait()))
            .collect()
    }
}
