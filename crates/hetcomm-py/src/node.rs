//! Python's side of the Node API and the harness (`docs/harness.md`): topics carrying Python
//! objects inside a system (the very object published reaches Python subscribers: nothing is
//! serialized), taps with Python functions, replacements, and the harness's counters.
//! `Module.advertise` / `subscribe` / `on_topic` and `Comm.tap` / `replace` / `harness_stats`
//! in `api.rs` call the functions here.

use std::sync::Arc;
use std::time::{Duration, Instant};

use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use serde::{Deserialize, Deserializer, Serialize, Serializer};

use hetcomm::{Message, MessageType, TapAction, TapPath, TapVerdict, TopicError};

use crate::errors::new_err;
use crate::value;

/// A Python object on a topic. Published from Python it is the object itself; injected from a
/// scenario file or a tool it arrives as MessagePack and becomes a Python value when read.
pub struct PyTopicValue(Inner);

enum Inner {
    Object(Py<PyAny>),
    Packed(rmpv::Value),
}

impl Message for PyTopicValue {
    const TYPE: MessageType = MessageType(0xFFFF_FF01);
    const NAME: &'static str = "Python object";
}

impl Serialize for PyTopicValue {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        match &self.0 {
            Inner::Packed(v) => v.serialize(s),
            Inner::Object(o) => Python::attach(|py| value::to_value(o.bind(py)))
                .map_err(|e| serde::ser::Error::custom(e.to_string()))?
                .serialize(s),
        }
    }
}

impl<'de> Deserialize<'de> for PyTopicValue {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        rmpv::Value::deserialize(d).map(|v| PyTopicValue(Inner::Packed(v)))
    }
}

fn to_py(py: Python<'_>, v: &PyTopicValue) -> PyResult<Py<PyAny>> {
    match &v.0 {
        Inner::Object(o) => Ok(o.clone_ref(py)),
        Inner::Packed(p) => Ok(value::to_py(py, p)?.unbind()),
    }
}

fn topic_error(e: TopicError) -> PyErr {
    match e {
        TopicError::Timeout { .. } => new_err("RecvTimeout", e.to_string()),
        TopicError::Closed => new_err("ClosedError", e.to_string()),
        _ => PyValueError::new_err(e.to_string()),
    }
}

/// Publishes Python objects on one topic of a system (`Module.advertise`).
#[pyclass(module = "hetcomm", frozen)]
pub struct Publisher(hetcomm::Publisher<PyTopicValue>);

#[pymethods]
impl Publisher {
    /// Hands `obj` itself to every subscriber of the topic (no copy, no serialization).
    fn publish(&self, py: Python<'_>, obj: Py<PyAny>) -> PyResult<()> {
        let p = self.0.clone();
        let v = PyTopicValue(Inner::Object(obj));
        py.detach(move || p.publish(v)).map_err(topic_error)
    }
    /// The topic's name.
    #[getter]
    fn topic(&self) -> String {
        self.0.topic().to_string()
    }
}

/// Values of one topic queued for one module (`Module.subscribe`); unsubscribes when gone.
#[pyclass(module = "hetcomm", frozen)]
pub struct Subscription(hetcomm::Subscription<PyTopicValue>);

#[pymethods]
impl Subscription {
    /// The oldest value waiting, or None.
    fn try_recv(&self, py: Python<'_>) -> PyResult<Option<Py<PyAny>>> {
        self.0.try_recv().map(|v| to_py(py, &v)).transpose()
    }
    /// Waits up to `timeout` seconds (None: forever) for a value; TimeoutError when none came.
    #[pyo3(signature = (timeout=None))]
    fn recv(&self, py: Python<'_>, timeout: Option<f64>) -> PyResult<Py<PyAny>> {
        let deadline = match timeout {
            Some(t) if t.is_finite() && t >= 0.0 => {
                Some(Instant::now() + Duration::from_secs_f64(t))
            }
            Some(t) => return Err(PyValueError::new_err(format!("bad timeout {t}"))),
            None => None,
        };
        loop {
            let slice = deadline.map_or(Duration::from_millis(100), |d| {
                d.saturating_duration_since(Instant::now())
                    .min(Duration::from_millis(100))
            });
            match py.detach(|| self.0.recv_timeout(slice)) {
                Ok(v) => return to_py(py, &v),
                Err(TopicError::Timeout { .. }) => {}
                Err(e) => return Err(topic_error(e)),
            }
            py.check_signals()?;
            if deadline.is_some_and(|d| Instant::now() >= d) {
                return Err(new_err(
                    "RecvTimeout",
                    format!("no value on topic `{}` in time", self.0.topic()),
                ));
            }
        }
    }
    /// Takes every value waiting and returns the newest, or None.
    fn latest(&self, py: Python<'_>) -> PyResult<Option<Py<PyAny>>> {
        self.0.latest().map(|v| to_py(py, &v)).transpose()
    }
    /// Values waiting.
    #[getter]
    fn pending(&self) -> usize {
        self.0.pending()
    }
    /// Values pushed out of a full queue so far.
    #[getter]
    fn dropped(&self) -> u64 {
        self.0.dropped()
    }
    /// The topic's name.
    #[getter]
    fn topic(&self) -> String {
        self.0.topic().to_string()
    }
}

