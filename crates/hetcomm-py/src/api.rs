//! The Python classes: `Comm`, `LocalFleet`, `Module`, `Ticket`, `BroadcastTicket`,
//! `Outcome`, `Envelope`, `RawMessage`, `Received`.
//!
//! Blocking calls (`Module.recv`, `Ticket.wait`) release the GIL while they wait, in slices of
//! [`SLICE`], checking for signals (Ctrl-C) between slices.

use std::path::PathBuf;
use std::sync::Mutex;
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
// Outcome

/// How a send ended. `kind` is one of:
///
/// - "delivered": the receiving router put the message in the destination module's inbox and
///   acknowledged it (in the inbox, not necessarily read yet);
/// - "sent": an unacknowledged transport took it; it cannot confirm delivery;
/// - "unconfirmed": frames left but no acknowledgement came back; it may or may not have
///   arrived (`reason` says why the sender stopped waiting);
/// - "failed": certainly not delivered (`reason` says why).
#[pyclass(module = "hetcomm", frozen, eq)]
#[derive(Clone, PartialEq)]
pub struct Outcome {
    inner: hetcomm::Outcome,
}

#[pymethods]
impl Outcome {
    /// "delivered", "sent", "unconfirmed" or "failed".
    #[getter]
    fn kind(&self) -> &'static str {
        match self.inner {
            hetcomm::Outcome::Delivered { .. } => "delivered",
            hetcomm::Outcome::Sent { .. } => "sent",
            hetcomm::Outcome::Unconfirmed { .. } => "unconfirmed",
            hetcomm::Outcome::Failed { .. } => "failed",
        }
    }
    /// Transmissions attempted.
    #[getter]
    fn attempts(&self) -> u32 {
        self.inner.attempts()
    }
    /// Delivered or sent.
    #[getter]
    fn is_success(&self) -> bool {
        self.inner.is_success()
    }
    /// In the destination module's inbox (acknowledged).
    #[getter]
    fn delivered(&self) -> bool {
        matches!(self.inner, hetcomm::Outcome::Delivered { .. })
    }
    /// Frames left but no acknowledgement came back: it may or may not have arrived.
    #[getter]
    fn unconfirmed(&self) -> bool {
        self.inner.is_unconfirmed()
    }
    /// Certainly not delivered.
    #[getter]
    fn failed(&self) -> bool {
        self.inner.is_failed()
    }
    /// Seconds from the first transmission to the acknowledgement (delivered only).
    #[getter]
    fn latency(&self) -> Option<f64> {
        match self.inner {
            hetcomm::Outcome::Delivered { latency, .. } => Some(latency.as_secs_f64()),
            _ => None,
        }
    }
    /// Why it failed or went unconfirmed: the Rust `FailReason`'s message (None otherwise).
    #[getter]
    fn reason(&self) -> Option<String> {
        self.inner.reason().map(|r| r.to_string())
    }
    /// Why it failed or went unconfirmed, as a short code: "no_acknowledgement",
    /// "unreachable", "congested", "inbox_full", "unknown_module", "link", "backpressure",
    /// "shutdown".
    #[getter]
    fn reason_code(&self) -> Option<&'static str> {
        self.inner.reason().map(|reason| match reason {
            FailReason::NoAcknowledgement => "no_acknowledgement",
            FailReason::Unreachable(_) => "unreachable",
            FailReason::InboxFull => "inbox_full",
            FailReason::UnknownModule => "unknown_module",
            FailReason::Link(_) => "link",
            FailReason::Backpressure => "backpressure",
            FailReason::Congested(_) => "congested",
            FailReason::Shutdown => "shutdown",
            _ => "other",
        })
    }
    fn __str__(&self) -> String {
        self.inner.to_string()
    }
    fn __repr__(&self) -> String {
        format!("<Outcome {}>", self.inner)
    }
}

fn outcome(o: hetcomm::Outcome) -> Outcome {
    Outcome { inner: o }
}

// ---------------------------------------------------------------------------------------------
// Tickets

/// The pending outcome of one send.
#[pyclass(module = "hetcomm", frozen)]
pub struct Ticket {
    inner: hetcomm::Ticket,
}

fn wait_ticket(
    py: Python<'_>,
    t: &hetcomm::Ticket,
    timeout: Option<Duration>,
) -> PyResult<Option<Outcome>> {
    let deadline = timeout.map(|t| Instant::now() + t);
    loop {
        let slice = match deadline {
            Some(d) => d.saturating_duration_since(Instant::now()).min(SLICE),
            None => SLICE,
        };
        if let Some(o) = py.detach(|| t.wait_timeout(slice)) {
            return Ok(Some(outcome(o)));
        }
        py.check_signals()?;
        if deadline.is_some_and(|d| Instant::now() >= d) {
            return Ok(None);
        }
    }
}

