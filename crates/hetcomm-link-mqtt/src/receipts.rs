//! What the broker said about each QoS 1 publish: the PUBACK that answers it, matched to the
//! send that made it, for the outcome of an unacknowledged send (`hetcomm_link::relay`).
//!
//! rumqttc does not say which packet id a publish got: its event loop reports
//! `Outgoing::Publish(pkid)` as it writes each one. Requests leave its queue in the order
//! they were queued, so every QoS 1 publish of the client is noted here, in that order, at the
//! moment it is queued (under this lock, so the notes and the queue agree), and the next
//! fresh packet id the loop reports belongs to the oldest note. A packet id already in flight
//! is a publish sent again after a reconnection (rumqttc keeps its packet id). When the
//! broker kept no session, rumqttc drops what it had in flight and what it had taken from the
//! queue at the disconnection; those receipts end unanswered at once. Any receipt not answered
//! within the bound ends unanswered, on a thread of the link's that sleeps until the next
//! receipt's deadline ([`Receipts::run_expiry`]).

use parking_lot::{Condvar, Mutex, MutexGuard};
use std::collections::{HashMap, VecDeque};
use std::time::{Duration, Instant};

use hetcomm_link::relay::{relay_receipt, RelayPromise, RelayReceipt, RelayVerdict};
use hetcomm_link::LinkError;
use rumqttc::v5::mqttbytes::v5::{Packet, PubAck, PubAckReason};
use rumqttc::v5::mqttbytes::QoS;
use rumqttc::v5::{Event, Request};
use rumqttc::Outgoing;

/// One QoS 1 publish noted; `None` for those nobody waits on (acknowledgements, presence,
/// frames of acknowledged sends).
type Note = Option<Waiting>;

/// A receipt waiting for the broker.
pub(crate) struct Waiting {
    promise: RelayPromise,
    deadline: Instant,
}

#[derive(Default)]
struct Book {
    /// QoS 1 publishes queued and not yet written, in queue order.
    queued: VecDeque<Note>,
    /// Written and not yet answered, by packet id.
    in_flight: HashMap<u16, Note>,
    /// A publish rumqttc holds back because its packet id is still in flight (a broker that
    /// answers out of order): it takes that id once the PUBACK for it came.
    collided: Option<(u16, Note)>,
    /// At the last disconnection: how many of `queued` (the oldest) rumqttc took from its
    /// queue to send again, if the broker kept the session.
    taken_at_disconnect: usize,
    /// The link closed: the expiry thread ends.
    closed: bool,
}

impl Book {
    /// The earliest deadline of a receipt still waiting.
    fn next_deadline(&self) -> Option<Instant> {
        let deadline = |n: &Note| n.as_ref().map(|w| w.deadline);
        self.queued
            .iter()
            .filter_map(deadline)
            .chain(self.in_flight.values().filter_map(deadline))
            .chain(self.collided.as_ref().and_then(|(_, n)| deadline(n)))
            .min()
    }
}

/// Makes one publish through `publish`, at QoS 1 with the promise of the receipt returned
/// (kept with the broker's PUBACK); at QoS 0 the broker confirms nothing: no receipt. What the
/// `mqtt` link and the `mqtt_bridge` give [`hetcomm_link::Link::send_relayed`].
pub(crate) fn with_receipt(
    qos: QoS,
    publish: impl FnOnce(Option<RelayPromise>) -> Result<(), LinkError>,
) -> Result<Option<RelayReceipt>, LinkError> {
    if qos == QoS::AtMostOnce {
        return publish(None).map(|()| None);
    }
    let (receipt, promise) = relay_receipt();
    publish(Some(promise))?;
    Ok(Some(receipt))
}

/// The receipts of one MQTT client's publishes.
pub(crate) struct Receipts {
    book: Mutex<Book>,
    /// Signalled when a receipt starts waiting, and at the close.
    waiting: Condvar,
    /// How long a receipt waits for its PUBACK.
    bound: Duration,
    /// The broker, as sentences name it.
    broker: Mutex<String>,
}

impl Receipts {
    pub(crate) fn new(bound: Duration, broker: String) -> Self {
        Receipts {
            book: Mutex::new(Book::default()),
            waiting: Condvar::new(),
            bound,
            broker: Mutex::new(broker),
        }
    }

