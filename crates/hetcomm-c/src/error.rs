//! Status codes, the per-thread error message, and the guard every exported function runs its
//! body in (a Rust panic becomes [`hetcomm_status::Panic`], never an unwind into C).

use std::cell::RefCell;
use std::ffi::{c_char, CStr, CString};
use std::panic::{catch_unwind, AssertUnwindSafe};

use hetcomm::{OpenError, RecvError, SendError};

/// What a call of the C API returned. `HETCOMM_STATUS_OK` (0) is success; every other code
/// leaves a message for the calling thread in [`hetcomm_last_error`].
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum hetcomm_status {
    /// Success.
    Ok = 0,
    /// A pointer argument was NULL, a string was not UTF-8, or a value was out of range.
    InvalidArgument = 1,
    /// The fleet file is invalid: the message lists each problem as `file:line:column`.
    Config = 2,
    /// No system of that name in the fleet.
    UnknownSystem = 3,
    /// No module of that name in the fleet.
    UnknownModule = 4,
    /// The fleet uses a transport kind that is not built into this library.
    TransportUnavailable = 5,
    /// A transport could not be opened (for example its port is taken).
    Transport = 6,
    /// The communication table says `X` for this pair of systems: nothing was sent.
    NoRoute = 7,
    /// The message is larger than the route's transport takes: nothing was sent.
    TooLarge = 8,
    /// The transport's `max_in_flight` sends to that system still await their outcome:
    /// nothing was sent; wait for an earlier ticket and send again.
    Backpressure = 9,
    /// The system was closed.
    Closed = 10,
    /// No message (or no outcome) within the timeout.
    Timeout = 11,
    /// Nothing to take: the inbox is empty (a non-blocking receive, `next_type`).
    Empty = 12,
    /// The caller's buffer is too small for the next message: the size needed was written to
    /// the length argument and the message stays first in line for the next receive.
    BufferTooSmall = 13,
    /// The send has not ended yet (polling a ticket).
    Pending = 14,
    /// A payload could not be encoded or decoded.
    Codec = 15,
    /// A bug inside the library: a Rust panic was caught at the C boundary.
    Panic = 16,
    /// The next message is of another type than the one asked for: it stays first in line.
    WrongType = 17,
}

/// An error on its way to C: its code and message.
#[derive(Debug)]
pub(crate) struct Error {
    pub status: hetcomm_status,
    pub message: String,
}

impl Error {
    pub(crate) fn new(status: hetcomm_status, message: impl Into<String>) -> Error {
        Error {
            status,
            message: message.into(),
        }
    }

    pub(crate) fn invalid(message: impl Into<String>) -> Error {
        Error::new(hetcomm_status::InvalidArgument, message)
    }
}

impl From<OpenError> for Error {
    fn from(e: OpenError) -> Error {
        let status = match &e {
            OpenError::Config(_) => hetcomm_status::Config,
            OpenError::UnknownSystem { .. } => hetcomm_status::UnknownSystem,
            OpenError::UnknownModule { .. } => hetcomm_status::UnknownModule,
            OpenError::KindUnavailable { .. } => hetcomm_status::TransportUnavailable,
            _ => hetcomm_status::Transport,
        };
        Error::new(status, e.to_string())
    }
}

impl From<SendError> for Error {
    fn from(e: SendError) -> Error {
        let status = match &e {
            SendError::UnknownSystem(_) => hetcomm_status::UnknownSystem,
            SendError::UnknownModule(_) => hetcomm_status::UnknownModule,
            SendError::NoRoute { .. } => hetcomm_status::NoRoute,
            SendError::TooLarge { .. } => hetcomm_status::TooLarge,
            SendError::Backpressure { .. } => hetcomm_status::Backpressure,
            SendError::Closed => hetcomm_status::Closed,
            _ => hetcomm_status::Codec,
        };
        Error::new(status, e.to_string())
    }
}

