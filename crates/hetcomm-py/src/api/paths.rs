//! Failover from Python (docs/failover.md): a pair's transports changed while running, the
//! state of each path, and the path switches, as a list since the last call or as a watch of
//! one's own (an iterator that sees every switch, whatever other consumers read).

use super::*;

/// A path switch as a dict: {"to", "from", "now", "at_s", "number"}.
pub(super) fn switch_dict<'py>(
    py: Python<'py>,
    s: &hetcomm::PathSwitch,
) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("to", &s.to)?;
    d.set_item("from", &s.from)?;
    d.set_item("now", &s.now)?;
    d.set_item("at_s", s.at.as_micros() as f64 / 1e6)?;
    d.set_item("number", s.number)?;
    Ok(d)
}

/// One path's state as a dict: {"transport", "up", "active", "srtt_s"}.
pub(super) fn path_dict<'py>(
    py: Python<'py>,
    p: &hetcomm::PathStatus,
) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("transport", &p.transport)?;
    d.set_item("up", p.up)?;
    d.set_item("active", p.active)?;
    d.set_item("srtt_s", p.srtt.map(|d| d.as_secs_f64()))?;
    Ok(d)
}

/// The path switches of one system from when it was made (`Comm.watch_paths()`). Iterating
/// it yields the switches waiting now and stops; `recv(timeout)` waits for the next one.
#[pyclass(module = "hetcomm", frozen)]
pub struct PathWatch {
    pub(super) inner: hetcomm::PathWatch,
}

#[pymethods]
impl PathWatch {
    /// The next switch if one is waiting, else None.
    fn try_recv<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyDict>>> {
        self.inner
            .try_next()
            .map(|s| switch_dict(py, &s))
            .transpose()
    }
    /// The next switch, waiting up to `timeout` seconds (None: until one comes, or Ctrl-C);
    /// None when none came in time. The GIL is released while it waits.
    #[pyo3(signature = (timeout=None))]
    fn recv<'py>(
        &self,
        py: Python<'py>,
        timeout: Option<f64>,
    ) -> PyResult<Option<Bound<'py, PyDict>>> {
        let deadline = match timeout {
            Some(t) if !(t >= 0.0 && t.is_finite()) => {
                return Err(PyValueError::new_err("timeout must be a number >= 0"))
            }
            Some(t) => Some(Instant::now() + Duration::from_secs_f64(t)),
            None => None,
        };
        loop {
            let slice = match deadline {
                Some(d) => d.saturating_duration_since(Instant::now()).min(SLICE),
                None => SLICE,
            };
            let got = py.detach(|| self.inner.next_timeout(slice));
            if let Some(s) = got {
                return switch_dict(py, &s).map(Some);
            }
            py.check_signals()?;
            if deadline.is_some_and(|d| Instant::now() >= d) {
                return Ok(None);
            }
        }
    }
    /// Switches dropped because more than 1024 were waiting unread.
    fn dropped(&self) -> u64 {
        self.inner.dropped()
    }
    fn __iter__(slf: Py<Self>) -> Py<Self> {
        slf
    }
    fn __next__<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyDict>>> {
        self.try_recv(py)
    }
}
