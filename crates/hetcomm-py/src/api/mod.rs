//! The Python classes: `Comm`, `LocalFleet`, `Module`, `Ticket`, `BroadcastTicket`,
//! `Outcome`, `Envelope`, `RawMessage`, `Received`.
//!
//! Blocking calls (`Module.recv`, `Ticket.wait`) release the GIL while they wait, in slices of
//! [`SLICE`], checking for signals (Ctrl-C) between slices.

mod comm;
mod message;
mod module;
mod outcome;
mod paths;

pub use comm::{Comm, LocalFleet};
pub use message::{Envelope, RawMessage, Received};
pub use module::Module;
pub use outcome::{BroadcastTicket, Outcome, Ticket};
pub use paths::PathWatch;

// Helpers the submodules share.
use message::{raw_message, received, unpack};
use module::inbox_stats;
use outcome::spin;

use parking_lot::Mutex;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::sync::PyOnceLock;
use pyo3::types::{PyBytes, PyDict, PyTuple};

use hetcomm::{FailReason, MessageType, RecvError, SendOptions};

use crate::errors::{self, new_err, open_error, recv_error, send_error};
use crate::value;

/// Longest time a blocking call stays detached before checking for signals.
const SLICE: Duration = Duration::from_millis(100);

static TYPES: PyOnceLock<Py<PyModule>> = PyOnceLock::new();

/// The Python half of the message layer: the type registry and dataclass building.
fn types_module(py: Python<'_>) -> PyResult<&Bound<'_, PyModule>> {
    TYPES
        .get_or_try_init(py, || Ok::<_, PyErr>(py.import("hetcomm._types")?.unbind()))
        .map(|m| m.bind(py))
}

fn timeout_arg(timeout: Option<f64>) -> PyResult<Option<Duration>> {
    timeout
        .map(|t| {
            Duration::try_from_secs_f64(t)
                .map_err(|_| PyValueError::new_err(format!("invalid timeout: {t} seconds")))
        })
        .transpose()
}

fn options(priority: Option<i64>) -> PyResult<SendOptions> {
    match priority {
        None => Ok(SendOptions::default()),
        Some(p) => u8::try_from(p).map(SendOptions::priority).map_err(|_| {
            PyValueError::new_err(format!("priority must be 0..=255 (100 is normal), not {p}"))
        }),
    }
}

fn message_type(type_id: i64) -> PyResult<MessageType> {
    u32::try_from(type_id).map(MessageType).map_err(|_| {
        PyValueError::new_err(format!(
            "message type id must be 0..=4294967295, not {type_id}"
        ))
    })
}

/// Drops `value` with the GIL released: closing a system joins its callback threads, which may
/// be waiting for the GIL.
fn drop_detached<T: Send>(value: T) {
    // Not attachable (interpreter finalizing): the closure, and `value` with it, is dropped
    // without detaching; nothing can be waiting for the GIL any more.
    let _ = Python::try_attach(|py| py.detach(move || drop(value)));
}

// ---------------------------------------------------------------------------------------------
// Free functions

/// Encodes a value (dataclass, dict, list, …) as one MessagePack value.
#[pyfunction]
pub fn pack<'py>(py: Python<'py>, obj: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyBytes>> {
    Ok(PyBytes::new(py, &value::pack(obj)?))
}

/// Decodes exactly one MessagePack value to plain Python values; raises DecodeError.
#[pyfunction(name = "unpack")]
pub fn unpack_py<'py>(py: Python<'py>, payload: &[u8]) -> PyResult<Bound<'py, PyAny>> {
    unpack(py, payload)
}

/// Decodes one frame with the Rust wire codec: (header dict, payload bytes). Raises
/// ValueError naming the `DecodeError` variant (e.g. "BadChecksum: ...").
#[pyfunction]
pub fn decode_frame<'py>(
    py: Python<'py>,
    frame: &[u8],
) -> PyResult<(Bound<'py, PyDict>, Bound<'py, PyBytes>)> {
    let f = hetcomm::wire::decode(frame).map_err(|e| {
        let dbg = format!("{e:?}");
        let variant = dbg.split([' ', '{', '(']).next().unwrap_or("").to_string();
        PyValueError::new_err(format!("{variant}: {e}"))
    })?;
    let h = &f.header;
    let d = PyDict::new(py);
    d.set_item("kind", h.kind as u8)?;
    d.set_item("flags", h.flags)?;
    d.set_item("priority", h.priority.0)?;
    d.set_item("transport", h.transport)?;
    let addr = |a: hetcomm::Address| -> PyResult<Bound<'py, PyDict>> {
        let x = PyDict::new(py);
        x.set_item("system", a.system.0)?;
        x.set_item("module", a.module.0)?;
        Ok(x)
    };
    d.set_item("source", addr(h.source)?)?;
    d.set_item("destination", addr(h.destination)?)?;
    d.set_item("incarnation", h.incarnation)?;
    d.set_item("seq", h.seq)?;
    d.set_item("message_type", h.message_type.0)?;
    d.set_item("timestamp", h.timestamp.as_micros())?;
    d.set_item("payload_len", f.payload.len())?;
    Ok((d, PyBytes::new(py, f.payload)))
}

/// The classes of this module, for `#[pymodule]`.
pub fn add_classes(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<Comm>()?;
    m.add_class::<LocalFleet>()?;
    m.add_class::<Module>()?;
    m.add_class::<Ticket>()?;
    m.add_class::<BroadcastTicket>()?;
    m.add_class::<Outcome>()?;
    m.add_class::<Envelope>()?;
    m.add_class::<RawMessage>()?;
    m.add_class::<Received>()?;
    m.add_class::<PathWatch>()?;
    m.add_function(wrap_pyfunction!(pack, m)?)?;
    m.add_function(wrap_pyfunction!(unpack_py, m)?)?;
    m.add_function(wrap_pyfunction!(decode_frame, m)?)?;
    crate::node::add_classes(m)?;
    Ok(())
}
