//! A module: send, broadcast, poll the inbox, receive, callbacks.

use parking_lot::{Mutex, MutexGuard};
use std::collections::{HashMap, VecDeque};
use std::ffi::{c_char, c_void, CStr, CString};
use std::sync::OnceLock;
use std::time::Duration;

use hetcomm::{Envelope, MessageType, Module, RawMessage, SendOptions};

use crate::error::{guard, guard_value, handle, hetcomm_status, out_arg, str_arg, Error};
use crate::ticket::{hetcomm_broadcast, hetcomm_ticket};

/// One module of an opened system (the Rust `hetcomm::Module`). Made by
/// `hetcomm_comm_module`, freed by [`hetcomm_module_free`].
/// Safe to use from several threads at once.
pub struct hetcomm_module {
    module: Module,
    /// The module's name for C.
    name: CString,
    /// Messages taken from the inbox that did not fit the caller's buffer: they come first at
    /// the next receive (front = next).
    held: Mutex<VecDeque<RawMessage>>,
}

impl hetcomm_module {
    pub(crate) fn new(module: Module) -> hetcomm_module {
        hetcomm_module {
            name: CString::new(module.name()).unwrap_or_default(),
            module,
            held: Mutex::new(VecDeque::new()),
        }
    }

    fn held(&self) -> MutexGuard<'_, VecDeque<RawMessage>> {
        self.held.lock()
    }

    /// The next message: a held one, or one from the inbox (`timeout_ms` < 0: wait forever,
    /// 0: do not wait).
    fn take(&self, timeout_ms: i64) -> Result<RawMessage, Error> {
        if let Some(m) = self.held().pop_front() {
            return Ok(m);
        }
        match timeout_ms {
            0 => self.module.try_recv_raw().ok_or_else(|| {
                Error::new(
                    hetcomm_status::Empty,
                    format!("no message waiting in `{}`", self.module.name()),
                )
            }),
            t if t < 0 => Ok(self.module.recv_raw_timeout(None)?),
            t => Ok(self
                .module
                .recv_raw_timeout(Some(Duration::from_millis(t as u64)))?),
        }
    }
}

/// The envelope of a received message.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct hetcomm_envelope {
    /// The message type id (the `N` of Rust's `#[message(id = N)]`).
    pub message_type: u32,
    /// The sending system's id.
    pub source_system: u16,
    /// The sending module's id.
    pub source_module: u16,
    /// The sending system's name: a static string, valid until the process exits.
    pub source_system_name: *const c_char,
    /// The sending module's name: a static string, valid until the process exits.
    pub source_module_name: *const c_char,
    /// The sender's sequence number: (source system, seq) is the message id.
    pub seq: u64,
    /// When the sender created it (sender's wall clock, microseconds since the UNIX epoch).
    pub timestamp_us: u64,
    /// When this system put it into the inbox (this system's wall clock, microseconds since
    /// the UNIX epoch: minus `timestamp_us`, the one-way latency when the clocks agree).
    pub received_at_us: u64,
    /// Receive priority (0 lowest, 100 normal, 255 highest).
    pub priority: u8,
    /// Whether it was one copy of a broadcast.
    pub broadcast: bool,
}

/// A friendly name as a C string that lives as long as the process. Names are interned by
/// the Rust library (one `&'static str` per distinct name), so this map stays as small as the
/// fleet files' names.
fn static_cstr(name: &'static str) -> *const c_char {
    static NAMES: OnceLock<Mutex<HashMap<(usize, usize), &'static CStr>>> = OnceLock::new();
    let mut names = NAMES.get_or_init(Default::default).lock();
    names
        .entry((name.as_ptr() as usize, name.len()))
        .or_insert_with(|| {
            let c = CString::new(name).unwrap_or_default();
            Box::leak(c.into_boxed_c_str())
        })
        .as_ptr()
}

