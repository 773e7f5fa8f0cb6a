//! [`CycloneLink`]: the `ros2` transport on Cyclone DDS (`dds = "cyclone"`, cargo feature
//! `cyclone`), through the `cyclors` bindings. The same topics, type and bytes as the rustdds
//! backend ([`crate::link`]), so systems on either talk to each other.
//!
//! * **Writes** go from the caller's thread: the frame and a 16-byte CDR header
//!   ([`crate::frame_cdr`]) are handed to Cyclone DDS as a raw sample (`dds_writecdr`), which
//!   sends the datagram before it returns.
//! * **Receiving**: Cyclone DDS's receive thread stores the sample in the reader and calls
//!   the reader's data-available listener, which only makes an eventfd readable (once until
//!   the reader is next drained). Whoever drives the link ([`Link::readable`], on a link
//!   opened with [`open_driven`](CycloneLink::open_driven) as the runtime opens it) or, with
//!   [`open`](CycloneLink::open), a thread of the link's own then takes every sample and
//!   hands the frames to the sink.
//! * **Delivering on the receive thread** (`deliver_on_receive_thread = true`): the listener
//!   takes the samples and hands the frames to the sink itself, on Cyclone's receive thread,
//!   so a module with inline callbacks answers there without any thread hand-off (as
//!   `ddsperf`'s listener mode does). Two things make that safe. A write made on that thread
//!   never waits: the writers' `max_blocking_time` is 0, so a write Cyclone would throttle
//!   (unacknowledged bytes over its high watermark) fails at once as congested instead of
//!   waiting for acknowledgements that only this very thread could read (writes from other
//!   threads still wait, up to 100 ms, by waiting for the acknowledgements and trying
//!   again). And a listener reached from inside another listener on the same thread (a
//!   write to a reader of this process, which Cyclone delivers on the writing thread) only
//!   signals, as the default mode does: delivering there could answer back into the first
//!   listener, which Cyclone would wait for forever.
//! * **Losses**: what Cyclone DDS reports as lost or rejected on the reader (sample lost /
//!   sample rejected statuses) is counted in [`LinkStats::frames_dropped`], with samples that
//!   are not frames. A KeepLast reader history that overflows before it is read drops its
//!   oldest samples without any status (DDS has none for it): keep `history_depth` above
//!   what a reader can fall behind, or use acknowledged delivery.

mod backlog;
mod domain;
mod notify;

use std::collections::HashMap;
use std::mem::MaybeUninit;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use cyclors::*;
use hetcomm_core::SystemId;
use hetcomm_link::{FrameSink, Link, LinkCaps, LinkError, LinkStats, Peer, Readable};

use crate::frame_cdr;
use crate::link::{Ros2OpenError, MAX_FRAME};
use crate::msg::FRAME_TYPE;
use crate::names;
use crate::settings::Ros2Settings;
use backlog::Backlog;
use domain::{blob_topic, dds_err, Participant, Qos};
use notify::Notifier;

pub use domain::config;

/// Samples taken from the reader per call.
const BATCH: usize = 32;

/// How long a write from a thread other than a listener's waits for a throttled writer.
const WRITE_BLOCKING: Duration = Duration::from_millis(100);

/// How long the backlog thread waits for a throttled writer before it counts a frame dropped.
const BACKLOG_BLOCKING: Duration = Duration::from_secs(1);

