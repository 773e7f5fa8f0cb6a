//! # hetcomm-link — the transport seam
//!
//! A [`Link`] moves whole frames (already encoded by the router) between systems. Every
//! transport — in-process, UDP, TCP, ROS 1, Bluetooth, emulated radios — implements this one
//! trait and declares its [`LinkCaps`], which the router reads (it never asks "which kind are
//! you?"). Frames a link receives go to the [`FrameSink`] it was opened with.
//!
//! This crate holds the trait, the in-process link ([`inproc`]), the [`layer`]s that go over
//! any link (the layer stack, taps, and [`emulation`]), and the [`conformance`] suite that
//! every transport runs, bare and wrapped. Transports with heavy dependencies live in their
//! own crates; each kind offers a [`registry::TransportFactory`] (its settings and how to open
//! it) that its crate adds to a [`registry::Registry`] with one line.
//!
//! ```
//! use std::sync::Arc;
//! use hetcomm_core::SystemId;
//! use hetcomm_link::{inproc::InprocHub, conformance::CollectSink, Link};
//!
//! let hub = InprocHub::new();
//! let sink_b = CollectSink::new();
//! let a = hub.open(SystemId(0), CollectSink::new());
//! let _b = hub.open(SystemId(1), sink_b.clone());
//! a.send(SystemId(1), b"frame").unwrap();
//! assert_eq!(sink_b.frames()[0].bytes, b"frame");
//! ```

pub mod batch;
pub mod bridge;
pub mod conformance;
pub mod emulation;
pub mod inproc;
pub mod layer;
pub mod readiness;
pub mod registry;
pub mod relay;
pub mod shape;

use std::sync::Arc;

/// Registers this crate's kinds, `inproc` and `emulated`, as every link crate registers its
/// own ([`registry`]).
pub fn register_transports(registry: &mut registry::Registry) {
    registry.register(inproc::InprocFactory);
    registry.register(emulation::EmulatedFactory);
}

use hetcomm_core::{FrameBuf, SystemId};

/// What a link can do; the router adapts to it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LinkCaps {
    /// Largest frame (header + payload) one `send` accepts.
    pub max_frame: usize,
    /// Largest frame carried without the link splitting it (its datagram/MTU size); equal to
    /// `max_frame` on links that never split.
    pub mtu: usize,
    /// Frames that were accepted arrive unless the peer is gone (no silent loss in transit).
    pub reliable: bool,
    /// Frames from one sender to one receiver arrive in the order they were sent.
    pub ordered: bool,
    /// The link can reach every peer with one send: a send to
    /// [`TO_ALL_SYSTEM`](hetcomm_core::wire::TO_ALL_SYSTEM) carries one frame to every system
    /// on the link (each receiver's router decides whether the table lets it take it). The
    /// router then sends a broadcast as one frame (`docs/wire-format.md`, native broadcasts)
    /// instead of a copy per destination. Layers that act per pair of systems (security,
    /// emulation) clear it.
    pub broadcast: bool,
}

/// Where a frame came from, as far as the link can tell.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Peer {
    /// The link knows which fleet system sent it (e.g. a connection from a known address).
    System(SystemId),
    /// The link cannot tell; the router relies on the frame header alone.
    Unknown,
}

