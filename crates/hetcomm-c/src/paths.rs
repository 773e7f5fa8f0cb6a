//! Failover from C (docs/failover.md): a pair's transports changed while running, and a
//! watch of a system's path switches (each watch sees every switch, whatever others read).

use parking_lot::Mutex;
use std::ffi::{c_char, CString};
use std::time::Duration;

use crate::comm::hetcomm_comm;
use crate::error::{guard, guard_value, handle, hetcomm_status, out_arg, str_arg, Error};

/// Changes, while running, the transports (fleet-file names, in order of preference) that
/// carry this system's traffic to `system`: `count` strings at `transports`. Each must be one
/// the pair's table cell lists (a reorder or a subset of it).
///
/// Errors (nothing changes; `hetcomm_last_error` says why): `HETCOMM_STATUS_UNKNOWN_SYSTEM`,
/// `HETCOMM_STATUS_NO_ROUTE` (the table says X), `HETCOMM_STATUS_INVALID_ARGUMENT` (no
/// transport given, or one the cell does not list).
///
/// # Safety
/// `comm` is NULL or a live handle; `system` NULL or a NUL-terminated string; `transports`
/// NULL or `count` pointers to NUL-terminated strings.
#[no_mangle]
pub unsafe extern "C" fn hetcomm_comm_set_transports(
    comm: *const hetcomm_comm,
    system: *const c_char,
    transports: *const *const c_char,
    count: usize,
) -> hetcomm_status {
    guard(|| {
        // SAFETY: the caller's contract.
        let (c, system) = unsafe { (handle(comm, "comm")?, str_arg(system, "system")?) };
        if transports.is_null() && count > 0 {
            return Err(Error::invalid("`transports` is NULL"));
        }
        let mut names = Vec::with_capacity(count);
        for i in 0..count {
            // SAFETY: `count` readable pointers by contract.
            let p = unsafe { *transports.add(i) };
            // SAFETY: NULL or NUL-terminated by contract.
            names.push(unsafe { str_arg(p, "transports[i]")? });
        }
        c.comm.set_transports(system, &names).map_err(|e| {
            let status = match e {
                hetcomm::PathsError::UnknownSystem(_) => hetcomm_status::UnknownSystem,
                hetcomm::PathsError::NoTraffic(_) => hetcomm_status::NoRoute,
                _ => hetcomm_status::InvalidArgument,
            };
            Error::new(status, e.to_string())
        })
    })
}

/// One path switch ([`hetcomm_path_watch_poll`]): the strings stay valid until the next poll
/// of the same watch or its free.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct hetcomm_path_switch {
    /// The destination system whose sends moved.
    pub to: *const c_char,
    /// The transport they took until then.
    pub from: *const c_char,
    /// The transport they take from then on.
    pub now: *const c_char,
    /// When, microseconds on the system's monotonic clock.
    pub at_us: u64,
    /// The system's switches so far, this one included (a gap: switches were dropped).
    pub number: u64,
}

/// Path switches of one system from when it was made ([`hetcomm_comm_watch_paths`]); free it
/// with [`hetcomm_path_watch_free`]. Holds up to 1024 unread switches (older ones are
/// dropped: a gap in `number` shows it). One thread at a time polls it.
pub struct hetcomm_path_watch {
    watch: hetcomm::PathWatch,
    /// The strings of the last switch polled.
    last: Mutex<[CString; 3]>,
}

/// Starts watching this system's path switches; `*out` is a new watch to free with
/// [`hetcomm_path_watch_free`].
///
/// # Safety
/// `comm` is NULL or a live handle; `out` NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn hetcomm_comm_watch_paths(
    comm: *const hetcomm_comm,
    out: *mut *mut hetcomm_path_watch,
) -> hetcomm_status {
    guard(|| {
        // SAFETY: the caller's contract.
        let c = unsafe { handle(comm, "comm")? };
        let out = out_arg(out, "out")?;
        let w = hetcomm_path_watch {
            watch: c.comm.watch_paths(),
            last: Mutex::new(Default::default()),
        };
        // SAFETY: checked non-NULL, writable by contract.
        unsafe { *out = Box::into_raw(Box::new(w)) };
        Ok(())
    })
}

/// The next path switch into `*out`, waiting up to `timeout_ms` for one (0: do not wait).
/// `HETCOMM_STATUS_EMPTY` when none came in time.
///
/// # Safety
/// `watch` is NULL or a live watch; `out` NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn hetcomm_path_watch_poll(
    watch: *const hetcomm_path_watch,
    timeout_ms: u64,
    out: *mut hetcomm_path_switch,
) -> hetcomm_status {
    guard(|| {
        // SAFETY: the caller's contract.
        let w = unsafe { handle(watch, "watch")? };
        let out = out_arg(out, "out")?;
        let next = match timeout_ms {
            0 => w.watch.try_next(),
            ms => w.watch.next_timeout(Duration::from_millis(ms)),
        };
        let s = next.ok_or_else(|| Error::new(hetcomm_status::Empty, "no path switch"))?;
        let c = |s: &str| CString::new(s).unwrap_or_default();
        let mut last = w.last.lock();
        *last = [c(&s.to), c(&s.from), c(&s.now)];
        let switch = hetcomm_path_switch {
            to: last[0].as_ptr(),
            from: last[1].as_ptr(),
            now: last[2].as_ptr(),
            at_us: s.at.as_micros(),
            number: s.number,
        };
        // SAFETY: checked non-NULL, writable by contract.
        unsafe { *out = switch };
        Ok(())
    })
}

/// Frees a watch (NULL is ignored).
///
/// # Safety
/// `watch` is NULL or a watch not freed yet; no other thread uses it during or after this.
#[no_mangle]
pub unsafe extern "C" fn hetcomm_path_watch_free(watch: *mut hetcomm_path_watch) {
    if !watch.is_null() {
        guard_value((), || {
            // SAFETY: made by Box::into_raw in hetcomm_comm_watch_paths; freed once.
            drop(unsafe { Box::from_raw(watch) });
        });
    }
}
