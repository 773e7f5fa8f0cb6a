//! What arrives: `Envelope`, `RawMessage`, `Received`, and decoding payloads into them.

// The parent's imports and shared helpers.
use super::*;

/// Where a message came from, when, at which priority.
#[pyclass(module = "hetcomm", frozen)]
pub struct Envelope {
    pub(super) inner: hetcomm::Envelope,
}

#[pymethods]
impl Envelope {
    /// The sending system's name.
    #[getter]
    fn source_system(&self) -> &str {
        self.inner.source_system
    }
    /// The sending module's name.
    #[getter]
    fn source_module(&self) -> &str {
        self.inner.source_module
    }
    /// (system id, module id) of the sender.
    #[getter]
    fn source(&self) -> (u16, u16) {
        let a = self.inner.source();
        (a.system.0, a.module.0)
    }
    /// (system id, module id) it was sent to.
    #[getter]
    fn destination(&self) -> (u16, u16) {
        let a = self.inner.header.destination;
        (a.system.0, a.module.0)
    }
    /// The message type id.
    #[getter]
    fn message_type(&self) -> u32 {
        self.inner.message_type().0
    }
    /// Receive priority, 0..=255 (100 normal).
    #[getter]
    fn priority(&self) -> u8 {
        self.inner.priority().0
    }
    /// The message id: (origin system id, sequence number).
    #[getter]
    fn message_id(&self) -> (u16, u64) {
        let id = self.inner.id();
        (id.origin.0, id.seq)
    }
    /// When the sender created it: microseconds on the sender's wall clock (real runs: since
    /// the UNIX epoch).
    #[getter]
    fn timestamp_us(&self) -> u64 {
        self.inner.timestamp().as_micros()
    }
    /// `timestamp_us` in seconds.
    #[getter]
    fn timestamp(&self) -> f64 {
        self.inner.timestamp().as_micros() as f64 / 1e6
    }
    /// When this system put it in the inbox: microseconds on the receiver's wall clock (real
    /// runs: since the UNIX epoch), so `received_at_us - timestamp_us` is the one-way latency
    /// when the two clocks agree.
    #[getter]
    fn received_at_us(&self) -> u64 {
        self.inner.received_at.as_micros()
    }
    /// `received_at_us` in seconds.
    #[getter]
    fn received_at(&self) -> f64 {
        self.inner.received_at.as_micros() as f64 / 1e6
    }
    /// Whether it was one copy of a broadcast.
    #[getter]
    fn is_broadcast(&self) -> bool {
        self.inner.is_broadcast()
    }
    /// The tag byte of the transport that carried it (0 when unknown).
    #[getter]
    fn transport(&self) -> u8 {
        self.inner.header.transport
    }
    fn __repr__(&self) -> String {
        let id = self.inner.id();
        format!(
            "<Envelope from {}.{} type={} priority={} id=({}, {}) timestamp_us={}{}>",
            self.inner.source_system,
            self.inner.source_module,
            self.inner.message_type().0,
            self.inner.priority().0,
            id.origin.0,
            id.seq,
            self.inner.timestamp().as_micros(),
            if self.inner.is_broadcast() {
                " broadcast"
            } else {
                ""
            }
        )
    }
}

/// An undecoded message with its envelope.
#[pyclass(module = "hetcomm", frozen)]
pub struct RawMessage {
    pub(super) envelope: Py<Envelope>,
    pub(super) payload: Vec<u8>,
    pub(super) type_id: u32,
}

#[pymethods]
impl RawMessage {
    #[getter]
    fn envelope(&self, py: Python<'_>) -> Py<Envelope> {
        self.envelope.clone_ref(py)
    }
    /// The encoded payload (one MessagePack value).
    #[getter]
    fn payload<'py>(&self, py: Python<'py>) -> Bound<'py, PyBytes> {
        PyBytes::new(py, &self.payload)
    }
    /// The message type id.
    #[getter]
    fn type_id(&self) -> u32 {
        self.type_id
    }
    /// The payload decoded to plain Python values (dict, list, int, …); raises DecodeError.
    fn data<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        unpack(py, &self.payload)
    }
    /// The payload decoded as its registered message class (or an UnknownMessage).
    fn decode<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        decode_message(py, self.type_id, &self.payload)
    }
    fn __repr__(&self) -> String {
        format!(
            "<RawMessage type={} {} bytes>",
            self.type_id,
            self.payload.len()
        )
    }
}

/// A message with its envelope; unpacks as `message, envelope = received`.
#[pyclass(module = "hetcomm", frozen)]
pub struct Received {
    pub(super) message: Py<PyAny>,
    pub(super) envelope: Py<Envelope>,
}

#[pymethods]
impl Received {
    /// An instance of the class registered for its type id, or an UnknownMessage.
    #[getter]
    fn message(&self, py: Python<'_>) -> Py<PyAny> {
        self.message.clone_ref(py)
    }
    #[getter]
    fn envelope(&self, py: Python<'_>) -> Py<Envelope> {
        self.envelope.clone_ref(py)
    }
    fn __iter__<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        PyTuple::new(
            py,
            [
                self.message.clone_ref(py),
                self.envelope.clone_ref(py).into_any(),
            ],
        )?
        .into_any()
        .try_iter()
        .map(|i| i.into_any())
    }
    fn __repr__(&self, py: Python<'_>) -> PyResult<String> {
        Ok(format!(
            "Received(message={}, envelope={})",
            self.message.bind(py).repr()?,
            self.envelope.bind(py).repr()?
        ))
    }
}

pub(super) fn unpack<'py>(py: Python<'py>, payload: &[u8]) -> PyResult<Bound<'py, PyAny>> {
    let v = value::unpack_value(payload).map_err(|e| new_err("DecodeError", e))?;
    value::to_py(py, &v)
}

/// Payload → registered class instance (or UnknownMessage), via `hetcomm._types`.
pub(super) fn decode_message<'py>(
    py: Python<'py>,
    type_id: u32,
    payload: &[u8],
) -> PyResult<Bound<'py, PyAny>> {
    let (data, error) = match value::unpack_value(payload) {
        Ok(v) => (value::to_py(py, &v)?, None),
        Err(e) => (py.None().into_bound(py), Some(e)),
    };
    types_module(py)?.call_method1(
        "decode_message",
        (type_id, data, PyBytes::new(py, payload), error),
    )
}

pub(super) fn raw_message(py: Python<'_>, raw: hetcomm::RawMessage) -> PyResult<RawMessage> {
    let type_id = raw.envelope.message_type().0;
    Ok(RawMessage {
        envelope: Py::new(
            py,
            Envelope {
                inner: raw.envelope,
            },
        )?,
        payload: raw.payload.into_vec(),
        type_id,
    })
}

pub(super) fn received(py: Python<'_>, raw: hetcomm::RawMessage) -> PyResult<Received> {
    let message = decode_message(py, raw.envelope.message_type().0, &raw.payload)?.unbind();
    Ok(Received {
        message,
        envelope: Py::new(
            py,
            Envelope {
                inner: raw.envelope,
            },
        )?,
    })
}