/// Keeps a notification function on a topic (`Module.on_topic`); removed when this is gone.
#[pyclass(module = "hetcomm", frozen)]
pub struct TopicNotification(#[allow(dead_code)] hetcomm::Notification);

/// Keeps a tap on its path (`Comm.tap`); `remove()` or dropping it takes the tap off.
#[pyclass(module = "hetcomm", frozen)]
pub struct TapHandle(parking_lot::Mutex<Option<hetcomm::TapHandle>>);

#[pymethods]
impl TapHandle {
    /// Takes the tap off.
    fn remove(&self) {
        self.0.lock().take();
    }
}

/// The replaced source of a path (`Comm.replace`): real messages are discarded while it lives.
#[pyclass(module = "hetcomm", frozen)]
pub struct Replacement(parking_lot::Mutex<Option<hetcomm::Replacement>>);

impl Replacement {
    fn with<T>(&self, f: impl FnOnce(&hetcomm::Replacement) -> T) -> PyResult<T> {
        let g = self.0.lock();
        g.as_ref()
            .map(f)
            .ok_or_else(|| new_err("ClosedError", "the replacement has ended"))
    }
}

#[pymethods]
impl Replacement {
    /// Injects `payload` (a value encoded as a send encodes it) of type `type_id` on a message
    /// path, as from the path's source.
    fn inject(&self, type_id: u32, payload: &Bound<'_, PyAny>) -> PyResult<()> {
        let bytes = value::pack(payload)?;
        self.with(|r| r.inject_raw(MessageType(type_id), &bytes))?
            .map_err(|e| PyValueError::new_err(e.to_string()))
    }
    /// Publishes `obj` on a replaced topic path.
    fn publish(&self, obj: Py<PyAny>) -> PyResult<()> {
        self.with(|r| r.publish(PyTopicValue(Inner::Object(obj))))?
            .map_err(|e| PyValueError::new_err(e.to_string()))
    }
    /// Ends the replacement: real messages flow again.
    fn end(&self) {
        self.0.lock().take();
    }
}

/// A path from `Comm.tap`'s keywords: `topic` (with `system`), or messages into `to`.
pub fn path(
    system: Option<&str>,
    topic: Option<&str>,
    to: Option<&str>,
    from: Option<&str>,
    module: Option<&str>,
    type_id: Option<u32>,
) -> PyResult<TapPath> {
    match (topic, to) {
        (Some(t), None) => {
            let system = system.ok_or_else(|| PyTypeError::new_err("a topic tap needs system="))?;
            Ok(TapPath::topic(system, t))
        }
        (None, Some(to)) => {
            let mut p = TapPath::messages(to);
            if let Some(f) = from {
                p = p.from(f);
            }
            if let Some(m) = module {
                p = p.module(m);
            }
            if let Some(t) = type_id {
                p = p.message_type(MessageType(t));
            }
            Ok(p)
        }
        _ => Err(PyTypeError::new_err(
            "give topic= (with system=) for a topic, or to= for messages into a system",
        )),
    }
}

/// What a Python tap function sees: a dict with `time_us`, and `topic` and `value` for a
/// topic, or `type`, `source`, `destination` (system id, module id) and `payload` for a message.
fn message_dict<'py>(py: Python<'py>, m: &hetcomm::TapMessage) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("time_us", m.time().as_micros())?;
    if let Some(t) = m.topic() {
        d.set_item("topic", t)?;
        let v = m
            .value::<PyTopicValue>()
            .map(|v| to_py(py, v))
            .transpose()?;
        d.set_item("value", v)?;
    }
    if let Some(h) = m.header() {
        d.set_item("type", h.message_type.0)?;
        d.set_item("source", (h.source.system.0, h.source.module.0))?;
        d.set_item(
            "destination",
            (h.destination.system.0, h.destination.module.0),
        )?;
        let payload = m
            .payload()
            .map(value::unpack_value)
            .transpose()
            .map_err(PyValueError::new_err)?;
        match payload {
            Some(p) => d.set_item("payload", value::to_py(py, &p)?)?,
            None => d.set_item("payload", py.None())?,
        }
    }
    Ok(d)
}