/// Keeps the calling thread alive, with the GIL released, while callbacks run on their
/// dispatcher threads: until `timeout` seconds pass (None: forever), a signal handler raises
/// (Ctrl-C: KeyboardInterrupt), or `open` says the handle was closed.
fn spin(py: Python<'_>, timeout: Option<f64>, open: impl Fn() -> bool) -> PyResult<()> {
    let deadline = timeout_arg(timeout)?.map(|d| Instant::now() + d);
    loop {
        py.check_signals()?;
        if !open() {
            return Ok(());
        }
        let slice = match deadline {
            Some(d) if Instant::now() >= d => return Ok(()),
            Some(d) => d.saturating_duration_since(Instant::now()).min(SLICE),
            None => SLICE,
        };
        py.detach(|| std::thread::sleep(slice));
    }
}

#[pymethods]
impl Ticket {
    /// The destination system's name.
    #[getter]
    fn destination(&self) -> &str {
        self.inner.destination()
    }
    /// Waits for the outcome (releasing the GIL); None if `timeout` seconds pass first. Every
    /// send ends (the retry budget bounds it), so without a timeout this returns.
    #[pyo3(signature = (timeout=None))]
    fn wait(&self, py: Python<'_>, timeout: Option<f64>) -> PyResult<Option<Outcome>> {
        wait_ticket(py, &self.inner, timeout_arg(timeout)?)
    }
    /// The outcome if the send has ended, else None.
    fn try_outcome(&self) -> Option<Outcome> {
        self.inner.try_outcome().map(outcome)
    }
    /// Whether the send has ended.
    #[getter]
    fn done(&self) -> bool {
        self.inner.try_outcome().is_some()
    }
    fn __repr__(&self) -> String {
        match self.inner.try_outcome() {
            Some(o) => format!("<Ticket to {}: {o}>", self.inner.destination()),
            None => format!("<Ticket to {}: pending>", self.inner.destination()),
        }
    }
}

/// The pending outcomes of one broadcast: one ticket per destination the table allows.
#[pyclass(module = "hetcomm", frozen)]
pub struct BroadcastTicket {
    inner: hetcomm::BroadcastTicket,
}

#[pymethods]
impl BroadcastTicket {
    /// One ticket per destination.
    #[getter]
    fn tickets(&self) -> Vec<Ticket> {
        self.inner
            .tickets()
            .iter()
            .map(|t| Ticket { inner: t.clone() })
            .collect()
    }
    /// The destination systems' names.
    #[getter]
    fn destinations(&self) -> Vec<String> {
        self.inner
            .tickets()
            .iter()
            .map(|t| t.destination().to_string())
            .collect()
    }
    /// Waits for every outcome: {destination: Outcome}. With a timeout (seconds, for the
    /// whole wait), destinations without an outcome by then map to None.
    #[pyo3(signature = (timeout=None))]
    fn wait<'py>(&self, py: Python<'py>, timeout: Option<f64>) -> PyResult<Bound<'py, PyDict>> {
        let deadline = timeout_arg(timeout)?.map(|t| Instant::now() + t);
        let out = PyDict::new(py);
        for t in self.inner.tickets() {
            let left = deadline.map(|d| d.saturating_duration_since(Instant::now()));
            out.set_item(t.destination(), wait_ticket(py, t, left)?)?;
        }
        Ok(out)
    }
    fn __len__(&self) -> usize {
        self.inner.tickets().len()
    }
    fn __repr__(&self) -> String {
        format!("<BroadcastTicket to {}>", self.destinations().join(", "))
    }
}

// ---------------------------------------------------------------------------------------------
// Envelope, RawMessage, Received

/// Where a message came from, when, at which priority.
#[pyclass(module = "hetcomm", frozen)]
pub struct Envelope {
    inner: hetcomm::Envelope,
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
    /// When the sender created it: microseconds on the sender's clock (real runs: since the
    /// UNIX epoch).
    #[getter]
    fn timestamp_us(&self) -> u64 {
        self.inner.timestamp().as_micros()
    }
    /// `timestamp_us` in seconds.
    #[getter]
    fn timestamp(&self) -> f64 {
        self.inner.timestamp().as_micros() as f64 / 1e6
    }
    /// When this system put it in the inbox: microseconds on the receiver's clock.
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
    envelope: Py<Envelope>,
    payload: Vec<u8>,
    type_id: u32,
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
    message: Py<PyAny>,
    envelope: Py<Envelope>,
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

fn unpack<'py>(py: Python<'py>, payload: &[u8]) -> PyResult<Bound<'py, PyAny>> {
    let v = value::unpack_value(payload).map_err(|e| new_err("DecodeError", e))?;
    value::to_py(py, &v)
}

