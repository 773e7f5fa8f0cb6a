//! The demonstration's set-up (who starts where, the leader's plan) and a reference run
//! with no communication at all.
//!
//! [`Scenario::thesis`] holds the starting poses from the first rows of Tables 13–15
//! (08:36:52): Alpha at (−190.494, −200) facing 0°, Charlie at (200, 5.73321) facing 90°,
//! Tango at (191.495, 60) facing 180°, and the leader's [`Schedule::thesis`].
//!
//! [`Scenario::run_open_loop`] feeds the schedule's commands straight into the rovers'
//! wheels, each follower after a fixed delay instead of over a link. It is the baseline a
//! run over the real communication layer can be compared with, and what the crate's
//! end-to-end test and example plots use.

use crate::kinematics::{DiffDrive, Pose};
use crate::report::{CommandKind, CommandRecord};
use crate::schedule::{Command, Schedule};
use crate::world::{PoseSample, VeConfig, VirtualEnvironment, WorldError};

/// Name of the thesis's leader rover.
pub const ALPHA: &str = "Alpha";
/// Name of the thesis's first follower (wired, ROS in the thesis).
pub const CHARLIE: &str = "Charlie";
/// Name of the thesis's second follower (wireless, Bluetooth in the thesis).
pub const TANGO: &str = "Tango";

/// The thesis's starting poses (Tables 13–15 at 08:36:52), leader first.
pub fn thesis_start_poses() -> Vec<(String, Pose)> {
    vec![
        (ALPHA.to_string(), Pose::new(-190.494, -200.0, 0.0)),
        (CHARLIE.to_string(), Pose::new(200.0, 5.73321, 90.0)),
        (TANGO.to_string(), Pose::new(191.495, 60.0, 180.0)),
    ]
}

/// Everything needed to start the demonstration: rovers, poses, the plan and the model.
#[derive(Debug, Clone, PartialEq)]
pub struct Scenario {
    /// Rover names and starting poses; the first one is the leader.
    pub start: Vec<(String, Pose)>,
    /// The leader's plan.
    pub schedule: Schedule,
    /// The kinematic model every rover uses.
    pub drive: DiffDrive,
    /// Update and log rates of the virtual environment.
    pub ve_config: VeConfig,
}

impl Default for Scenario {
    /// Same as [`Scenario::thesis`].
    fn default() -> Self {
        Scenario::thesis()
    }
}

/// The output of [`Scenario::run_open_loop`]: what the virtual environment logged and the
/// command records in the shape of Tables 9–11.
#[derive(Debug, Clone, PartialEq)]
pub struct OpenLoopRun {
    /// Pose log of every rover at the environment's log rate.
    pub samples: Vec<PoseSample>,
    /// Commands sent by the leader and received by each follower, in time order.
    pub commands: Vec<CommandRecord>,
}

impl Scenario {
    /// The thesis's three rovers, its leader plan, the default [`DiffDrive`] and 100/10 Hz rates.
    pub fn thesis() -> Self {
        Scenario {
            start: thesis_start_poses(),
            schedule: Schedule::thesis(),
            drive: DiffDrive::default(),
            ve_config: VeConfig::default(),
        }
    }

    /// The leader's name (the first starting pose), if there is any rover.
    pub fn leader(&self) -> Option<&str> {
        self.start.first().map(|(n, _)| n.as_str())
    }

    /// A virtual environment at t = 0 holding every rover at its starting pose with the
    /// wheels of the schedule's initial command (the thesis's rovers start moving straight
    /// without being told to).
    pub fn environment(&self) -> Result<VirtualEnvironment, WorldError> {
        let mut ve = VirtualEnvironment::with_config(self.drive, self.ve_config)?;
        let (l, r) = self.schedule.initial().wheels();
        for (name, pose) in &self.start {
            ve.add_rover(name, *pose)?;
            ve.set_wheels(name, l, r)?;
        }
        Ok(ve)
    }