/// The verdict of a Python modify function's return: None (pass), "drop", ("delay", s),
/// ("duplicate", n). A changed `payload` or `value` in the dict becomes the message's.
fn run_modify(py: Python<'_>, f: &Py<PyAny>, m: &mut hetcomm::TapMessage) -> PyResult<TapVerdict> {
    let d = message_dict(py, m)?;
    let before_payload = d.get_item("payload")?.map(|v| v.unbind());
    let before_value = d.get_item("value")?.map(|v| v.unbind());
    let ret = f.call1(py, (d.clone(),))?;
    if let (Some(after), Some(before)) = (d.get_item("payload")?, before_payload) {
        if !after.is(before.bind(py)) {
            m.set_payload(value::pack(&after)?);
        }
    }
    if let (Some(after), Some(before)) = (d.get_item("value")?, before_value) {
        if !after.is(before.bind(py)) {
            m.set_value(PyTopicValue(Inner::Object(after.unbind())));
        }
    }
    let ret = ret.bind(py);
    if ret.is_none() {
        return Ok(TapVerdict::Pass);
    }
    if let Ok(s) = ret.extract::<String>() {
        if s == "drop" {
            return Ok(TapVerdict::Drop);
        }
    }
    if let Ok((kind, x)) = ret.extract::<(String, f64)>() {
        match kind.as_str() {
            "delay" if x.is_finite() && x >= 0.0 => {
                return Ok(TapVerdict::Delay(Duration::from_secs_f64(x)))
            }
            "duplicate" if x >= 0.0 && x.fract() == 0.0 && x < 1e6 => {
                return Ok(TapVerdict::Duplicate(x as u32))
            }
            _ => {}
        }
    }
    Err(PyValueError::new_err(format!(
        "a tap function returns None, \"drop\", (\"delay\", seconds) or (\"duplicate\", n), not {ret}"
    )))
}

/// The action of `Comm.tap`: `observe` and `modify` call `function` with the GIL (an exception
/// is reported through `sys.unraisablehook` and the message passes unchanged).
pub fn action(
    kind: &str,
    function: Option<Py<PyAny>>,
    delay: Option<f64>,
    copies: u32,
) -> PyResult<TapAction> {
    let need_fn = move || {
        function.ok_or_else(|| PyTypeError::new_err(format!("action \"{kind}\" needs function=")))
    };
    Ok(match kind {
        "observe" => {
            let f = need_fn()?;
            TapAction::Observe(Arc::new(move |m: &hetcomm::TapMessage| {
                let _ = Python::try_attach(|py| {
                    if let Err(e) = message_dict(py, m).and_then(|d| f.call1(py, (d,))) {
                        e.write_unraisable(py, Some(f.bind(py)));
                    }
                });
            }))
        }
        "modify" => {
            let f = need_fn()?;
            TapAction::Modify(Arc::new(move |m: &mut hetcomm::TapMessage| {
                Python::try_attach(|py| match run_modify(py, &f, m) {
                    Ok(v) => v,
                    Err(e) => {
                        e.write_unraisable(py, Some(f.bind(py)));
                        TapVerdict::Pass
                    }
                })
                .unwrap_or(TapVerdict::Pass)
            }))
        }
        "drop" => TapAction::Drop,
        "delay" => match delay {
            Some(s) if s.is_finite() && s >= 0.0 => TapAction::Delay(Duration::from_secs_f64(s)),
            _ => return Err(PyValueError::new_err("action \"delay\" needs delay= seconds ≥ 0")),
        },
        "duplicate" => TapAction::Duplicate(copies),
        other => {
            return Err(PyValueError::new_err(format!(
                "unknown tap action {other:?}: observe, drop, delay, duplicate or modify (replace is Comm.replace)"
            )))
        }
    })
}