/// Payload → registered class instance (or UnknownMessage), via `hetcomm._types`.
fn decode_message<'py>(
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

fn raw_message(py: Python<'_>, raw: hetcomm::RawMessage) -> PyResult<RawMessage> {
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

fn received(py: Python<'_>, raw: hetcomm::RawMessage) -> PyResult<Received> {
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

// ---------------------------------------------------------------------------------------------
// Module

/// One module (Sense, Plan, Act, …) of an opened system: sends, broadcasts, polls and
/// subscribes. Safe to use from several Python threads.
#[pyclass(module = "hetcomm", frozen)]
pub struct Module {
    inner: Mutex<Option<hetcomm::Module>>,
    system: String,
}

impl Drop for Module {
    fn drop(&mut self) {
        if let Some(m) = self.inner.get_mut().ok().and_then(Option::take) {
            drop_detached(m);
        }
    }
}

impl Module {
    fn get(&self) -> PyResult<hetcomm::Module> {
        self.inner
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .clone()
            .ok_or_else(|| new_err("ClosedError", "the system is closed"))
    }

    /// (type id, payload) of a message object, via `hetcomm._types.prepare`.
    fn encode(&self, msg: &Bound<'_, PyAny>) -> PyResult<(MessageType, Vec<u8>)> {
        let py = msg.py();
        let (type_id, payload): (u32, Option<Vec<u8>>) = types_module(py)?
            .call_method1("prepare", (msg,))?
            .extract()?;
        let payload = match payload {
            Some(p) => p,
            None => value::pack(msg)?,
        };
        Ok((MessageType(type_id), payload))
    }

    fn recv_raw_inner(
        &self,
        py: Python<'_>,
        timeout: Option<f64>,
    ) -> PyResult<hetcomm::RawMessage> {
        let module = self.get()?;
        let total = timeout_arg(timeout)?;
        let deadline = total.map(|t| Instant::now() + t);
        loop {
            let slice = match deadline {
                Some(d) => d.saturating_duration_since(Instant::now()).min(SLICE),
                None => SLICE,
            };
            match py.detach(|| module.recv_raw_timeout(Some(slice))) {
                Ok(raw) => return Ok(raw),
                Err(RecvError::Timeout(_)) => {}
                Err(e) => return Err(recv_error(e)),
            }
            py.check_signals()?;
            if deadline.is_some_and(|d| Instant::now() >= d) {
                return Err(recv_error(RecvError::Timeout(total.unwrap_or_default())));
            }
        }
    }
}

/// Wraps a Python callable as a module callback: runs on the module's callback thread with the
/// GIL; an exception is reported through `sys.unraisablehook` (printed by default).
fn make_callback(
    cb: Py<PyAny>,
    raw_mode: bool,
) -> impl Fn(hetcomm::RawMessage) + Send + Sync + 'static {
    move |raw| {
        // Not attachable: the interpreter is shutting down; the message is dropped.
        let _ = Python::try_attach(|py| {
            let arg = if raw_mode {
                raw_message(py, raw)
                    .and_then(|r| Py::new(py, r))
                    .map(Py::into_any)
            } else {
                received(py, raw)
                    .and_then(|r| Py::new(py, r))
                    .map(Py::into_any)
            };
            let result = arg.and_then(|a| cb.call1(py, (a,)));
            if let Err(e) = result {
                e.write_unraisable(py, Some(cb.bind(py)));
            }
        });
    }
}

#[pymethods]
impl Module {
    /// This module's name.
    #[getter]
    fn name(&self) -> PyResult<String> {
        Ok(self.get()?.name().to_string())
    }
    /// The name of the system it belongs to.
    #[getter]
    fn system(&self) -> &str {
        &self.system
    }
    /// (system id, module id).
    #[getter]
    fn address(&self) -> PyResult<(u16, u16)> {
        let a = self.get()?.address();
        Ok((a.system.0, a.module.0))
    }

    /// Sends `msg` (an instance of a `@hetcomm.message` class, or an UnknownMessage to
    /// forward) to `module` of `system`. Returns at once with a Ticket for the outcome; an
    /// exception means nothing was sent.
    #[pyo3(signature = (system, module, msg, priority=None))]
    fn send(
        &self,
        system: &str,
        module: &str,
        msg: &Bound<'_, PyAny>,
        priority: Option<i64>,
    ) -> PyResult<Ticket> {
        let opts = options(priority)?;
        let (ty, payload) = self.encode(msg)?;
        let m = self.get()?;
        m.send_raw(system, module, ty, &payload, opts)
            .map(|t| Ticket { inner: t })
            .map_err(send_error)
    }

    /// Sends an already-encoded payload with the given type id.
    #[pyo3(signature = (system, module, type_id, payload, priority=None))]
    fn send_raw(
        &self,
        system: &str,
        module: &str,
        type_id: i64,
        payload: &[u8],
        priority: Option<i64>,
    ) -> PyResult<Ticket> {
        let opts = options(priority)?;
        self.get()?
            .send_raw(system, module, message_type(type_id)?, payload, opts)
            .map(|t| Ticket { inner: t })
            .map_err(send_error)
    }

    /// Sends `msg` to `module` on every other system this one may talk to.
    #[pyo3(signature = (module, msg, priority=None))]
    fn broadcast(
        &self,
        module: &str,
        msg: &Bound<'_, PyAny>,
        priority: Option<i64>,
    ) -> PyResult<BroadcastTicket> {
        let opts = options(priority)?;
        let (ty, payload) = self.encode(msg)?;
        self.get()?
            .broadcast_raw(module, ty, &payload, opts)
            .map(|t| BroadcastTicket { inner: t })
            .map_err(send_error)
    }

    /// Broadcasts an already-encoded payload.
    #[pyo3(signature = (module, type_id, payload, priority=None))]
    fn broadcast_raw(
        &self,
        module: &str,
        type_id: i64,
        payload: &[u8],
        priority: Option<i64>,
    ) -> PyResult<BroadcastTicket> {
        let opts = options(priority)?;
        self.get()?
            .broadcast_raw(module, message_type(type_id)?, payload, opts)
            .map(|t| BroadcastTicket { inner: t })
            .map_err(send_error)
    }

    /// Whether a message is waiting.
    fn has_message(&self) -> PyResult<bool> {
        Ok(self.get()?.has_message())
    }
    /// How many messages are waiting.
    fn pending(&self) -> PyResult<usize> {
        Ok(self.get()?.pending())
    }
    /// The type id of the message `recv` would return next, or None.
    fn next_type(&self) -> PyResult<Option<u32>> {
        Ok(self.get()?.next_type().map(|t| t.0))
    }

    /// Waits (releasing the GIL) up to `timeout` seconds (None: forever) for the next message
    /// of any type; returns Received(message, envelope). Raises RecvTimeout, ClosedError, or
    /// DecodeError (the message is consumed).
    #[pyo3(signature = (timeout=None))]
    fn recv(&self, py: Python<'_>, timeout: Option<f64>) -> PyResult<Received> {
        let raw = self.recv_raw_inner(py, timeout)?;
        received(py, raw)
    }

    /// The next message if one is waiting, else None.
    fn try_recv(&self, py: Python<'_>) -> PyResult<Option<Received>> {
        match self.get()?.try_recv_raw() {
            Some(raw) => received(py, raw).map(Some),
            None => Ok(None),
        }
    }

    /// Like `recv`, undecoded.
    #[pyo3(signature = (timeout=None))]
    fn recv_raw(&self, py: Python<'_>, timeout: Option<f64>) -> PyResult<RawMessage> {
        let raw = self.recv_raw_inner(py, timeout)?;
        raw_message(py, raw)
    }

    /// Like `try_recv`, undecoded.
    fn try_recv_raw(&self, py: Python<'_>) -> PyResult<Option<RawMessage>> {
        match self.get()?.try_recv_raw() {
            Some(raw) => raw_message(py, raw).map(Some),
            None => Ok(None),
        }
    }

    /// Calls `callback(received)` for every message of class `cls` (a `@hetcomm.message`
    /// class, or a type id) that arrives from now on, instead of queueing it. Callbacks of one
    /// module run one at a time on its callback thread.
    fn on(&self, py: Python<'_>, cls: &Bound<'_, PyAny>, callback: Py<PyAny>) -> PyResult<()> {
        if !callback.bind(py).is_callable() {
            return Err(PyTypeError::new_err("callback must be callable"));
        }
        let type_id: u32 = types_module(py)?
            .call_method1("type_id_of", (cls,))?
            .extract()?;
        let m = self.get()?;
        let f = make_callback(callback, false);
        py.detach(|| m.on_raw(MessageType(type_id), f));
        Ok(())
    }

    /// Calls `callback(received)` for every message of a type without its own callback.
    fn on_any(&self, py: Python<'_>, callback: Py<PyAny>) -> PyResult<()> {
        if !callback.bind(py).is_callable() {
            return Err(PyTypeError::new_err("callback must be callable"));
        }
        let m = self.get()?;
        let f = make_callback(callback, false);
        py.detach(|| m.on_any(f));
        Ok(())
    }

    /// Calls `callback(raw_message)` (undecoded) for every message of type `type_id`.
    fn on_raw(&self, py: Python<'_>, type_id: i64, callback: Py<PyAny>) -> PyResult<()> {
        if !callback.bind(py).is_callable() {
            return Err(PyTypeError::new_err("callback must be callable"));
        }
        let ty = message_type(type_id)?;
        let m = self.get()?;
        let f = make_callback(callback, true);
        py.detach(|| m.on_raw(ty, f));
        Ok(())
    }

    /// This module's inbox counters.
    fn inbox_stats<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        inbox_stats(py, &self.get()?.inbox_stats())
    }

    /// Advertises topic `topic` of this module's system (the thesis's Advertise): a Publisher
    /// whose `publish(obj)` hands `obj` itself to the topic's subscribers.
    fn advertise(&self, topic: &str) -> PyResult<crate::node::Publisher> {
        crate::node::advertise(&self.get()?, topic)
    }

    /// Subscribes to topic `topic` (the thesis's Subscribe): a Subscription queueing up to
    /// `capacity` values.
    #[pyo3(signature = (topic, capacity=64))]
    fn subscribe(&self, topic: &str, capacity: usize) -> PyResult<crate::node::Subscription> {
        crate::node::subscribe(&self.get()?, topic, capacity)
    }

    /// Calls `callback(value)` for every value published on `topic` (the thesis's
    /// Notification), on the publishing thread; keep the returned handle.
    fn on_topic(
        &self,
        topic: &str,
        callback: Py<PyAny>,
    ) -> PyResult<crate::node::TopicNotification> {
        crate::node::on_topic(&self.get()?, topic, callback)
    }

    fn __repr__(&self) -> String {
        match self.get() {
            Ok(m) => format!("<Module {}.{}>", self.system, m.name()),
            Err(_) => format!("<Module of {} (closed)>", self.system),
        }
    }
}

