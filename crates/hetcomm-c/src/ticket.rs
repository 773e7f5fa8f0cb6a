//! Outcomes: a ticket per send, a set of tickets per broadcast.

use std::ffi::{c_char, CString};
use std::time::Duration;

use hetcomm::{FailReason, Outcome, Ticket};

use crate::error::{guard, guard_value, handle, hetcomm_status, out_arg, Error};

/// The pending outcome of one send (the Rust `hetcomm::Ticket`). Free with
/// [`hetcomm_ticket_free`]; freeing it does not cancel the send (its outcome is still counted
/// in the system's statistics).
pub struct hetcomm_ticket {
    pub(crate) ticket: Ticket,
    destination: CString,
}

impl hetcomm_ticket {
    pub(crate) fn new(ticket: Ticket) -> hetcomm_ticket {
        hetcomm_ticket {
            destination: CString::new(ticket.destination()).unwrap_or_default(),
            ticket,
        }
    }
}

/// The pending outcomes of one broadcast: one ticket per destination the table allows. Free
/// with [`hetcomm_broadcast_free`].
pub struct hetcomm_broadcast {
    pub(crate) tickets: Vec<hetcomm_ticket>,
}

/// How a send ended. Each kind says only what the sender knows.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum hetcomm_outcome_kind {
    /// In the destination module's inbox, acknowledged by the receiving system (not
    /// necessarily read yet).
    Delivered = 0,
    /// Handed to a transport that cannot confirm (unacknowledged mode).
    Sent = 1,
    /// Frames left but no acknowledgement came back: it may or may not have arrived.
    Unconfirmed = 2,
    /// Certainly not delivered.
    Failed = 3,
    /// Handed to a transport whose broker (MQTT at QoS 1) confirmed it has it
    /// (unacknowledged mode): still not known to be delivered.
    Relayed = 4,
}

/// Why a send ended unconfirmed or failed.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum hetcomm_fail_reason {
    /// Not a failure (delivered or sent).
    None = 0,
    /// No acknowledgement came back within the attempt budget.
    NoAcknowledgement = 1,
    /// The link could not reach the peer on the last attempt.
    Unreachable = 2,
    /// The link's queue towards the peer was full on the last attempt.
    Congested = 3,
    /// The destination module's inbox was full and refused the message.
    InboxFull = 4,
    /// The destination system has no such module.
    UnknownModule = 5,
    /// The link refused the frame for another reason.
    Link = 6,
    /// Not sent: the destination's window was full (a broadcast reports this per destination).
    Backpressure = 7,
    /// The system shut down before an outcome.
    Shutdown = 8,
    /// A reason newer than this header.
    Other = 9,
    /// What the broker of the transport said (it refused the frame, or nobody is subscribed
    /// to its destination), or that it said nothing in time.
    Relay = 10,
    /// The link will never carry the message as it is (a bridge could not convert it to the
    /// mapped ROS type, or no topic is mapped for it): failed on its first attempt, nothing
    /// sent, never retried.
    Refused = 11,
}

/// One send's outcome.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct hetcomm_outcome {
    /// How it ended.
    pub kind: hetcomm_outcome_kind,
    /// Transmissions it took (or attempted).
    pub attempts: u32,
    /// For delivered sends: from the first transmission to the acknowledgement, in
    /// microseconds; 0 otherwise.
    pub latency_us: u64,
    /// For unconfirmed and failed sends: why; `HETCOMM_FAIL_REASON_NONE` otherwise.
    pub reason: hetcomm_fail_reason,
}

