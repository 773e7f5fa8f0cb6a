//! Outcomes and the tickets that wait for them: `Outcome`, `Ticket`, `BroadcastTicket`.

// The parent's imports and shared helpers.
use super::*;

/// How a send ended. `kind` is one of:
///
/// - "delivered": the receiving router put the message in the destination module's inbox and
///   acknowledged it (in the inbox, not necessarily read yet);
/// - "sent": an unacknowledged transport took it; it cannot confirm delivery;
/// - "relayed": an unacknowledged transport took it and the broker it goes through (MQTT at
///   QoS 1) confirmed it has it: still not known to be delivered;
/// - "unconfirmed": frames left but no acknowledgement came back; it may or may not have
///   arrived (`reason` says why the sender stopped waiting);
/// - "failed": certainly not delivered (`reason` says why).
#[pyclass(module = "hetcomm", frozen, eq)]
#[derive(Clone, PartialEq)]
pub struct Outcome {
    pub(super) inner: hetcomm::Outcome,
}

#[pymethods]
impl Outcome {
    /// "delivered", "sent", "relayed", "unconfirmed" or "failed".
    #[getter]
    fn kind(&self) -> &'static str {
        match self.inner {
            hetcomm::Outcome::Delivered { .. } => "delivered",
            hetcomm::Outcome::Sent { .. } => "sent",
            hetcomm::Outcome::Relayed { .. } => "relayed",
            hetcomm::Outcome::Unconfirmed { .. } => "unconfirmed",
            hetcomm::Outcome::Failed { .. } => "failed",
        }
    }
    /// Transmissions attempted.
    #[getter]
    fn attempts(&self) -> u32 {
        self.inner.attempts()
    }
    /// Delivered, sent or relayed.
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
    /// "unreachable", "congested", "no_session", "inbox_full", "unknown_module", "link", "refused",
    /// "relay" (what the broker said, or that it said nothing in time), "backpressure",
    /// "shutdown".
    #[getter]
    fn reason_code(&self) -> Option<&'static str> {
        self.inner.reason().map(|reason| match reason {
            FailReason::NoAcknowledgement => "no_acknowledgement",
            FailReason::Unreachable(_) => "unreachable",
            FailReason::InboxFull => "inbox_full",
            FailReason::UnknownModule => "unknown_module",
            FailReason::Link(_) => "link",
            FailReason::Refused(_) => "refused",
            FailReason::Relay(_) => "relay",
            FailReason::Backpressure => "backpressure",
            FailReason::Congested(_) => "congested",
            FailReason::NoSession(_) => "no_session",
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

pub(super) fn outcome(o: hetcomm::Outcome) -> Outcome {
    Outcome { inner: o }
}

// ---------------------------------------------------------------------------------------------
// Tickets

/// The pending outcome of one send.
#[pyclass(module = "hetcomm", frozen)]
pub struct Ticket {
    pub(super) inner: hetcomm::Ticket,
}

pub(super) fn wait_ticket(
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
pub(super) fn spin(py: Python<'_>, timeout: Option<f64>, open: impl Fn() -> bool) -> PyResult<()> {
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
    /// The transport (fleet-file name) that carried the send once it ended: for a delivery,
    /// the one its acknowledgement came back on (docs/failover.md). None while pending.
    #[getter]
    fn transport(&self) -> Option<String> {
        self.inner.transport().map(str::to_string)
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
    pub(super) inner: hetcomm::BroadcastTicket,
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