impl From<&Envelope> for hetcomm_envelope {
    fn from(e: &Envelope) -> Self {
        hetcomm_envelope {
            message_type: e.message_type().0,
            source_system: e.source().system.0,
            source_module: e.source().module.0,
            source_system_name: static_cstr(e.source_system),
            source_module_name: static_cstr(e.source_module),
            seq: e.header.seq,
            timestamp_us: e.timestamp().0,
            received_at_us: e.received_at.0,
            priority: e.priority().0,
            broadcast: e.is_broadcast(),
        }
    }
}

/// A received message owned by the library: made by [`hetcomm_module_recv_alloc`], read with
/// [`hetcomm_message_data`] and [`hetcomm_message_envelope`], freed by
/// [`hetcomm_message_free`].
pub struct hetcomm_message {
    envelope: hetcomm_envelope,
    raw: RawMessage,
}

/// Inbox counters of one module.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default)]
pub struct hetcomm_inbox_stats {
    /// Messages accepted into the inbox.
    pub accepted: u64,
    /// Messages taken out (by receives or callbacks).
    pub taken: u64,
    /// Messages lost to overflow, whatever the policy.
    pub dropped: u64,
    /// Messages queued now.
    pub len: usize,
    /// The inbox's bound.
    pub capacity: usize,
}

/// A function the library calls with each message a callback was registered for. `user` is
/// the pointer given at registration; `envelope` and `data` are valid only during the call
/// (copy what you keep). It must not unwind (a C++ exception must not leave it).
pub type hetcomm_callback = Option<
    unsafe extern "C" fn(
        user: *mut c_void,
        envelope: *const hetcomm_envelope,
        data: *const u8,
        len: usize,
    ),
>;

/// The normal priority (the default for sends).
pub const HETCOMM_PRIORITY_NORMAL: u8 = 100;

/// Frees a module handle. NULL is ignored. Messages this handle held back for a larger buffer
/// (`HETCOMM_STATUS_BUFFER_TOO_SMALL`) are dropped with it.
///
/// # Safety
/// `module` is NULL or a handle from `hetcomm_comm_module`, not
/// freed yet and not used by another thread during or after this call.
#[no_mangle]
pub unsafe extern "C" fn hetcomm_module_free(module: *mut hetcomm_module) {
    if !module.is_null() {
        // SAFETY: made by Box::into_raw in hetcomm_comm_module; freed once by contract.
        guard_value((), || drop(unsafe { Box::from_raw(module) }));
    }
}

/// The module's name (valid while `module` is), or NULL for NULL.
///
/// # Safety
/// `module` is NULL or a live handle.
#[no_mangle]
pub unsafe extern "C" fn hetcomm_module_name(module: *const hetcomm_module) -> *const c_char {
    // SAFETY: the caller's contract.
    unsafe { module.as_ref() }.map_or(std::ptr::null(), |m| m.name.as_ptr())
}

/// Sends `len` bytes at `data` (an encoded payload: MessagePack for messages other programs
/// decode, see docs/wire-format.md) as a message of type `message_type` to module `module` of
/// system `system`, at `priority` ([`HETCOMM_PRIORITY_NORMAL`] by default). Returns at once;
/// the payload is copied. When `ticket` is not NULL, `*ticket` receives a new ticket for the
/// outcome (free it with `hetcomm_ticket_free`).
///
/// Errors mean nothing was sent: `HETCOMM_STATUS_UNKNOWN_SYSTEM`,
/// `HETCOMM_STATUS_UNKNOWN_MODULE`, `HETCOMM_STATUS_NO_ROUTE`, `HETCOMM_STATUS_TOO_LARGE`,
/// `HETCOMM_STATUS_BACKPRESSURE`, `HETCOMM_STATUS_CLOSED`, `HETCOMM_STATUS_INVALID_ARGUMENT`.
///
/// # Safety
/// `module` is NULL or a live handle; `system` and `to_module` NULL or NUL-terminated;
/// `data` points to `len` readable bytes (or is NULL with `len` 0); `ticket` NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn hetcomm_module_send(
    module: *const hetcomm_module,
    system: *const c_char,
    to_module: *const c_char,
    message_type: u32,
    data: *const u8,
    len: usize,
    priority: u8,
    ticket: *mut *mut hetcomm_ticket,
) -> hetcomm_status {
    guard(|| {
        // SAFETY: the caller's contract.
        let (m, system, to_module, payload) = unsafe {
            (
                handle(module, "module")?,
                str_arg(system, "system")?,
                str_arg(to_module, "to_module")?,
                bytes_arg(data, len)?,
            )
        };
        let t = m.module.send_raw(
            system,
            to_module,
            MessageType(message_type),
            payload,
            SendOptions::priority(priority),
        )?;
        if !ticket.is_null() {
            // SAFETY: non-NULL, writable by contract.
            unsafe { *ticket = Box::into_raw(Box::new(hetcomm_ticket::new(t))) };
        }
        Ok(())
    })
}

