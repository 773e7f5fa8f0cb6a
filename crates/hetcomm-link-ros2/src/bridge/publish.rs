//! The bridge's published topics: a send waits (at most `connect_timeout_ms`) until the DDS
//! readers that discovery knows on its topic are matched to its writer, and a closing bridge
//! waits until the readers matched acknowledged what it wrote.
//!
//! A DDS writer keeps no sample for a reader that matches after the write (volatile
//! durability), so a sample written by a fresh process before discovery matched the reader
//! reaches nobody, and a process that exits at once takes unacknowledged samples with it. A
//! reliable writer resends a sample until every reader matched at the time of the write
//! acknowledged it: waiting for the match before the write and for the acknowledgements
//! before the participant goes makes a one-shot send arrive.

use parking_lot::Mutex;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use rustdds::no_key::DataWriter;
use rustdds::{DataWriterStatus, DomainParticipant, StatusEvented, GUID};

use crate::raw::{RawAdapter, RawCdr};

/// How often a waiting send looks again, and how long a check of the readers discovery knows
/// stays good for sends that do not wait.
const POLL: Duration = Duration::from_millis(2);
const RECHECK: Duration = Duration::from_millis(100);
/// How long after a reader matched the writer a send still waits: the reader's side matches
/// the writer when it reads the writer's own announcement, which the writer's side cannot
/// see, and a volatile reader (Cyclone DDS's) that matches after a write acknowledges that
/// sample without reading it. On loopback the reader's side matched within 15 ms of ours when
/// idle; 100 ms was not always enough on a loaded machine.
pub(crate) const SETTLE: Duration = Duration::from_millis(250);

/// One published topic: its writer and the readers matched to it.
pub(super) struct Published {
    /// The ROS topic, e.g. `/tango/cmd_vel`.
    pub(super) topic: String,
    /// Its DDS topic and type names.
    dds_topic: String,
    dds_type: String,
    pub(super) writer: DataWriter<RawCdr, RawAdapter>,
    /// The readers matched, each with when it was.
    matched: Mutex<std::collections::HashMap<GUID, Instant>>,
    /// When every reader discovery knew on the topic was last seen matched (None: not since
    /// the last change).
    checked: Mutex<Option<Instant>>,
    /// Something was written: a closing bridge waits for its acknowledgements.
    wrote: AtomicBool,
}

impl Published {
    /// `writer`, on DDS topic `dds_topic` of type `dds_type`, for ROS topic `topic`.
    pub(super) fn new(
        topic: &str,
        dds_topic: String,
        dds_type: String,
        writer: DataWriter<RawCdr, RawAdapter>,
    ) -> Published {
        Published {
            topic: topic.to_string(),
            dds_topic,
            dds_type,
            writer,
            matched: Mutex::new(Default::default()),
            checked: Mutex::new(None),
            wrote: AtomicBool::new(false),
        }
    }

    /// Applies the writer's pending status events to the matched readers.
    fn refresh(&self) {
        let mut matched = self.matched.lock();
        while let Some(status) = self.writer.try_recv_status() {
            if let DataWriterStatus::PublicationMatched {
                current, reader, ..
            } = status
            {
                if current.count_change() > 0 {
                    matched.insert(reader, Instant::now());
                } else if current.count_change() < 0 {
                    matched.remove(&reader);
                }
                *self.checked.lock() = None;
            }
        }
    }

    /// (readers matched at least [`SETTLE`] ago, readers discovery knows on the topic with
    /// its type that are not).
    fn state(&self, dp: &DomainParticipant) -> (usize, usize) {
        self.refresh();
        let matched = self.matched.lock();
        let settled = |at: &Instant| at.elapsed() >= SETTLE;
        let unmatched = dp
            .discovered_readers()
            .iter()
            .map(|r| &r.subscription_topic_data)
            .filter(|t| *t.topic_name() == self.dds_topic && *t.type_name() == self.dds_type)
            .filter(|t| !matched.get(&t.key()).is_some_and(settled))
            .count();
        (matched.values().filter(|at| settled(at)).count(), unmatched)
    }

    /// Waits, at most `timeout`, until every reader discovery knows on the topic is matched
    /// (at least one); fine if one is matched by then. The reason if none is: then nothing
    /// may be written.
    pub(super) fn wait(&self, dp: &DomainParticipant, timeout: Duration) -> Result<(), String> {
        {
            let checked = self.checked.lock();
            if checked.is_some_and(|t| t.elapsed() < RECHECK) {
                drop(checked);
                self.refresh();
                let fresh = self.checked.lock();
                if fresh.is_some() {
                    return Ok(());
                }
            }
        }
        let deadline = Instant::now() + timeout;
        loop {
            let (matched, unmatched) = self.state(dp);
            if matched > 0 && (unmatched == 0 || Instant::now() >= deadline) {
                *self.checked.lock() = Some(Instant::now());
                return Ok(());
            }
            if Instant::now() >= deadline {
                return Err(format!(
                    "no subscriber of {} matched within {} ms (nothing was published)",
                    self.topic,
                    timeout.as_millis()
                ));
            }
            std::thread::sleep(POLL);
        }
    }

    /// Records that a sample was written.
    pub(super) fn wrote(&self) {
        self.wrote.store(true, Ordering::Relaxed);
    }

    /// Waits, at most `timeout`, until the readers matched acknowledged what was written.
    pub(super) fn flush(&self, timeout: Duration) {
        if self.wrote.load(Ordering::Relaxed) {
            let _ = self.writer.wait_for_acknowledgments(timeout);
        }
    }
}
