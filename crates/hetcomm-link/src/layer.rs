//! Layers over links: what sits between the router and a transport, on both directions.
//!
//! A [`LinkLayer`] wraps the two halves of a link: the *send side* (the [`Link`] the router
//! calls) and the *receive side* (the [`FrameSink`] the link hands frames to). A [`LayerStack`]
//! lists layers from the router down to the link and wraps both halves in the right order:
//!
//! ```text
//!  router ──send──▶ top layer's link ──▶ … ──▶ bottom layer's link ──▶ transport link
//!  router ◀─frame── top layer's sink ◀── … ◀── bottom layer's sink ◀── transport link
//! ```
//!
//! The stack is built where links are opened (`hetcomm`'s `transports.rs`), for the
//! real-time runtime and the simulator alike, so a layer exists identically in both; under
//! simulation ([`LayerContext::virtual_time`]) a layer whose model the simulator applies
//! itself (emulation) leaves the link as it is.
//!
//! A layer wraps one link in one call, [`LinkLayer::wrap`]: it is handed the sink above and a
//! function that opens the link below, so the state its two sides share is made for that
//! link alone. Writing a layer: a wrapper link implements [`Link`] with
//! [`forward_link!`](crate::forward_link) and a wrapper sink implements [`FrameSink`] with
//! [`forward_sink!`](crate::forward_sink):
//! both write only the methods the layer changes and forward the rest, so nothing a link
//! offers (its driven receive side, [`Link::readable`], above all) is lost by wrapping. The
//! stack also refuses a wrapper that hides a receive side the link has
//! ([`LayerError::HidesReceive`]).
//!
//! Layers that exist: emulation ([`EmulationLayer`](crate::emulation::EmulationLayer)) and
//! taps ([`TapLayer`]). An empty stack wraps nothing: a link with no layers costs nothing
//! extra.
//!
//! ```
//! use std::sync::Arc;
//! use std::sync::atomic::{AtomicU64, Ordering};
//! use hetcomm_core::SystemId;
//! use hetcomm_link::conformance::CollectSink;
//! use hetcomm_link::inproc::InprocHub;
//! use hetcomm_link::layer::{LayerContext, LayerStack, Tap, TapLayer};
//! use hetcomm_link::{Link, Peer};
//!
//! #[derive(Default)]
//! struct Count(AtomicU64, AtomicU64);
//! impl Tap for Count {
//!     fn on_send(&self, _to: SystemId, _head: &[u8], _body: &[u8]) {
//!         self.0.fetch_add(1, Ordering::Relaxed);
//!     }
//!     fn on_receive(&self, _frame: &[u8], _from: Peer) {
//!         self.1.fetch_add(1, Ordering::Relaxed);
//!     }
//! }
//!
//! let count = Arc::new(Count::default());
//! let stack = LayerStack::new().with(Arc::new(TapLayer::new(count.clone())));
//! let hub = InprocHub::new();
//! let (ctx_a, ctx_b) = (LayerContext::new(SystemId(1)), LayerContext::new(SystemId(2)));
//! let a = stack
//!     .open(&ctx_a, CollectSink::new(), &mut |sink| Ok(Arc::new(hub.open(SystemId(1), sink))))
//!     .unwrap();
//! let sink_b = CollectSink::new();
//! let _b = stack
//!     .open(&ctx_b, sink_b.clone(), &mut |sink| Ok(Arc::new(hub.open(SystemId(2), sink))))
//!     .unwrap();
//! a.send(SystemId(2), b"frame").unwrap();
//! assert_eq!(sink_b.frames()[0].bytes, b"frame");
//! assert_eq!((count.0.load(Ordering::Relaxed), count.1.load(Ordering::Relaxed)), (1, 1));
//! ```

use std::sync::Arc;

use hetcomm_core::{FrameBuf, SystemId};

use crate::{FrameSink, Link, LinkError, Peer};

/// Where a layer is being applied.
#[derive(Clone, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub struct LayerContext {
    /// The system whose link is wrapped.
    pub local: SystemId,
    /// The link is a simulator's, in virtual time: a layer whose model the simulator applies
    /// itself (emulation) must not apply it again in real time.
    pub virtual_time: bool,
}

impl LayerContext {
    /// A context for system `local`'s link, in real time.
    pub fn new(local: SystemId) -> Self {
        LayerContext {
            local,
            virtual_time: false,
        }
    }

    /// The same context for a simulated link (virtual time).
    pub fn in_virtual_time(mut self) -> Self {
        self.virtual_time = true;
        self
    }
}