/// Reads a payload argument.
///
/// # Safety
/// `data` points to `len` readable bytes, or is NULL with `len` 0.
unsafe fn bytes_arg<'a>(data: *const u8, len: usize) -> Result<&'a [u8], Error> {
    if data.is_null() {
        if len == 0 {
            return Ok(&[]);
        }
        return Err(Error::invalid(format!("`data` is NULL with `len` {len}")));
    }
    // SAFETY: the caller's contract.
    Ok(unsafe { std::slice::from_raw_parts(data, len) })
}

/// Sends the payload to module `to_module` of every other system this one may talk to (the
/// thesis's "All"; systems whose pair is `X` are skipped). One ticket per destination in
/// `*broadcast` when it is not NULL (free it with `hetcomm_broadcast_free`); a destination
/// whose window is full gets a ticket that failed with `HETCOMM_FAIL_REASON_BACKPRESSURE`.
///
/// # Safety
/// As [`hetcomm_module_send`]; `broadcast` NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn hetcomm_module_broadcast(
    module: *const hetcomm_module,
    to_module: *const c_char,
    message_type: u32,
    data: *const u8,
    len: usize,
    priority: u8,
    broadcast: *mut *mut hetcomm_broadcast,
) -> hetcomm_status {
    guard(|| {
        // SAFETY: the caller's contract.
        let (m, to_module, payload) = unsafe {
            (
                handle(module, "module")?,
                str_arg(to_module, "to_module")?,
                bytes_arg(data, len)?,
            )
        };
        let b = m.module.broadcast_raw(
            to_module,
            MessageType(message_type),
            payload,
            SendOptions::priority(priority),
        )?;
        if !broadcast.is_null() {
            let tickets = b
                .tickets()
                .iter()
                .cloned()
                .map(hetcomm_ticket::new)
                .collect();
            // SAFETY: non-NULL, writable by contract.
            unsafe { *broadcast = Box::into_raw(Box::new(hetcomm_broadcast { tickets })) };
        }
        Ok(())
    })
}

/// Whether a message is waiting (the thesis's `CheckForMessage`). False for NULL.
///
/// # Safety
/// `module` is NULL or a live handle.
#[no_mangle]
pub unsafe extern "C" fn hetcomm_module_has_message(module: *const hetcomm_module) -> bool {
    // SAFETY: the caller's contract.
    let Some(m) = (unsafe { module.as_ref() }) else {
        return false;
    };
    guard_value(false, || !m.held().is_empty() || m.module.has_message())
}

/// How many messages are waiting (0 for NULL).
///
/// # Safety
/// `module` is NULL or a live handle.
#[no_mangle]
pub unsafe extern "C" fn hetcomm_module_pending(module: *const hetcomm_module) -> usize {
    // SAFETY: the caller's contract.
    let Some(m) = (unsafe { module.as_ref() }) else {
        return 0;
    };
    guard_value(0, || m.held().len() + m.module.pending())
}

/// The type of the message the next receive returns (the thesis's `GetNextMessageType`), in
/// `*message_type`; `HETCOMM_STATUS_EMPTY` when no message waits.
///
/// # Safety
/// `module` is NULL or a live handle; `message_type` NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn hetcomm_module_next_type(
    module: *const hetcomm_module,
    message_type: *mut u32,
) -> hetcomm_status {
    guard(|| {
        // SAFETY: the caller's contract.
        let m = unsafe { handle(module, "module")? };
        let out = out_arg(message_type, "message_type")?;
        let next = match m.held().front() {
            Some(h) => Some(h.envelope.message_type()),
            None => m.module.next_type(),
        };
        let t = next.ok_or_else(|| {
            Error::new(
                hetcomm_status::Empty,
                format!("no message waiting in `{}`", m.module.name()),
            )
        })?;
        // SAFETY: checked non-NULL, writable by contract.
        unsafe { *out = t.0 };
        Ok(())
    })
}

