//! A system's scheduled faults (the verdict on every frame it sends, injections) and the
//! queue of what is held back until later, with the real-time thread that drives it.

use std::cmp::Reverse;
use std::sync::atomic::Ordering;
use std::sync::Weak;
use std::time::Duration;

use hetcomm_core::{SystemId, Time};

use super::*;

impl SystemHarness {
    /// Installs a fault schedule (once per system).
    pub(crate) fn set_faults(&self, faults: Faults) {
        if self.faults.set(faults).is_ok() {
            self.faulted.store(true, Ordering::Release);
        }
    }

    /// What the scheduled faults do with a frame of `len` bytes from this system to `to` at
    /// `now`.
    fn fault_verdict(&self, now: Time, from: SystemId, to: SystemId, len: usize) -> FaultVerdict {
        match self.faults.get() {
            Some(f) => f.verdict(now, from, to, len),
            None => FaultVerdict::Pass,
        }
    }

    /// Applies the fault schedule to a frame about to leave on `link`; true: the harness
    /// took it (dropped it, or holds it back), false: it goes now.
    #[cold]
    #[inline(never)]
    pub(crate) fn fault_frame(
        &self,
        from: SystemId,
        link: usize,
        to: SystemId,
        frame: &[u8],
        body: &[u8],
        now: Time,
    ) -> bool {
        match self.fault_verdict(now, from, to, frame.len() + body.len()) {
            FaultVerdict::Pass => false,
            FaultVerdict::Drop => {
                bump(&self.counters.fault_dropped, 1);
                true
            }
            FaultVerdict::Delay(d) => {
                bump(&self.counters.fault_delayed, 1);
                let mut bytes = Vec::with_capacity(frame.len() + body.len());
                bytes.extend_from_slice(frame);
                bytes.extend_from_slice(body);
                self.hold(now + d, Held::Frame { link, to, bytes });
                true
            }
        }
    }

    /// Counts an item that could not be handed over.
    pub(crate) fn count_lost(&self) {
        bump(&self.counters.lost_on_close, 1);
    }

    /// Injects an encoded payload on a message path or a topic.
    pub(crate) fn inject_bytes(
        &self,
        core: &SystemCore,
        target: &Target,
        message_type: MessageType,
        payload: &[u8],
        now: Time,
    ) -> Result<(), InjectError> {
        match target {
            Target::Messages(m) => {
                let module = m.module.ok_or_else(|| InjectError::Unsupported {
                    path: format!("{target:?}"),
                    reason: "the path names no destination module".into(),
                })?;
                let header = self.injected_header(core, m, module, message_type, now);
                bump(&self.counters.injected, 1);
                match core.deliver_untapped(header, PayloadBuf::copy_from_slice(payload), now, None)
                {
                    AckStatus::Delivered => Ok(()),
                    other => Err(InjectError::Refused(other)),
                }
            }
            Target::Topic(name) => {
                let value = self.topics.decode(name, payload)?;
                self.inject_value(target, value, now)
            }
        }
    }

    /// A header for an injected message: as from the path's source system (the destination
    /// itself when the path names none), numbered in a space of its own.
    fn injected_header(
        &self,
        core: &SystemCore,
        m: &MessageMatch,
        module: ModuleId,
        message_type: MessageType,
        now: Time,
    ) -> Header {
        let mut h = Header::data(
            hetcomm_core::Address {
                system: m.from.unwrap_or(core.id),
                module,
            },
            hetcomm_core::Address {
                system: m.to,
                module,
            },
            m.message_type.unwrap_or(message_type),
        );
        h.seq = (1 << 63) | self.inject_seq.fetch_add(1, Ordering::Relaxed);
        h.timestamp = now;
        h
    }

