//! Running a scenario file ([`hetcomm_config::scenario`]) on the systems of this process:
//! faults become each sending system's fault schedule, injections real sends at their time,
//! taps taps. Scenario time 0 is the moment the scenario is applied.
//!
//! ```
//! use hetcomm::sim::{SimFleet, SimOptions};
//! let fleet = hetcomm::config::parse_str(r#"
//!     [systems]
//!     A = 0
//!     B = 1
//!     [modules]
//!     Plan = 0
//!     [transports.net]
//!     kind = "inproc"
//!     [table]
//!     columns = ["A", "B"]
//!     A = ["X", "net"]
//!     B = ["net", "X"]
//! "#, "fleet.toml", None).unwrap();
//! let scenario = hetcomm::config::scenario::parse_scenario(r#"
//!     [[partition]]
//!     between = ["A", "B"]
//!     start = 1.0
//!     end = 2.0
//! "#, "cut.toml", &fleet).unwrap();
//! let sim = SimFleet::open(fleet, SimOptions::default()).unwrap();
//! let run = sim.apply_scenario(&scenario, 1).unwrap();
//! assert_eq!(run.faulted_systems(), 2);
//! ```

use parking_lot::Mutex;
use std::sync::{Arc, Weak};
use std::time::Duration;

use hetcomm_config::scenario::{FaultEffect, Scenario, ScenarioTap, TapKind, TapSpec};
use hetcomm_core::{MessageType, Time};

use super::faults::{Effect, FaultRule, Faults};
use super::{resolve, Held, Replacement, TapAction, TapError, TapHandle, TapPath};
use crate::comm::{Comm, LocalFleet, SystemHandle};
use crate::module::Module;
use crate::sim::SimFleet;
use crate::{Outcome, SendError, SendOptions, Ticket};

/// Why a scenario could not be applied.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ScenarioError {
    /// A tap of the scenario could not be placed.
    #[error("{origin}:{line}: {source}")]
    Tap {
        /// The scenario file.
        origin: String,
        /// The tap's line.
        line: usize,
        /// Why.
        source: TapError,
    },
}

/// What happened to one scheduled injection.
#[derive(Debug)]
pub enum InjectionResult {
    /// Not yet due.
    Pending,
    /// Sent; the ticket tells the outcome.
    Sent(Ticket),
    /// Refused by the sender (unknown name, `X` pair, window full, closed).
    Refused(SendError),
}

/// One injection of a running scenario.
#[derive(Debug)]
pub struct InjectionRecord {
    /// Scenario time, seconds.
    pub at_s: f64,
    /// `From.Module → To.Module type N`.
    pub what: String,
    /// What happened.
    pub result: InjectionResult,
}

/// A scenario applied to the systems of this process; dropping it removes its taps and
/// replacements (faults and injections stay scheduled while the systems are open).
pub struct ScenarioRun {
    taps: Vec<TapHandle>,
    replacements: Vec<Replacement>,
    injections: Arc<Mutex<Vec<InjectionRecord>>>,
    faulted: usize,
    start: Time,
}

impl ScenarioRun {
    /// How many systems of this process got a fault schedule.
    pub fn faulted_systems(&self) -> usize {
        self.faulted
    }

    /// How many taps (replacements included) were placed.
    pub fn taps(&self) -> usize {
        self.taps.len() + self.replacements.len()
    }

    /// Scenario time 0 on the systems' clock.
    pub fn start(&self) -> Time {
        self.start
    }

    /// One line per injection: when, what, and its outcome so far.
    pub fn injection_report(&self) -> Vec<String> {
        let log = self.injections.lock();
        log.iter()
            .map(|r| {
                let result = match &r.result {
                    InjectionResult::Pending => "not yet due".to_string(),
                    InjectionResult::Sent(t) => match t.try_outcome() {
                        Some(Outcome::Delivered { attempts, .. }) => {
                            format!("delivered ({attempts} attempt(s))")
                        }
                        Some(o) => format!("{o:?}"),
                        None => "sent, outcome pending".to_string(),
                    },
                    InjectionResult::Refused(e) => format!("refused: {e}"),
                };
                format!("{:6.2} s  {}: {result}", r.at_s, r.what)
            })
            .collect()
    }
}

impl ScenarioRun {
    /// Leaves its taps and replacements on for as long as their systems are open.
    fn keep(self) {
        self.taps.into_iter().for_each(TapHandle::keep);
        for r in self.replacements {
            r.tap.keep();
        }
    }
}