/// Receives the next message into the caller's buffer (the thesis's `GetMessage`): waits up
/// to `timeout_ms` milliseconds (a negative value: forever; 0: not at all). On success the
/// payload is in `buf`, its length in `*len` and, when `envelope` is not NULL, its envelope in
/// `*envelope`.
///
/// `HETCOMM_STATUS_BUFFER_TOO_SMALL`: the next message is larger than `capacity`; `*len` is
/// the size needed and the message stays first in line, so call again with a larger buffer
/// (`buf` may be NULL with `capacity` 0 to ask for the size). `HETCOMM_STATUS_EMPTY` (timeout
/// 0) or `HETCOMM_STATUS_TIMEOUT`: no message. `HETCOMM_STATUS_CLOSED`: the system closed.
///
/// # Safety
/// `module` is NULL or a live handle; `buf` points to `capacity` writable bytes (or is NULL
/// with `capacity` 0); `len` NULL or writable; `envelope` NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn hetcomm_module_recv(
    module: *const hetcomm_module,
    timeout_ms: i64,
    buf: *mut u8,
    capacity: usize,
    len: *mut usize,
    envelope: *mut hetcomm_envelope,
) -> hetcomm_status {
    guard(|| {
        // SAFETY: the caller's contract.
        let m = unsafe { handle(module, "module")? };
        let len = out_arg(len, "len")?;
        if buf.is_null() && capacity != 0 {
            return Err(Error::invalid(format!(
                "`buf` is NULL with `capacity` {capacity}"
            )));
        }
        let msg = m.take(timeout_ms)?;
        let n = msg.payload.len();
        // SAFETY: checked non-NULL, writable by contract.
        unsafe { *len = n };
        if n > capacity {
            m.held().push_front(msg);
            return Err(Error::new(
                hetcomm_status::BufferTooSmall,
                format!("the next message is {n} bytes and the buffer holds {capacity}: it stays in the inbox"),
            ));
        }
        if n > 0 {
            // SAFETY: `buf` holds `capacity` >= n writable bytes by contract and does not
            // overlap the library's payload.
            unsafe { std::ptr::copy_nonoverlapping(msg.payload.as_ptr(), buf, n) };
        }
        if !envelope.is_null() {
            // SAFETY: non-NULL, writable by contract.
            unsafe { *envelope = (&msg.envelope).into() };
        }
        Ok(())
    })
}

/// Receives the next message into a buffer the library allocates (any size): waits as
/// [`hetcomm_module_recv`] does. On success `*message` is a new message to read with
/// [`hetcomm_message_data`] / [`hetcomm_message_envelope`] and free with
/// [`hetcomm_message_free`].
///
/// # Safety
/// `module` is NULL or a live handle; `message` NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn hetcomm_module_recv_alloc(
    module: *const hetcomm_module,
    timeout_ms: i64,
    message: *mut *mut hetcomm_message,
) -> hetcomm_status {
    // SAFETY: the caller's contract, passed on.
    unsafe { recv_alloc(module, None, timeout_ms, message) }
}

/// [`hetcomm_module_recv_alloc`] for a message of type `message_type` only: when the next
/// message is of another type it stays first in line and this returns
/// `HETCOMM_STATUS_WRONG_TYPE` (typed receives, as Rust's `Module::recv::<M>`).
///
/// # Safety
/// As [`hetcomm_module_recv_alloc`].
#[no_mangle]
pub unsafe extern "C" fn hetcomm_module_recv_alloc_type(
    module: *const hetcomm_module,
    message_type: u32,
    timeout_ms: i64,
    message: *mut *mut hetcomm_message,
) -> hetcomm_status {
    // SAFETY: the caller's contract, passed on.
    unsafe { recv_alloc(module, Some(message_type), timeout_ms, message) }
}

