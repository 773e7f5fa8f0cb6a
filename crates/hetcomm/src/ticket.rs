//! Tickets: how a caller learns a send's outcome without being blocked by the send.

use parking_lot::{Condvar, Mutex};
use std::sync::Arc;
use std::time::{Duration, Instant};

use hetcomm_router::Outcome;

/// Where the runtime puts a send's outcome.
#[derive(Default)]
pub(crate) struct OutcomeSlot {
    state: Mutex<SlotState>,
    ready: Condvar,
}

#[derive(Default)]
struct SlotState {
    outcome: Option<Outcome>,
    /// The transport that carried it (see [`Ticket::transport`]).
    transport: Option<&'static str>,
    /// Threads in `wait`: most tickets are never waited on, and signalling the condition
    /// variable is a system call, so it is only signalled when someone waits.
    waiters: usize,
}

impl OutcomeSlot {
    pub(crate) fn complete(&self, outcome: Outcome, transport: Option<&'static str>) {
        let mut s = self.lock();
        s.outcome = Some(outcome);
        s.transport = transport;
        if s.waiters > 0 {
            self.ready.notify_all();
        }
    }

    fn lock(&self) -> parking_lot::MutexGuard<'_, SlotState> {
        self.state.lock()
    }

    /// Waits for the outcome until `deadline` (None: forever).
    fn wait_until(&self, deadline: Option<Instant>) -> Option<Outcome> {
        let mut s = self.lock();
        loop {
            if let Some(outcome) = s.outcome.as_ref() {
                return Some(outcome.clone());
            }
            s.waiters += 1;
            match deadline {
                None => self.ready.wait(&mut s),
                Some(d) => {
                    let left = d.saturating_duration_since(Instant::now());
                    if left.is_zero() {
                        s.waiters -= 1;
                        return None;
                    }
                    self.ready.wait_for(&mut s, left);
                }
            }
            s.waiters -= 1;
        }
    }
}

/// Outcome slots of ended sends whose tickets were dropped, for the next sends: a stream of
/// acknowledged sends then allocates no slot per message. Slots end on the thread that
/// received their acknowledgement and are made on the sending thread; without the pool each
/// would be a trip to the shared heap (an allocator's per-thread cache keeps only a few
/// blocks freed elsewhere).
#[derive(Default)]
pub(crate) struct SlotPool(Mutex<Vec<Arc<OutcomeSlot>>>);

/// At most this many spare slots are kept (the default window of one destination).
const SPARE_SLOTS: usize = 1024;

impl SlotPool {
    /// An empty slot: a spare one when there is one.
    pub(crate) fn take(&self) -> Arc<OutcomeSlot> {
        self.0.lock().pop().unwrap_or_default()
    }

    /// Keeps the slots that nobody else holds (their tickets were dropped), emptied, for
    /// [`SlotPool::take`]; the others stay with their tickets.
    pub(crate) fn give_back(&self, slots: impl IntoIterator<Item = Arc<OutcomeSlot>>) {
        let mut spare = None;
        for mut slot in slots {
            let Some(s) = Arc::get_mut(&mut slot) else {
                continue;
            };
            *s.state.get_mut() = SlotState::default();
            let spare = spare.get_or_insert_with(|| self.0.lock());
            if spare.len() < SPARE_SLOTS {
                spare.push(slot);
            }
        }
    }
}

/// The pending outcome of one send. Dropping it is fine: the outcome is still counted in the
/// system's statistics.
#[derive(Clone)]
pub struct Ticket {
    pub(crate) slot: TicketSlot,
    pub(crate) destination: &'static str,
}

/// Where a ticket finds its outcome.
#[derive(Clone)]
pub(crate) enum TicketSlot {
    /// Known when the send returned (a direct in-process hand-over): nothing to share. With
    /// the transport that carried it.
    Ready(Outcome, Option<&'static str>),
    /// Filled in later by the runtime.
    Pending(Arc<OutcomeSlot>),
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
        self.destination
    }

    /// The outcome, if the send has ended.
    pub fn try_outcome(&self) -> Option<Outcome> {
        match &self.slot {
            TicketSlot::Ready(o, _) => Some(o.clone()),
            TicketSlot::Pending(slot) => slot.lock().outcome.clone(),
        }
    }

    /// The fleet-file name of the transport that carried the send, once it has ended: for a
    /// delivery (or a refusal by the receiver), the one its acknowledgement came back on;
    /// otherwise the one its last frame was offered on (`docs/failover.md`). None while the
    /// send is pending and when no frame was offered (refused before sending).
    pub fn transport(&self) -> Option<&str> {
        match &self.slot {
            TicketSlot::Ready(_, t) => *t,
            TicketSlot::Pending(slot) => {
                let s = slot.lock();
                s.outcome.as_ref().and(s.transport)
            }
        }
    }

    /// Waits for the outcome. Every send ends (the retry budget bounds it), so this returns.
    pub fn wait(&self) -> Outcome {
        loop {
            if let Some(o) = self.wait_until(None) {
                return o;
            }
        }
    }

    /// Waits up to `timeout` for the outcome.
    pub fn wait_timeout(&self, timeout: Duration) -> Option<Outcome> {
        self.wait_until(Some(Instant::now() + timeout))
    }

    fn wait_until(&self, deadline: Option<Instant>) -> Option<Outcome> {
        match &self.slot {
            TicketSlot::Ready(o, _) => Some(o.clone()),
            TicketSlot::Pending(slot) => slot.wait_until(deadline),
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
            .map(|t| (t.destination.to_string(), t.wait()))
            .collect()
    }
}
