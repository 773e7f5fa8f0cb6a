//! Opening and closing a system, its modules, its counters.

use std::ffi::{c_char, CString};
use std::path::Path;

use hetcomm::Comm;

use crate::error::{guard, guard_value, handle, hetcomm_status, out_arg, str_arg, Error};
use crate::module::hetcomm_module;

/// One opened system of a fleet (the Rust `hetcomm::Comm`). Made by [`hetcomm_comm_open`] or
/// [`hetcomm_comm_open_str`], freed by [`hetcomm_comm_close`]. Safe to use from several
/// threads at once.
pub struct hetcomm_comm {
    pub(crate) comm: Comm,
    name: CString,
    /// Per open transport: (name, listening address or None).
    endpoints: Vec<(CString, Option<CString>)>,
}

impl hetcomm_comm {
    fn new(comm: Comm) -> hetcomm_comm {
        let c = |s: &str| CString::new(s).unwrap_or_default();
        hetcomm_comm {
            name: c(comm.name()),
            endpoints: comm
                .endpoints()
                .iter()
                .map(|(n, a)| (c(n), a.as_deref().map(c)))
                .collect(),
            comm,
        }
    }
}

/// Counters of one system (a summary of the Rust `hetcomm::SystemStats`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default)]
pub struct hetcomm_stats {
    /// Sends accepted.
    pub sends: u64,
    /// Frames handed to links (first attempts and retransmissions).
    pub transmissions: u64,
    /// Retransmissions after a timeout or a link error.
    pub retransmissions: u64,
    /// Sends that ended delivered (acknowledged: in the destination module's inbox).
    pub delivered: u64,
    /// Sends that ended sent without confirmation (unacknowledged transports).
    pub sent: u64,
    /// Sends that ended unconfirmed (frames left, no acknowledgement came back).
    pub unconfirmed: u64,
    /// Sends that ended failed (certainly not delivered).
    pub failed: u64,
    /// Messages put into this system's inboxes.
    pub received: u64,
    /// Duplicate frames suppressed.
    pub duplicates: u64,
    /// Frames that failed to decode.
    pub malformed: u64,
    /// Sends refused because the destination's window was full.
    pub backpressured: u64,
    /// Messages lost to full inboxes, over every module of this system.
    pub inbox_dropped: u64,
    /// Frames the links dropped (over every link of this system).
    pub link_dropped: u64,
    /// Callback invocations that failed (for the C API: never, the payload is not decoded).
    pub callback_failures: u64,
    /// Messages for a module id this system's fleet file does not have.
    pub unknown_module: u64,
}

/// Loads the fleet file at `path` and opens the system named `system` of it: its transports
/// open (UDP sockets bind, TCP listens) before this returns. On success `*out` is a new handle
/// to free with [`hetcomm_comm_close`]; on error `*out` is left unchanged.
///
/// Errors: `HETCOMM_STATUS_CONFIG` (the message lists every problem as `file:line:column`),
/// `HETCOMM_STATUS_UNKNOWN_SYSTEM`, `HETCOMM_STATUS_TRANSPORT_UNAVAILABLE`,
/// `HETCOMM_STATUS_TRANSPORT`, `HETCOMM_STATUS_INVALID_ARGUMENT`.
///
/// # Safety
/// `path` and `system` are NULL or NUL-terminated strings; `out` is NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn hetcomm_comm_open(
    path: *const c_char,
    system: *const c_char,
    out: *mut *mut hetcomm_comm,
) -> hetcomm_status {
    guard(|| {
        // SAFETY: the caller's contract.
        let (path, system) = unsafe { (str_arg(path, "path")?, str_arg(system, "system")?) };
        let out = out_arg(out, "out")?;
        let comm = Comm::open(Path::new(path), system)?;
        // SAFETY: checked non-NULL; the caller gave a writable pointer.
        unsafe { *out = Box::into_raw(Box::new(hetcomm_comm::new(comm))) };
        Ok(())
    })
}

/// [`hetcomm_comm_open`] from fleet-file text: `origin` names it in error messages (like a
/// file name). Relative paths in the fleet are taken from the current directory.
///
/// # Safety
/// `toml`, `origin` and `system` are NULL or NUL-terminated strings; `out` is NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn hetcomm_comm_open_str(
    toml: *const c_char,
    origin: *const c_char,
    system: *const c_char,
    out: *mut *mut hetcomm_comm,
) -> hetcomm_status {
    guard(|| {
        // SAFETY: the caller's contract.
        let (toml, origin, system) = unsafe {
            (
                str_arg(toml, "toml")?,
                str_arg(origin, "origin")?,
                str_arg(system, "system")?,
            )
        };
        let out = out_arg(out, "out")?;
        let fleet = hetcomm::parse_fleet(toml, origin, None)
            .map_err(|e| Error::from(hetcomm::OpenError::Config(e)))?;
        let comm = Comm::open_fleet(&fleet, system)?;
        // SAFETY: checked non-NULL; the caller gave a writable pointer.
        unsafe { *out = Box::into_raw(Box::new(hetcomm_comm::new(comm))) };
        Ok(())
    })
}

