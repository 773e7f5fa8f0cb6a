//! Python bindings of hetcomm: the native half (`hetcomm._hetcomm`) of the `hetcomm` Python
//! package. The pure-Python half (`python/hetcomm`) holds the message-class registry
//! (`@hetcomm.message(id=N)` dataclasses), building instances from decoded payloads, and the
//! exception classes. See README.md.

use pyo3::prelude::*;

mod api;
mod errors;
mod node;
mod value;

#[pymodule]
fn _hetcomm(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    api::add_classes(m)?;
    Ok(())
}