/// Receives the frames a link reads. Called on the link's receive thread (or, for the
/// in-process link, on the sender's thread): must not block for long.
pub trait FrameSink: Send + Sync + 'static {
    /// One complete frame, as sent. The bytes are only borrowed for the call.
    fn on_frame(&self, frame: &[u8], from: Peer);

    /// One complete frame, as sent, handed over: the sink may keep the buffer (e.g. as the
    /// message's payload, without copying it). Links call it only when
    /// [`takes_frames`](FrameSink::takes_frames) says so, and only for frames in a buffer of
    /// their own (a large frame read straight from a stream, reassembled from datagrams, or
    /// copied out of a large datagram); the buffer may belong to the link's pool, and goes back
    /// to it when dropped. The default
    /// lends the bytes to [`on_frame`](FrameSink::on_frame).
    fn on_frame_owned(&self, frame: FrameBuf, from: Peer) {
        self.on_frame(&frame, from)
    }

    /// Several complete frames that arrived together (one datagram carrying a batch), in
    /// order. A sink can handle them at the cost of one (locking, clock reading, …) instead
    /// of one per frame. The default hands each to [`on_frame`](FrameSink::on_frame).
    fn on_frames(&self, frames: &mut dyn Iterator<Item = &[u8]>, from: Peer) {
        for frame in frames {
            self.on_frame(frame, from);
        }
    }

    /// Whether [`on_frame_owned`](FrameSink::on_frame_owned) keeps frames rather than copying
    /// them: a link then gives up a reusable buffer for a fresh one per large frame. The
    /// default is false.
    fn takes_frames(&self) -> bool {
        false
    }

    /// What the link knows about a peer's reachability ([`LinkEvent`]): a connection came up
    /// or was lost, a presence service saw the peer come or go, a security layer completed a
    /// handshake. Every layer forwards it (a layer may hold back what it knows to be untrue
    /// above it); the system's sink hands it to the router, which fails a pair's traffic
    /// over to its next transport on a peer lost and sends what waited on a peer up
    /// (`docs/failover.md`). Called on any thread; must not block for long. The default
    /// ignores it.
    fn on_event(&self, event: LinkEvent) {
        let _ = event;
    }
}

/// What a link reports about a peer through [`FrameSink::on_event`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum LinkEvent {
    /// The link can carry frames to the peer now: a connection to it came up, a presence
    /// service saw it, or (from a security layer) a secure session with it was made, so
    /// frames refused for want of one ([`LinkError::NoSession`]) may go at once.
    PeerUp(SystemId),
    /// The link lost the peer: its connection closed or failed, or a presence service said
    /// it left. Frames to it may still be accepted (a stream link reconnects), but nothing
    /// is known to arrive until it is up again.
    PeerDown(SystemId),
}

impl LinkEvent {
    /// The peer the event is about.
    pub fn peer(&self) -> SystemId {
        match *self {
            LinkEvent::PeerUp(p) | LinkEvent::PeerDown(p) => p,
        }
    }
}

/// Why a link could not take a frame.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum LinkError {
    /// The destination has no endpoint on this link, or cannot be reached now.
    #[error("peer {peer} unreachable: {reason}")]
    Unreachable {
        /// The destination system.
        peer: SystemId,
        /// What went wrong, e.g. "connection refused".
        reason: String,
    },
    /// The frame is larger than [`LinkCaps::max_frame`].
    #[error("frame of {len} bytes exceeds this link's limit of {max} bytes")]
    TooLarge {
        /// The frame's length.
        len: usize,
        /// The link's limit.
        max: usize,
    },
    /// The link's queue towards that peer is full (the frame was not taken).
    #[error("link to {peer} is congested: {reason}")]
    Congested {
        /// The destination system.
        peer: SystemId,
        /// What is full.
        reason: String,
    },
    /// The frame was not sent, and will not be: the link needs a session with the peer
    /// first (a security handshake) and has none yet. The handshake has been started; a
    /// later attempt goes out once it completes. Nothing of the frame left this system.
    #[error("no secure session with {peer}: {reason}")]
    NoSession {
        /// The destination system.
        peer: SystemId,
        /// Where the handshake stands, e.g. "the handshake has not been answered".
        reason: String,
    },
    /// The link will never carry this frame as it is: what it holds cannot be put on this
    /// transport (a bridge's message type has no mapping, or its payload does not convert to
    /// the mapped ROS type). Nothing was sent; a retry would be refused the same way, so the
    /// router fails the send at once, with this reason.
    #[error("refused by the link: {reason}")]
    Refused {
        /// The destination system.
        peer: SystemId,
        /// Why the frame cannot be carried, e.g. "message type 40 for Drive does not convert
        /// to geometry_msgs/Twist: …".
        reason: String,
    },
    /// The link was closed.
    #[error("link closed")]
    Closed,
    /// An operating-system error.
    #[error("i/o error: {0}")]
    Io(#[from] std::io::Error),
}

/// A transport endpoint of one system. Sending is on the caller's thread; receiving is the
/// link's own business (a thread, a callback, or synchronous delivery for in-process).
pub trait Link: Send + Sync {
    /// What this link can do.
    fn caps(&self) -> LinkCaps;

