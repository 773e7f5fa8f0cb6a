//! How a send ends: its [`Outcome`] and, where it did not arrive or was not confirmed, the
//! [`FailReason`].

use std::time::Duration;

use hetcomm_core::wire::AckStatus;

#[cfg(doc)]
use super::Router;

/// Why a send failed ([`Outcome::Failed`]) or why the sender stopped waiting for its
/// confirmation ([`Outcome::Unconfirmed`]).
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum FailReason {
    /// Frames went out but no acknowledgement came back within the attempt budget (only in
    /// [`Outcome::Unconfirmed`]: the message may have arrived and its acknowledgement been lost).
    #[error("no acknowledgement")]
    NoAcknowledgement,
    /// The link could not reach the peer on the last attempt.
    #[error("peer unreachable: {0}")]
    Unreachable(String),
    /// The link's queue towards the peer was full on the last attempt.
    #[error("link congested: {0}")]
    Congested(String),
    /// The destination module's inbox was full and refused the message.
    #[error("destination inbox full")]
    InboxFull,
    /// The destination system does not host that module.
    #[error("destination system has no such module")]
    UnknownModule,
    /// Nothing of the message left: on every attempt the link had no secure session with the
    /// peer (its security handshake was not answered). The text names the peer and where the
    /// handshake stood, e.g. "no secure session with B: handshake unanswered for 0.3 s; …".
    #[error("{0}")]
    NoSession(String),
    /// The link refused the frame for another reason.
    #[error("transport error: {0}")]
    Link(String),
    /// An unacknowledged send on a link whose frames pass through an intermediary that
    /// confirms taking them (an MQTT broker's PUBACK): the intermediary did not confirm the
    /// frame in time (in [`Outcome::Unconfirmed`]), or said nobody would get it (in
    /// [`Outcome::Failed`]). The text is the link's, naming the intermediary, e.g. "the
    /// broker mqtt://127.0.0.1:1883 did not confirm it within 2000 ms".
    #[error("{0}")]
    Relay(String),
    /// The link will never carry the message as it is (a bridge could not convert it to the
    /// mapped ROS type, or no topic is mapped for it): failed on its first attempt, nothing
    /// sent, never retried.
    #[error("refused by the link: {0}")]
    Refused(String),
    /// Not sent: the destination's [`Route::max_in_flight`] sends already awaited their
    /// outcome (a broadcast reports this per destination; a single send is refused with
    /// [`SendError::Backpressure`] instead).
    #[error("not sent: max_in_flight sends to that system already await their outcome")]
    Backpressure,
    /// The router was shut down with the send unresolved.
    #[error("shut down before an outcome")]
    Shutdown,
}

/// The one result every send ends with. Each variant says only what the sender knows:
///
/// | outcome | the message is … |
/// |---|---|
/// | [`Delivered`](Outcome::Delivered) | in the destination module's inbox (not necessarily read yet) |
/// | [`Sent`](Outcome::Sent) | handed to the transport, which cannot confirm (unacknowledged mode) |
/// | [`Relayed`](Outcome::Relayed) | taken by the broker the transport goes through, which said so (unacknowledged mode); not known to be delivered |
/// | [`Unconfirmed`](Outcome::Unconfirmed) | maybe delivered: frames left, no acknowledgement came back |
/// | [`Failed`](Outcome::Failed) | certainly not delivered |
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Outcome {
    /// The destination router put the message into the module's inbox and said so. Delivered
    /// means in the inbox, not read by the module.
    Delivered {
        /// Transmissions it took.
        attempts: u32,
        /// From the first transmission to the acknowledgement.
        latency: Duration,
    },
    /// The transport took the frame; it cannot confirm delivery (unacknowledged mode).
    Sent {
        /// Transmissions it took (more than one if the transport refused earlier ones).
        attempts: u32,
    },
    /// The transport took the frame, and the intermediary it goes through (an MQTT broker,
    /// with its QoS 1 PUBACK) confirmed it has it (unacknowledged mode). Not delivery: the
    /// broker may still drop it (a restart without persistence, a subscriber's full queue).
    /// Had the intermediary not confirmed in time, the send ends
    /// [`Unconfirmed`](Outcome::Unconfirmed) with [`FailReason::Relay`].
    Relayed {
        /// Transmissions it took.
        attempts: u32,
    },
    /// At least one frame left this system but no acknowledgement came back before the
    /// attempt budget ran out (or the link was lost, or the router shut down): the message may
    /// or may not have arrived. The sender cannot tell which; only the receiver can.
    Unconfirmed {
        /// Why the sender stopped waiting.
        reason: FailReason,
        /// Transmissions attempted.
        attempts: u32,
    },
    /// Certainly not delivered: no frame left this system (refused, unreachable on every
    /// attempt, too large, shut down before sending), or the receiver answered that it did not
    /// take the message (inbox full, no such module).
    Failed {
        /// Why.
        reason: FailReason,
        /// Transmissions attempted.
        attempts: u32,
    },
}