/// Why a layer could not be put over a link.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum LayerError {
    /// The layer failed to build its wrapper (e.g. its delay thread could not start).
    #[error("layer `{layer}` could not wrap the link: {source}")]
    Wrap {
        /// The layer's [`LinkLayer::name`].
        layer: String,
        /// What went wrong.
        #[source]
        source: Box<dyn std::error::Error + Send + Sync>,
    },
    /// The wrapper has no receive side ([`Link::readable`]) although the link it wraps has
    /// one: nobody would read that link, and no frame would ever arrive.
    #[error(
        "layer `{layer}` hides the receive side of the link it wraps (Link::readable): no frame would be read"
    )]
    HidesReceive {
        /// The layer's [`LinkLayer::name`].
        layer: String,
    },
    /// The link under the layers could not be opened: the opener's error, as it is.
    #[error(transparent)]
    Open(Box<dyn std::error::Error + Send + Sync>),
}

/// Opens the link under a layer, delivering to the sink it is handed: the layers below and, at
/// the bottom, the transport's own link. Called at most once per [`LinkLayer::wrap`].
pub type OpenBelow<'a> = &'a mut dyn FnMut(Arc<dyn FrameSink>) -> Result<Arc<dyn Link>, LayerError>;

/// Something put between the router and a link, on both directions: the send side and the
/// receive side. See the [module docs](self).
pub trait LinkLayer: Send + Sync {
    /// A short name for errors and tools (`emulation`, `tap`, …).
    fn name(&self) -> &str;

    /// Wraps one link, both sides, in one call: `sink` is where the layer above (or the
    /// router) takes received frames; the layer wraps it, opens the link below with the
    /// wrapped sink through `open`, and returns the link the layer above sends through. What
    /// the two sides share is made here, for this link alone, so a layer used for a second
    /// link binds nothing of the first. A wrapper must offer everything the link offers
    /// that it does not change (write it with [`forward_link!`](crate::forward_link) and
    /// [`forward_sink!`](crate::forward_sink)). A layer that changes nothing returns
    /// `open(sink)`.
    fn wrap(
        &self,
        ctx: &LayerContext,
        sink: Arc<dyn FrameSink>,
        open: OpenBelow<'_>,
    ) -> Result<Arc<dyn Link>, LayerError>;
}

/// Layers in order from the router down to the link. Cheap to clone.
#[derive(Clone, Default)]
pub struct LayerStack {
    layers: Vec<Arc<dyn LinkLayer>>,
}

impl LayerStack {
    /// A stack with no layers: wraps nothing.
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds `layer` below the layers already in the stack (nearer the link).
    pub fn push(&mut self, layer: Arc<dyn LinkLayer>) {
        self.layers.push(layer);
    }

    /// The stack with `layer` added below the others.
    pub fn with(mut self, layer: Arc<dyn LinkLayer>) -> Self {
        self.push(layer);
        self
    }

    /// Whether the stack has no layers.
    pub fn is_empty(&self) -> bool {
        self.layers.is_empty()
    }

    /// The layers' names, from the router down.
    pub fn names(&self) -> Vec<&str> {
        self.layers.iter().map(|l| l.name()).collect()
    }

    /// Opens a link through the layers: `open` opens the transport's own link with the sink
    /// the bottom layer hands it; frames it reads pass through the bottom layer first and the
    /// top layer last on their way to the router's `sink`, and the router's sends through
    /// the top layer first. Fails if opening fails (with `open`'s error), if a layer cannot
    /// build its wrapper, or if a layer hides the receive side of the link below
    /// ([`LayerError::HidesReceive`]). An empty stack returns `open(sink)`.
    pub fn open(
        &self,
        ctx: &LayerContext,
        sink: Arc<dyn FrameSink>,
        open: OpenBelow<'_>,
    ) -> Result<Arc<dyn Link>, LayerError> {
        open_through(&self.layers, ctx, sink, open)
    }
}

/// `layers[0]` over `layers[1]` over … over what `open` opens.
fn open_through(
    layers: &[Arc<dyn LinkLayer>],
    ctx: &LayerContext,
    sink: Arc<dyn FrameSink>,
    open: OpenBelow<'_>,
) -> Result<Arc<dyn Link>, LayerError> {
    let Some((top, below)) = layers.split_first() else {
        return open(sink);
    };
    let mut driven = false;
    let wrapped = top.wrap(ctx, sink, &mut |sink| {
        let link = open_through(below, ctx, sink, open)?;
        driven = link.readable().is_some();
        Ok(link)
    })?;
    if driven && wrapped.readable().is_none() {
        return Err(LayerError::HidesReceive {
            layer: top.name().to_string(),
        });
    }
    Ok(wrapped)
}