fn inbox_stats<'py>(py: Python<'py>, s: &hetcomm::InboxStats) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("accepted", s.accepted)?;
    d.set_item("taken", s.taken)?;
    d.set_item("dropped_oldest", s.dropped_oldest)?;
    d.set_item("dropped_newest", s.dropped_newest)?;
    d.set_item("dropped_after_wait", s.dropped_after_wait)?;
    d.set_item("refused_from_link", s.refused_from_link)?;
    d.set_item("len", s.len)?;
    d.set_item("capacity", s.capacity)?;
    Ok(d)
}

// ---------------------------------------------------------------------------------------------
// Comm, LocalFleet

/// One opened system of a fleet. The system closes when the last Comm and Module objects of it
/// are gone, or on `close()` / leaving a `with` block (then only if no Module object of it is
/// still alive).
#[pyclass(module = "hetcomm", frozen)]
pub struct Comm {
    inner: Mutex<Option<hetcomm::Comm>>,
    name: String,
}

impl Drop for Comm {
    fn drop(&mut self) {
        if let Some(c) = self.inner.get_mut().ok().and_then(Option::take) {
            drop_detached(c);
        }
    }
}

impl Comm {
    fn wrap(c: hetcomm::Comm) -> Comm {
        Comm {
            name: c.name().to_string(),
            inner: Mutex::new(Some(c)),
        }
    }
    fn get(&self) -> PyResult<hetcomm::Comm> {
        self.inner
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .clone()
            .ok_or_else(|| new_err("ClosedError", "the system is closed"))
    }
}