/// The two allocating receives: the next message (of `only_type`, when given; another type
/// stays first in line and gives `HETCOMM_STATUS_WRONG_TYPE`) as a new library-owned message.
///
/// # Safety
/// As [`hetcomm_module_recv_alloc`].
unsafe fn recv_alloc(
    module: *const hetcomm_module,
    only_type: Option<u32>,
    timeout_ms: i64,
    message: *mut *mut hetcomm_message,
) -> hetcomm_status {
    guard(|| {
        // SAFETY: the caller's contract.
        let m = unsafe { handle(module, "module")? };
        let out = out_arg(message, "message")?;
        let raw = m.take(timeout_ms)?;
        let found = raw.envelope.message_type().0;
        if let Some(wanted) = only_type.filter(|&wanted| wanted != found) {
            m.held().push_front(raw);
            return Err(Error::new(
                hetcomm_status::WrongType,
                format!("the next message is of type {found}, not {wanted}: it stays in the inbox"),
            ));
        }
        let msg = hetcomm_message {
            envelope: (&raw.envelope).into(),
            raw,
        };
        // SAFETY: checked non-NULL, writable by contract.
        unsafe { *out = Box::into_raw(Box::new(msg)) };
        Ok(())
    })
}

/// The payload of a library-owned message: its bytes (valid until the message is freed) and,
/// in `*len`, their number. NULL (and `*len` 0) for a NULL message.
///
/// # Safety
/// `message` is NULL or a live message; `len` NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn hetcomm_message_data(
    message: *const hetcomm_message,
    len: *mut usize,
) -> *const u8 {
    // SAFETY: the caller's contract.
    let m = unsafe { message.as_ref() };
    if !len.is_null() {
        // SAFETY: non-NULL, writable by contract.
        unsafe { *len = m.map_or(0, |m| m.raw.payload.len()) };
    }
    m.map_or(std::ptr::null(), |m| m.raw.payload.as_ptr())
}

/// The envelope of a library-owned message (valid until the message is freed; NULL for NULL).
///
/// # Safety
/// `message` is NULL or a live message.
#[no_mangle]
pub unsafe extern "C" fn hetcomm_message_envelope(
    message: *const hetcomm_message,
) -> *const hetcomm_envelope {
    // SAFETY: the caller's contract.
    unsafe { message.as_ref() }.map_or(std::ptr::null(), |m| &m.envelope as *const _)
}

/// Frees a message from [`hetcomm_module_recv_alloc`]. NULL is ignored.
///
/// # Safety
/// `message` is NULL or a message from this library, not freed yet.
#[no_mangle]
pub unsafe extern "C" fn hetcomm_message_free(message: *mut hetcomm_message) {
    if !message.is_null() {
        // SAFETY: made by Box::into_raw in hetcomm_module_recv_alloc; freed once by contract.
        guard_value((), || drop(unsafe { Box::from_raw(message) }));
    }
}

/// The C side's user pointer, handed back to its callback on the module's callback thread.
#[derive(Clone, Copy)]
struct UserPtr(*mut c_void);
// SAFETY: the C API documents that the user pointer is used from the callback thread; making
// it safe to use there is the registering program's part of the contract.
unsafe impl Send for UserPtr {}
// SAFETY: as above.
unsafe impl Sync for UserPtr {}

fn c_callback(
    cb: unsafe extern "C" fn(*mut c_void, *const hetcomm_envelope, *const u8, usize),
    user: UserPtr,
) -> impl Fn(RawMessage) + Send + Sync + 'static {
    move |raw: RawMessage| {
        let user = user;
        let env: hetcomm_envelope = (&raw.envelope).into();
        // SAFETY: the function pointer and user pointer were given by the C program for this
        // use; the envelope and payload outlive the call.
        unsafe { cb(user.0, &env, raw.payload.as_ptr(), raw.payload.len()) };
    }
}