impl From<&Outcome> for hetcomm_outcome {
    fn from(o: &Outcome) -> Self {
        let reason = |r: &FailReason| match r {
            FailReason::NoAcknowledgement => hetcomm_fail_reason::NoAcknowledgement,
            FailReason::Unreachable(_) => hetcomm_fail_reason::Unreachable,
            FailReason::Congested(_) => hetcomm_fail_reason::Congested,
            FailReason::InboxFull => hetcomm_fail_reason::InboxFull,
            FailReason::UnknownModule => hetcomm_fail_reason::UnknownModule,
            FailReason::Link(_) => hetcomm_fail_reason::Link,
            FailReason::Backpressure => hetcomm_fail_reason::Backpressure,
            FailReason::Shutdown => hetcomm_fail_reason::Shutdown,
            FailReason::Relay(_) => hetcomm_fail_reason::Relay,
            FailReason::Refused(_) => hetcomm_fail_reason::Refused,
            #[allow(unreachable_patterns)]
            _ => hetcomm_fail_reason::Other,
        };
        let (kind, attempts, latency_us, reason) = match o {
            Outcome::Delivered { attempts, latency } => (
                hetcomm_outcome_kind::Delivered,
                *attempts,
                latency.as_micros() as u64,
                hetcomm_fail_reason::None,
            ),
            Outcome::Sent { attempts } => (
                hetcomm_outcome_kind::Sent,
                *attempts,
                0,
                hetcomm_fail_reason::None,
            ),
            Outcome::Relayed { attempts } => (
                hetcomm_outcome_kind::Relayed,
                *attempts,
                0,
                hetcomm_fail_reason::None,
            ),
            Outcome::Unconfirmed {
                reason: r,
                attempts,
            } => (hetcomm_outcome_kind::Unconfirmed, *attempts, 0, reason(r)),
            Outcome::Failed {
                reason: r,
                attempts,
            } => (hetcomm_outcome_kind::Failed, *attempts, 0, reason(r)),
        };
        hetcomm_outcome {
            kind,
            attempts,
            latency_us,
            reason,
        }
    }
}

/// Writes `outcome` to `out` (checked non-NULL by the caller of this function).
fn write(out: *mut hetcomm_outcome, outcome: &Outcome) {
    // SAFETY: checked non-NULL by every caller; writable by the C caller's contract.
    unsafe { *out = outcome.into() };
}

/// Waits for the send's outcome and writes it to `*out`. Every send ends (its attempt budget
/// bounds it), so this returns.
///
/// # Safety
/// `ticket` is NULL or a live ticket; `out` NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn hetcomm_ticket_wait(
    ticket: *const hetcomm_ticket,
    out: *mut hetcomm_outcome,
) -> hetcomm_status {
    guard(|| {
        // SAFETY: the caller's contract.
        let t = unsafe { handle(ticket, "ticket")? };
        let out = out_arg(out, "out")?;
        write(out, &t.ticket.wait());
        Ok(())
    })
}

/// Waits up to `timeout_ms` milliseconds for the outcome: `HETCOMM_STATUS_TIMEOUT` if the send
/// has not ended by then (`*out` untouched; the ticket can be waited on again).
///
/// # Safety
/// `ticket` is NULL or a live ticket; `out` NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn hetcomm_ticket_wait_timeout(
    ticket: *const hetcomm_ticket,
    timeout_ms: u64,
    out: *mut hetcomm_outcome,
) -> hetcomm_status {
    guard(|| {
        // SAFETY: the caller's contract.
        let t = unsafe { handle(ticket, "ticket")? };
        let out = out_arg(out, "out")?;
        match t.ticket.wait_timeout(Duration::from_millis(timeout_ms)) {
            Some(o) => {
                write(out, &o);
                Ok(())
            }
            None => Err(Error::new(
                hetcomm_status::Timeout,
                format!(
                    "the send to `{}` has not ended after {timeout_ms} ms",
                    t.ticket.destination()
                ),
            )),
        }
    })
}

/// The outcome if the send has ended, without waiting: `HETCOMM_STATUS_PENDING` if not yet.
///
/// # Safety
/// `ticket` is NULL or a live ticket; `out` NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn hetcomm_ticket_poll(
    ticket: *const hetcomm_ticket,
    out: *mut hetcomm_outcome,
) -> hetcomm_status {
    guard(|| {
        // SAFETY: the caller's contract.
        let t = unsafe { handle(ticket, "ticket")? };
        let out = out_arg(out, "out")?;
        match t.ticket.try_outcome() {
            Some(o) => {
                write(out, &o);
                Ok(())
            }
            None => Err(Error::new(
                hetcomm_status::Pending,
                format!("the send to `{}` has not ended yet", t.ticket.destination()),
            )),
        }
    })
}