/// Frees a system handle. The system itself closes (its transports and threads stop) when
/// this handle and every module handle of it are freed. NULL is ignored.
///
/// # Safety
/// `comm` is NULL or a handle from `hetcomm_comm_open*` not freed yet; no other thread uses
/// it during or after this call.
#[no_mangle]
pub unsafe extern "C" fn hetcomm_comm_close(comm: *mut hetcomm_comm) {
    if !comm.is_null() {
        guard_value((), || {
            // SAFETY: made by Box::into_raw in hetcomm_comm_open*; freed once by contract.
            drop(unsafe { Box::from_raw(comm) });
        });
    }
}

/// The system's friendly name (valid while `comm` is), or NULL if `comm` is NULL.
///
/// # Safety
/// `comm` is NULL or a live handle.
#[no_mangle]
pub unsafe extern "C" fn hetcomm_comm_name(comm: *const hetcomm_comm) -> *const c_char {
    // SAFETY: the caller's contract.
    match unsafe { comm.as_ref() } {
        Some(c) => c.name.as_ptr(),
        None => std::ptr::null(),
    }
}

/// The system's numeric id (0 if `comm` is NULL).
///
/// # Safety
/// `comm` is NULL or a live handle.
#[no_mangle]
pub unsafe extern "C" fn hetcomm_comm_id(comm: *const hetcomm_comm) -> u16 {
    // SAFETY: the caller's contract.
    unsafe { comm.as_ref() }.map_or(0, |c| c.comm.id().0)
}

/// How many transports this system has open (0 if `comm` is NULL).
///
/// # Safety
/// `comm` is NULL or a live handle.
#[no_mangle]
pub unsafe extern "C" fn hetcomm_comm_endpoint_count(comm: *const hetcomm_comm) -> usize {
    // SAFETY: the caller's contract.
    unsafe { comm.as_ref() }.map_or(0, |c| c.endpoints.len())
}

/// The `index`th open transport: its name, and where it listens (e.g.
/// `udp://127.0.0.1:40123`; NULL for transports without an address). Both strings stay valid
/// while `comm` is. `address` may be NULL if not wanted.
///
/// # Safety
/// `comm` is NULL or a live handle; `name` and `address` are NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn hetcomm_comm_endpoint(
    comm: *const hetcomm_comm,
    index: usize,
    name: *mut *const c_char,
    address: *mut *const c_char,
) -> hetcomm_status {
    guard(|| {
        // SAFETY: the caller's contract.
        let c = unsafe { handle(comm, "comm")? };
        let name = out_arg(name, "name")?;
        let (n, a) = c.endpoints.get(index).ok_or_else(|| {
            Error::invalid(format!(
                "endpoint index {index} out of range: the system has {} transports",
                c.endpoints.len()
            ))
        })?;
        // SAFETY: checked non-NULL (address: checked below); writable by contract.
        unsafe {
            *name = n.as_ptr();
            if !address.is_null() {
                *address = a.as_ref().map_or(std::ptr::null(), |a| a.as_ptr());
            }
        }
        Ok(())
    })
}

/// Opens a handle to the module named `module` of this system; free it with
/// `hetcomm_module_free`. A module handle keeps its system open.
///
/// Errors: `HETCOMM_STATUS_UNKNOWN_MODULE`, `HETCOMM_STATUS_INVALID_ARGUMENT`.
///
/// # Safety
/// `comm` is NULL or a live handle; `module` NULL or a NUL-terminated string; `out` NULL or
/// writable.
#[no_mangle]
pub unsafe extern "C" fn hetcomm_comm_module(
    comm: *const hetcomm_comm,
    module: *const c_char,
    out: *mut *mut hetcomm_module,
) -> hetcomm_status {
    guard(|| {
        // SAFETY: the caller's contract.
        let (c, name) = unsafe { (handle(comm, "comm")?, str_arg(module, "module")?) };
        let out = out_arg(out, "out")?;
        let m = c.comm.module(name)?;
        // SAFETY: checked non-NULL, writable by contract.
        unsafe { *out = Box::into_raw(Box::new(hetcomm_module::new(m))) };
        Ok(())
    })
}

/// Fills `*out` with this system's counters.
///
/// # Safety
/// `comm` is NULL or a live handle; `out` NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn hetcomm_comm_stats(
    comm: *const hetcomm_comm,
    out: *mut hetcomm_stats,
) -> hetcomm_status {
    guard(|| {
        // SAFETY: the caller's contract.
        let c = unsafe { handle(comm, "comm")? };
        let out = out_arg(out, "out")?;
        let s = c.comm.stats();
        let r = &s.router;
        let stats = hetcomm_stats {
            sends: r.sends,
            transmissions: r.transmissions,
            retransmissions: r.retransmissions,
            delivered: r.delivered,
            sent: r.sent,
            unconfirmed: r.unconfirmed,
            failed: r.failed,
            received: r.received,
            duplicates: r.duplicates,
            malformed: r.malformed,
            backpressured: r.backpressured,
            inbox_dropped: s.inboxes.iter().map(|(_, i)| i.dropped()).sum(),
            link_dropped: s.links.iter().map(|(_, l)| l.frames_dropped).sum(),
            callback_failures: s.callback_failures,
            unknown_module: s.unknown_module,
        };
        // SAFETY: checked non-NULL, writable by contract.
        unsafe { *out = stats };
        Ok(())
    })
}