    /// Puts one frame on the link towards system `to`. `Ok` means the transport accepted it,
    /// not that it arrived.
    fn send(&self, to: SystemId, frame: &[u8]) -> Result<(), LinkError>;

    /// Like [`send`](Link::send), for the frame `head` followed by `body`: a sender can put a
    /// large payload behind its header without copying it into one buffer first. Links that
    /// write with vectored I/O (the stream links) send the pieces as they are; the default
    /// joins them and calls `send`.
    fn send_parts(&self, to: SystemId, head: &[u8], body: &[u8]) -> Result<(), LinkError> {
        if body.is_empty() {
            return self.send(to, head);
        }
        let mut frame = Vec::with_capacity(head.len() + body.len());
        frame.extend_from_slice(head);
        frame.extend_from_slice(body);
        self.send(to, &frame)
    }

    /// Like [`send`](Link::send), for a frame the caller gives away (a layer that built it,
    /// such as the security layer's sealed frames). A link that writes on a thread of its own
    /// may keep the buffer and write it after this returns, while the caller prepares the next
    /// frame (the stream links do for a sender that streams; see their "Write-behind" docs).
    /// `Ok` means the same as for `send`: the link took the frame, in order with every other
    /// frame to `to`, and counts it in [`LinkStats::frames_dropped`] if it cannot write it
    /// later. The default sends it at once and drops the buffer (back to its pool, if any).
    fn send_owned(&self, to: SystemId, frame: FrameBuf) -> Result<(), LinkError> {
        self.send(to, &frame)
    }

    /// Counters kept by the link (frames, drops, reconnects, …), for tools and tests.
    fn stats(&self) -> LinkStats {
        LinkStats::default()
    }

    /// Like [`send`](Link::send), but the link may hold the frame back in a per-peer batch so
    /// that it goes out together with the frames sent after it, in one write or datagram.
    /// Held frames go out in order, before any later frame to the same peer: when the batch is
    /// full, at the next plain `send` to that peer, or at [`flush`](Link::flush). The runtime
    /// decides when holding is worth it (see `batch_linger_us` in the fleet file); links that
    /// do not batch send at once, which is the default.
    fn send_held(&self, to: SystemId, frame: &[u8]) -> Result<(), LinkError> {
        self.send(to, frame)
    }

    /// Puts every held frame on the link now. A frame that then fails is counted in
    /// [`LinkStats::frames_dropped`]; the first error is returned.
    fn flush(&self) -> Result<(), LinkError> {
        Ok(())
    }

    /// Whether [`send_held`](Link::send_held) can hold frames back on this link.
    fn batches(&self) -> bool {
        false
    }

    /// The link's receive side, when a waiting thread may drive it (see [`Readable`]).
    /// `None` (the default): the link receives on its own.
    fn readable(&self) -> Option<&dyn Readable> {
        None
    }

    /// Whether the link itself guarantees the integrity of the bytes it delivers, so that a
    /// frame's CRC need only cover its header (`hetcomm_core::wire::FLAG_HEADER_CRC`): frames
    /// arrive whole and unaltered or not at all. True for reliable, checksummed byte streams
    /// (TCP, Unix stream sockets, Bluetooth RFCOMM). The default, false, is the safe answer:
    /// the router then checksums every payload it sends on this link and refuses frames with
    /// a header-only CRC that arrive on it.
    fn checksums_payload(&self) -> bool {
        false
    }

    /// Like [`send_parts`](Link::send_parts), for a link whose frames pass through an
    /// intermediary that confirms taking them (an MQTT broker's PUBACK at QoS 1): `Some`
    /// receipt that the link completes when the intermediary answers, or when it gives up
    /// waiting (its own bound; see [`relay`]). The runtime asks for one for an unacknowledged
    /// send's frame, whose outcome then says what the intermediary confirmed. The default,
    /// for links with nothing to confirm, sends and gives `None`.
    fn send_relayed(
        &self,
        to: SystemId,
        head: &[u8],
        body: &[u8],
    ) -> Result<Option<relay::RelayReceipt>, LinkError> {
        self.send_parts(to, head, body).map(|()| None)
    }
}

