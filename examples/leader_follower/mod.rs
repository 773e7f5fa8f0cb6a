//! The thesis's leader–follower demonstration (§5.1), written the way a user would write it:
//! the rovers' autonomy code and the virtual environment use only the public `hetcomm` API.
//!
//! - **Alpha** (leader): its Plan module follows a schedule in simulated seconds (straight,
//!   turn left, straight, turn left, straight) and sends each `Command` to Charlie; its Act
//!   module sends `Wheels` to its virtual environment at a fixed rate (Fig. 25).
//! - **Charlie** (follower): Plan forwards each command to Tango and acts on it; Act reports
//!   `Wheels` at the same rate and keeps the previous motion when no command arrives (Fig. 26).
//! - **Tango** (follower): as Charlie, without forwarding.
//! - **Virtual environments**: integrate each rover's pose from its `Wheels` with the
//!   differential-drive model of `hetcomm-sim`, log poses, and publish positions for
//!   range-dependent links. Either three VEs that poll (the thesis's layout) or one VE that
//!   receives every rover's `Wheels` through callbacks (the improvement §5.1 asks for).
//!
//! [`run`] drives it all in virtual time (repeatable for a seed) or in real time.

use parking_lot::Mutex;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};

use hetcomm::sim::{SimFleet, SimOptions};
use hetcomm::{Comm, LocalFleet, Message, Module, Time};
use hetcomm_sim::report::{self, CommandKind, CommandRecord};
use hetcomm_sim::{DiffDrive, PoseSample, Scenario};
use serde::{Deserialize, Serialize};

pub mod bridged;
mod environment;
pub mod scenario;

use bridged::Relay;
pub use environment::Environment;

/// What the leader tells a follower to do (the thesis's Command message).
#[derive(Serialize, Deserialize, Message, Debug, Clone, Copy, PartialEq, Eq)]
#[message(id = 0)]
pub struct Command {
    /// 0 straight, 1 turn left, 2 stop.
    pub code: u8,
}

/// A rover's wheel speeds, sent to its virtual environment (the thesis's Wheels message).
#[derive(Serialize, Deserialize, Message, Debug, Clone, Copy, PartialEq)]
#[message(id = 1)]
pub struct Wheels {
    /// Left wheel speed.
    pub left: f64,
    /// Right wheel speed.
    pub right: f64,
}

/// Wheel speeds for a command code (Fig. 26): straight 1/1, left pivot −10/+10, stop 0/0.
pub fn wheels_for(code: u8) -> Wheels {
    match code {
        1 => Wheels {
            left: -10.0,
            right: 10.0,
        },
        2 => Wheels {
            left: 0.0,
            right: 0.0,
        },
        _ => Wheels {
            left: 1.0,
            right: 1.0,
        },
    }
}

/// The fleet of Tables 6–8 as one self-contained file: `R` in-process, `B` the emulated
/// `bluetooth-classic` radio. `fleet.toml` in this folder imports the thesis's own files and
/// loads to the same fleet (a test checks it).
pub const EMBEDDED_FLEET: &str = r#"
name = "leader-follower"
[systems]
Alpha = 0
Charlie = 1
Tango = 2
VirtualEnv = 3
VirtualEnv2 = 4
VirtualEnv3 = 5
[modules]
Plan = 0
Act = 1
World = 2
[letters]
R = "wired"
B = "radio"
[transports.wired]
kind = "inproc"
[transports.radio]
kind = "emulated"
profile = "bluetooth-classic"
attempts = 8
# The rovers carry Class 1 radios in open field (20 dBm, free-space exponent 2, -90 dBm
# sensitivity: 50% loss at about 3 km); the profile's default short-range radio would lose
# Charlie and Tango, who start ~55 m apart. The VE publishes positions, so range still applies.
tx_power_dbm = 20.0
path_loss_exponent = 2.0
sensitivity_dbm = -90.0
[table]
columns     = ["Alpha", "Charlie", "Tango", "VirtualEnv", "VirtualEnv2", "VirtualEnv3"]
Alpha       = ["X", "R", "X", "R", "X", "X"]
Charlie     = ["R", "X", "B", "X", "R", "X"]
Tango       = ["X", "B", "X", "X", "X", "R"]
VirtualEnv  = ["R", "X", "X", "X", "X", "X"]
VirtualEnv2 = ["X", "R", "X", "X", "X", "X"]
VirtualEnv3 = ["X", "X", "R", "X", "X", "X"]
"#;