impl From<RecvError> for Error {
    fn from(e: RecvError) -> Error {
        let status = match &e {
            RecvError::Timeout(_) => hetcomm_status::Timeout,
            RecvError::Closed => hetcomm_status::Closed,
            _ => hetcomm_status::Codec,
        };
        Error::new(status, e.to_string())
    }
}

thread_local! {
    /// The message of the last failed call on this thread.
    static LAST_ERROR: RefCell<CString> = RefCell::new(CString::default());
}

fn set_last_error(message: &str) {
    // An interior NUL would cut the C string: show it instead.
    let text = CString::new(message.replace('\0', "\\0")).unwrap_or_default();
    LAST_ERROR.with(|e| *e.borrow_mut() = text);
}

/// Runs `body`, turning its error or panic into a status code and the thread's message.
pub(crate) fn guard(body: impl FnOnce() -> Result<(), Error>) -> hetcomm_status {
    match catch_unwind(AssertUnwindSafe(body)) {
        Ok(Ok(())) => hetcomm_status::Ok,
        Ok(Err(e)) => {
            set_last_error(&e.message);
            e.status
        }
        Err(panic) => {
            let what = panic
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| panic.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "unknown panic".into());
            set_last_error(&format!(
                "internal error (a bug in hetcomm; please report it): {what}"
            ));
            hetcomm_status::Panic
        }
    }
}

/// Runs `body` for a function that cannot report a status (it returns a value): a panic gives
/// `fallback` and leaves its message for the thread.
pub(crate) fn guard_value<T>(fallback: T, body: impl FnOnce() -> T) -> T {
    let mut out = None;
    let status = guard(|| {
        out = Some(body());
        Ok(())
    });
    match out {
        Some(v) if status == hetcomm_status::Ok => v,
        _ => fallback,
    }
}

/// The message of the last call on this thread that returned an error (an empty string if
/// none has). The pointer stays valid until the next failing call on this thread; copy the
/// text to keep it. Never NULL.
#[no_mangle]
pub extern "C" fn hetcomm_last_error() -> *const c_char {
    LAST_ERROR.with(|e| e.borrow().as_ptr())
}

/// The name of a status code, e.g. `"HETCOMM_STATUS_TIMEOUT"` (a static string; `"unknown"`
/// for a number that is no status). Takes an `int` so that any value is safe to pass.
#[no_mangle]
pub extern "C" fn hetcomm_status_name(status: i32) -> *const c_char {
    let name: &'static CStr = match status {
        0 => c"HETCOMM_STATUS_OK",
        1 => c"HETCOMM_STATUS_INVALID_ARGUMENT",
        2 => c"HETCOMM_STATUS_CONFIG",
        3 => c"HETCOMM_STATUS_UNKNOWN_SYSTEM",
        4 => c"HETCOMM_STATUS_UNKNOWN_MODULE",
        5 => c"HETCOMM_STATUS_TRANSPORT_UNAVAILABLE",
        6 => c"HETCOMM_STATUS_TRANSPORT",
        7 => c"HETCOMM_STATUS_NO_ROUTE",
        8 => c"HETCOMM_STATUS_TOO_LARGE",
        9 => c"HETCOMM_STATUS_BACKPRESSURE",
        10 => c"HETCOMM_STATUS_CLOSED",
        11 => c"HETCOMM_STATUS_TIMEOUT",
        12 => c"HETCOMM_STATUS_EMPTY",
        13 => c"HETCOMM_STATUS_BUFFER_TOO_SMALL",
        14 => c"HETCOMM_STATUS_PENDING",
        15 => c"HETCOMM_STATUS_CODEC",
        16 => c"HETCOMM_STATUS_PANIC",
        17 => c"HETCOMM_STATUS_WRONG_TYPE",
        _ => c"unknown",
    };
    name.as_ptr()
}

/// Reads a C string argument as UTF-8; `what` names it in the error.
///
/// # Safety
/// `p` is NULL or points to a NUL-terminated string that outlives `'a`.
pub(crate) unsafe fn str_arg<'a>(p: *const c_char, what: &str) -> Result<&'a str, Error> {
    if p.is_null() {
        return Err(Error::invalid(format!("`{what}` is NULL")));
    }
    // SAFETY: non-NULL and NUL-terminated by the caller's contract.
    unsafe { CStr::from_ptr(p) }
        .to_str()
        .map_err(|e| Error::invalid(format!("`{what}` is not UTF-8: {e}")))
}