    fn lock(&self) -> MutexGuard<'_, Book> {
        self.book.lock()
    }

    fn broker(&self) -> String {
        self.broker.lock().clone()
    }

    /// The broker the client now talks to (one of several, in turn).
    pub(crate) fn set_broker(&self, broker: String) {
        *self.broker.lock() = broker;
    }

    /// Queues a publish with `queue` (which returns whether it queued it), noting it when it
    /// is QoS 1, with `promise` (taken) if someone waits on it. Under the lock, so notes keep
    /// the queue's order.
    pub(crate) fn queue(
        &self,
        qos: QoS,
        promise: &mut Option<RelayPromise>,
        queue: impl FnOnce() -> bool,
    ) -> bool {
        if qos == QoS::AtMostOnce {
            return queue();
        }
        let mut book = self.lock();
        let queued = queue();
        if queued {
            let note = promise.take().map(|promise| Waiting {
                promise,
                deadline: Instant::now() + self.bound,
            });
            let wake = note.is_some() && book.next_deadline().is_none();
            book.queued.push_back(note);
            drop(book);
            if wake {
                self.waiting.notify_all();
            }
        }
        queued
    }

    /// Ends receipts as their deadlines pass, until [`Receipts::close`] (on a thread of its
    /// own: the client's event loop may sleep for a keep-alive interval when the broker is
    /// silent).
    pub(crate) fn run_expiry(&self) {
        let mut book = self.lock();
        while !book.closed {
            match book.next_deadline() {
                None => self.waiting.wait(&mut book),
                Some(d) => {
                    let left = d.saturating_duration_since(Instant::now());
                    if left.is_zero() {
                        drop(book);
                        self.expire(Instant::now());
                        book = self.lock();
                    } else {
                        self.waiting.wait_for(&mut book, left);
                    }
                }
            }
        }
    }

    /// Ends the expiry thread. Receipts still waiting end unanswered when the link's client
    /// goes (their promises are dropped).
    pub(crate) fn close(&self) {
        self.lock().closed = true;
        self.waiting.notify_all();
    }

    /// What the client's event loop reports, before the link acts on it.
    pub(crate) fn on_event(&self, event: &Event) {
        match event {
            Event::Outgoing(Outgoing::Publish(pkid)) if *pkid != 0 => {
                let mut book = self.lock();
                if !book.in_flight.contains_key(pkid) {
                    let note = book.queued.pop_front().flatten();
                    book.taken_at_disconnect = book.taken_at_disconnect.saturating_sub(1);
                    book.in_flight.insert(*pkid, note);
                }
            }
            Event::Outgoing(Outgoing::AwaitAck(pkid)) => {
                let mut book = self.lock();
                let note = book.queued.pop_front().flatten();
                book.collided = Some((*pkid, note));
            }
            Event::Incoming(Packet::PubAck(ack)) => self.answered(ack),
            _ => {}
        }
    }

    fn answered(&self, ack: &PubAck) {
        let mut book = self.lock();
        let note = book.in_flight.remove(&ack.pkid).flatten();
        if let Some((pkid, _)) = &book.collided {
            if *pkid == ack.pkid {
                let (pkid, note) = book.collided.take().expect("just seen");
                book.in_flight.insert(pkid, note);
            }
        }
        drop(book);
        let Some(waiting) = note else { return };
        let broker = self.broker();
        let verdict = match ack.reason {
            PubAckReason::Success => RelayVerdict::Confirmed,
            PubAckReason::NoMatchingSubscribers => RelayVerdict::Refused(format!(
                "the broker {broker} had no subscriber for it (nobody received it)"
            )),
            other => RelayVerdict::Refused(format!(
                "the broker {broker} refused it: {}",
                crate::event_loop::words(&format!("{other:?}"))
            )),
        };
        waiting.promise.keep(verdict);
    }

    /// The connection broke: rumqttc took `pending`, its requests to send again if the broker
    /// kept the session (what was in flight, then what was still in its queue).
    pub(crate) fn disconnected(&self, pending: &VecDeque<Request>) {
        let fresh = pending
            .iter()
            .filter(|r| matches!(r, Request::Publish(p) if p.qos != QoS::AtMostOnce && p.pkid == 0))
            .count();
        self.lock().taken_at_disconnect = fresh;
    }

    /// A connection came up: without a session, rumqttc dropped what it meant to send again.
    pub(crate) fn connected(&self, session_present: bool) {
        if session_present {
            return;
        }
        let mut book = self.lock();
        let taken = book.taken_at_disconnect.min(book.queued.len());
        book.taken_at_disconnect = 0;
        let mut lost: Vec<Waiting> = book.in_flight.drain().filter_map(|(_, n)| n).collect();
        lost.extend(book.queued.drain(..taken).flatten());
        lost.extend(book.collided.take().and_then(|(_, n)| n));
        drop(book);
        let why = format!(
            "the connection to the broker {} broke before it confirmed, and the broker kept no session (`clean_session = true`): it may or may not have been passed on",
            self.broker()
        );
        for waiting in lost {
            waiting.promise.keep(RelayVerdict::Unanswered(why.clone()));
        }
    }

    /// Ends the receipts that waited past their bound.
    pub(crate) fn expire(&self, now: Instant) {
        let mut book = self.lock();
        let late = |n: &Note| n.as_ref().is_some_and(|w| w.deadline <= now);
        let any_late = book.queued.iter().any(late)
            || book.in_flight.values().any(late)
            || book.collided.as_ref().is_some_and(|(_, n)| late(n));
        if !any_late {
            return;
        }
        let mut expired = Vec::new();
        let mut take = |n: &mut Note| {
            if late(n) {
                expired.extend(n.take());
            }
        };
        book.queued.iter_mut().for_each(&mut take);
        book.in_flight.values_mut().for_each(&mut take);
        if let Some((_, n)) = book.collided.as_mut() {
            take(n);
        }
        drop(book);
        let why = format!(
            "the broker {} did not confirm it within {} ms",
            self.broker(),
            self.bound.as_millis()
        );
        for waiting in expired {
            waiting.promise.keep(RelayVerdict::Unanswered(why.clone()));
        }
    }
}