/// The single-VE variant's fleet (also in `fleet-single-ve.toml`).
pub const EMBEDDED_SINGLE_VE_FLEET: &str = include_str!("fleet-single-ve.toml");

/// How long the demonstration waits for a bridged robot's first odometry.
pub const BRIDGED_WAIT: Duration = Duration::from_secs(30);

/// How often rovers act and report their wheels, and VEs step (10 Hz).
pub const CONTROL_PERIOD: Duration = Duration::from_millis(100);

fn seconds_since(t0: Time, t: Time) -> f64 {
    t.saturating_since(t0).as_secs_f64()
}

/// The leader's autonomy code: Plan follows the schedule, Act drives the wheels.
pub struct Leader {
    plan: Module,
    act: Module,
    name: String,
    follower: String,
    environment: String,
    schedule: hetcomm_sim::Schedule,
    last_t: Option<f64>,
    wheels: Wheels,
    /// Commands sent, for Table 9.
    pub sent: Vec<CommandRecord>,
}

impl Leader {
    /// The leader `comm`, commanding `follower`, reporting to `environment`.
    pub fn new(
        comm: &Comm,
        follower: &str,
        environment: &str,
        schedule: hetcomm_sim::Schedule,
    ) -> Result<Leader, hetcomm::OpenError> {
        Ok(Leader {
            plan: comm.module("Plan")?,
            act: comm.module("Act")?,
            name: comm.name().to_string(),
            follower: follower.to_string(),
            environment: environment.to_string(),
            wheels: wheels_for(schedule.initial().code() as u8),
            schedule,
            last_t: None,
            sent: Vec::new(),
        })
    }

    /// One control step at `t_s` seconds into the scenario.
    pub fn step(&mut self, t_s: f64) -> Result<(), hetcomm::SendError> {
        // Plan: every command that fell due since the last step (none is ever skipped).
        let after = self.last_t.unwrap_or(f64::NEG_INFINITY);
        let due: Vec<_> = self.schedule.due_between(after, t_s).collect();
        for entry in due {
            let code = entry.command.code() as u8;
            self.plan.send(&self.follower, "Plan", &Command { code })?;
            self.sent.push(CommandRecord::new(
                &self.name,
                t_s,
                code.into(),
                CommandKind::Sent,
            ));
            self.wheels = wheels_for(code);
        }
        self.last_t = Some(t_s);
        // Act: report the wheels at the control rate.
        self.act.send(&self.environment, "World", &self.wheels)?;
        Ok(())
    }
}

/// A follower's autonomy code (Fig. 26): poll for commands, forward them, act on them.
pub struct Follower {
    plan: Module,
    act: Module,
    name: String,
    next: Option<Relay>,
    environment: String,
    start: Time,
    wheels: Wheels,
    /// Commands received, for Tables 10 and 11.
    pub received: Vec<CommandRecord>,
}

impl Follower {
    /// A follower forwarding to `next` (if any), reporting to `environment`; `start` is the
    /// scenario's time origin on this system's clock.
    pub fn new(
        comm: &Comm,
        next: Option<&str>,
        environment: &str,
        start: Time,
    ) -> Result<Follower, hetcomm::OpenError> {
        Ok(Follower {
            plan: comm.module("Plan")?,
            act: comm.module("Act")?,
            name: comm.name().to_string(),
            next: next.map(|name| Relay {
                name: name.to_string(),
                bridged: None,
            }),
            environment: environment.to_string(),
            start,
            wheels: wheels_for(0), // every rover starts driving straight
            received: Vec::new(),
        })
    }

    /// The next rover is a bridged robot (it runs ROS, not hetcomm, [`bridged`]): forward each
    /// command as a [`bridged::Twist`] by `drive`, and repeat the current one at every step,
    /// starting with command `initial`.
    pub fn bridge_next(&mut self, drive: DiffDrive, initial: u8) {
        if let Some(next) = &mut self.next {
            next.bridged = Some((drive, initial));
        }
    }