/// A receive side that a thread waiting for messages can drive itself, so that a frame
/// reaches the module that waits for it without a hand-off between threads (a wake-up that
/// crosses CPUs costs tens of microseconds). The runtime makes sure one thread at a time
/// reads; the link does not start a receive thread of its own for it.
pub trait Readable: Send + Sync {
    /// A descriptor that polls readable (`POLLIN`) whenever [`read_ready`](Readable::read_ready)
    /// may find something to read, open for as long as this receive side lives
    /// ([`readiness::readable_fd`] borrows it for that long).
    fn fd(&self) -> std::os::fd::RawFd;

    /// Reads, without blocking, what has arrived (at most `budget` reads), hands each complete
    /// frame to the link's sink, and does the link's periodic upkeep (e.g. expiring partial
    /// messages). Returns the number of frames handed on.
    fn read_ready(&self, budget: usize) -> std::io::Result<usize>;

    /// Whether something waits to be read, when the link can tell without a system call (its
    /// receive queue is in memory this process maps, as `shm`'s is). A thread that spins
    /// looks here instead of polling [`fd`](Readable::fd), and calls
    /// [`read_ready`](Readable::read_ready) on `Some(true)`. `None` (the default): the link
    /// cannot tell; poll its descriptor.
    fn pending(&self) -> Option<bool> {
        None
    }

    /// A thread starts (`true`) or stops (`false`) spinning on this link: reading it through
    /// [`pending`](Readable::pending) without sleeping in between. A link whose senders wake
    /// its descriptor may tell them to skip the wake-up meanwhile; when told `false` it makes
    /// its descriptor readable again if something arrived that no wake-up announced, so a
    /// thread that then sleeps on the descriptor still wakes. The default does nothing.
    fn set_spinning(&self, spinning: bool) {
        let _ = spinning;
    }
}

/// Counters a link may keep. Links fill in what applies to them.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct LinkStats {
    /// Frames accepted by `send`.
    pub frames_sent: u64,
    /// Frames handed to the sink.
    pub frames_received: u64,
    /// Frames dropped: on receive (malformed, unknown sender, reassembly failure, …) and
    /// frames held for batching that a later flush failed to send.
    pub frames_dropped: u64,
    /// Times a connection to a peer was (re)established.
    pub connects: u64,
    /// Bytes currently held for reassembly or queued.
    pub buffered_bytes: u64,
    /// Datagrams the operating system dropped before the link could read them (e.g. its
    /// socket's receive buffer was full), where the OS reports it (UDP on Linux); 0 elsewhere.
    /// Counted in datagrams, not frames, and not part of `frames_dropped`.
    pub kernel_drops: u64,
    /// What the security layer over this link did (all zero on an unsecured link).
    pub security: SecurityStats,
}

/// Counters of the security layer over a link (`hetcomm-security`): handshakes, and every
/// frame it refused, by reason. A refused frame never reaches the router, so these are the
/// only place it is counted.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SecurityStats {
    /// Whether a security layer is over this link at all.
    pub enabled: bool,
    /// Sessions established with peers (handshakes completed, as initiator or responder).
    pub handshakes: u64,
    /// Frames that failed authentication: wrong key, tampered header or payload, a forged
    /// handshake, or a truncated secured frame.
    pub rejected_auth: u64,
    /// Authentic frames seen before (replays) or too old for the replay window, and
    /// handshake initiations no newer than the last one accepted from that system.
    pub rejected_replay: u64,
    /// Authentic frames the communication table does not allow on this transport (an `X`
    /// pair or a pair on another transport), or whose inner header claims another origin or
    /// destination than the authenticated ones; and any frame or handshake from a member of
    /// the fleet that the table does not connect to this system on this transport (refused
    /// before it is opened), or addressed to another system.
    pub rejected_table: u64,
    /// Frames or handshakes from a system that is not in the fleet or has no public key.
    pub rejected_unknown_sender: u64,
    /// Frames for a session this system does not have (the peer restarted, or an old
    /// capture replayed after this system restarted): dropped, and a new handshake started.
    pub rejected_no_session: u64,
    /// Frames that waited for a handshake that did not complete in time, and were dropped.
    pub handshake_timeouts: u64,
}

