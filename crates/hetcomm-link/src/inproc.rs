//! The in-process link: systems of one process hand frames to each other's sinks directly, on
//! the sender's thread (no copy into a queue, no thread wake-up).

use parking_lot::RwLock;
use std::collections::HashMap;
use std::sync::Arc;

use hetcomm_core::{wire::HEADER_LEN, wire::MAX_PAYLOAD, SystemId};

use crate::registry::config::{KindSpec, RegisteredSettings, SettingsReader, TransportKind};
use crate::registry::{OpenFailure, OpenRequest, Opened, TransportFactory};
use crate::{FrameSink, Link, LinkCaps, LinkError, Peer};

/// The meeting point of one in-process transport instance: every system opened on it registers
/// its sink here.
#[derive(Clone, Default)]
pub struct InprocHub {
    sinks: Arc<RwLock<HashMap<SystemId, Arc<dyn FrameSink>>>>,
}

impl InprocHub {
    /// A hub with no systems.
    pub fn new() -> Self {
        Self::default()
    }

    /// Registers `system` with the sink its frames go to, and returns its link. Opening the
    /// same system again replaces its sink.
    pub fn open(&self, system: SystemId, sink: Arc<dyn FrameSink>) -> InprocLink {
        let registered = sink.clone();
        self.sinks.write().insert(system, sink);
        InprocLink {
            hub: self.clone(),
            local: system,
            sink: registered,
        }
    }

    /// Unregisters `system`; frames to it then fail as unreachable.
    pub fn close(&self, system: SystemId) {
        self.sinks.write().remove(&system);
    }
}

/// One system's endpoint on an [`InprocHub`].
pub struct InprocLink {
    hub: InprocHub,
    local: SystemId,
    /// The sink this link registered, so that dropping it never unregisters a newer link
    /// opened for the same system.
    sink: Arc<dyn FrameSink>,
}

impl Link for InprocLink {
    fn caps(&self) -> LinkCaps {
        let max = HEADER_LEN + MAX_PAYLOAD;
        LinkCaps {
            max_frame: max,
            mtu: max,
            reliable: true,
            ordered: true,
            broadcast: false,
        }
    }

    fn send(&self, to: SystemId, frame: &[u8]) -> Result<(), LinkError> {
        let max = self.caps().max_frame;
        if frame.len() > max {
            return Err(LinkError::TooLarge {
                len: frame.len(),
                max,
            });
        }
        // Clone the sink out so the hub lock is not held while the receiver runs.
        let sink = self.hub.sinks.read().get(&to).cloned();
        match sink {
            Some(sink) => {
                sink.on_frame(frame, Peer::System(self.local));
                Ok(())
            }
            None => Err(LinkError::Unreachable {
                peer: to,
                reason: "no system with that id is open on this in-process transport".into(),
            }),
        }
    }
}

impl Drop for InprocLink {
    fn drop(&mut self) {
        let mut sinks = self.hub.sinks.write();
        if sinks
            .get(&self.local)
            .is_some_and(|s| Arc::ptr_eq(s, &self.sink))
        {
            sinks.remove(&self.local);
        }
    }
}

/// The `inproc` transport factory: a system's link of an in-process transport is its place on
/// the hub the program keeps for that transport ([`OpenHost::hub`]). Its systems may hand
/// messages over directly ([`TransportFactory::hands_over`]); nothing leaves the process.
///
/// [`OpenHost::hub`]: crate::registry::OpenHost::hub
pub struct InprocFactory;

/// Settings of an `inproc` transport: it has no keys of its own.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct InprocSettings;

/// Its settings half: no keys, and frames that stay in the process.
impl KindSpec for InprocFactory {
    fn kind(&self) -> TransportKind {
        TransportKind::Inproc
    }

    fn keys(&self) -> &[&'static str] {
        &[]
    }

    fn parse(&self, _: &mut SettingsReader<'_, '_>) -> Option<RegisteredSettings> {
        Some(RegisteredSettings::new(InprocSettings))
    }

    fn in_process(&self) -> bool {
        true
    }
}

impl TransportFactory for InprocFactory {
    fn kind(&self) -> TransportKind {
        TransportKind::Inproc
    }

    fn spec(self: Arc<Self>) -> Option<Arc<dyn KindSpec>> {
        Some(self)
    }

    fn open(&self, request: OpenRequest<'_>) -> Result<Opened, OpenFailure> {
        let hub = request.host.hub(&request.transport.name);
        Ok(Opened {
            link: Arc::new(hub.open(request.local, request.sink)),
            local_address: None,
        })
    }

    fn leaves_process(&self) -> bool {
        false
    }

    fn hands_over(&self) -> bool {
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::conformance::{self, Harness};

    struct InprocHarness(InprocHub);

    impl Harness for InprocHarness {
        fn open(&mut self, system: SystemId, sink: Arc<dyn FrameSink>) -> Box<dyn Link> {
            Box::new(self.0.open(system, sink))
        }
    }

    #[test]
    fn dropping_a_replaced_link_keeps_the_newer_one() {
        let hub = InprocHub::new();
        let sink = crate::conformance::CollectSink::new();
        let a = hub.open(SystemId(1), crate::conformance::CollectSink::new());
        let old = hub.open(SystemId(2), crate::conformance::CollectSink::new());
        let _new = hub.open(SystemId(2), sink.clone());
        drop(old);
        a.send(SystemId(2), b"still here").unwrap();
        assert_eq!(sink.frames().len(), 1);
    }

    #[test]
    fn inproc_passes_conformance() {
        conformance::run_all(&mut InprocHarness(InprocHub::new()));
    }

    #[test]
    fn inproc_passes_conformance_wrapped_in_emulation() {
        conformance::run_all(&mut conformance::Layered::emulated(InprocHarness(
            InprocHub::new(),
        )));
    }
}