    /// Tells a bridged next rover to stop (the run is over; a ROS base keeps its last
    /// velocity).
    pub fn stop_bridged(&mut self) -> Result<(), hetcomm::SendError> {
        if let Some(Relay {
            name,
            bridged: Some((drive, code)),
        }) = &mut self.next
        {
            *code = 2;
            self.plan
                .send(name, "Plan", &bridged::twist_for(drive, 2))?;
        }
        Ok(())
    }

    /// One control step.
    pub fn step(&mut self) -> Result<(), Box<dyn std::error::Error>> {
        while let Some(r) = self.plan.try_recv::<Command>()? {
            let t = seconds_since(self.start, r.envelope.received_at);
            self.received.push(CommandRecord::new(
                &self.name,
                t,
                r.message.code.into(),
                CommandKind::Received,
            ));
            match &mut self.next {
                Some(Relay {
                    bridged: Some((_, code)),
                    ..
                }) => *code = r.message.code,
                Some(next) => {
                    self.plan.send(&next.name, "Plan", &r.message)?;
                }
                None => {}
            }
            self.wheels = wheels_for(r.message.code);
        }
        // A ROS base expects its velocity command as a stream.
        if let Some(Relay {
            name,
            bridged: Some((drive, code)),
        }) = &self.next
        {
            self.plan
                .send(name, "Plan", &bridged::twist_for(drive, *code))?;
        }
        // No new command: keep the previous motion.
        self.act.send(&self.environment, "World", &self.wheels)?;
        Ok(())
    }
}

/// The VE layout.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Layout {
    /// One VE per rover, polling (the thesis's Tables 6–7).
    ThreeVe,
    /// One VE for every rover, with callbacks.
    SingleVe,
}

/// Lets a tool take part in a run without changing the rovers' code: watch the systems
/// and the rovers' poses (recording, statistics for a monitor, a live Foxglove view) or stand in for some of them (replaying a
/// recording). Every method but [`RunHooks::opened`] does nothing unless written.
pub trait RunHooks: Send {
    /// Systems whose autonomy code this run must not run: [`RunHooks::step`] sends for them.
    fn replaced(&self) -> Vec<String> {
        Vec::new()
    }
    /// Every system of this process is open; `start` is the scenario's time origin on their
    /// clock.
    fn opened(&mut self, systems: &[Comm], start: Time) -> Result<(), Box<dyn std::error::Error>>;
    /// A control step at `t_s` of replaced `system`, where its code would have run.
    fn step(&mut self, system: &str, t_s: f64) -> Result<(), Box<dyn std::error::Error>> {
        let _ = (system, t_s);
        Ok(())
    }
    /// The virtual environments stepped to `t_s`: every rover's pose (rover, pose) now.
    fn poses(
        &mut self,
        t_s: f64,
        poses: &[(String, hetcomm_sim::Pose)],
    ) -> Result<(), Box<dyn std::error::Error>> {
        let _ = (t_s, poses);
        Ok(())
    }
    /// The run is over (a simulation has settled): command records of the replaced systems
    /// (what their code would have logged), for the tables.
    fn finish(&mut self) -> Result<Vec<CommandRecord>, Box<dyn std::error::Error>> {
        Ok(Vec::new())
    }
}

/// Shared [`RunHooks`] for [`DemoOptions::hooks`].
#[derive(Clone)]
pub struct Hooks(pub Arc<Mutex<dyn RunHooks>>);

impl std::fmt::Debug for Hooks {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Hooks")
    }
}

impl Hooks {
    fn lock(&self) -> parking_lot::MutexGuard<'_, dyn RunHooks + 'static> {
        self.0.lock()
    }
}

/// How to run the demonstration.
#[derive(Clone, Debug)]
pub struct DemoOptions {
    /// Seed of the emulated links.
    pub seed: u64,
    /// VE layout.
    pub layout: Layout,
    /// A fleet to use instead of the embedded one.
    pub fleet: Option<hetcomm::config::Fleet>,
    /// Run in real time instead of virtual time.
    pub realtime: bool,
    /// Print a progress line while running.
    pub progress: bool,
    /// Followers whose autonomy code runs in another process (e.g. the Python Tango in
    /// `examples/python/`): not opened here; the fleet must carry their traffic over a network
    /// transport. Real time only.
    pub external: Vec<String>,
    /// A tool taking part in the run (recording, monitor statistics, replay).
    pub hooks: Option<Hooks>,
    /// A scenario file's faults, injections and taps, applied at the start of the run.
    pub scenario: Option<hetcomm::config::scenario::Scenario>,
}

