//! [`Watch`]: the traffic and counters of the systems open in this process, published live.
//!
//! An observer per system ([`hetcomm::Observer`], the one observation point) copies each
//! receipt, outcome and first send attempt into a bounded queue; one thread names and encodes
//! them ([`hetcomm_record::events`], the recorder's code path) and publishes them, and once a
//! second publishes the statistics (as the monitor shows them), the security layers'
//! rejection counters and the path-switch counter of every watched system. A full queue
//! drops the newest item and counts it (`/hetcomm/foxglove`'s `dropped`): the observed
//! threads never wait for the viewer.

use std::collections::HashSet;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{self, Receiver, RecvTimeoutError, SyncSender};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use hetcomm::observe::{OutcomeRecord, PathChangeRecord, ReceiptRecord, SendRecord};
use hetcomm::{Comm, Observer, ObserverHandle};
use hetcomm_record::events::{EventBuilder, Observed};
use hetcomm_record::format::Event;
use hetcomm_record::stats::{MonitorState, PairStats};
use hetcomm_record::Encoding;
use serde_json::json;

use crate::{
    message_topic, outcome_topic, schemas, Channels, PATHS_TOPIC_PREFIX, SECURITY_TOPIC_PREFIX,
    SERVER_TOPIC,
};

/// Items waiting to be published at most; beyond, they are dropped and counted.
const QUEUE: usize = 8192;
/// How often the counters are published.
const PERIOD: Duration = Duration::from_secs(1);

/// What a [`Watch`] has done so far (also published on `/hetcomm/foxglove`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct WatchCounters {
    /// Receipts, outcomes and sends the observers saw and offered to the queue.
    pub observed: u64,
    /// Messages published on the message and outcome topics.
    pub published: u64,
    /// Dropped because the queue was full (the publishing thread fell behind).
    pub dropped: u64,
    /// Taken from the queue but not publishable (a channel could not be made, or the event
    /// did not encode).
    pub unpublishable: u64,
}

#[derive(Default)]
struct Counters {
    observed: AtomicU64,
    published: AtomicU64,
    dropped: AtomicU64,
    unpublishable: AtomicU64,
}

impl Counters {
    fn snapshot(&self) -> WatchCounters {
        WatchCounters {
            observed: self.observed.load(Ordering::Relaxed),
            published: self.published.load(Ordering::Relaxed),
            dropped: self.dropped.load(Ordering::Relaxed),
            unpublishable: self.unpublishable.load(Ordering::Relaxed),
        }
    }
}

/// Publishes the watched systems until dropped ([`crate::FoxgloveView::watch`]).
pub struct Watch {
    handles: Vec<ObserverHandle>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
    counters: Arc<Counters>,
}

impl Watch {
    pub(crate) fn start(channels: Arc<Channels>, systems: &[Comm]) -> anyhow::Result<Watch> {
        Watch::start_with_queue(channels, systems, QUEUE)
    }

    fn start_with_queue(
        channels: Arc<Channels>,
        systems: &[Comm],
        queue: usize,
    ) -> anyhow::Result<Watch> {
        let Some(first) = systems.first() else {
            anyhow::bail!("no system to watch");
        };
        let builder = EventBuilder::new(first.fleet(), Encoding::Json);
        let local: Arc<HashSet<u16>> = Arc::new(systems.iter().map(|c| c.id().0).collect());
        let counters = Arc::new(Counters::default());
        let (tx, rx) = mpsc::sync_channel(queue);
        let mut handles = Vec::new();
        let mut watched = Vec::new();
        for comm in systems {
            let stats = PairStats::new(comm);
            handles.push(stats.attach(comm));
            handles.push(comm.observe(Arc::new(TrafficObserver {
                system: comm.name().into(),
                local: local.clone(),
                queue: tx.clone(),
                counters: counters.clone(),
            })));
            watched.push((comm.clone(), stats));
        }
        let stop = Arc::new(AtomicBool::new(false));
        let publisher = Publisher {
            channels,
            builder,
            watched,
            state: MonitorState::default(),
            counters: counters.clone(),
            rx,
        };
        let stop2 = stop.clone();
        let thread = std::thread::Builder::new()
            .name("hetcomm-foxglove".into())
            .spawn(move || publisher.run(&stop2))?;
        Ok(Watch {
            handles,
            stop,
            thread: Some(thread),
            counters,
        })
    }

    /// Counts so far.
    pub fn counters(&self) -> WatchCounters {
        self.counters.snapshot()
    }

    /// Stops watching, publishes what is queued and the counters a last time, and returns
    /// the final counts (as dropping it does, without the counts).
    pub fn finish(mut self) -> WatchCounters {
        self.shutdown();
        self.counters()
    }