thread_local! {
    /// Set while this thread runs one of our listeners (see the module docs).
    static IN_LISTENER: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

/// One destination: its topic and writer.
struct Dest {
    topic: String,
    writer: dds_entity_t,
}

#[derive(Default)]
struct Counters {
    sent: AtomicU64,
    received: AtomicU64,
    /// Samples that were not frames, and failed writes.
    dropped: AtomicU64,
    malformed: AtomicU64,
}

/// What the receive side and the link share.
struct Shared {
    counters: Counters,
    reader: dds_entity_t,
    /// Signalled by the listener: the samples wait for the link's driver.
    notifier: Notifier,
    closed: AtomicBool,
    sink: Arc<dyn FrameSink>,
    /// One reader at a time: samples are taken and delivered in order.
    reading: Mutex<()>,
    /// The listener delivers (`deliver_on_receive_thread`).
    deliver_in_listener: bool,
}

/// A `ros2` link on Cyclone DDS: frames as `std_msgs/msg/UInt8MultiArray` on
/// `<namespace>/<System>`.
pub struct CycloneLink {
    // Dropped first: deleting it deletes the reader and waits for its listener's calls,
    // which use `shared`.
    _participant: Participant,
    topic: String,
    dests: Arc<HashMap<SystemId, Dest>>,
    connect_timeout: Duration,
    shared: Arc<Shared>,
    /// Takes what the listener left, on a link opened with [`open`](CycloneLink::open).
    receiver: Option<JoinHandle<()>>,
    driven: bool,
    /// Frames a listener's thread could not write at once (`deliver_on_receive_thread`).
    /// Present exactly when the writers' `max_blocking_time` is 0: a throttled write then
    /// returns at once, and [`CycloneLink::write`] does the waiting off listeners.
    backlog: Option<Arc<Backlog>>,
    /// Writes the backlog's frames, waiting as long as a blocking writer would.
    backlog_writer: Option<JoinHandle<()>>,
}

impl CycloneLink {
    /// Opens system `local`'s link, read by a thread of its own.
    pub fn open(
        local: SystemId,
        names: &[(SystemId, String)],
        settings: &Ros2Settings,
        sink: Arc<dyn FrameSink>,
    ) -> Result<CycloneLink, Ros2OpenError> {
        Self::open_with(local, names, settings, sink, false)
    }

    /// Opens system `local`'s link, read through [`Link::readable`] by whoever drives it.
    pub fn open_driven(
        local: SystemId,
        names: &[(SystemId, String)],
        settings: &Ros2Settings,
        sink: Arc<dyn FrameSink>,
    ) -> Result<CycloneLink, Ros2OpenError> {
        Self::open_with(local, names, settings, sink, true)
    }

    fn open_with(
        local: SystemId,
        names: &[(SystemId, String)],
        settings: &Ros2Settings,
        sink: Arc<dyn FrameSink>,
        driven: bool,
    ) -> Result<CycloneLink, Ros2OpenError> {
        let own = names
            .iter()
            .find(|(id, _)| *id == local)
            .ok_or(Ros2OpenError::UnknownLocal(local))?;
        let io_err = |e: std::io::Error| Ros2OpenError::Dds {
            what: "the receive side".into(),
            reason: e.to_string(),
        };
        let notifier = Notifier::new().map_err(io_err)?;
        let participant = Participant::new(settings)?;
        let dp = participant.handle;
        let (qos, wqos) = (Qos::reader(settings), Qos::writer(settings));
        let type_name = names::dds_type(FRAME_TYPE);
        let topic_of = |name: &str| names::system_topic(&settings.namespace, name);

        let own_topic = topic_of(&own.1);
        let topic = blob_topic(dp, &names::dds_topic(&own_topic), &type_name)?;
        // SAFETY: valid handles and QoS; the listener is set below, once `shared` exists.
        let reader = unsafe { dds_create_reader(dp, topic, qos.0, std::ptr::null()) };
        if reader < 0 {
            return Err(dds_err(format!("the reader of {own_topic}"), reader));
        }
        let mut dests = HashMap::new();
        for (id, name) in names.iter().filter(|(id, _)| *id != local) {
            let t = topic_of(name);
            let topic = blob_topic(dp, &names::dds_topic(&t), &type_name)?;
            // SAFETY: valid handles and QoS; no listener.
            let writer = unsafe { dds_create_writer(dp, topic, wqos.0, std::ptr::null()) };
            if writer < 0 {
                return Err(dds_err(format!("the writer of {t}"), writer));
            }
            dests.insert(*id, Dest { topic: t, writer });
        }

        let shared = Arc::new(Shared {
            counters: Counters::default(),
            reader,
            notifier,
            closed: AtomicBool::new(false),
            sink,
            reading: Mutex::new(()),
            deliver_in_listener: settings.deliver_on_receive_thread,
        });
        // SAFETY: the listener's argument is `shared`, which outlives the reader (the
        // participant, deleted first when the link drops, takes the reader with it and waits
        // for listener calls in progress); the listener object is copied and deleted here.
        let rc = unsafe {
            let listener = dds_create_listener(Arc::as_ptr(&shared) as *mut _);
            dds_lset_data_available(listener, Some(on_data_available));
            let rc = dds_set_listener(reader, listener);
            dds_delete_listener(listener);
            rc
        };
        if rc < 0 {
            return Err(dds_err(format!("the listener of {own_topic}"), rc));
        }
        // Samples stored before the listener was set raised no call: the driver takes them.
        shared.notifier.signal();
        let receiver = match driven {
            true => None,
            false => {
                let rx = shared.clone();
                let thread = std::thread::Builder::new()
                    .name(format!("hetcomm-cyclone-rx-{}", own.1))
                    .spawn(move || {
                        while !rx.closed.load(Ordering::Relaxed) {
                            if rx.notifier.wait(Duration::from_millis(50)) {
                                rx.read();
                            }
                        }
                    })
                    .map_err(io_err)?;
                Some(thread)
            }
        };
        let dests = Arc::new(dests);
        let (backlog, backlog_writer) = match settings.deliver_on_receive_thread {
            false => (None, None),
            true => {
                let backlog = Arc::new(Backlog::default());
                let (queue, dests, shared) = (backlog.clone(), dests.clone(), shared.clone());
                let thread = std::thread::Builder::new()
                    .name(format!("hetcomm-cyclone-backlog-{}", own.1))
                    .spawn(move || write_backlog(&queue, &dests, &shared))
                    .map_err(io_err)?;
                (Some(backlog), Some(thread))
            }
        };
        Ok(CycloneLink {
            _participant: participant,
            topic: own_topic,
            dests,
            connect_timeout: Duration::from_millis(settings.connect_timeout_ms),
            shared,
            receiver,
            driven,
            backlog,
            backlog_writer,
        })
    }

    /// This system's ROS 2 topic, e.g. `/hetcomm/Bravo`.
    pub fn topic(&self) -> &str {
        &self.topic
    }

    /// Samples on this system's topic that were not frames (not a serialized
    /// `std_msgs/msg/UInt8MultiArray`, or no data).
    pub fn malformed(&self) -> u64 {
        self.shared.counters.malformed.load(Ordering::Relaxed)
    }

    /// Samples Cyclone DDS reported lost or rejected on this system's reader.
    pub fn lost(&self) -> u64 {
        let mut lost = MaybeUninit::<dds_sample_lost_status_t>::zeroed();
        let mut rejected = MaybeUninit::<dds_sample_rejected_status_t>::zeroed();
        // SAFETY: the reader lives as long as the link; the statuses are plain structs that
        // Cyclone fills in (left zeroed if the call fails).
        unsafe {
            dds_get_sample_lost_status(self.shared.reader, lost.as_mut_ptr());
            dds_get_sample_rejected_status(self.shared.reader, rejected.as_mut_ptr());
            u64::from(lost.assume_init().total_count)
                + u64::from(rejected.assume_init().total_count)
        }
    }

    /// Readers matched to `dest`'s writer.
    fn matched(dest: &Dest) -> u32 {
        let mut status = MaybeUninit::<dds_publication_matched_status_t>::zeroed();
        // SAFETY: a live writer; the status is left zeroed if the call fails.
        unsafe {
            dds_get_publication_matched_status(dest.writer, status.as_mut_ptr());
            status.assume_init().current_count
        }
    }

    /// Waits (at most the connect timeout) for a reader to be matched to `dest`'s writer.
    fn wait_matched(&self, to: SystemId, dest: &Dest) -> Result<(), LinkError> {
        let deadline = Instant::now() + self.connect_timeout;
        let mut pause = Duration::from_micros(200);
        while Self::matched(dest) == 0 {
            if Instant::now() >= deadline {
                return Err(LinkError::Unreachable {
                    peer: to,
                    reason: format!(
                        "no subscriber of {} matched within {} ms (is that system running, on \
                         the same domain_id, reachable by DDS discovery?)",
                        dest.topic,
                        self.connect_timeout.as_millis()
                    ),
                });
            }
            std::thread::sleep(pause);
            pause = (pause * 2).min(Duration::from_millis(10));
        }
        Ok(())
    }

    /// Writes one sample made of `parts` (the frame's pieces) to `to`.
    fn write(&self, to: SystemId, parts: &[&[u8]]) -> Result<(), LinkError> {
        let len: usize = parts.iter().map(|p| p.len()).sum();
        if len > MAX_FRAME {
            return Err(LinkError::TooLarge {
                len,
                max: MAX_FRAME,
            });
        }
        let Some(dest) = self.dests.get(&to) else {
            return Err(LinkError::Unreachable {
                peer: to,
                reason: "not a system of this ros2 transport".into(),
            });
        };
        if Self::matched(dest) == 0 {
            self.wait_matched(to, dest)?;
        }
        let rc = match IN_LISTENER.with(|c| c.get()) {
            false if self.backlog.is_some() => write_waiting(dest, parts, WRITE_BLOCKING),
            false => write_sample(dest, parts),
            // On a listener's thread: never wait; what cannot go now (or must stay behind
            // frames that could not) goes to the backlog thread.
            true => match &self.backlog {
                Some(backlog) if !backlog.is_empty() => backlog_push(backlog, to, parts),
                Some(backlog) => match write_sample(dest, parts) {
                    DDS_RETCODE_TIMEOUT => backlog_push(backlog, to, parts),
                    rc => rc,
                },
                None => write_sample(dest, parts),
            },
        };
        match rc {
            rc if rc >= 0 => {
                self.shared.counters.sent.fetch_add(1, Ordering::Relaxed);
                Ok(())
            }
            DDS_RETCODE_TIMEOUT => Err(LinkError::Congested {
                peer: to,
                reason: format!(
                    "the DDS writer of {} is full (unacknowledged samples)",
                    dest.topic
                ),
            }),
            rc => {
                self.shared.counters.dropped.fetch_add(1, Ordering::Relaxed);
                Err(LinkError::Unreachable {
                    peer: to,
                    reason: format!("DDS write on {}: {}", dest.topic, domain::retcode(rc)),
                })
            }
        }
    }
}

/// Writes one sample made of `parts` (a frame's pieces, with the CDR header in front) on
/// `dest`'s writer; Cyclone's return code.
fn write_sample(dest: &Dest, parts: &[&[u8]]) -> dds_return_t {
    let len: usize = parts.iter().map(|p| p.len()).sum();
    let (header, pad) = frame_cdr::header(len);
    let iov = |b: &[u8]| ddsrt_iovec_t {
        iov_base: b.as_ptr() as *mut _,
        iov_len: b.len(),
    };
    let mut iovs = Vec::with_capacity(parts.len() + 2);
    iovs.push(iov(&header));
    iovs.extend(parts.iter().filter(|p| !p.is_empty()).map(|p| iov(p)));
    iovs.push(iov(&frame_cdr::PADDING[..pad]));
    let size = header.len() + len + pad;
    // SAFETY: the writer is live; its sertype is the blob type, whose from_ser_iov copies
    // the vectors (which outlive the call) into a sample of `size` bytes; dds_writecdr
    // takes over the sample's reference (also when the write fails).
    unsafe {
        let mut sertype: *const ddsi_sertype = std::ptr::null();
        let rc = dds_get_entity_sertype(dest.writer, &mut sertype);
        if rc < 0 {
            return rc;
        }
        let sample = ddsi_serdata_from_ser_iov(
            sertype,
            ddsi_serdata_kind_SDK_DATA,
            iovs.len(),
            iovs.as_ptr(),
            size,
        );
        dds_writecdr(dest.writer, sample)
    }
}

/// [`write_sample`] on a writer that never blocks, waiting up to `limit` as a blocking one
/// would: while Cyclone throttles the writer, for its acknowledgements (read by Cyclone's
/// receive thread), then again. Not for a listener's thread.
fn write_waiting(dest: &Dest, parts: &[&[u8]], limit: Duration) -> dds_return_t {
    let mut rc = write_sample(dest, parts);
    let deadline = Instant::now() + limit;
    while rc == DDS_RETCODE_TIMEOUT && Instant::now() < deadline {
        // SAFETY: a live writer; waits at most 1 ms.
        unsafe { dds_wait_for_acks(dest.writer, 1_000_000) };
        rc = write_sample(dest, parts);
    }
    rc
}

/// Queues a frame a listener's thread could not write: OK, or TIMEOUT (reported as
/// congested) when the backlog is full.
fn backlog_push(backlog: &Backlog, to: SystemId, parts: &[&[u8]]) -> dds_return_t {
    match backlog.push(to, parts) {
        true => DDS_RETCODE_OK as dds_return_t,
        false => DDS_RETCODE_TIMEOUT,
    }
}

/// The backlog thread: writes queued frames in order, each waiting up to a second for a
/// throttled writer; a frame that still cannot go is counted as dropped (the router
/// retransmits an acknowledged send's frame).
fn write_backlog(backlog: &Backlog, dests: &HashMap<SystemId, Dest>, shared: &Shared) {
    while let Some((to, frame)) = backlog.pop() {
        let rc = match dests.get(&to) {
            Some(dest) => write_waiting(dest, &[&frame], BACKLOG_BLOCKING),
            None => DDS_RETCODE_BAD_PARAMETER as dds_return_t,
        };
        if rc < 0 {
            shared.counters.dropped.fetch_add(1, Ordering::Relaxed);
        }
    }
}

impl Shared {
    /// Takes every sample in the reader and hands the frames to the sink; returns how many.
    /// Another thread taking already: returns 0 (it re-armed the notifier before it took, so
    /// a sample stored after its last take signals again).
    fn read(&self) -> usize {
        let _reading = match self.reading.try_lock() {
            Ok(guard) => guard,
            Err(std::sync::TryLockError::Poisoned(e)) => e.into_inner(),
            Err(std::sync::TryLockError::WouldBlock) => {
                // The other reader may have made its last take already: make sure whoever
                // drives the link looks again.
                self.notifier.signal();
                return 0;
            }
        };
        // Re-armed before taking: a sample stored after this signals again.
        self.notifier.rearm();
        let mut frames = 0;
        let mut samples = [std::ptr::null_mut::<ddsi_serdata>(); BATCH];
        let mut infos = [MaybeUninit::<dds_sample_info_t>::zeroed(); BATCH];
        loop {
            // SAFETY: a live reader; arrays of BATCH entries for samples and infos.
            let n = unsafe {
                dds_takecdr(
                    self.reader,
                    samples.as_mut_ptr(),
                    BATCH as u32,
                    infos.as_mut_ptr().cast(),
                    DDS_ANY_STATE,
                )
            };
            if n <= 0 {
                return frames;
            }
            for (sample, info) in samples.iter().zip(&infos).take(n as usize) {
                // SAFETY: dds_takecdr filled the first n infos and gave us a reference to
                // each of the first n samples, released here after use.
                unsafe {
                    if info.assume_init_ref().valid_data {
                        frames += usize::from(self.deliver(*sample));
                    }
                    ddsi_serdata_unref(*sample);
                }
            }
        }
    }

    /// Hands the frame in `sample` to the sink; counts it as malformed if it is not one.
    ///
    /// # Safety
    /// `sample` is a live sample of the blob type.
    unsafe fn deliver(&self, sample: *mut ddsi_serdata) -> bool {
        let size = ddsi_serdata_size(sample) as usize;
        let mut bytes = ddsrt_iovec_t {
            iov_base: std::ptr::null_mut(),
            iov_len: 0,
        };
        let held = ddsi_serdata_to_ser_ref(sample, 0, size, &mut bytes);
        let slice = match bytes.iov_base.is_null() {
            true => &[][..],
            false => std::slice::from_raw_parts(bytes.iov_base as *const u8, bytes.iov_len),
        };
        let ok = match frame_cdr::frame(slice) {
            Ok(frame) => {
                self.counters.received.fetch_add(1, Ordering::Relaxed);
                self.sink.on_frame(frame, Peer::Unknown);
                true
            }
            Err(_) => {
                self.counters.malformed.fetch_add(1, Ordering::Relaxed);
                self.counters.dropped.fetch_add(1, Ordering::Relaxed);
                false
            }
        };
        ddsi_serdata_to_ser_unref(held, &bytes);
        ok
    }
}

/// Called by Cyclone DDS's receive thread (or a local writer's thread) after it stored a
/// sample in the reader.
unsafe extern "C" fn on_data_available(_reader: dds_entity_t, arg: *mut std::ffi::c_void) {
    // SAFETY: `arg` is the link's `Shared`, alive as long as the reader.
    let shared = unsafe { &*(arg as *const Shared) };
    if !shared.deliver_in_listener || IN_LISTENER.with(|c| c.get()) {
        shared.notifier.signal();
        return;
    }
    IN_LISTENER.with(|c| c.set(true));
    // A panic must not unwind into C; a sink that panicked loses only that call's frames.
    let _ = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| shared.read()));
    IN_LISTENER.with(|c| c.set(false));
}

