//! The virtual environments of the demonstration: each integrates the poses of the rovers
//! that report their Wheels to it, and takes the poses of bridged rovers from their odometry.

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use hetcomm::{Comm, Message, Module, Time};
use hetcomm_sim::report::CommandRecord;
use hetcomm_sim::{Pose, PoseSample, Scenario, VirtualEnvironment};

use super::bridged::{Odometer, Odometry};
use super::{seconds_since, Wheels};

/// A virtual environment: integrates the poses of the rovers that report to it, and takes the
/// poses of bridged rovers from their odometry.
pub struct Environment {
    world: Module,
    start: Time,
    env: Arc<Mutex<VirtualEnvironment>>,
    odometers: Arc<Mutex<Odometers>>,
    callbacks: bool,
}

/// The bridged rovers of one environment, what their odometry showed them do, and their log.
#[derive(Default)]
struct Odometers {
    rovers: Vec<Odometer>,
    /// Commands a rover's odometry showed it start executing.
    observed: Vec<CommandRecord>,
    log: Vec<PoseSample>,
    /// Log instants taken so far.
    logged: u64,
}

impl Odometers {
    fn apply(&mut self, rover: &str, t_s: f64, odom: &Odometry) {
        if let Some(o) = self.rovers.iter_mut().find(|o| o.name == rover) {
            self.observed.extend(o.update(odom, t_s));
        }
    }
}

impl Environment {
    /// A VE for `rovers` (name, starting pose), of which those in `bridged` are robots that
    /// run ROS behind a bridge ([`bridged`]). With `callbacks`, messages are applied the
    /// moment they arrive; otherwise [`Environment::step`] polls for them.
    pub fn new(
        comm: &Comm,
        scenario: &Scenario,
        rovers: &[(String, Pose)],
        bridged: &[String],
        start: Time,
        callbacks: bool,
    ) -> Result<Environment, Box<dyn std::error::Error>> {
        let mut env = VirtualEnvironment::with_config(scenario.drive, scenario.ve_config)?;
        let mut odometers = Odometers::default();
        let initial = scenario.schedule.initial().code() as u8;
        for (name, pose) in rovers {
            if bridged.contains(name) {
                odometers
                    .rovers
                    .push(Odometer::new(name, *pose, scenario.drive, initial));
                continue;
            }
            env.add_rover(name, *pose)?;
            let (l, r) = hetcomm_sim::Command::Straight.wheels();
            env.set_wheels(name, l, r)?;
        }
        let env = Arc::new(Mutex::new(env));
        let odometers = Arc::new(Mutex::new(odometers));
        let world = comm.module("World")?;
        if callbacks {
            let env = env.clone();
            world.on::<Wheels>(move |r| {
                let t = seconds_since(start, r.envelope.received_at);
                apply(&env, r.envelope.source_system, t, r.message);
            })?;
            let odometers = odometers.clone();
            world.on::<Odometry>(move |r| {
                let t = seconds_since(start, r.envelope.received_at);
                if let Ok(mut o) = odometers.lock() {
                    o.apply(r.envelope.source_system, t, &r.message);
                }
            })?;
        }
        Ok(Environment {
            world,
            start,
            env,
            odometers,
            callbacks,
        })
    }

    /// Applies waiting messages (when polling), then integrates up to `t_s`.
    pub fn step(&self, t_s: f64) -> Result<(), Box<dyn std::error::Error>> {
        let mut odometers = self.odometers.lock().map_err(|_| "odometers poisoned")?;
        if !self.callbacks {
            while let Some(raw) = self.world.try_recv_raw() {
                let t = seconds_since(self.start, raw.envelope.received_at);
                let from = raw.envelope.source_system;
                match raw.envelope.message_type() {
                    Wheels::TYPE => {
                        let w = hetcomm::payload::decode::<Wheels>(&raw.payload)?;
                        apply(&self.env, from, t, w);
                    }
                    Odometry::TYPE => {
                        let odom = hetcomm::payload::decode::<Odometry>(&raw.payload)?;
                        odometers.apply(from, t, &odom);
                    }
                    other => {
                        return Err(format!(
                            "the virtual environment got message type {} from {from}, \
                             expected Wheels ({}) or Odometry ({})",
                            other.0,
                            Wheels::TYPE.0,
                            Odometry::TYPE.0
                        )
                        .into())
                    }
                }
            }
        }
        let mut env = self.env.lock().map_err(|_| "environment poisoned")?;
        env.advance(t_s)?;
        // Bridged rovers are logged on the environment's log grid, at their latest odometry.
        let log_hz = f64::from(env.config().log_hz);
        let o = &mut *odometers;
        while !o.rovers.is_empty() && (o.logged as f64) <= t_s * log_hz + 1e-6 {
            let at = o.logged as f64 / log_hz;
            o.log.extend(o.rovers.iter().map(|r| PoseSample {
                t_s: at,
                rover: r.name.clone(),
                pose: r.pose,
            }));
            o.logged += 1;
        }
        Ok(())
    }

    /// Current poses (rover name, pose): of the rovers it integrates and of the bridged ones.
    pub fn poses(&self) -> Vec<(String, Pose)> {
        let mut all: Vec<(String, Pose)> = self
            .env
            .lock()
            .map(|e| e.poses().map(|(n, p)| (n.to_string(), p)).collect())
            .unwrap_or_default();
        if let Ok(o) = self.odometers.lock() {
            all.extend(o.rovers.iter().map(|r| (r.name.clone(), r.pose)));
        }
        all
    }

    /// Hands over the pose log.
    pub fn take_log(&self) -> Vec<PoseSample> {
        let mut log = self
            .env
            .lock()
            .map(|mut e| e.take_log())
            .unwrap_or_default();
        if let Ok(mut o) = self.odometers.lock() {
            log.append(&mut o.log);
        }
        log
    }

    /// Hands over the commands bridged rovers were seen to start executing (their odometry's
    /// velocity became that command's): the tables' "received" rows for robots that run no
    /// code of ours.
    pub fn take_observed(&self) -> Vec<CommandRecord> {
        self.odometers
            .lock()
            .map(|mut o| std::mem::take(&mut o.observed))
            .unwrap_or_default()
    }

    /// Waits up to `timeout` for the first odometry from bridged `rover`: it is on the
    /// bridge's network and publishing.
    pub fn wait_for_odometry(
        comm: &Comm,
        rover: &str,
        timeout: Duration,
    ) -> Result<(), Box<dyn std::error::Error>> {
        let world = comm.module("World")?;
        let deadline = Instant::now() + timeout;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            match world.recv_timeout::<Odometry>(left) {
                Ok(r) if r.envelope.source_system == rover => return Ok(()),
                Ok(_) => {}
                Err(hetcomm::RecvError::Timeout(_)) => {
                    return Err(format!(
                        "no odometry from {rover} reached {}'s World module in {} s: is the \
                         robot running, on the bridge's network (domain, topics of the fleet \
                         file)?",
                        comm.name(),
                        timeout.as_secs()
                    )
                    .into())
                }
                Err(e) => return Err(e.into()),
            }
        }
    }
}

/// Wheels take effect at the time they arrived.
fn apply(env: &Mutex<VirtualEnvironment>, rover: &str, t_s: f64, w: Wheels) {
    if let Ok(mut env) = env.lock() {
        // Both can only fail on non-finite input, which the model then ignores.
        let _ = env.advance(t_s);
        let _ = env.set_wheels(rover, w.left, w.right);
    }
}