    fn shutdown(&mut self) {
        // No new items, then what is queued is published, with a last refresh of the counters.
        self.handles.clear();
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

impl Drop for Watch {
    fn drop(&mut self) {
        self.shutdown();
    }
}

/// One system's observer: copies what is to be shown and queues it.
struct TrafficObserver {
    system: Arc<str>,
    /// The systems watched in this process: a message to one of them is shown as received.
    local: Arc<HashSet<u16>>,
    queue: SyncSender<Observed>,
    counters: Arc<Counters>,
}

impl TrafficObserver {
    fn offer(&self, item: Observed) {
        self.counters.observed.fetch_add(1, Ordering::Relaxed);
        if self.queue.try_send(item).is_err() {
            self.counters.dropped.fetch_add(1, Ordering::Relaxed);
        }
    }
}

impl Observer for TrafficObserver {
    fn on_send(&self, r: &SendRecord<'_>) {
        // A message to a watched system is shown once, when it arrives; one to a system of
        // another process (or one that never arrives) as it left.
        if !self.local.contains(&r.header.destination.system.0) {
            self.offer(Observed::send(r));
        }
    }
    fn on_receipt(&self, r: &ReceiptRecord<'_>) {
        self.offer(Observed::receipt(r));
    }
    fn on_outcome(&self, r: &OutcomeRecord<'_>) {
        self.offer(Observed::outcome(&self.system, r));
    }
    fn on_path_change(&self, r: &PathChangeRecord<'_>) {
        self.offer(Observed::path_switch(&self.system, r));
    }
}

/// The publishing thread's state.
struct Publisher {
    channels: Arc<Channels>,
    builder: EventBuilder,
    watched: Vec<(Comm, Arc<PairStats>)>,
    state: MonitorState,
    counters: Arc<Counters>,
    rx: Receiver<Observed>,
}

impl Publisher {
    fn run(mut self, stop: &AtomicBool) {
        let mut next = Instant::now() + PERIOD;
        let mut rejected_before = vec![0u64; self.watched.len()];
        loop {
            let stopping = stop.load(Ordering::Relaxed);
            let wait = match stopping {
                true => Duration::ZERO,
                false => next.saturating_duration_since(Instant::now()),
            };
            match self.rx.recv_timeout(wait) {
                Ok(item) => self.publish_item(&item),
                Err(RecvTimeoutError::Timeout) if stopping => break,
                Err(RecvTimeoutError::Timeout) => {}
                Err(RecvTimeoutError::Disconnected) => break,
            }
            if Instant::now() >= next {
                next += PERIOD;
                self.publish_counters(&mut rejected_before);
            }
        }
        self.publish_counters(&mut rejected_before);
    }

    fn publish_item(&self, item: &Observed) {
        let event = self.builder.event(item);
        if let Event::PathSwitch(e) = &event {
            let result = publish_path_switch(
                &self.channels,
                &e.source_system,
                &e.destination_system,
                &e.from,
                &e.to,
            );
            let counter = match result {
                Ok(()) => &self.counters.published,
                Err(_) => &self.counters.unpublishable,
            };
            counter.fetch_add(1, Ordering::Relaxed);
            return;
        }
        let result = (|| -> anyhow::Result<()> {
            let channel = match &event {
                Event::Send(e) => self.message_channel(&e.message)?,
                Event::Receipt(e) => self.message_channel(&e.message)?,
                Event::Outcome(e) => self.channels.json(
                    &outcome_topic(&e.source_system, &e.destination_system),
                    "hetcomm.Outcome",
                    schemas::outcome,
                )?,
                Event::PathSwitch(_) => return Ok(()),
            };
            channel.log(&serde_json::to_vec(&event)?);
            Ok(())
        })();
        let counter = match result {
            Ok(()) => &self.counters.published,
            Err(_) => &self.counters.unpublishable,
        };
        counter.fetch_add(1, Ordering::Relaxed);
    }

    fn message_channel(
        &self,
        m: &hetcomm_record::format::Envelope,
    ) -> anyhow::Result<Arc<foxglove::RawChannel>> {
        self.channels.json(
            &message_topic(&m.destination.system, &m.destination.module, m.message_type),
            &format!("hetcomm.Message.type{}", m.message_type),
            || schemas::message(m.message_type, m.payload_value().as_ref()),
        )
    }

    /// The statistics, and each system's security and path counters.
    fn publish_counters(&mut self, rejected_before: &mut [u64]) {
        let now = Instant::now();
        for (comm, stats) in &self.watched {
            self.state.ingest(stats.report(comm), now);
        }
        let mut failed = self
            .channels
            .publish_stats(&self.state.pairs(), &self.state.systems(now))
            .is_err();
        for ((comm, _), before) in self.watched.iter().zip(rejected_before.iter_mut()) {
            let s = comm.stats();
            let mut sec = serde_json::Map::new();
            let mut enabled = false;
            let mut sums = [0u64; schemas::SECURITY_COUNTERS.len()];
            for (_, l) in &s.links {
                let x = &l.security;
                enabled |= x.enabled;
                let values = [
                    x.rejected_auth,
                    x.rejected_replay,
                    x.rejected_table,
                    x.rejected_unknown_sender,
                    x.rejected_no_session,
                    x.handshake_timeouts,
                    x.handshakes,
                ];
                for (sum, v) in sums.iter_mut().zip(values) {
                    *sum += v;
                }
            }
            // Every counter but the last (handshakes made) counts a frame or handshake refused.
            let rejected: u64 = sums[..sums.len() - 1].iter().sum();
            sec.insert("system".into(), json!(comm.name()));
            sec.insert("enabled".into(), json!(enabled));
            for (name, v) in schemas::SECURITY_COUNTERS.iter().zip(sums) {
                sec.insert((*name).into(), json!(v));
            }
            sec.insert("rejected".into(), json!(rejected));
            sec.insert(
                "rejected_since_last".into(),
                json!(rejected.saturating_sub(*before)),
            );
            *before = rejected;
            let paths = json!({"system": comm.name(), "path_changes": s.router.path_changes});
            failed |= self
                .log_json(
                    &format!("{SECURITY_TOPIC_PREFIX}/{}", comm.name()),
                    "hetcomm.Security",
                    schemas::security,
                    &serde_json::Value::Object(sec),
                )
                .is_err();
            failed |= self
                .log_json(
                    &format!("{PATHS_TOPIC_PREFIX}/{}", comm.name()),
                    "hetcomm.Paths",
                    schemas::paths,
                    &paths,
                )
                .is_err();
        }
        let c = self.counters.snapshot();
        let server = json!({
            "system": self.watched.iter().map(|(c, _)| c.name()).collect::<Vec<_>>().join(","),
            "observed": c.observed,
            "published": c.published,
            "dropped": c.dropped,
            "unpublishable": c.unpublishable,
        });
        failed |= self
            .log_json(
                SERVER_TOPIC,
                "hetcomm.FoxgloveServer",
                schemas::server,
                &server,
            )
            .is_err();
        if failed {
            self.counters.unpublishable.fetch_add(1, Ordering::Relaxed);
        }
    }

    fn log_json(
        &self,
        topic: &str,
        schema_name: &str,
        schema: fn() -> String,
        value: &serde_json::Value,
    ) -> anyhow::Result<()> {
        self.channels
            .json(topic, schema_name, schema)?
            .log(&serde_json::to_vec(value)?);
        Ok(())
    }
}

/// One path switch on `/hetcomm/paths/<system>` ([`crate::FoxgloveView::publish_path_switch`]).
pub(crate) fn publish_path_switch(
    channels: &Channels,
    system: &str,
    destination: &str,
    from: &str,
    to: &str,
) -> anyhow::Result<()> {
    let value = json!({"system": system, "destination": destination, "from": from, "to": to});
    channels
        .json(
            &format!("{PATHS_TOPIC_PREFIX}/{system}"),
            "hetcomm.Paths",
            schemas::paths,
        )?
        .log(&serde_json::to_vec(&value)?);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::FoxgloveView;
    use hetcomm::{LocalFleet, MessageType, SendOptions};

    /// A publishing thread that cannot keep up loses items, and every one is counted: the
    /// observed sends never wait for it.
    #[test]
    fn a_full_queue_drops_and_counts_instead_of_blocking_the_sender() {
        let fleet = hetcomm::parse_fleet(
            "[systems]\nA = 0\nB = 1\n[modules]\nM = 0\n[transports.t]\nkind = \"inproc\"\n\
             [table]\ncolumns = [\"A\", \"B\"]\nA = [\"X\", \"t\"]\nB = [\"t\", \"X\"]\n",
            "<test>",
            None,
        )
        .unwrap();
        let fleet = LocalFleet::open(fleet).unwrap();
        let view = FoxgloveView::start("127.0.0.1:0", "test").unwrap();
        let watch = Watch::start_with_queue(view.channels.clone(), fleet.systems(), 4).unwrap();
        let a = fleet.system("A").unwrap().module("M").unwrap();
        // The publishing thread blocks on its first new channel while the test holds them.
        let held = view.channels.json.lock();
        let started = Instant::now();
        for _ in 0..50 {
            let t = a
                .send_raw("B", "M", MessageType(1), &[0xc0], SendOptions::default())
                .unwrap();
            assert!(matches!(
                t.wait_timeout(Duration::from_secs(5)),
                Some(hetcomm::Outcome::Delivered { .. })
            ));
        }
        assert!(
            started.elapsed() < Duration::from_secs(5),
            "the sends waited"
        );
        drop(held);
        let c = watch.finish();
        // Each send: a receipt at B and an outcome at A.
        assert_eq!(c.observed, 100, "{c:?}");
        assert!(c.dropped >= 100 - 4 - 1, "{c:?}");
        assert_eq!(
            c.published + c.dropped + c.unpublishable,
            c.observed,
            "{c:?}"
        );
    }
}