/// A reference from a handle pointer; `what` names it in the error.
///
/// # Safety
/// `p` is NULL or a live handle of type `T` made by this library.
pub(crate) unsafe fn handle<'a, T>(p: *const T, what: &str) -> Result<&'a T, Error> {
    // SAFETY: the caller's contract.
    unsafe { p.as_ref() }.ok_or_else(|| Error::invalid(format!("`{what}` is NULL")))
}

/// Checks an output pointer is not NULL; `what` names it in the error.
pub(crate) fn out_arg<T>(p: *mut T, what: &str) -> Result<*mut T, Error> {
    if p.is_null() {
        Err(Error::invalid(format!("`{what}` is NULL")))
    } else {
        Ok(p)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn last_error() -> String {
        // SAFETY: hetcomm_last_error never returns NULL and the string lives until the next
        // failing call on this thread.
        unsafe { CStr::from_ptr(hetcomm_last_error()) }
            .to_string_lossy()
            .into_owned()
    }

    #[test]
    fn a_panic_becomes_a_status_and_a_message_not_an_unwind() {
        let status = guard(|| panic!("boom at the boundary"));
        assert_eq!(status, hetcomm_status::Panic);
        assert!(
            last_error().contains("boom at the boundary"),
            "{}",
            last_error()
        );
        assert_eq!(guard_value(7, || -> i32 { panic!("again") }), 7);
        assert!(last_error().contains("again"));
    }

    #[test]
    fn errors_leave_their_message_and_success_leaves_it_alone() {
        let status = guard(|| Err(Error::new(hetcomm_status::Timeout, "late\0ness")));
        assert_eq!(status, hetcomm_status::Timeout);
        assert_eq!(last_error(), "late\\0ness");
        assert_eq!(guard(|| Ok(())), hetcomm_status::Ok);
        assert_eq!(last_error(), "late\\0ness");
    }

    #[test]
    fn every_status_has_its_header_name() {
        use hetcomm_status::*;
        let all = [
            (Ok, "OK"),
            (InvalidArgument, "INVALID_ARGUMENT"),
            (Config, "CONFIG"),
            (UnknownSystem, "UNKNOWN_SYSTEM"),
            (UnknownModule, "UNKNOWN_MODULE"),
            (TransportUnavailable, "TRANSPORT_UNAVAILABLE"),
            (Transport, "TRANSPORT"),
            (NoRoute, "NO_ROUTE"),
            (TooLarge, "TOO_LARGE"),
            (Backpressure, "BACKPRESSURE"),
            (Closed, "CLOSED"),
            (Timeout, "TIMEOUT"),
            (Empty, "EMPTY"),
            (BufferTooSmall, "BUFFER_TOO_SMALL"),
            (Pending, "PENDING"),
            (Codec, "CODEC"),
            (Panic, "PANIC"),
            (WrongType, "WRONG_TYPE"),
        ];
        for (status, name) in all {
            // SAFETY: static strings.
            let got = unsafe { CStr::from_ptr(hetcomm_status_name(status as i32)) };
            assert_eq!(got.to_str().unwrap(), format!("HETCOMM_STATUS_{name}"));
        }
        // SAFETY: a static string.
        let unknown = unsafe { CStr::from_ptr(hetcomm_status_name(-1)) };
        assert_eq!(unknown.to_str().unwrap(), "unknown");
    }

    #[test]
    fn null_arguments_are_errors_not_dereferences() {
        // SAFETY: NULL is allowed by the contract of each.
        unsafe {
            assert!(str_arg(std::ptr::null(), "system").is_err());
            assert!(handle::<u8>(std::ptr::null(), "comm").is_err());
        }
        assert!(out_arg::<u8>(std::ptr::null_mut(), "out").is_err());
    }
}