/// The destination system's name (valid while the ticket is), or NULL for a NULL ticket.
///
/// # Safety
/// `ticket` is NULL or a live ticket.
#[no_mangle]
pub unsafe extern "C" fn hetcomm_ticket_destination(
    ticket: *const hetcomm_ticket,
) -> *const c_char {
    // SAFETY: the caller's contract.
    unsafe { ticket.as_ref() }.map_or(std::ptr::null(), |t| t.destination.as_ptr())
}

/// Frees a ticket (the send goes on). NULL is ignored.
///
/// # Safety
/// `ticket` is NULL or a ticket from a send of this library, not freed yet and not used by
/// another thread during or after this call.
#[no_mangle]
pub unsafe extern "C" fn hetcomm_ticket_free(ticket: *mut hetcomm_ticket) {
    if !ticket.is_null() {
        // SAFETY: made by Box::into_raw in a send; freed once by contract.
        guard_value((), || drop(unsafe { Box::from_raw(ticket) }));
    }
}

/// How many destinations a broadcast went to (one ticket each; 0 for NULL).
///
/// # Safety
/// `broadcast` is NULL or a live broadcast handle.
#[no_mangle]
pub unsafe extern "C" fn hetcomm_broadcast_count(broadcast: *const hetcomm_broadcast) -> usize {
    // SAFETY: the caller's contract.
    unsafe { broadcast.as_ref() }.map_or(0, |b| b.tickets.len())
}

/// The ticket of the `index`th destination of a broadcast, borrowed: valid while the
/// broadcast handle is, not to be freed. NULL if `broadcast` is NULL or `index` is out of
/// range.
///
/// # Safety
/// `broadcast` is NULL or a live broadcast handle.
#[no_mangle]
pub unsafe extern "C" fn hetcomm_broadcast_ticket(
    broadcast: *const hetcomm_broadcast,
    index: usize,
) -> *const hetcomm_ticket {
    // SAFETY: the caller's contract.
    unsafe { broadcast.as_ref() }
        .and_then(|b| b.tickets.get(index))
        .map_or(std::ptr::null(), |t| t as *const hetcomm_ticket)
}

/// Frees a broadcast handle and its tickets (the sends go on). NULL is ignored.
///
/// # Safety
/// `broadcast` is NULL or a handle from a broadcast of this library, not freed yet and not
/// used by another thread during or after this call.
#[no_mangle]
pub unsafe extern "C" fn hetcomm_broadcast_free(broadcast: *mut hetcomm_broadcast) {
    if !broadcast.is_null() {
        // SAFETY: made by Box::into_raw in a broadcast; freed once by contract.
        guard_value((), || drop(unsafe { Box::from_raw(broadcast) }));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_refused_send_has_its_own_reason_and_no_known_reason_is_other() {
        let refused = Outcome::Failed {
            reason: FailReason::Refused("Drive does not convert to geometry_msgs/Twist".into()),
            attempts: 1,
        };
        let c = hetcomm_outcome::from(&refused);
        assert_eq!(c.kind, hetcomm_outcome_kind::Failed);
        assert_eq!((c.reason, c.attempts), (hetcomm_fail_reason::Refused, 1));
        assert_eq!(hetcomm_fail_reason::Refused as u32, 11);
        let unreachable = Outcome::Unconfirmed {
            reason: FailReason::Unreachable("no route".into()),
            attempts: 3,
        };
        let c = hetcomm_outcome::from(&unreachable);
        assert_eq!(c.reason, hetcomm_fail_reason::Unreachable);
        // `NoSession` has no code of its own yet: it is reported as `Other`.
        let no_session = Outcome::Failed {
            reason: FailReason::NoSession("handshake pending".into()),
            attempts: 1,
        };
        assert_eq!(
            hetcomm_outcome::from(&no_session).reason,
            hetcomm_fail_reason::Other
        );
    }
}