impl Outcome {
    /// The outcome an acknowledgement with `status` reports.
    pub(crate) fn acknowledged(status: AckStatus, attempts: u32, latency: Duration) -> Outcome {
        match status {
            AckStatus::Delivered => Outcome::Delivered { attempts, latency },
            AckStatus::InboxFull => Outcome::Failed {
                reason: FailReason::InboxFull,
                attempts,
            },
            AckStatus::UnknownModule => Outcome::Failed {
                reason: FailReason::UnknownModule,
                attempts,
            },
        }
    }

    /// Delivered, sent without confirmation on a transport that cannot confirm, or relayed
    /// (a broker confirmed it has the frame).
    pub fn is_success(&self) -> bool {
        matches!(
            self,
            Outcome::Delivered { .. } | Outcome::Sent { .. } | Outcome::Relayed { .. }
        )
    }

    /// Maybe delivered: frames left but no acknowledgement came back.
    pub fn is_unconfirmed(&self) -> bool {
        matches!(self, Outcome::Unconfirmed { .. })
    }

    /// Certainly not delivered.
    pub fn is_failed(&self) -> bool {
        matches!(self, Outcome::Failed { .. })
    }

    /// Why the send failed or went unconfirmed (`None` for the successes).
    pub fn reason(&self) -> Option<&FailReason> {
        match self {
            Outcome::Unconfirmed { reason, .. } | Outcome::Failed { reason, .. } => Some(reason),
            Outcome::Delivered { .. } | Outcome::Sent { .. } | Outcome::Relayed { .. } => None,
        }
    }

    /// Transmissions attempted.
    pub fn attempts(&self) -> u32 {
        match *self {
            Outcome::Delivered { attempts, .. }
            | Outcome::Sent { attempts }
            | Outcome::Relayed { attempts }
            | Outcome::Unconfirmed { attempts, .. }
            | Outcome::Failed { attempts, .. } => attempts,
        }
    }
}

impl std::fmt::Display for Outcome {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Outcome::Delivered { attempts, latency } => {
                write!(
                    f,
                    "delivered to the inbox (attempts: {attempts}, {} µs)",
                    latency.as_micros()
                )
            }
            Outcome::Sent { attempts } => {
                write!(f, "sent without confirmation (attempts: {attempts})")
            }
            Outcome::Relayed { attempts } => {
                write!(
                    f,
                    "sent; the broker confirmed it has it, not that it was delivered (attempts: {attempts})"
                )
            }
            Outcome::Unconfirmed { reason, attempts } => {
                write!(
                    f,
                    "unconfirmed: {reason}; it may or may not have arrived (attempts: {attempts})"
                )
            }
            Outcome::Failed { reason, attempts } => {
                write!(f, "failed: {reason} (attempts: {attempts})")
            }
        }
    }
}