/// Open options from the Python arguments: a private key file, read now so that a bad file
/// is reported as such (ValueError naming the file and what is wrong).
fn open_options(private_key_file: Option<PathBuf>) -> PyResult<hetcomm::OpenOptions> {
    let options = hetcomm::OpenOptions::new();
    match private_key_file {
        None => Ok(options),
        Some(path) => options
            .private_key_file(&path)
            .map_err(|e| pyo3::exceptions::PyValueError::new_err(e.to_string())),
    }
}

#[pymethods]
impl Comm {
    /// Places a tap (docs/harness.md) on topic `topic` of `system`, or on messages into
    /// system `to` (narrowed by `from_`, `module`, `type`). `action`: "observe" or "modify"
    /// (with `function`), "drop", "delay" (`delay` seconds), "duplicate" (`copies`).
    #[pyo3(signature = (action, *, to=None, from_=None, module=None, r#type=None, system=None, topic=None, function=None, delay=None, copies=1))]
    #[allow(clippy::too_many_arguments)] // Python keywords
    fn tap(
        &self,
        action: &str,
        to: Option<&str>,
        from_: Option<&str>,
        module: Option<&str>,
        r#type: Option<u32>,
        system: Option<&str>,
        topic: Option<&str>,
        function: Option<Py<PyAny>>,
        delay: Option<f64>,
        copies: u32,
    ) -> PyResult<crate::node::TapHandle> {
        let path = crate::node::path(system, topic, to, from_, module, r#type)?;
        let action = crate::node::action(action, function, delay, copies)?;
        crate::node::tap(&self.get()?, &path, action)
    }

    /// Replaces the source of a path (keywords as `tap`): real messages are discarded while
    /// the returned Replacement lives; its `inject` / `publish` supply the path instead.
    #[pyo3(signature = (*, to=None, from_=None, module=None, r#type=None, system=None, topic=None))]
    fn replace(
        &self,
        to: Option<&str>,
        from_: Option<&str>,
        module: Option<&str>,
        r#type: Option<u32>,
        system: Option<&str>,
        topic: Option<&str>,
    ) -> PyResult<crate::node::Replacement> {
        let path = crate::node::path(system, topic, to, from_, module, r#type)?;
        crate::node::replace(&self.get()?, &path)
    }

    /// What this system's harness did: taps' and faults' counters.
    fn harness_stats(&self, py: Python<'_>) -> PyResult<Py<PyDict>> {
        crate::node::stats(py, &self.get()?.harness_stats())
    }

    /// Applies the parts of a scenario file (docs/harness.md) that concern this system, with
    /// scenario time 0 now; `seed` seeds random loss and jitter unless the file has its own.
    #[pyo3(signature = (path, seed=0))]
    fn apply_scenario(&self, path: PathBuf, seed: u64) -> PyResult<crate::node::ScenarioRun> {
        let c = self.get()?;
        let sc = crate::node::load_scenario(&path, c.fleet())?;
        crate::node::scenario_run(c.apply_scenario(&sc, seed))
    }

    /// Loads a fleet file and opens one system of it. Raises ConfigError (with
    /// file:line:column), UnknownSystemError, TransportUnavailableError, TransportError.
    /// On a secured fleet, `private_key_file` is this system's `.key` file (`hetcomm keygen`
    /// writes them), instead of the fleet file's `private_key_file` or HETCOMM_PRIVATE_KEY.
    #[staticmethod]
    #[pyo3(signature = (path, system, private_key_file=None))]
    fn open(
        py: Python<'_>,
        path: PathBuf,
        system: &str,
        private_key_file: Option<PathBuf>,
    ) -> PyResult<Comm> {
        let options = open_options(private_key_file)?;
        let system = system.to_string();
        py.detach(move || hetcomm::Comm::open_with(&path, &system, options))
            .map(Comm::wrap)
            .map_err(open_error)
    }

    /// Opens one system of a fleet given as TOML text (`origin` names it in errors). In-process
    /// transports of systems opened this way meet if they share `origin`.
    #[staticmethod]
    #[pyo3(signature = (text, system, origin="<string>", private_key_file=None))]
    fn from_toml(
        py: Python<'_>,
        text: &str,
        system: &str,
        origin: &str,
        private_key_file: Option<PathBuf>,
    ) -> PyResult<Comm> {
        let fleet = hetcomm::parse_fleet(text, origin, None)
            .map_err(|e| errors::config_error(&e, e.to_string()))?;
        let options = open_options(private_key_file)?;
        let system = system.to_string();
        py.detach(move || hetcomm::Comm::open_fleet_options(&fleet, &system, options))
            .map(Comm::wrap)
            .map_err(open_error)
    }

    /// This system's name.
    #[getter]
    fn name(&self) -> &str {
        &self.name
    }
    /// This system's id.
    #[getter]
    fn id(&self) -> PyResult<u16> {
        Ok(self.get()?.id().0)
    }
    /// The transports this system has open: [(transport name, address or None)].
    #[getter]
    fn endpoints(&self) -> PyResult<Vec<(String, Option<String>)>> {
        Ok(self.get()?.endpoints().to_vec())
    }
    /// The fleet's system names, by id.
    #[getter]
    fn systems(&self) -> PyResult<Vec<String>> {
        Ok(self
            .get()?
            .fleet()
            .systems
            .iter()
            .map(|s| s.name.clone())
            .collect())
    }
    /// The fleet's module names, by id.
    #[getter]
    fn modules(&self) -> PyResult<Vec<String>> {
        Ok(self
            .get()?
            .fleet()
            .modules
            .iter()
            .map(|m| m.name.clone())
            .collect())
    }
    /// A handle to one of this system's modules.
    fn module(&self, name: &str) -> PyResult<Module> {
        let m = self.get()?.module(name).map_err(open_error)?;
        Ok(Module {
            inner: Mutex::new(Some(m)),
            system: self.name.clone(),
        })
    }
    /// Counters: {"router": {...}, "inboxes": {module: {...}}, "links": {transport: {...}},
    /// "callback_failures": n, "held_frames": n}.
    fn stats<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let s = self.get()?.stats();
        let r = &s.router;
        let router = PyDict::new(py);
        for (k, v) in [
            ("sends", r.sends),
            ("transmissions", r.transmissions),
            ("retransmissions", r.retransmissions),
            ("delivered", r.delivered),
            ("sent", r.sent),
            ("unconfirmed", r.unconfirmed),
            ("failed", r.failed),
            ("received", r.received),
            ("acks_sent", r.acks_sent),
            ("acks_received", r.acks_received),
            ("stale_acks", r.stale_acks),
            ("duplicates", r.duplicates),
            ("malformed", r.malformed),
            ("unknown_origin", r.unknown_origin),
            ("misrouted", r.misrouted),
            ("held", r.held),
            ("gaps_skipped", r.gaps_skipped),
            ("backpressured", r.backpressured),
            ("path_changes", r.path_changes),
            ("peer_mismatch", r.peer_mismatch),
        ] {
            router.set_item(k, v)?;
        }
        let inboxes = PyDict::new(py);
        for (name, st) in &s.inboxes {
            inboxes.set_item(name, inbox_stats(py, st)?)?;
        }
        let links = PyDict::new(py);
        for (name, l) in &s.links {
            let d = PyDict::new(py);
            d.set_item("frames_sent", l.frames_sent)?;
            d.set_item("frames_received", l.frames_received)?;
            d.set_item("frames_dropped", l.frames_dropped)?;
            d.set_item("kernel_drops", l.kernel_drops)?;
            d.set_item("connects", l.connects)?;
            d.set_item("buffered_bytes", l.buffered_bytes)?;
            let sec = PyDict::new(py);
            let x = &l.security;
            sec.set_item("enabled", x.enabled)?;
            sec.set_item("handshakes", x.handshakes)?;
            sec.set_item("rejected_auth", x.rejected_auth)?;
            sec.set_item("rejected_replay", x.rejected_replay)?;
            sec.set_item("rejected_table", x.rejected_table)?;
            sec.set_item("rejected_unknown_sender", x.rejected_unknown_sender)?;
            sec.set_item("rejected_no_session", x.rejected_no_session)?;
            sec.set_item("handshake_timeouts", x.handshake_timeouts)?;
            d.set_item("security", sec)?;
            links.set_item(name, d)?;
        }
        let out = PyDict::new(py);
        out.set_item("router", router)?;
        out.set_item("inboxes", inboxes)?;
        out.set_item("links", links)?;
        out.set_item("callback_failures", s.callback_failures)?;
        out.set_item("held_frames", s.held_frames)?;
        Ok(out)
    }
    /// Runs this system's callbacks until `timeout` seconds pass (None: until interrupted,
    /// e.g. by Ctrl-C, which raises KeyboardInterrupt) or this handle is closed, like rospy's
    /// `spin()`. Callbacks run on their own threads; this only keeps the caller waiting,
    /// with the GIL released.
    #[pyo3(signature = (timeout=None))]
    fn spin(&self, py: Python<'_>, timeout: Option<f64>) -> PyResult<()> {
        spin(py, timeout, || {
            self.inner
                .lock()
                .unwrap_or_else(|e| e.into_inner())
                .is_some()
        })
    }
    /// Drops this handle to the system (it closes once no Module object of it is left).
    fn close(&self) {
        let c = self.inner.lock().unwrap_or_else(|e| e.into_inner()).take();
        if let Some(c) = c {
            drop_detached(c);
        }
    }
    fn __enter__(slf: Py<Self>) -> Py<Self> {
        slf
    }
    fn __exit__(
        &self,
        _exc_type: Option<Bound<'_, PyAny>>,
        _exc: Option<Bound<'_, PyAny>>,
        _tb: Option<Bound<'_, PyAny>>,
    ) -> bool {
        self.close();
        false
    }
    fn __repr__(&self) -> String {
        format!("<Comm {}>", self.name)
    }
}

/// Every system of a fleet, opened in this process (in-process transports connect them).
#[pyclass(module = "hetcomm", frozen)]
pub struct LocalFleet {
    inner: Mutex<Option<hetcomm::LocalFleet>>,
}

impl Drop for LocalFleet {
    fn drop(&mut self) {
        if let Some(f) = self.inner.get_mut().ok().and_then(Option::take) {
            drop_detached(f);
        }
    }
}

impl LocalFleet {
    fn with<R>(&self, f: impl FnOnce(&hetcomm::LocalFleet) -> PyResult<R>) -> PyResult<R> {
        let guard = self.inner.lock().unwrap_or_else(|e| e.into_inner());
        match guard.as_ref() {
            Some(fleet) => f(fleet),
            None => Err(new_err("ClosedError", "the fleet is closed")),
        }
    }
}

#[pymethods]
impl LocalFleet {
    /// Applies a scenario file (docs/harness.md) to every system of the fleet, with scenario
    /// time 0 now; `seed` seeds random loss and jitter unless the file has its own.
    #[pyo3(signature = (path, seed=0))]
    fn apply_scenario(&self, path: PathBuf, seed: u64) -> PyResult<crate::node::ScenarioRun> {
        self.with(|f| {
            let fleet = f
                .systems()
                .first()
                .map(|c| c.fleet().clone())
                .ok_or_else(|| PyValueError::new_err("the fleet has no system open"))?;
            let sc = crate::node::load_scenario(&path, &fleet)?;
            crate::node::scenario_run(f.apply_scenario(&sc, seed))
        })
    }

