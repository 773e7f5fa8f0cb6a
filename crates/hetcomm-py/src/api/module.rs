//! `Module`: one module of an opened system (send, broadcast, poll, callbacks).

// The parent's imports and shared helpers.
use super::*;

/// One module (Sense, Plan, Act, …) of an opened system: sends, broadcasts, polls and
/// subscribes. Safe to use from several Python threads.
#[pyclass(module = "hetcomm", frozen)]
pub struct Module {
    pub(super) inner: Mutex<Option<hetcomm::Module>>,
    pub(super) system: String,
}

impl Drop for Module {
    fn drop(&mut self) {
        if let Some(m) = self.inner.get_mut().take() {
            drop_detached(m);
        }
    }
}

impl Module {
    fn get(&self) -> PyResult<hetcomm::Module> {
        self.inner
            .lock()
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
pub(super) fn make_callback(
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

pub(super) fn inbox_stats<'py>(
    py: Python<'py>,
    s: &hetcomm::InboxStats,
) -> PyResult<Bound<'py, PyDict>> {
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