impl Readable for Shared {
    fn fd(&self) -> std::os::fd::RawFd {
        self.notifier.fd()
    }

    fn read_ready(&self, _budget: usize) -> std::io::Result<usize> {
        // Everything is taken at once: the notifier signals once until it is re-armed.
        Ok(self.read())
    }
}

impl Link for CycloneLink {
    fn caps(&self) -> LinkCaps {
        LinkCaps {
            max_frame: MAX_FRAME,
            mtu: MAX_FRAME,
            reliable: false,
            ordered: true,
            broadcast: false,
        }
    }

    fn send(&self, to: SystemId, frame: &[u8]) -> Result<(), LinkError> {
        self.write(to, &[frame])
    }

    fn send_parts(&self, to: SystemId, head: &[u8], body: &[u8]) -> Result<(), LinkError> {
        self.write(to, &[head, body])
    }

    fn readable(&self) -> Option<&dyn Readable> {
        self.driven.then_some(&*self.shared as &dyn Readable)
    }

    fn stats(&self) -> LinkStats {
        let c = &self.shared.counters;
        LinkStats {
            frames_sent: c.sent.load(Ordering::Relaxed),
            frames_received: c.received.load(Ordering::Relaxed),
            frames_dropped: c.dropped.load(Ordering::Relaxed) + self.lost(),
            buffered_bytes: self.backlog.as_ref().map_or(0, |b| b.bytes() as u64),
            ..LinkStats::default()
        }
    }
}

impl Drop for CycloneLink {
    fn drop(&mut self) {
        self.shared.closed.store(true, Ordering::Relaxed);
        if let Some(backlog) = &self.backlog {
            let unsent = backlog.close() as u64;
            self.shared
                .counters
                .dropped
                .fetch_add(unsent, Ordering::Relaxed);
        }
        if let Some(t) = self.backlog_writer.take() {
            let _ = t.join();
        }
        if let Some(t) = self.receiver.take() {
            let _ = t.join();
        }
        // The fields drop next, `_participant` first: the reader and writers go with it.
    }
}
