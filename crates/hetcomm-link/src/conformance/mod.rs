//! The conformance suite every transport runs: one set of behaviours, checked the same way on
//! every [`Link`] implementation (as iceoryx2 does for its backends).
//!
//! A transport's tests implement [`Harness`] (how to open an endpoint for a system) and call
//! [`run_all`], once on the bare link and once wrapped in emulation ([`Layered::emulated`]).
//! Checks adapt to the link's declared [`LinkCaps`](crate::LinkCaps): an unreliable link need
//! not deliver everything, but every frame it does not deliver must be one the links counted
//! as lost (`frames_dropped` of either end, the receiver's `kernel_drops`): on loopback a
//! healthy unreliable link loses frames only where a buffer overflowed, and says so. Where the
//! harness configures loss ([`Harness::configured_loss`], an emulation), what arrives must
//! also be within a statistical bound of it. No link may corrupt, invent or mislabel a frame.
//!
//! **Driven links.** A link that offers a receive side ([`Link::readable`]) starts no receive
//! thread: nothing arrives unless someone reads it. The suite reads such links itself, through
//! `readable()` only, as the runtime's waiting threads do; so a wrapper that does not pass the
//! receive side on fails every check that expects a frame. Links without one deliver on their
//! own (a receive thread, or the sender's thread for in-process links), and
//! [`receive_side_delivers`] checks them that way, with nobody reading.
//!
//! What is checked: delivery both ways with the right sender; sizes from 1 byte to 1 MiB + 1;
//! many frames against the declared caps (no loss if reliable, no reordering if ordered, never
//! a duplicate or an invented frame); an unknown destination and an oversize frame are errors;
//! traffic resumes after a peer restart; frames arrive through the link's receive side (read
//! through `Readable` on a driven link, by the link itself otherwise); frames held for batching go out at `flush` and before a later plain send;
//! `send_parts` delivers head and body as one frame; frames given away (`send_owned`) keep
//! their place among the others and their buffers come back; frames handed to a sink that takes them
//! ([`FrameSink::on_frame_owned`]) arrive intact; and a layer stack over the link (a tap on
//! both sides) sees and passes on every frame, whichever way it was sent or received.
//!
//! The suite's files: this one the [`Harness`] a transport implements and the layered
//! harnesses; `sinks.rs` the endpoints and sinks the checks read with ([`CollectSink`]);
//! `checks.rs` the checks themselves.

mod checks;
mod sinks;

pub use checks::*;
pub use sinks::{CollectSink, Received};

use std::sync::Arc;
use std::time::{Duration, Instant};

use hetcomm_core::SystemId;

use crate::emulation::{EmulationLayer, ModelParams, PositionTable};
use crate::layer::{LayerContext, LayerStack};
use crate::{FrameSink, Link};

/// How long a check waits for frames to arrive before it fails.
pub const WAIT: Duration = Duration::from_secs(10);

/// Opens link endpoints for the suite.
pub trait Harness {
    /// Opens an endpoint for `system` whose received frames go to `sink`. Opening a system that
    /// was opened before (and whose link was dropped) must work: that is a peer restart.
    ///
    /// A link with a receive side ([`Link::readable`]) is returned as it is: the suite reads
    /// it (a harness must not start a thread of its own that reads it too).
    fn open(&mut self, system: SystemId, sink: Arc<dyn FrameSink>) -> Box<dyn Link>;

    /// The fraction of frames (0 to 1) this harness's links lose by design, such as an
    /// emulation with `loss_percent`: checks then require what arrives to be within a
    /// statistical bound of it. 0 (the default) for links as they are: on loopback a healthy
    /// link loses only frames it counts.
    fn configured_loss(&self) -> f64 {
        0.0
    }
}

/// A harness whose links are wrapped in a [`LayerStack`], both sides, as the runtime wraps
/// links where it opens them.
pub struct Layered<H> {
    /// The harness that opens the bare links.
    pub inner: H,
    /// The layers put over them.
    pub stack: LayerStack,
}

impl<H: Harness> Layered<H> {
    /// `inner`'s links with `stack` over them.
    pub fn new(inner: H, stack: LayerStack) -> Self {
        Layered { inner, stack }
    }

    /// `inner`'s links wrapped in emulation with a model that loses, delays and changes
    /// nothing (the default parameters), so every check applies unchanged: what is tested is
    /// that the wrapping itself loses nothing a link offers.
    pub fn emulated(inner: H) -> Self {
        let layer = EmulationLayer::new(
            ModelParams::default(),
            1,
            PositionTable::new(),
            Instant::now(),
        );
        Self::new(inner, LayerStack::new().with(Arc::new(layer)))
    }
}