impl std::fmt::Debug for ScenarioRun {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ScenarioRun")
            .field("taps", &self.taps())
            .field("faulted", &self.faulted)
            .finish()
    }
}

fn at(start: Time, s: f64) -> Time {
    start + Duration::from_secs_f64(s)
}

/// Applies `sc` to `systems` (those of the fleet open in this process) with scenario time 0 at
/// `start`; `seed` seeds the faults unless the scenario has its own.
pub(crate) fn install(
    systems: &[Comm],
    sc: &Scenario,
    start: Time,
    seed: u64,
) -> Result<ScenarioRun, ScenarioError> {
    let seed = sc.seed.unwrap_or(seed);
    let mut run = ScenarioRun {
        taps: Vec::new(),
        replacements: Vec::new(),
        injections: Default::default(),
        faulted: 0,
        start,
    };
    let by_name = |name: &str| systems.iter().find(|c| c.name() == name);
    let id = |name: &str| {
        systems
            .first()
            .and_then(|c| c.fleet().system_by_name(name))
            .map(|s| s.id)
    };
    for comm in systems {
        let mut rules = Vec::new();
        for f in &sc.faults {
            let effect = match f.effect {
                FaultEffect::Cut => Effect::Cut,
                FaultEffect::Degrade {
                    loss,
                    latency_ms,
                    jitter_ms,
                } => Effect::Degrade {
                    loss,
                    latency: Duration::from_secs_f64(latency_ms / 1e3),
                    jitter: Duration::from_secs_f64(jitter_ms / 1e3),
                },
            };
            for (a, b) in f.pairs.iter().filter(|(a, _)| a == comm.name()) {
                rules.push(FaultRule {
                    from: id(a),
                    to: id(b),
                    start: at(start, f.window.start_s),
                    end: at(start, f.window.end_s),
                    effect,
                });
            }
        }
        if !rules.is_empty() {
            let core = &comm.handle.core;
            core.harness.set_faults(Faults::new(rules, seed));
            run.faulted += 1;
        }
    }
    for inj in &sc.injections {
        let Some(comm) = by_name(&inj.from.0) else {
            continue;
        };
        let index = {
            let mut log = run.injections.lock();
            log.push(InjectionRecord {
                at_s: inj.at_s,
                what: format!(
                    "{}.{} → {}.{} type {}",
                    inj.from.0, inj.from.1, inj.to.0, inj.to.1, inj.message_type.0
                ),
                result: InjectionResult::Pending,
            });
            log.len() - 1
        };
        let handle: Weak<SystemHandle> = Arc::downgrade(&comm.handle);
        let log = Arc::downgrade(&run.injections);
        let (module, to, ty, payload) = (
            inj.from.1.clone(),
            inj.to.clone(),
            inj.message_type,
            inj.payload.clone(),
        );
        comm.handle.core.harness.hold(
            at(start, inj.at_s),
            Held::Run(Box::new(move |_, _| {
                let Some(sys) = handle.upgrade() else { return };
                let found = sys
                    .core
                    .directory
                    .module_ids
                    .get(module.as_str())
                    .and_then(|id| sys.core.modules.get(id))
                    .cloned();
                let result = match found {
                    Some(core) => Module { sys, core }.send_raw(
                        &to.0,
                        &to.1,
                        ty,
                        &payload,
                        SendOptions::default(),
                    ),
                    None => Err(SendError::UnknownModule(module.clone())),
                };
                if let Some(log) = log.upgrade() {
                    let mut log = log.lock();
                    log[index].result = match result {
                        Ok(t) => InjectionResult::Sent(t),
                        Err(e) => InjectionResult::Refused(e),
                    };
                }
            })),
        );
    }
    for tap in &sc.taps {
        let path = tap_path(&tap.path);
        let Some(comm) = by_name(path.system()) else {
            continue;
        };
        let window = tap
            .window
            .map(|w| (at(start, w.start_s), at(start, w.end_s)));
        let located = |source| ScenarioError::Tap {
            origin: sc.origin.clone(),
            line: tap.line,
            source,
        };
        let action = match tap.kind {
            TapKind::Observe => TapAction::observe(|_| {}),
            TapKind::Drop => TapAction::Drop,
            TapKind::Delay(ms) => TapAction::Delay(Duration::from_secs_f64(ms / 1e3)),
            TapKind::Duplicate(n) => TapAction::Duplicate(n),
            TapKind::Replace => {
                let r = comm.replace_between(&path, window).map_err(located)?;
                schedule_script(comm, &path, tap, start).map_err(located)?;
                run.replacements.push(r);
                continue;
            }
        };
        run.taps
            .push(comm.tap_between(&path, action, window).map_err(located)?);
    }
    Ok(run)
}

