//! Rust errors → the Python exceptions of `hetcomm._errors` (a base `HetcommError` and one
//! subclass per kind), with the same messages as the Rust `Display`.

use pyo3::exceptions::PyRuntimeError;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

use hetcomm::{OpenError, RecvError, SendError};

/// An exception of class `name` (from `hetcomm._errors`) with `msg`.
pub fn new_err(name: &'static str, msg: impl Into<String>) -> PyErr {
    let msg = msg.into();
    Python::attach(|py| match exception(py, name) {
        Ok(cls) => match cls.call1((msg.clone(),)) {
            Ok(value) => PyErr::from_value(value),
            Err(e) => e,
        },
        Err(_) => PyRuntimeError::new_err(format!("{name}: {msg}")),
    })
}

fn exception<'py>(py: Python<'py>, name: &str) -> PyResult<Bound<'py, PyAny>> {
    py.import("hetcomm._errors")?.getattr(name)
}

/// Maps an error opening a fleet or a system.
pub fn open_error(e: OpenError) -> PyErr {
    let msg = e.to_string();
    match e {
        OpenError::Config(errors) => config_error(&errors, msg),
        OpenError::UnknownSystem { .. } => new_err("UnknownSystemError", msg),
        OpenError::UnknownModule { .. } => new_err("UnknownModuleError", msg),
        OpenError::KindUnavailable { .. } => new_err("TransportUnavailableError", msg),
        OpenError::Transport { .. } => new_err("TransportError", msg),
        _ => new_err("HetcommError", msg),
    }
}

/// A `ConfigError` whose message is every located problem (`file:line:column: message`) and
/// whose `errors` attribute lists them as dicts (`line` and `column` are None for a problem
/// with no position, such as a file that cannot be read).
pub fn config_error(errors: &hetcomm::config::ConfigErrors, msg: String) -> PyErr {
    let err = new_err("ConfigError", msg);
    Python::attach(|py| {
        let list = PyList::empty(py);
        for e in &errors.0 {
            let d = PyDict::new(py);
            let _ = d.set_item("file", &e.file);
            // Line 0: the problem has no position (the file could not be read).
            let located = e.line > 0;
            let _ = d.set_item("line", located.then_some(e.line));
            let _ = d.set_item("column", located.then_some(e.column));
            let _ = d.set_item("message", &e.message);
            let _ = d.set_item("help", e.help.as_deref());
            let _ = list.append(d);
        }
        let _ = err.value(py).setattr("errors", list);
    });
    err
}

/// Maps a refused send.
pub fn send_error(e: SendError) -> PyErr {
    let msg = e.to_string();
    match e {
        SendError::UnknownSystem(_) => new_err("UnknownSystemError", msg),
        SendError::UnknownModule(_) => new_err("UnknownModuleError", msg),
        SendError::NoRoute { .. } => new_err("NoRouteError", msg),
        SendError::TooLarge { .. } => new_err("TooLargeError", msg),
        SendError::Backpressure { .. } => new_err("BackpressureError", msg),
        SendError::Encode(_) => new_err("EncodeError", msg),
        SendError::TypeConflict(_) => new_err("TypeConflictError", msg),
        SendError::Closed => new_err("ClosedError", msg),
        _ => new_err("HetcommError", msg),
    }
}

/// Maps a failed receive.
pub fn recv_error(e: RecvError) -> PyErr {
    let msg = e.to_string();
    match e {
        RecvError::WrongType { .. } => new_err("WrongTypeError", msg),
        RecvError::Decode(_) => new_err("DecodeError", msg),
        RecvError::Timeout(_) => new_err("RecvTimeout", msg),
        RecvError::Closed => new_err("ClosedError", msg),
        RecvError::TypeConflict(_) => new_err("TypeConflictError", msg),
        _ => new_err("HetcommError", msg),
    }
}
