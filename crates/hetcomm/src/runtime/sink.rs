//! A link's frames into the system: the sink each link delivers to.

use super::*;

/// What link number `link` of a system hands its frames to.
pub(super) struct SystemSink {
    pub(super) core: Weak<SystemCore>,
    pub(super) link: usize,
}

impl SystemSink {
    /// Gives arriving frames to the open system's router (`handle`, with one clock reading),
    /// then carries out what they caused.
    fn handle(&self, handle: impl FnOnce(&mut Router<Arc<OutcomeSlot>>, Time)) {
        let Some(core) = self.core.upgrade() else {
            return;
        };
        if core.is_closed() {
            return;
        }
        let now = core.clock.now();
        let mut router = core.router();
        handle(&mut router, now);
        core.pump_at(router, now);
    }
}

/// The system a link saw a frame come from, as the router takes it.
fn peer_system(from: Peer) -> Option<SystemId> {
    match from {
        Peer::System(id) => Some(id),
        Peer::Unknown => None,
    }
}

impl FrameSink for SystemSink {
    fn on_frame(&self, frame: &[u8], from: Peer) {
        self.on_frames(&mut std::iter::once(frame), from);
    }

    /// The frames of one batch datagram: one clock reading, one router lock and one pump for
    /// all of them instead of one each (they arrived at the same moment).
    fn on_frames(&self, frames: &mut dyn Iterator<Item = &[u8]>, from: Peer) {
        let peer = peer_system(from);
        self.handle(|router, now| {
            for frame in frames {
                router.handle_frame_from(now, self.link, peer, frame);
            }
        });
    }

    /// A large frame in a buffer of its own: the router delivers its payload in that buffer.
    fn on_frame_owned(&self, frame: FrameBuf, from: Peer) {
        let peer = peer_system(from);
        self.handle(|router, now| router.handle_frame_owned_from(now, self.link, peer, frame));
    }

    fn takes_frames(&self) -> bool {
        true
    }

    /// A security session with `peer` is up: sends that waited for it go now.
    fn on_peer_up(&self, peer: SystemId) {
        let link = self.link;
        self.handle(|router, now| {
            router.handle_link_event(now, hetcomm_router::LinkEvent::PeerUp { link, peer })
        });
    }
}