    /// Publishes a value to a topic's subscribers, past its taps.
    pub(crate) fn inject_value(
        &self,
        target: &Target,
        value: TopicValue,
        now: Time,
    ) -> Result<(), InjectError> {
        match target {
            Target::Topic(name) => {
                bump(&self.counters.injected, 1);
                self.topics.deliver(name, value, now);
                Ok(())
            }
            Target::Messages(_) => Err(InjectError::Unsupported {
                path: format!("{target:?}"),
                reason: "a message path takes encoded payloads (Replacement::inject)".into(),
            }),
        }
    }

    /// Holds `item` until `at`.
    pub(crate) fn hold(&self, at: Time, item: Held) {
        let id = self.next_due_id.fetch_add(1, Ordering::Relaxed);
        self.queue.lock().push(Reverse(Due { at, id, item }));
        self.wake.notify_all();
        self.ensure_driver();
        // Under simulation the simulator drives the queue: it must learn the new due time.
        if let Some((weak, false)) = self.owner.get() {
            if let Some(core) = weak.upgrade() {
                core.sim_held(at);
            }
        }
    }

    /// The earliest time something held is due.
    pub(crate) fn next_due(&self) -> Option<Time> {
        self.queue.lock().peek().map(|Reverse(d)| d.at)
    }

    /// Hands over everything due at or before `now`, in time order.
    pub(crate) fn fire_due(&self, core: &SystemCore, now: Time) {
        loop {
            let item = {
                let mut q = self.queue.lock();
                match q.peek() {
                    Some(Reverse(d)) if d.at <= now => q.pop().map(|Reverse(d)| d.item),
                    _ => None,
                }
            };
            let Some(item) = item else { return };
            self.fire(core, item, now);
        }
    }

    fn fire(&self, core: &SystemCore, item: Held, now: Time) {
        match item {
            Held::Deliver { header, payload } => {
                if core.deliver_untapped(header, payload, now, None) != AckStatus::Delivered {
                    bump(&self.counters.lost_on_close, 1);
                }
            }
            Held::Topic { topic, value } => self.topics.deliver(&topic, value, now),
            Held::Frame { link, to, bytes } => {
                if core.send_held_frame(link, to, &bytes).is_err() {
                    bump(&self.counters.lost_on_close, 1);
                }
            }
            Held::Run(f) => f(core, now),
        }
    }

    /// Starts the real-time driver thread if it is needed and not running.
    fn ensure_driver(&self) {
        let Some((weak, true)) = self.owner.get() else {
            return;
        };
        let mut driver = self.driver.lock();
        if driver.is_some() {
            return;
        }
        let weak = weak.clone();
        let name = weak
            .upgrade()
            .map(|c| c.name)
            .unwrap_or("closed")
            .to_string();
        *driver = std::thread::Builder::new()
            .name(format!("hetcomm-harness-{name}"))
            .spawn(move || drive(weak))
            .ok();
    }

    /// Counts what is still held when the system closes, and wakes the driver so it ends.
    pub(crate) fn close(&self) {
        let left = {
            let mut q = self.queue.lock();
            let n = q.len() as u64;
            q.clear();
            n
        };
        bump(&self.counters.lost_on_close, left);
        self.wake.notify_all();
        let handle = self.driver.lock().take();
        if let Some(h) = handle {
            if h.thread().id() != std::thread::current().id() {
                let _ = h.join();
            }
        }
    }
}

/// The real-time driver: sleeps until the next held item is due, hands it over, and ends when
/// the system closes.
fn drive(core: Weak<SystemCore>) {
    loop {
        let Some(c) = core.upgrade() else { return };
        if c.is_closed() {
            return;
        }
        let now = c.clock.now();
        c.harness.fire_due(&c, now);
        let h = &c.harness;
        let mut q = h.queue.lock();
        let wait = match q.peek() {
            Some(Reverse(d)) => {
                Duration::from_micros(d.at.as_micros().saturating_sub(c.clock.now().as_micros()))
            }
            // Look again now and then so that a closed system's thread ends.
            None => Duration::from_millis(200),
        };
        if !wait.is_zero() {
            h.wake
                .wait_for(&mut q, wait.min(Duration::from_millis(200)));
        }
    }
}