impl Default for DemoOptions {
    fn default() -> Self {
        DemoOptions {
            seed: 1,
            layout: Layout::ThreeVe,
            fleet: None,
            realtime: false,
            progress: false,
            external: Vec::new(),
            hooks: None,
            scenario: None,
        }
    }
}

/// What a run produced.
#[derive(Clone, Debug)]
pub struct DemoReport {
    /// Commands sent by Alpha and received by Charlie and Tango (Tables 9–12).
    pub commands: Vec<CommandRecord>,
    /// Poses logged by the VEs (Tables 13–15), sorted by time then rover.
    pub samples: Vec<PoseSample>,
    /// Wall time the run took.
    pub wall: Duration,
    /// Simulated seconds.
    pub simulated_s: f64,
    /// What the scenario (if any) did: its schedule, each system's harness counters, and the
    /// injections' outcomes, one line each.
    pub scenario: Vec<String>,
    /// When the scenario cut systems off (partitions, silences), shaded in the plots.
    pub bands: Vec<report::plot::Band>,
    /// Robots that ran behind a bridge transport (ROS or plain MQTT) ([`bridged`]): their poses come from
    /// their odometry, their "received" commands from when their odometry showed them.
    pub bridged: Vec<String>,
}

/// Runs the demonstration.
pub fn run(options: &DemoOptions) -> Result<DemoReport, Box<dyn std::error::Error>> {
    let fleet = match (&options.fleet, options.layout) {
        (Some(f), _) => f.clone(),
        (None, Layout::ThreeVe) => {
            hetcomm::config::parse_str(EMBEDDED_FLEET, "<embedded leader-follower fleet>", None)?
        }
        (None, Layout::SingleVe) => hetcomm::config::parse_str(
            EMBEDDED_SINGLE_VE_FLEET,
            "<embedded single-VE fleet>",
            None,
        )?,
    };
    let scenario = Scenario::thesis();
    let leader_name = scenario.leader().unwrap_or("Alpha").to_string();
    for name in &options.external {
        if *name == leader_name
            || fleet.system_by_name(name).is_none()
            || name.starts_with("VirtualEnv")
        {
            return Err(format!("--external {name}: only a follower rover of the fleet (Charlie, Tango) can run elsewhere").into());
        }
    }
    if !options.external.is_empty() && !options.realtime {
        return Err("a follower running in another process needs real time: add --realtime".into());
    }
    // Robots behind bridge transports run ROS, not hetcomm: not opened here, commanded with
    // Twist, seen through their odometry (module `bridged`).
    let bridged = hetcomm::registry().bridged_robots(&fleet);
    let chain = [("Charlie", Some("Tango")), ("Tango", None)];
    for name in &bridged {
        if !chain.iter().any(|(n, next)| n == name && next.is_none()) {
            return Err(format!(
                "`{name}` is a bridged robot (it runs ROS, not hetcomm): only the last follower, \
                 Tango, can be one, since a bridged robot forwards no commands"
            )
            .into());
        }
        if !options.realtime {
            return Err(format!(
                "`{name}` is a bridged robot (it runs ROS, not hetcomm): it needs real time, add \
                 --realtime"
            )
            .into());
        }
    }
    let external = |name: &str| options.external.iter().chain(&bridged).any(|e| e == name);
    let (sim, local) = if options.realtime {
        let names: Vec<&str> = fleet
            .systems
            .iter()
            .map(|s| s.name.as_str())
            .filter(|n| !external(n))
            .collect();
        // The bridges' message types are declared, so a bridge refuses to open if one does
        // not fit its ROS type (instead of failing at the first command).
        let declared = hetcomm::OpenOptions::new()
            .message::<bridged::Twist>()
            .message::<bridged::Odometry>();
        (
            None,
            Some(LocalFleet::open_systems_with(
                fleet.clone(),
                &names,
                declared,
            )?),
        )
    } else {
        let opts = SimOptions {
            seed: options.seed,
            ..SimOptions::default()
        };
        (Some(SimFleet::open(fleet.clone(), opts)?), None)
    };
    let system = |name: &str| -> Result<Comm, hetcomm::OpenError> {
        match (&sim, &local) {
            (Some(s), _) => s.system(name),
            (_, Some(l)) => l.system(name),
            _ => unreachable!("one of the two is always open"),
        }
    };
    let single = options.layout == Layout::SingleVe;
    let ve_of = |rover: &str| -> &'static str {
        match (single, rover) {
            (true, _) | (false, "Alpha") => "VirtualEnv",
            (false, "Charlie") => "VirtualEnv2",
            _ => "VirtualEnv3",
        }
    };
    // A bridged robot must be there before the scenario starts: its odometry is its pose.
    for name in &bridged {
        Environment::wait_for_odometry(&system(ve_of(name))?, name, BRIDGED_WAIT)?;
    }
    // Two origins in real time: `start` on the wall clock, which received messages'
    // `received_at` is on, and `clock_start` on the systems' (monotonic) clock, which
    // scenarios and recordings count on. Under simulation both are the virtual clock.
    let (start, clock_start) = match &sim {
        Some(s) => (s.now(), s.now()),
        None => {
            let now = Time::now_mono();
            (Time::wall_at(now), now)
        }
    };
    let replaced = match &options.hooks {
        Some(h) => {
            let systems = match (&sim, &local) {
                (Some(s), _) => s.systems(),
                (_, Some(l)) => l.systems(),
                _ => unreachable!("one of the two is always open"),
            };
            let mut h = h.lock();
            h.opened(systems, clock_start)?;
            h.replaced()
        }
        None => Vec::new(),
    };
    let is_replaced = |name: &str| replaced.iter().any(|r| r == name);
    let scenario_run = match (&options.scenario, &sim, &local) {
        (Some(sc), Some(s), _) => Some(s.apply_scenario(sc, options.seed)?),
        (Some(sc), _, Some(l)) => Some(l.apply_scenario(sc, options.seed)?),
        _ => None,
    };
    let mut leader = match is_replaced(&leader_name) {
        true => None,
        false => Some(Leader::new(
            &system("Alpha")?,
            "Charlie",
            ve_of("Alpha"),
            scenario.schedule.clone(),
        )?),
    };
    // Every follower in order, None where the hooks stand in for it.
    let mut followers = Vec::new();
    for (name, next) in chain {
        if is_replaced(name) {
            followers.push((name, None));
        } else if !external(name) {
            let mut f = Follower::new(&system(name)?, next, ve_of(name), start)?;
            if next.is_some_and(|n| bridged.iter().any(|b| b == n)) {
                f.bridge_next(scenario.drive, scenario.schedule.initial().code() as u8);
            }
            followers.push((name, Some(f)));
        }
    }
    let mut environments = Vec::new();
    if single {
        environments.push(Environment::new(
            &system("VirtualEnv")?,
            &scenario,
            &scenario.start,
            &bridged,
            start,
            true,
        )?);
    } else {
        for (rover, pose) in &scenario.start {
            let ve = system(ve_of(rover))?;
            environments.push(Environment::new(
                &ve,
                &scenario,
                &[(rover.clone(), *pose)],
                &bridged,
                start,
                false,
            )?);
        }
    }
    let ids: Vec<(String, hetcomm::SystemId)> = fleet
        .systems
        .iter()
        .map(|s| (s.name.clone(), s.id))
        .collect();

    let end_s = scenario.schedule.end_s() + 2.0;
    let steps = (end_s / CONTROL_PERIOD.as_secs_f64()).round() as u64;
    let wall = Instant::now();
    for k in 0..=steps {
        let t = k as f64 * CONTROL_PERIOD.as_secs_f64();
        match &sim {
            Some(s) => s.run_until(start + Duration::from_secs_f64(t)),
            None => {
                let due = wall + Duration::from_secs_f64(t);
                std::thread::sleep(due.saturating_duration_since(Instant::now()));
            }
        }
        match (&mut leader, &options.hooks) {
            (Some(leader), _) => leader.step(t)?,
            (None, Some(h)) => h.lock().step(&leader_name, t)?,
            (None, None) => {}
        }
        for (name, follower) in &mut followers {
            match (follower, &options.hooks) {
                (Some(f), _) => f.step()?,
                (None, Some(h)) => h.lock().step(name, t)?,
                (None, None) => {}
            }
        }
        let mut poses = Vec::new();
        for ve in &environments {
            ve.step(t)?;
            poses.extend(ve.poses());
        }
        // Publish positions for range-dependent links.
        let positions = match (&sim, &local) {
            (Some(s), _) => s.positions(),
            (_, Some(l)) => l.positions(),
            _ => unreachable!("one of the two is always open"),
        };
        for (name, pose) in &poses {
            if let Some((_, id)) = ids.iter().find(|(n, _)| n == name) {
                positions.set(*id, pose.x, pose.y);
            }
        }
        if let Some(h) = &options.hooks {
            h.lock().poses(t, &poses)?;
        }
        if options.progress && (k % 10 == 0 || k == steps) {
            let width = 30;
            let done = (k as usize * width) / steps.max(1) as usize;
            eprint!(
                "\r[{}{}] {t:5.1} / {end_s:.1} s {}",
                "#".repeat(done),
                " ".repeat(width - done),
                if options.realtime {
                    "real time"
                } else {
                    "simulated"
                }
            );
        }
    }
    if let Some(s) = &sim {
        s.run_idle(start + Duration::from_secs_f64(end_s + 60.0));
    }
    for (_, follower) in &mut followers {
        if let Some(f) = follower {
            f.stop_bridged()?;
        }
    }
    if options.progress {
        eprintln!();
    }
    let bands = match (&options.scenario, &scenario_run) {
        (Some(sc), Some(run)) => {
            scenario::bands(sc, run.start().saturating_since(clock_start).as_secs_f64())
        }
        _ => Vec::new(),
    };
    let scenario = match (&options.scenario, &scenario_run) {
        (Some(sc), Some(run)) => {
            let stats: Vec<(String, hetcomm::HarnessStats)> = fleet
                .systems
                .iter()
                .filter_map(|s| {
                    system(&s.name)
                        .ok()
                        .map(|c| (s.name.clone(), c.harness_stats()))
                })
                .collect();
            scenario::report_lines(sc, run, &stats)
        }
        _ => Vec::new(),
    };
    // Each rover's records in its place, a replaced rover's from the hooks.
    let mut hooked = match &options.hooks {
        Some(h) => h.lock().finish()?,
        None => Vec::new(),
    };
    let mut take = |name: &str| {
        let (mine, rest) = std::mem::take(&mut hooked)
            .into_iter()
            .partition(|c: &CommandRecord| c.rover == name);
        hooked = rest;
        mine
    };
    let mut commands = match leader {
        Some(l) => l.sent,
        None => take(&leader_name),
    };
    for (name, follower) in followers {
        commands.extend(match follower {
            Some(f) => f.received,
            None => take(name),
        });
    }
    commands.extend(environments.iter().flat_map(|e| e.take_observed()));
    commands.extend(hooked);
    let mut samples: Vec<PoseSample> = environments.iter().flat_map(|e| e.take_log()).collect();
    samples.sort_by(|a, b| a.t_s.total_cmp(&b.t_s).then_with(|| a.rover.cmp(&b.rover)));
    Ok(DemoReport {
        commands,
        samples,
        wall: wall.elapsed(),
        simulated_s: end_s,
        scenario,
        bands,
        bridged,
    })
}

/// Writes tables, CSV and plots into `dir`; returns the files written.
pub fn write_outputs(
    report: &DemoReport,
    dir: &Path,
) -> Result<Vec<PathBuf>, Box<dyn std::error::Error>> {
    let mut files = report::write_tables(dir, &report.commands, &report.samples)?;
    files.extend(report::plot::write_all(
        dir,
        &report.samples,
        &report.commands,
        &report.bands,
    )?);
    Ok(files)
}

/// The tables in the shape of the thesis's Tables 9–15, as text.
pub fn tables(report: &DemoReport) -> String {
    format!(
        "{}\n{}\n{}",
        report::command_tables(&report.commands),
        report::command_timing_matrix(&report.commands),
        report::pose_tables(&report.samples)
    )
}

/// The thesis's Tables 9–15 as published, each beside this run's figures with how and why
/// they differ.
pub fn beside_thesis(report: &DemoReport) -> String {
    report::thesis::beside(&report.commands, &report.samples)
}