/// Implements [`FrameSink`] for a type that wraps another sink, forwarding to it every method
/// the wrapper does not write itself: the receive-side counterpart of
/// [`forward_link!`](crate::forward_link), with the same syntax.
///
/// ```
/// use std::sync::Arc;
/// use hetcomm_link::{forward_sink, FrameSink, Peer};
///
/// /// Drops empty frames before they reach the router.
/// struct NoEmpty(Arc<dyn FrameSink>);
///
/// forward_sink! {
///     [impl] NoEmpty => 0;
///     fn on_frame(&self, frame: &[u8], from: Peer) {
///         if !frame.is_empty() {
///             self.0.on_frame(frame, from);
///         }
///     }
/// }
/// ```
///
/// A method the wrapper leaves out is forwarded, except that when the wrapper writes
/// `on_frame` and not the others, `on_frame_owned` lends the frame to the wrapper's
/// `on_frame`, `on_frames` hands each frame to it, and `takes_frames` is false: a wrapper that
/// looks at frames sees every one.
#[macro_export]
macro_rules! forward_sink {
    (
        [$($gen:tt)*] $ty:ty => $($field:tt).+ ;
        $( $(#[$attr:meta])* fn $name:ident $args:tt $(-> $ret:ty)? $body:block )*
    ) => {
        $($gen)* $crate::FrameSink for $ty {
            $( $(#[$attr])* fn $name $args $(-> $ret)? $body )*
            $crate::forward_sink!(@rest [$($name)*] $($field).+);
        }
    };
    (@rest [$($n:ident)*] $($field:tt).+) => {
        $crate::__if_named!(on_frame [$($n)*] {} {
            fn on_frame(&self, frame: &[u8], from: $crate::Peer) {
                $crate::FrameSink::on_frame(&self.$($field).+, frame, from)
            }
        });
        $crate::__if_named!(on_frame_owned [$($n)*] {} {
            $crate::__if_named!(on_frame [$($n)*] {
                fn on_frame_owned(&self, frame: $crate::__core::FrameBuf, from: $crate::Peer) {
                    $crate::FrameSink::on_frame(self, &frame, from)
                }
            } {
                fn on_frame_owned(&self, frame: $crate::__core::FrameBuf, from: $crate::Peer) {
                    $crate::FrameSink::on_frame_owned(&self.$($field).+, frame, from)
                }
            });
        });
        $crate::__if_named!(on_frames [$($n)*] {} {
            $crate::__if_named!(on_frame [$($n)*] {
                fn on_frames(
                    &self,
                    frames: &mut dyn ::std::iter::Iterator<Item = &[u8]>,
                    from: $crate::Peer,
                ) {
                    for frame in frames {
                        $crate::FrameSink::on_frame(self, frame, from);
                    }
                }
            } {
                fn on_frames(
                    &self,
                    frames: &mut dyn ::std::iter::Iterator<Item = &[u8]>,
                    from: $crate::Peer,
                ) {
                    $crate::FrameSink::on_frames(&self.$($field).+, frames, from)
                }
            });
        });
        $crate::__if_named!(on_event [$($n)*] {} {
            fn on_event(&self, event: $crate::LinkEvent) {
                $crate::FrameSink::on_event(&self.$($field).+, event)
            }
        });
        $crate::__if_named!(takes_frames [$($n)*] {} {
            $crate::__if_named!(on_frame [$($n)*] {
                fn takes_frames(&self) -> bool {
                    false
                }
            } {
                fn takes_frames(&self) -> bool {
                    $crate::FrameSink::takes_frames(&self.$($field).+)
                }
            });
        });
    };
}

/// What a [`TapLayer`] shows: every frame the router sends and every frame the link
/// receives, as they pass. Called on the sending thread and on the link's receive thread:
/// must be quick and must not block.
pub trait Tap: Send + Sync + 'static {
    /// A frame the router sends to `to`: `head` followed by `body` (`body` is empty for a
    /// frame sent in one piece).
    fn on_send(&self, to: SystemId, head: &[u8], body: &[u8]);

    /// A frame the link received, before the layers above and the router see it.
    fn on_receive(&self, frame: &[u8], from: Peer);
}

/// A layer that shows every frame, both ways, to a [`Tap`] and changes nothing: vectored
/// sends, batching, owned frames and driven receiving all pass through as they are.
pub struct TapLayer {
    tap: Arc<dyn Tap>,
}

impl TapLayer {
    /// A layer showing frames to `tap`.
    pub fn new(tap: Arc<dyn Tap>) -> Self {
        TapLayer { tap }
    }
}

impl LinkLayer for TapLayer {
    fn name(&self) -> &str {
        "tap"
    }

    fn wrap(
        &self,
        _ctx: &LayerContext,
        sink: Arc<dyn FrameSink>,
        open: OpenBelow<'_>,
    ) -> Result<Arc<dyn Link>, LayerError> {
        let link = open(Arc::new(TapSink {
            inner: sink,
            tap: self.tap.clone(),
        }))?;
        Ok(Arc::new(TapLink {
            inner: link,
            tap: self.tap.clone(),
        }))
    }
}

/// The send side of a [`TapLayer`].
struct TapLink {
    inner: Arc<dyn Link>,
    tap: Arc<dyn Tap>,
}

crate::forward_link! {
    [impl] TapLink => inner;
    fn send(&self, to: SystemId, frame: &[u8]) -> Result<(), LinkError> {
        self.tap.on_send(to, frame, &[]);
        self.inner.send(to, frame)
    }
    fn send_parts(&self, to: SystemId, head: &[u8], body: &[u8]) -> Result<(), LinkError> {
        self.tap.on_send(to, head, body);
        self.inner.send_parts(to, head, body)
    }
    fn send_held(&self, to: SystemId, frame: &[u8]) -> Result<(), LinkError> {
        self.tap.on_send(to, frame, &[]);
        self.inner.send_held(to, frame)
    }
    fn send_owned(&self, to: SystemId, frame: FrameBuf) -> Result<(), LinkError> {
        self.tap.on_send(to, &frame, &[]);
        self.inner.send_owned(to, frame)
    }
}

/// The receive side of a [`TapLayer`].
struct TapSink {
    inner: Arc<dyn FrameSink>,
    tap: Arc<dyn Tap>,
}

crate::forward_sink! {
    [impl] TapSink => inner;
    fn on_frame(&self, frame: &[u8], from: Peer) {
        self.tap.on_receive(frame, from);
        self.inner.on_frame(frame, from);
    }
    fn on_frame_owned(&self, frame: FrameBuf, from: Peer) {
        self.tap.on_receive(&frame, from);
        self.inner.on_frame_owned(frame, from);
    }
    fn on_frames(&self, frames: &mut dyn Iterator<Item = &[u8]>, from: Peer) {
        let tap = &self.tap;
        self.inner
            .on_frames(&mut frames.inspect(|f| tap.on_receive(f, from)), from);
    }
    fn takes_frames(&self) -> bool {
        self.inner.takes_frames()
    }
}

#[cfg(test)]
mod tests {
    use parking_lot::Mutex;
    use std::os::fd::RawFd;

    use super::*;
    use crate::conformance::CollectSink;
    use crate::emulation::{EmulationLayer, ModelParams, PositionTable};
    use crate::inproc::InprocHub;
    use crate::{LinkCaps, Readable};

    const A: SystemId = SystemId(1);
    const B: SystemId = SystemId(2);

    /// A link with a receive side that hands one canned frame to its sink per `read_ready`.
    struct Driven {
        sink: Arc<dyn FrameSink>,
    }

    impl Readable for Driven {
        fn fd(&self) -> RawFd {
            0
        }
        fn read_ready(&self, _budget: usize) -> std::io::Result<usize> {
            self.sink.on_frame(b"read", Peer::System(B));
            Ok(1)
        }
    }

    impl Link for Driven {
        fn caps(&self) -> LinkCaps {
            LinkCaps {
                max_frame: 1000,
                mtu: 1000,
                reliable: true,
                ordered: true,
                broadcast: false,
            }
        }
        fn send(&self, _to: SystemId, _frame: &[u8]) -> Result<(), LinkError> {
            Ok(())
        }
        fn readable(&self) -> Option<&dyn Readable> {
            Some(self)
        }
    }

    /// A layer whose wrapper forgets the receive side, as `EmulatedLink` once did.
    struct Forgetful;

    struct ForgetfulLink(Arc<dyn Link>);

    impl Link for ForgetfulLink {
        fn caps(&self) -> LinkCaps {
            self.0.caps()
        }
        fn send(&self, to: SystemId, frame: &[u8]) -> Result<(), LinkError> {
            self.0.send(to, frame)
        }
    }

    impl LinkLayer for Forgetful {
        fn name(&self) -> &str {
            "forgetful"
        }
        fn wrap(
            &self,
            _ctx: &LayerContext,
            sink: Arc<dyn FrameSink>,
            open: OpenBelow<'_>,
        ) -> Result<Arc<dyn Link>, LayerError> {
            Ok(Arc::new(ForgetfulLink(open(sink)?)))
        }
    }

    /// Opens `link` under `stack` (a link made before, whatever sink it is handed).
    fn over(
        stack: &LayerStack,
        ctx: &LayerContext,
        link: &Arc<dyn Link>,
    ) -> Result<Arc<dyn Link>, LayerError> {
        stack.open(ctx, CollectSink::new(), &mut |_| Ok(link.clone()))
    }

    fn emulation() -> Arc<dyn LinkLayer> {
        Arc::new(EmulationLayer::new(
            ModelParams::default(),
            1,
            PositionTable::new(),
            std::time::Instant::now(),
        ))
    }

    #[test]
    fn emulation_keeps_the_receive_side_of_a_driven_link() {
        let sink = CollectSink::new();
        let link: Arc<dyn Link> = Arc::new(Driven { sink: sink.clone() });
        let stack = LayerStack::new().with(emulation());
        let wrapped = over(&stack, &LayerContext::new(A), &link).unwrap();
        let rx = wrapped
            .readable()
            .expect("the emulated link offers the receive side");
        assert_eq!(rx.read_ready(8).unwrap(), 1);
        assert_eq!(sink.frames()[0].bytes, b"read");
    }

    #[test]
    fn a_layer_that_hides_the_receive_side_is_refused() {
        let link: Arc<dyn Link> = Arc::new(Driven {
            sink: CollectSink::new(),
        });
        let stack = LayerStack::new().with(Arc::new(Forgetful));
        let err = over(&stack, &LayerContext::new(A), &link)
            .err()
            .expect("refused");
        assert!(
            matches!(&err, LayerError::HidesReceive { layer } if layer == "forgetful"),
            "{err}"
        );
    }

    #[test]
    fn emulation_leaves_a_simulated_link_alone() {
        let link: Arc<dyn Link> = Arc::new(Driven {
            sink: CollectSink::new(),
        });
        let ctx = LayerContext::new(A).in_virtual_time();
        let wrapped = over(&LayerStack::new().with(emulation()), &ctx, &link).unwrap();
        assert!(Arc::ptr_eq(&wrapped, &link));
    }

    /// Records, in order, which tap saw each frame and in which direction.
    struct Named(&'static str, Arc<Mutex<Vec<String>>>);

    impl Tap for Named {
        fn on_send(&self, _to: SystemId, _head: &[u8], _body: &[u8]) {
            self.1.lock().push(format!("send {}", self.0));
        }
        fn on_receive(&self, _frame: &[u8], _from: Peer) {
            self.1.lock().push(format!("receive {}", self.0));
        }
    }

    #[test]
    fn the_top_layer_is_nearest_the_router_both_ways() {
        let log = Arc::new(Mutex::new(Vec::new()));
        let stack = LayerStack::new()
            .with(Arc::new(TapLayer::new(Arc::new(Named("top", log.clone())))))
            .with(Arc::new(TapLayer::new(Arc::new(Named(
                "bottom",
                log.clone(),
            )))));
        assert_eq!(stack.names(), ["tap", "tap"]);
        let hub = InprocHub::new();
        let (ca, cb) = (LayerContext::new(A), LayerContext::new(B));
        let a = stack
            .open(&ca, CollectSink::new(), &mut |s| {
                Ok(Arc::new(hub.open(A, s)))
            })
            .unwrap();
        let sink = CollectSink::new();
        let _b = stack
            .open(&cb, sink.clone(), &mut |s| Ok(Arc::new(hub.open(B, s))))
            .unwrap();
        a.send(B, b"x").unwrap();
        assert_eq!(sink.frames().len(), 1);
        assert_eq!(
            *log.lock(),
            ["send top", "send bottom", "receive bottom", "receive top"]
        );
    }

    #[test]
    fn an_empty_stack_wraps_nothing() {
        let hub = InprocHub::new();
        let sink: Arc<dyn FrameSink> = CollectSink::new();
        let stack = LayerStack::new();
        assert!(stack.is_empty());
        let ctx = LayerContext::new(A);
        let mut handed = None;
        let link = stack
            .open(&ctx, sink.clone(), &mut |s| {
                handed = Some(s.clone());
                Ok(Arc::new(hub.open(A, s)))
            })
            .unwrap();
        assert!(Arc::ptr_eq(&handed.expect("opened"), &sink));
        let bare: Arc<dyn Link> = Arc::new(hub.open(A, sink));
        assert!(Arc::ptr_eq(&over(&stack, &ctx, &bare).unwrap(), &bare));
        drop(link);
    }
}
