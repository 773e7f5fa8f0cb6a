//! # hetcomm-c — the C API of hetcomm
//!
//! A C ABI over the public Rust API of the `hetcomm` facade, built as a shared library
//! (`libhetcomm_c.so`) and a static one (`libhetcomm_c.a`) with the header
//! `include/hetcomm.h`, generated from this crate by cbindgen and checked in
//! (`tests/header.rs` fails when it is stale; `HETCOMM_BLESS=1 cargo test -p hetcomm-c --test
//! header` rewrites it). `include/hetcomm.hpp` is a header-only C++17 wrapper over it.
//! Installing both for CMake (`find_package(hetcomm)`) and pkg-config, and the mapping to the
//! thesis's C++ API: `docs/cpp.md`.
//!
//! What this layer does: handles (`hetcomm_comm`, `hetcomm_module`, `hetcomm_ticket`,
//! `hetcomm_broadcast`, `hetcomm_message`) owning Rust values, raw payloads in and out
//! (the program encodes its messages; MessagePack for messages other languages read), status
//! codes with a per-thread message ([`hetcomm_last_error`]). What it does not do: encode
//! messages (the C++ wrapper does, with msgpack-c), or let a Rust panic cross into C (each
//! function runs in a guard that turns a panic into `HETCOMM_STATUS_PANIC`).
//!
//! ```c
//! hetcomm_comm *comm;
//! hetcomm_module *plan;
//! if (hetcomm_comm_open("fleet.toml", "Alpha", &comm) != HETCOMM_STATUS_OK) {
//!     fprintf(stderr, "%s\n", hetcomm_last_error());
//!     return 1;
//! }
//! hetcomm_comm_module(comm, "Plan", &plan);
//! const uint8_t command[] = {0x81, 0xa4, 'c', 'o', 'd', 'e', 0x01}; /* {"code": 1} */
//! hetcomm_ticket *ticket;
//! hetcomm_module_send(plan, "Charlie", "Act", 0, command, sizeof command,
//!                     HETCOMM_PRIORITY_NORMAL, &ticket);
//! hetcomm_outcome outcome;
//! hetcomm_ticket_wait(ticket, &outcome); /* outcome.kind == HETCOMM_OUTCOME_KIND_DELIVERED */
//! hetcomm_ticket_free(ticket);
//! hetcomm_module_free(plan);
//! hetcomm_comm_close(comm);
//! ```
//!
//! Conventions: every function that can fail returns a [`hetcomm_status`]; output arguments
//! are written only on success (except the size needed on `HETCOMM_STATUS_BUFFER_TOO_SMALL`);
//! NULL handles and arguments are reported as `HETCOMM_STATUS_INVALID_ARGUMENT`, never
//! dereferenced; every handle is safe to share between threads; strings are UTF-8.

// The C names are the API: snake_case types, as C programs spell them.
#![allow(non_camel_case_types)]

mod comm;
mod error;
mod module;
mod paths;
mod ticket;

pub use comm::{
    hetcomm_comm, hetcomm_comm_close, hetcomm_comm_endpoint, hetcomm_comm_endpoint_count,
    hetcomm_comm_id, hetcomm_comm_module, hetcomm_comm_name, hetcomm_comm_open,
    hetcomm_comm_open_str, hetcomm_comm_stats, hetcomm_stats,
};
pub use error::{hetcomm_last_error, hetcomm_status, hetcomm_status_name};
pub use module::{
    hetcomm_callback, hetcomm_envelope, hetcomm_inbox_stats, hetcomm_message, hetcomm_message_data,
    hetcomm_message_envelope, hetcomm_message_free, hetcomm_module, hetcomm_module_broadcast,
    hetcomm_module_free, hetcomm_module_has_message, hetcomm_module_inbox_stats,
    hetcomm_module_name, hetcomm_module_next_type, hetcomm_module_on, hetcomm_module_on_any,
    hetcomm_module_pending, hetcomm_module_recv, hetcomm_module_recv_alloc,
    hetcomm_module_recv_alloc_type, hetcomm_module_send, hetcomm_module_set_inline_callbacks,
    hetcomm_module_set_wait_spin, HETCOMM_PRIORITY_NORMAL,
};
pub use paths::{
    hetcomm_comm_set_transports, hetcomm_comm_watch_paths, hetcomm_path_switch, hetcomm_path_watch,
    hetcomm_path_watch_free, hetcomm_path_watch_poll,
};
pub use ticket::{
    hetcomm_broadcast, hetcomm_broadcast_count, hetcomm_broadcast_free, hetcomm_broadcast_ticket,
    hetcomm_fail_reason, hetcomm_outcome, hetcomm_outcome_kind, hetcomm_ticket,
    hetcomm_ticket_destination, hetcomm_ticket_free, hetcomm_ticket_poll, hetcomm_ticket_wait,
    hetcomm_ticket_wait_timeout,
};

/// The library's version (`"0.1.0"`), a static string.
#[no_mangle]
pub extern "C" fn hetcomm_version() -> *const std::ffi::c_char {
    static VERSION: &std::ffi::CStr = match std::ffi::CStr::from_bytes_with_nul(
        concat!(env!("CARGO_PKG_VERSION"), "\0").as_bytes(),
    ) {
        Ok(v) => v,
        Err(_) => c"unknown",
    };
    VERSION.as_ptr()
}
