//! `Comm` (one opened system) and `LocalFleet` (every system of a fleet in this process).

// The parent's imports and shared helpers.
use super::*;

/// One opened system of a fleet. The system closes when the last Comm and Module objects of it
/// are gone, or on `close()` / leaving a `with` block (then only if no Module object of it is
/// still alive).
#[pyclass(module = "hetcomm", frozen)]
pub struct Comm {
    pub(super) inner: Mutex<Option<hetcomm::Comm>>,
    pub(super) name: String,
}

impl Drop for Comm {
    fn drop(&mut self) {
        if let Some(c) = self.inner.get_mut().take() {
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
            .clone()
            .ok_or_else(|| new_err("ClosedError", "the system is closed"))
    }
}

/// Open options from the Python arguments: a private key file, read now so that a bad file
/// is reported as such (ValueError naming the file and what is wrong).
pub(super) fn open_options(private_key_file: Option<PathBuf>) -> PyResult<hetcomm::OpenOptions> {
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
            ("ack_frames_sent", r.ack_frames_sent),
            ("acks_received", r.acks_received),
            ("stale_acks", r.stale_acks),
            ("duplicates", r.duplicates),
            ("too_old", r.too_old),
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
        let switches = s
            .path_switches
            .iter()
            .map(|c| paths::switch_dict(py, c))
            .collect::<PyResult<Vec<_>>>()?;
        out.set_item("path_switches", switches)?;
        Ok(out)
    }
    /// Changes, while running, the transports that carry this system's traffic to
    /// `system`, in order of preference: each must be one the pair's table cell lists (a
    /// reorder or a subset of it). Raises ValueError with the reason, changing nothing,
    /// otherwise (docs/failover.md).
    fn set_transports(&self, system: &str, transports: Vec<String>) -> PyResult<()> {
        let names: Vec<&str> = transports.iter().map(String::as_str).collect();
        self.get()?
            .set_transports(system, &names)
            .map_err(|e| PyValueError::new_err(e.to_string()))
    }
    /// The transports that may carry this system's traffic to `system`, in order of
    /// preference: [{"transport", "up", "active", "srtt_s"}].
    fn paths<'py>(&self, py: Python<'py>, system: &str) -> PyResult<Vec<Bound<'py, PyDict>>> {
        self.get()?
            .paths(system)
            .iter()
            .map(|p| paths::path_dict(py, p))
            .collect()
    }
    /// The path switches since the last call of this (on any handle of this system):
    /// [{"to", "from", "now", "at_s", "number"}], oldest first.
    fn path_changes<'py>(&self, py: Python<'py>) -> PyResult<Vec<Bound<'py, PyDict>>> {
        self.get()?
            .path_changes()
            .iter()
            .map(|s| paths::switch_dict(py, s))
            .collect()
    }
    /// A watch of this system's path switches from now on: every switch, whatever other
    /// consumers read (`for s in watch`, `watch.recv(timeout)`).
    fn watch_paths(&self) -> PyResult<PathWatch> {
        Ok(PathWatch {
            inner: self.get()?.watch_paths(),
        })
    }
    /// Runs this system's callbacks until `timeout` seconds pass (None: until interrupted,
    /// e.g. by Ctrl-C, which raises KeyboardInterrupt) or this handle is closed, like rospy's
    /// `spin()`. Callbacks run on their own threads; this only keeps the caller waiting,
    /// with the GIL released.
    #[pyo3(signature = (timeout=None))]
    fn spin(&self, py: Python<'_>, timeout: Option<f64>) -> PyResult<()> {
        spin(py, timeout, || self.inner.lock().is_some())
    }
    /// Drops this handle to the system (it closes once no Module object of it is left).
    fn close(&self) {
        let c = self.inner.lock().take();
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
    pub(super) inner: Mutex<Option<hetcomm::LocalFleet>>,
}

impl Drop for LocalFleet {
    fn drop(&mut self) {
        if let Some(f) = self.inner.get_mut().take() {
            drop_detached(f);
        }
    }
}

impl LocalFleet {
    fn with<R>(&self, f: impl FnOnce(&hetcomm::LocalFleet) -> PyResult<R>) -> PyResult<R> {
        let guard = self.inner.lock();
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
        spin(py, timeout, || self.inner.lock().is_some())
    }
    /// Drops this handle to the fleet (systems close once no Comm or Module of them is left).
    fn close(&self) {
        let f = self.inner.lock().take();
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