/// Places the fleet file's `[[tap]]`s that act at `comm`'s system, for as long as it is open;
/// their windows and scripts count from now. The loader checked them against the fleet, so
/// an error here means a [`hetcomm_config::Fleet`] built by hand with a tap that cannot be
/// placed; it is reported at the tap's line.
pub(crate) fn install_fleet_taps(comm: &Comm) -> Result<(), crate::OpenError> {
    let fleet = comm.fleet();
    if fleet.taps.is_empty() {
        return Ok(());
    }
    let sc = Scenario {
        origin: fleet
            .source
            .as_ref()
            .map_or_else(|| "the fleet file".to_string(), |p| p.display().to_string()),
        taps: fleet.taps.clone(),
        ..Scenario::default()
    };
    let now = comm.handle.core.clock.now();
    match install(std::slice::from_ref(comm), &sc, now, 0) {
        Ok(run) => {
            run.keep();
            Ok(())
        }
        Err(ScenarioError::Tap {
            origin,
            line,
            source,
        }) => Err(crate::OpenError::Config(hetcomm_config::ConfigErrors(
            vec![hetcomm_config::ConfigError {
                file: origin,
                line,
                column: 1,
                message: source.to_string(),
                help: Some("correct or remove this [[tap]]".into()),
            }],
        ))),
    }
}

/// Schedules a replacement's scripted messages or values on the destination system.
fn schedule_script(
    comm: &Comm,
    path: &TapPath,
    tap: &ScenarioTap,
    start: Time,
) -> Result<(), TapError> {
    let target = resolve(comm, path)?;
    let ty = tap.script_type.unwrap_or(MessageType(0));
    for (t, payload) in &tap.script {
        let target = target.clone();
        let payload = payload.clone();
        comm.handle.core.harness.hold(
            at(start, *t),
            Held::Run(Box::new(move |core, now| {
                // A failure (a topic nobody advertised yet, a full inbox) is counted by the
                // harness as lost, where the run's statistics show it.
                if core
                    .harness
                    .inject_bytes(core, &target, ty, &payload, now)
                    .is_err()
                {
                    core.harness.count_lost();
                }
            })),
        );
    }
    Ok(())
}

fn tap_path(spec: &TapSpec) -> TapPath {
    match spec {
        TapSpec::Topic { system, topic } => TapPath::topic(system, topic),
        TapSpec::Messages {
            from,
            to,
            module,
            message_type,
        } => TapPath::Messages {
            from: from.clone(),
            to: to.clone(),
            module: module.clone(),
            message_type: *message_type,
        },
    }
}

impl LocalFleet {
    /// Applies a scenario to this fleet's systems, with scenario time 0 now. Apply it before
    /// making [`crate::Sender`]s: a fault schedule makes in-process sends take their link
    /// (so that frames can be cut), which a sender made earlier has already skipped.
    pub fn apply_scenario(&self, sc: &Scenario, seed: u64) -> Result<ScenarioRun, ScenarioError> {
        let now = match self.systems().first() {
            Some(c) => c.handle.core.clock.now(),
            None => Time::now_mono(),
        };
        install(self.systems(), sc, now, seed)
    }
}

impl SimFleet {
    /// Applies a scenario to the simulated systems, with scenario time 0 at the current
    /// virtual time (see [`LocalFleet::apply_scenario`]).
    pub fn apply_scenario(&self, sc: &Scenario, seed: u64) -> Result<ScenarioRun, ScenarioError> {
        install(self.systems(), sc, self.now(), seed)
    }
}

impl Comm {
    /// Applies the parts of a scenario that concern this system (its sends' faults, its
    /// injections, taps acting here), with scenario time 0 now: one system per process.
    pub fn apply_scenario(&self, sc: &Scenario, seed: u64) -> Result<ScenarioRun, ScenarioError> {
        let now = self.handle.core.clock.now();
        install(std::slice::from_ref(self), sc, now, seed)
    }
}