    /// Runs the scenario with commands applied directly, no communication involved.
    ///
    /// The leader applies each schedule command when it falls due and records it as
    /// [`CommandKind::Sent`]; each follower named in `follower_delays` applies (and records
    /// as [`CommandKind::Received`]) the same command `delay_s` seconds later, at the first
    /// update-grid instant at or after that time. Rovers not listed, and negative or
    /// non-finite delays, get no commands and keep their initial wheels. Runs until the
    /// schedule's end time; a command that would be received after it is dropped.
    pub fn run_open_loop(
        &self,
        follower_delays: &[(&str, f64)],
    ) -> Result<OpenLoopRun, WorldError> {
        let mut ve = self.environment()?;
        let leader = self.leader().map(str::to_string);
        let hz = f64::from(self.ve_config.update_hz);
        // Delays are turned into whole grid steps up front so delivery is decided on the
        // integer step index, never by comparing accumulated floats.
        let mut followers: Vec<(&str, u64)> = Vec::new();
        for &(name, delay) in follower_delays {
            if Some(name) == leader.as_deref() || !(delay.is_finite() && delay >= 0.0) {
                continue;
            }
            if ve.pose(name).is_none() {
                return Err(WorldError::UnknownRover(name.to_string()));
            }
            followers.push((name, (delay * hz - 1e-6).ceil().max(0.0) as u64));
        }
        let end_step = (self.schedule.end_s() * hz + 1e-6).floor() as u64;
        // (due step, rover, command) for deliveries still in flight.
        let mut pending: Vec<(u64, String, Command)> = Vec::new();
        let mut commands = Vec::new();
        let mut player = self.schedule.player();
        for step in 0..=end_step {
            let t_s = step as f64 / hz;
            ve.advance(t_s)?;
            if let Some(leader) = &leader {
                while let Some(c) = player.command_at(t_s) {
                    let (l, r) = c.wheels();
                    ve.set_wheels(leader, l, r)?;
                    commands.push(CommandRecord::new(leader, t_s, c.code(), CommandKind::Sent));
                    for (name, delay_steps) in &followers {
                        pending.push((step + delay_steps, name.to_string(), c));
                    }
                }
            }
            // Deliver in the order the commands were issued, then keep the rest.
            let mut still = Vec::with_capacity(pending.len());
            for (due, name, c) in pending.drain(..) {
                if due <= step {
                    let (l, r) = c.wheels();
                    ve.set_wheels(&name, l, r)?;
                    commands.push(CommandRecord::new(
                        &name,
                        t_s,
                        c.code(),
                        CommandKind::Received,
                    ));
                } else {
                    still.push((due, name, c));
                }
            }
            pending = still;
        }
        Ok(OpenLoopRun {
            samples: ve.take_log(),
            commands,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn thesis_start_matches_tables() {
        let s = Scenario::thesis();
        assert_eq!(s.leader(), Some("Alpha"));
        let ve = s.environment().unwrap();
        assert_eq!(ve.pose("Alpha"), Some(Pose::new(-190.494, -200.0, 0.0)));
        assert_eq!(ve.pose("Charlie"), Some(Pose::new(200.0, 5.73321, 90.0)));
        assert_eq!(ve.pose("Tango"), Some(Pose::new(191.495, 60.0, 180.0)));
        assert_eq!(ve.wheels("Tango"), Some((1.0, 1.0)));
    }

    #[test]
    fn open_loop_records_commands_with_delays() {
        let run = Scenario::thesis()
            .run_open_loop(&[(CHARLIE, 0.0), (TANGO, 0.5)])
            .unwrap();
        let tango: Vec<f64> = run
            .commands
            .iter()
            .filter(|c| c.rover == TANGO)
            .map(|c| c.t_s)
            .collect();
        assert_eq!(tango, [2.5, 5.5, 8.5, 10.5]);
        let charlie: Vec<f64> = run
            .commands
            .iter()
            .filter(|c| c.rover == CHARLIE)
            .map(|c| c.t_s)
            .collect();
        assert_eq!(charlie, [2.0, 5.0, 8.0, 10.0]);
        assert_eq!(run.commands.len(), 12);
        // 131 logging instants (0.0 ..= 13.0 at 10 Hz), three rovers each.
        assert_eq!(run.samples.len(), 131 * 3);
        assert!(Scenario::thesis()
            .run_open_loop(&[("Nobody", 0.0)])
            .is_err());
        // A delay past the end drops the deliveries.
        let late = Scenario::thesis().run_open_loop(&[(TANGO, 20.0)]).unwrap();
        assert_eq!(late.commands.len(), 4);
    }
}