/// A harness whose links each get their own [`LayerStack`], made per system when it opens:
/// for layers that keep state per link (the security layer holds a system's keys and
/// sessions).
pub struct LayeredPerSystem<H, F> {
    /// The harness that opens the bare links.
    pub inner: H,
    /// Makes the layers for a system's link.
    pub make: F,
}

impl<H: Harness, F: FnMut(SystemId) -> LayerStack> Harness for LayeredPerSystem<H, F> {
    fn open(&mut self, system: SystemId, sink: Arc<dyn FrameSink>) -> Box<dyn Link> {
        let stack = (self.make)(system);
        Layered::new(&mut self.inner, stack).open(system, sink)
    }

    fn configured_loss(&self) -> f64 {
        self.inner.configured_loss()
    }
}

impl<H: Harness + ?Sized> Harness for &mut H {
    fn open(&mut self, system: SystemId, sink: Arc<dyn FrameSink>) -> Box<dyn Link> {
        (**self).open(system, sink)
    }

    fn configured_loss(&self) -> f64 {
        (**self).configured_loss()
    }
}

impl<H: Harness> Harness for Layered<H> {
    fn open(&mut self, system: SystemId, sink: Arc<dyn FrameSink>) -> Box<dyn Link> {
        let ctx = LayerContext::new(system);
        let Layered { inner, stack } = self;
        let wrapped = stack
            .open(&ctx, sink, &mut |sink| {
                Ok(Arc::from(inner.open(system, sink)))
            })
            .unwrap_or_else(|e| panic!("layers {:?}: {e}", stack.names()));
        Box::new(wrapped)
    }

    /// The inner harness's: the layers put over it are taken to lose nothing
    /// ([`Layered::emulated`] uses a model that loses nothing).
    fn configured_loss(&self) -> f64 {
        self.inner.configured_loss()
    }
}

/// Runs every check, each with fresh endpoints.
pub fn run_all(h: &mut dyn Harness) {
    delivers_both_ways(h);
    preserves_sizes(h);
    many_frames_respect_caps(h);
    unknown_destination_is_an_error(h);
    oversize_frame_is_refused(h);
    traffic_resumes_after_peer_restart(h);
    receive_side_delivers(h);
    held_frames_are_flushed(h);
    send_parts_arrive_as_one_frame(h);
    given_frames_keep_their_place(h);
    owned_frames_arrive_intact(h);
    layers_see_and_pass_every_frame(h);
}

#[cfg(test)]
mod tests {
    use std::sync::atomic::{AtomicU64, Ordering};

    use super::*;
    use crate::inproc::{InprocHub, InprocLink};
    use crate::LinkCaps;
    use crate::LinkError;

    /// An in-process link that says it is unreliable and silently loses 9 frames of 10.
    struct Leaky {
        inner: InprocLink,
        sent: AtomicU64,
    }

    impl Link for Leaky {
        fn caps(&self) -> LinkCaps {
            LinkCaps {
                reliable: false,
                ..self.inner.caps()
            }
        }

        fn send(&self, to: SystemId, frame: &[u8]) -> Result<(), LinkError> {
            if self.sent.fetch_add(1, Ordering::Relaxed).is_multiple_of(10) {
                self.inner.send(to, frame)
            } else {
                Ok(())
            }
        }
    }

    struct LeakyHarness(InprocHub);

    impl Harness for LeakyHarness {
        fn open(&mut self, system: SystemId, sink: Arc<dyn FrameSink>) -> Box<dyn Link> {
            Box::new(Leaky {
                inner: self.0.open(system, sink),
                sent: AtomicU64::new(0),
            })
        }
    }

    /// A conformance check.
    type Check = fn(&mut dyn Harness);

    /// Whether `check` fails on a link that loses 90% of its frames without a count.
    fn fails_on_a_leaky_link(check: Check) -> bool {
        let mut h = LeakyHarness(InprocHub::new());
        std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| check(&mut h))).is_err()
    }

    /// Each failing check waits [`WAIT`] for the frames that never come: two of them.
    #[test]
    fn a_link_that_loses_most_frames_uncounted_fails_the_checks() {
        let checks: [(&str, Check); 2] = [
            ("many_frames_respect_caps", many_frames_respect_caps),
            ("receive_side_delivers", receive_side_delivers),
        ];
        for (name, check) in checks {
            assert!(
                fails_on_a_leaky_link(check),
                "{name} passed a 90%-loss link"
            );
        }
    }
}