/// `Comm.harness_stats()` as a dict.
pub fn stats(py: Python<'_>, s: &hetcomm::HarnessStats) -> PyResult<Py<PyDict>> {
    let d = PyDict::new(py);
    for (k, v) in [
        ("tapped", s.tapped),
        ("dropped", s.dropped),
        ("delayed", s.delayed),
        ("duplicated", s.duplicated),
        ("modified", s.modified),
        ("replaced", s.replaced),
        ("injected", s.injected),
        ("fault_dropped", s.fault_dropped),
        ("fault_delayed", s.fault_delayed),
        ("lost_on_close", s.lost_on_close),
    ] {
        d.set_item(k, v)?;
    }
    Ok(d.unbind())
}

/// `Module.advertise`.
pub fn advertise(m: &hetcomm::Module, topic: &str) -> PyResult<Publisher> {
    m.advertise::<PyTopicValue>(topic)
        .map(Publisher)
        .map_err(topic_error)
}

/// `Module.subscribe`.
pub fn subscribe(m: &hetcomm::Module, topic: &str, capacity: usize) -> PyResult<Subscription> {
    m.subscribe_with_capacity::<PyTopicValue>(topic, capacity)
        .map(Subscription)
        .map_err(topic_error)
}

/// `Module.on_topic`: `callback(value)` on the publishing thread, with the GIL.
pub fn on_topic(
    m: &hetcomm::Module,
    topic: &str,
    callback: Py<PyAny>,
) -> PyResult<TopicNotification> {
    m.on_topic::<PyTopicValue>(topic, move |v| {
        let _ = Python::try_attach(|py| {
            if let Err(e) = to_py(py, &v).and_then(|o| callback.call1(py, (o,))) {
                e.write_unraisable(py, Some(callback.bind(py)));
            }
        });
    })
    .map(TopicNotification)
    .map_err(topic_error)
}

/// `Comm.tap`.
pub fn tap(c: &hetcomm::Comm, path: &TapPath, action: TapAction) -> PyResult<TapHandle> {
    c.tap(path, action)
        .map(|h| TapHandle(parking_lot::Mutex::new(Some(h))))
        .map_err(|e| PyValueError::new_err(e.to_string()))
}

/// `Comm.replace`.
pub fn replace(c: &hetcomm::Comm, path: &TapPath) -> PyResult<Replacement> {
    c.replace(path)
        .map(|r| Replacement(parking_lot::Mutex::new(Some(r))))
        .map_err(|e| PyValueError::new_err(e.to_string()))
}

/// Registers this file's classes.
pub fn add_classes(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<Publisher>()?;
    m.add_class::<Subscription>()?;
    m.add_class::<TopicNotification>()?;
    m.add_class::<TapHandle>()?;
    m.add_class::<Replacement>()?;
    m.add_class::<ScenarioRun>()?;
    Ok(())
}

/// A scenario file applied to systems of this process (`Comm.apply_scenario`,
/// `LocalFleet.apply_scenario`); its taps stay while this object lives.
#[pyclass(module = "hetcomm", frozen)]
pub struct ScenarioRun(parking_lot::Mutex<Option<hetcomm::harness::scenario::ScenarioRun>>);

#[pymethods]
impl ScenarioRun {
    /// One line per injection: when, what, and its outcome so far.
    fn injection_report(&self) -> Vec<String> {
        self.0
            .lock()
            .as_ref()
            .map(|r| r.injection_report())
            .unwrap_or_default()
    }
    /// How many systems got a fault schedule.
    #[getter]
    fn faulted_systems(&self) -> usize {
        self.0.lock().as_ref().map_or(0, |r| r.faulted_systems())
    }
    /// Removes the scenario's taps (faults and injections stay scheduled).
    fn end(&self) {
        self.0.lock().take();
    }
}

/// Loads a scenario file against `fleet`: ConfigError (file:line:column) when it is wrong.
pub fn load_scenario(
    path: &std::path::Path,
    fleet: &hetcomm::config::Fleet,
) -> PyResult<hetcomm::config::scenario::Scenario> {
    hetcomm::config::scenario::load_scenario(path, fleet)
        .map_err(|e| crate::errors::config_error(&e, e.to_string()))
}

/// Wraps an applied scenario.
pub fn scenario_run(
    r: Result<hetcomm::harness::scenario::ScenarioRun, hetcomm::harness::scenario::ScenarioError>,
) -> PyResult<ScenarioRun> {
    r.map(|r| ScenarioRun(parking_lot::Mutex::new(Some(r))))
        .map_err(|e| PyValueError::new_err(e.to_string()))
}