/// Calls `callback(user, envelope, data, len)` for every message of type `message_type` that
/// arrives from now on, instead of queueing it for polling; replaces a callback already set
/// for that type.
///
/// **Thread:** callbacks run on the module's callback thread, a thread of the library named
/// `hetcomm-cb-<module>` (cut to 15 bytes by Linux), never the thread that registered them
/// and never a thread in a `hetcomm_*` call of yours; the
/// callbacks of one module run one at a time, in arrival order (priority first). `user` must
/// stay valid, and `callback` callable, until the system is closed (its `hetcomm_comm` and
/// every module handle freed).
///
/// # Safety
/// `module` is NULL or a live handle; `callback` is NULL (an error) or a function that does
/// not unwind; `user` is whatever `callback` expects.
#[no_mangle]
pub unsafe extern "C" fn hetcomm_module_on(
    module: *const hetcomm_module,
    message_type: u32,
    callback: hetcomm_callback,
    user: *mut c_void,
) -> hetcomm_status {
    guard(|| {
        // SAFETY: the caller's contract.
        let m = unsafe { handle(module, "module")? };
        let cb = callback.ok_or_else(|| Error::invalid("`callback` is NULL"))?;
        m.module
            .on_raw(MessageType(message_type), c_callback(cb, UserPtr(user)));
        Ok(())
    })
}

/// [`hetcomm_module_on`] for every message of a type that has no callback of its own.
///
/// # Safety
/// As [`hetcomm_module_on`].
#[no_mangle]
pub unsafe extern "C" fn hetcomm_module_on_any(
    module: *const hetcomm_module,
    callback: hetcomm_callback,
    user: *mut c_void,
) -> hetcomm_status {
    guard(|| {
        // SAFETY: the caller's contract.
        let m = unsafe { handle(module, "module")? };
        let cb = callback.ok_or_else(|| Error::invalid("`callback` is NULL"))?;
        m.module.on_any(c_callback(cb, UserPtr(user)));
        Ok(())
    })
}

/// Lets receives on this module spin up to `spin_us` microseconds for a message before they
/// sleep (the Rust `Module::set_wait_spin`): lower latency for a busy core.
///
/// # Safety
/// `module` is NULL or a live handle.
#[no_mangle]
pub unsafe extern "C" fn hetcomm_module_set_wait_spin(
    module: *const hetcomm_module,
    spin_us: u64,
) -> hetcomm_status {
    guard(|| {
        // SAFETY: the caller's contract.
        let m = unsafe { handle(module, "module")? };
        m.module.set_wait_spin(Duration::from_micros(spin_us));
        Ok(())
    })
}

/// With `inline` true, this module's callbacks run at the delivery, on the thread that
/// delivers the message (the sender's thread for an in-process link, a link's reader thread,
/// Cyclone DDS's receive thread with `deliver_on_receive_thread`), instead of the module's
/// callback thread (the Rust `Module::set_inline_callbacks`): a reply sent from the callback
/// leaves without a thread hand-off. Such a callback must be short and must not wait, and
/// callbacks may then run on several threads at once.
///
/// # Safety
/// `module` is NULL or a live handle.
#[no_mangle]
pub unsafe extern "C" fn hetcomm_module_set_inline_callbacks(
    module: *const hetcomm_module,
    inline: bool,
) -> hetcomm_status {
    guard(|| {
        // SAFETY: the caller's contract.
        let m = unsafe { handle(module, "module")? };
        m.module.set_inline_callbacks(inline);
        Ok(())
    })
}

/// Fills `*out` with this module's inbox counters.
///
/// # Safety
/// `module` is NULL or a live handle; `out` NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn hetcomm_module_inbox_stats(
    module: *const hetcomm_module,
    out: *mut hetcomm_inbox_stats,
) -> hetcomm_status {
    guard(|| {
        // SAFETY: the caller's contract.
        let m = unsafe { handle(module, "module")? };
        let out = out_arg(out, "out")?;
        let s = m.module.inbox_stats();
        // SAFETY: checked non-NULL, writable by contract.
        unsafe {
            *out = hetcomm_inbox_stats {
                accepted: s.accepted,
                taken: s.taken,
                dropped: s.dropped(),
                len: s.len,
                capacity: s.capacity,
            }
        };
        Ok(())
    })
}