    /// Loads a fleet file and opens every system of it.
    #[staticmethod]
    fn open_file(py: Python<'_>, path: PathBuf) -> PyResult<LocalFleet> {
        py.detach(move || hetcomm::LocalFleet::open_file(&path))
            .map(|f| LocalFleet {
                inner: Mutex::new(Some(f)),
            })
            .map_err(open_error)
    }

    /// Parses a fleet from TOML text (`origin` names it in errors) and opens every system.
    #[staticmethod]
    #[pyo3(signature = (text, origin="<string>"))]
    fn from_toml(py: Python<'_>, text: &str, origin: &str) -> PyResult<LocalFleet> {
        let fleet = hetcomm::parse_fleet(text, origin, None)
            .map_err(|e| errors::config_error(&e, e.to_string()))?;
        py.detach(move || hetcomm::LocalFleet::open(fleet))
            .map(|f| LocalFleet {
                inner: Mutex::new(Some(f)),
            })
            .map_err(open_error)
    }

    /// One system by name.
    fn system(&self, name: &str) -> PyResult<Comm> {
        self.with(|f| f.system(name).map(Comm::wrap).map_err(open_error))
    }
    /// Shortcut for `system(system).module(module)`.
    fn module(&self, system: &str, module: &str) -> PyResult<Module> {
        self.system(system)?.module(module)
    }
    /// Every system, by id.
    #[getter]
    fn systems(&self) -> PyResult<Vec<Comm>> {
        self.with(|f| Ok(f.systems().iter().cloned().map(Comm::wrap).collect()))
    }
    /// Runs the fleet's callbacks until `timeout` seconds pass (None: until interrupted, e.g.
    /// by Ctrl-C, which raises KeyboardInterrupt) or the fleet is closed; see `Comm.spin`.
    #[pyo3(signature = (timeout=None))]
    fn spin(&self, py: Python<'_>, timeout: Option<f64>) -> PyResult<()> {
        spin(py, timeout, || {
            self.inner
                .lock()
                .unwrap_or_else(|e| e.into_inner())
                .is_some()
        })
    }
    /// Drops this handle to the fleet (systems close once no Comm or Module of them is left).
    fn close(&self) {
        let f = self.inner.lock().unwrap_or_else(|e| e.into_inner()).take();
        if let Some(f) = f {
            drop_detached(f);
        }
    }
    fn __enter__(slf: Py<Self>) -> Py<Self> {
        slf
    }
    fn __exit__(
        &self,
        _exc_type: Option<Bound<'_, PyAny>>,
        _exc: Option<Bound<'_, PyAny>>,
        _tb: Option<Bound<'_, PyAny>>,
    ) -> bool {
        self.close();
        false
    }
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
    m.add_function(wrap_pyfunction!(pack, m)?)?;
    m.add_function(wrap_pyfunction!(unpack_py, m)?)?;
    m.add_function(wrap_pyfunction!(decode_frame, m)?)?;
    crate::node::add_classes(m)?;
    Ok(())
}