impl SecurityStats {
    /// Every frame the layer refused, whatever the reason.
    pub fn rejected(&self) -> u64 {
        self.rejected_auth
            + self.rejected_replay
            + self.rejected_table
            + self.rejected_unknown_sender
            + self.rejected_no_session
    }
}

/// What [`forward_link!`] names, reachable from any crate that uses it.
#[doc(hidden)]
pub use hetcomm_core as __core;

/// Implements [`Link`] for a type that wraps another link, forwarding to it every method the
/// wrapper does not write itself. This is the pass-through base of every link wrapper and
/// [layer](crate::layer): a method added to [`Link`] is added here once, and no wrapper can
/// forget to pass it on (as [`Link::readable`] once was, leaving a wrapped socket unread).
///
/// Everything forwarded: `forward_link!(TcpLink, inner);` or, with generics,
/// `forward_link!(impl<F: Family> RfcommLink<F>, inner);`.
///
/// Some methods written by the wrapper, the rest forwarded to the field at the given path:
///
/// ```
/// use hetcomm_core::SystemId;
/// use hetcomm_link::{forward_link, Link, LinkError};
///
/// /// Counts what its inner link is asked to send.
/// struct Counting<L> {
///     inner: L,
///     sent: std::sync::atomic::AtomicU64,
/// }
///
/// forward_link! {
///     [impl<L: Link>] Counting<L> => inner;
///     fn send(&self, to: SystemId, frame: &[u8]) -> Result<(), LinkError> {
///         self.sent.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
///         self.inner.send(to, frame)
///     }
///     // Writing `send` means saying what held frames do: here, they keep the inner
///     // link's batching (writing `fn batches(&self) -> bool { false }` instead would send
///     // them at once through `send`).
///     fn send_held(&self, to: SystemId, frame: &[u8]) -> Result<(), LinkError> {
///         self.sent.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
///         self.inner.send_held(to, frame)
///     }
/// }
/// ```
///
/// A wrapper that writes `send` and says nothing of held frames is refused at compile time:
///
/// ```compile_fail
/// use hetcomm_core::SystemId;
/// use hetcomm_link::{forward_link, Link, LinkError};
///
/// struct Quiet<L> {
///     inner: L,
/// }
///
/// forward_link! {
///     [impl<L: Link>] Quiet<L> => inner;
///     fn send(&self, to: SystemId, frame: &[u8]) -> Result<(), LinkError> {
///         self.inner.send(to, frame)
///     }
/// }
/// ```
///
/// What a method the wrapper leaves out does:
///
/// - Every method the wrapper does not write is forwarded, with one exception:
/// - a wrapper that writes `send` gets the trait's defaults for the `send_parts`,
///   `send_owned`, `send_held` and `send_relayed` (no receipt) it does not write (they go through its `send`: the parts
///   joined, an owned frame lent, a held frame sent at once), so it sees every frame; and it
///   must write `send_held` (its `batches` is then the inner link's unless it writes that
///   too) or `batches` (false), or the macro refuses it: what held frames do is never left
///   to a rule. A wrapper that wants vectored writes or write-behind kept writes
///   `send_parts` / `send_owned` too.
#[macro_export]
macro_rules! forward_link {
    (
        [$($gen:tt)*] $ty:ty => $($field:ident).+ ;
        $( $(#[$attr:meta])* fn $name:ident $args:tt $(-> $ret:ty)? $body:block )*
    ) => {
        $($gen)* $crate::Link for $ty {
            $( $(#[$attr])* fn $name $args $(-> $ret)? $body )*
            $crate::forward_link!(@rest [$($name)*] $($field).+);
        }
    };
    (impl<$($g:ident : $bound:path),+> $ty:ty, $field:ident) => {
        $crate::forward_link!([impl<$($g: $bound),+>] $ty => $field;);
    };
    ($ty:ty, $field:ident) => {
        $crate::forward_link!([impl] $ty => $field;);
    };
    (@rest [$($n:ident)*] $($field:ident).+) => {
        $crate::__if_named!(caps [$($n)*] {} {
            fn caps(&self) -> $crate::LinkCaps {
                $crate::Link::caps(&self.$($field).+)
            }
        });
        $crate::__if_named!(send [$($n)*] {} {
            fn send(
                &self,
                to: $crate::__core::SystemId,
                frame: &[u8],
            ) -> ::std::result::Result<(), $crate::LinkError> {
                $crate::Link::send(&self.$($field).+, to, frame)
            }
        });
        // The send family. A wrapper that leaves `send` alone has every send method it does
        // not write forwarded. One that writes `send` gets the trait's defaults for the
        // others it does not write (through its `send`: parts joined, an owned frame lent, a
        // held frame at once), so it sees every frame; and it says what becomes of held
        // frames: it writes `send_held` (then the inner link's `batches` stays, unless it
        // writes that too) or `batches` (false: held frames go at once, through its `send`).
        // Leaving both out once turned batching off unnoticed.
        $crate::__if_named!(send [$($n)*] {
            $crate::__if_named!(batches [$($n)*] {} {
                $crate::__if_named!(send_held [$($n)*] {
                    fn batches(&self) -> bool {
                        $crate::Link::batches(&self.$($field).+)
                    }
                } {
                    ::std::compile_error!(
                        "forward_link!: a wrapper that writes `send` writes `send_held` too (to keep the inner link's batching) or `batches` (false: held frames go at once through its `send`)"
                    );
                });
            });
        } {
            $crate::__if_named!(send_parts [$($n)*] {} {
                fn send_parts(
                    &self,
                    to: $crate::__core::SystemId,
                    head: &[u8],
                    body: &[u8],
                ) -> ::std::result::Result<(), $crate::LinkError> {
                    $crate::Link::send_parts(&self.$($field).+, to, head, body)
                }
            });
            $crate::__if_named!(send_owned [$($n)*] {} {
                fn send_owned(
                    &self,
                    to: $crate::__core::SystemId,
                    frame: $crate::__core::FrameBuf,
                ) -> ::std::result::Result<(), $crate::LinkError> {
                    $crate::Link::send_owned(&self.$($field).+, to, frame)
                }
            });
            $crate::__if_named!(send_held [$($n)*] {} {
                fn send_held(
                    &self,
                    to: $crate::__core::SystemId,
                    frame: &[u8],
                ) -> ::std::result::Result<(), $crate::LinkError> {
                    $crate::Link::send_held(&self.$($field).+, to, frame)
                }
            });
            $crate::__if_named!(batches [$($n)*] {} {
                fn batches(&self) -> bool {
                    $crate::Link::batches(&self.$($field).+)
                }
            });
            $crate::__if_named!(send_relayed [$($n)*] {} {
                fn send_relayed(
                    &self,
                    to: $crate::__core::SystemId,
                    head: &[u8],
                    body: &[u8],
                ) -> ::std::result::Result<
                    ::std::option::Option<$crate::relay::RelayReceipt>,
                    $crate::LinkError,
                > {
                    $crate::Link::send_relayed(&self.$($field).+, to, head, body)
                }
            });
        });
        $crate::__if_named!(stats [$($n)*] {} {
            fn stats(&self) -> $crate::LinkStats {
                $crate::Link::stats(&self.$($field).+)
            }
        });
        $crate::__if_named!(flush [$($n)*] {} {
            fn flush(&self) -> ::std::result::Result<(), $crate::LinkError> {
                $crate::Link::flush(&self.$($field).+)
            }
        });
        $crate::__if_named!(readable [$($n)*] {} {
            fn readable(&self) -> ::std::option::Option<&dyn $crate::Readable> {
                $crate::Link::readable(&self.$($field).+)
            }
        });
        $crate::__if_named!(checksums_payload [$($n)*] {} {
            fn checksums_payload(&self) -> bool {
                $crate::Link::checksums_payload(&self.$($field).+)
            }
        });
    };
}

/// `__if_named!(m [names] {then} {else})`: `then` if method `m` is among `names`, else
/// `else`. What [`forward_link!`] and [`forward_sink!`] use to leave out the methods a wrapper
/// writes itself (`macro_rules` can only compare an identifier with a literal one, hence an
/// arm per method).
#[doc(hidden)]
#[macro_export]
macro_rules! __if_named {
    (caps [caps $($r:ident)*] {$($y:tt)*} $n:tt) => { $($y)* };
    (send [send $($r:ident)*] {$($y:tt)*} $n:tt) => { $($y)* };
    (send_parts [send_parts $($r:ident)*] {$($y:tt)*} $n:tt) => { $($y)* };
    (send_owned [send_owned $($r:ident)*] {$($y:tt)*} $n:tt) => { $($y)* };
    (stats [stats $($r:ident)*] {$($y:tt)*} $n:tt) => { $($y)* };
    (send_held [send_held $($r:ident)*] {$($y:tt)*} $n:tt) => { $($y)* };
    (flush [flush $($r:ident)*] {$($y:tt)*} $n:tt) => { $($y)* };
    (batches [batches $($r:ident)*] {$($y:tt)*} $n:tt) => { $($y)* };
    (readable [readable $($r:ident)*] {$($y:tt)*} $n:tt) => { $($y)* };
    (checksums_payload [checksums_payload $($r:ident)*] {$($y:tt)*} $n:tt) => { $($y)* };
    (send_relayed [send_relayed $($r:ident)*] {$($y:tt)*} $n:tt) => { $($y)* };
    (on_frame [on_frame $($r:ident)*] {$($y:tt)*} $n:tt) => { $($y)* };
    (on_frame_owned [on_frame_owned $($r:ident)*] {$($y:tt)*} $n:tt) => { $($y)* };
    (on_frames [on_frames $($r:ident)*] {$($y:tt)*} $n:tt) => { $($y)* };
    (takes_frames [takes_frames $($r:ident)*] {$($y:tt)*} $n:tt) => { $($y)* };
    (on_event [on_event $($r:ident)*] {$($y:tt)*} $n:tt) => { $($y)* };
    ($m:ident [$o:ident $($r:ident)*] $y:tt $n:tt) => {
        $crate::__if_named!($m [$($r)*] $y $n);
    };
    ($m:ident [] $y:tt {$($n:tt)*}) => { $($n)* };
}

impl<L: Link + ?Sized> Link for Arc<L> {
    fn caps(&self) -> LinkCaps {
        (**self).caps()
    }
    fn send(&self, to: SystemId, frame: &[u8]) -> Result<(), LinkError> {
        (**self).send(to, frame)
    }
    fn send_parts(&self, to: SystemId, head: &[u8], body: &[u8]) -> Result<(), LinkError> {
        (**self).send_parts(to, head, body)
    }
    fn send_owned(&self, to: SystemId, frame: FrameBuf) -> Result<(), LinkError> {
        (**self).send_owned(to, frame)
    }
    fn send_relayed(
        &self,
        to: SystemId,
        head: &[u8],
        body: &[u8],
    ) -> Result<Option<relay::RelayReceipt>, LinkError> {
        (**self).send_relayed(to, head, body)
    }
    fn stats(&self) -> LinkStats {
        (**self).stats()
    }
    fn send_held(&self, to: SystemId, frame: &[u8]) -> Result<(), LinkError> {
        (**self).send_held(to, frame)
    }
    fn flush(&self) -> Result<(), LinkError> {
        (**self).flush()
    }
    fn batches(&self) -> bool {
        (**self).batches()
    }
    fn readable(&self) -> Option<&dyn Readable> {
        (**self).readable()
    }
    fn checksums_payload(&self) -> bool {
        (**self).checksums_payload()
    }
}

impl<S: FrameSink + ?Sized> FrameSink for Arc<S> {
    fn on_frame(&self, frame: &[u8], from: Peer) {
        (**self).on_frame(frame, from)
    }
    fn on_frame_owned(&self, frame: FrameBuf, from: Peer) {
        (**self).on_frame_owned(frame, from)
    }
    fn on_frames(&self, frames: &mut dyn Iterator<Item = &[u8]>, from: Peer) {
        (**self).on_frames(frames, from)
    }
    fn takes_frames(&self) -> bool {
        (**self).takes_frames()
    }
    fn on_event(&self, event: LinkEvent) {
        (**self).on_event(event)
    }
}
