//! The virtual environment (VE): rover poses, their current wheel commands, and a pose log.
//!
//! In the thesis each virtual environment receives periodic *Wheels* messages and uses
//! them to compute each rover's new position from its previous one (§5.1.2.4); it also
//! acts as the data logger behind Tables 13–15 and Appendix A. [`VirtualEnvironment`] is
//! that, minus the messaging: whoever owns it calls [`set_wheels`](VirtualEnvironment::set_wheels)
//! when a *Wheels* message arrives and [`advance`](VirtualEnvironment::advance) as simulated
//! time passes.
//!
//! # Time model
//!
//! Simulated time runs on a fixed grid of `1 / update_hz` seconds (default 100 Hz, i.e.
//! 10 ms steps), counted as an integer step index so that times such as 2.0 s are exact.
//! `advance(now_s)` moves every rover through each whole grid step up to `now_s`, using
//! the wheel commands it holds at that moment; a time within 1 µs below a grid point counts
//! as reaching it (so `advance(0.29)` reaches step 29 despite `0.29·100 = 28.999…`).
//! Wheel commands set after `advance(t)` therefore take effect from grid time `t` on.
//! Because the state only changes at grid points, the result does not depend on how the
//! caller slices time into `advance` calls: `advance(13.0)` once equals 1300 calls of 10 ms,
//! bit for bit.
//!
//! Every `update_hz / log_hz` steps (default every 10th step, i.e. 10 Hz) each rover's
//! pose is appended to the log as a [`PoseSample`], in the order rovers were added. A
//! rover's starting pose is logged when it is added on a logging instant (e.g. at t = 0).
//!
//! The VE reads no clock and uses no randomness: the same calls give the same log.

use crate::kinematics::{DiffDrive, Pose};

/// Times beyond this many seconds are rejected, so a bogus timestamp cannot make
/// [`VirtualEnvironment::advance`] loop for days (10⁷ s ≈ 116 days of simulated time).
pub const MAX_TIME_S: f64 = 1e7;

/// Tolerance, in grid steps, for a time just below a grid point to count as that point.
const GRID_SNAP_STEPS: f64 = 1e-6;

/// A time-stamped pose of one rover, as logged by the virtual environment.
#[derive(Debug, Clone, PartialEq)]
pub struct PoseSample {
    /// Simulated time in seconds from the start of the scenario.
    pub t_s: f64,
    /// The rover's friendly name (e.g. "Alpha").
    pub rover: String,
    /// The rover's pose at `t_s`.
    pub pose: Pose,
}

/// Rates of the virtual environment's update grid and of its pose log.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct VeConfig {
    /// Integration steps per simulated second (default 100, i.e. 10 ms steps).
    pub update_hz: u32,
    /// Pose log samples per simulated second (default 10); must divide `update_hz`.
    pub log_hz: u32,
}

impl Default for VeConfig {
    /// 100 Hz integration and a 10 Hz pose log.
    fn default() -> Self {
        VeConfig {
            update_hz: 100,
            log_hz: 10,
        }
    }
}

/// Why a virtual-environment call was refused (the environment is left unchanged).
#[derive(Debug, Clone, PartialEq)]
pub enum WorldError {
    /// `update_hz` or `log_hz` was 0, or `log_hz` does not divide `update_hz`.
    BadConfig(VeConfig),
    /// No rover of this name has been added.
    UnknownRover(String),
    /// A rover of this name already exists.
    DuplicateRover(String),
    /// A wheel command was NaN or infinite; the rover keeps its previous wheels.
    BadWheels {
        /// The rover the command was for.
        rover: String,
        /// The rejected left wheel command.
        left: f64,
        /// The rejected right wheel command.
        right: f64,
    },
    /// A starting pose had a non-finite coordinate.
    BadPose(String),
    /// A time was NaN, infinite, negative or above [`MAX_TIME_S`].
    BadTime(f64),
}

impl std::fmt::Display for WorldError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            WorldError::BadConfig(c) => write!(
                f,
                "bad VE config: update_hz {} and log_hz {} must be > 0 with log_hz dividing update_hz",
                c.update_hz, c.log_hz
            ),
            WorldError::UnknownRover(r) => write!(f, "unknown rover {r:?}"),
            WorldError::DuplicateRover(r) => write!(f, "rover {r:?} already exists"),
            WorldError::BadWheels { rover, left, right } => {
                write!(f, "non-finite wheel command ({left}, {right}) for rover {rover:?}")
            }
            WorldError::BadPose(r) => write!(f, "non-finite starting pose for rover {r:?}"),
            WorldError::BadTime(t) => {
                write!(f, "time {t} s is not finite or outside [0, {MAX_TIME_S}]")
            }
        }
    }
}

impl std::error::Error for WorldError {}

#[derive(Debug, Clone)]
struct RoverState {
    name: String,
    pose: Pose,
    left: f64,
    right: f64,
}

/// Rover poses integrated over simulated time from their latest wheel commands.
#[derive(Debug, Clone)]
pub struct VirtualEnvironment {
    drive: DiffDrive,
    config: VeConfig,
    step: u64,
    rovers: Vec<RoverState>,
    log: Vec<PoseSample>,
}

impl VirtualEnvironment {
    /// An empty environment at t = 0 with the default 100 Hz update grid and 10 Hz log.
    pub fn new(drive: DiffDrive) -> Self {
        VirtualEnvironment {
            drive,
            config: VeConfig::default(),
            step: 0,
            rovers: Vec::new(),
            log: Vec::new(),
        }
    }

    /// An empty environment at t = 0 with the given rates (checked, see [`VeConfig`]).
    pub fn with_config(drive: DiffDrive, config: VeConfig) -> Result<Self, WorldError> {
        if config.update_hz == 0 || config.log_hz == 0 || config.update_hz % config.log_hz != 0 {
            return Err(WorldError::BadConfig(config));
        }
        Ok(VirtualEnvironment {
            config,
            ..VirtualEnvironment::new(drive)
        })
    }

    /// The kinematic model the environment integrates with.
    pub fn drive(&self) -> &DiffDrive {
        &self.drive
    }

    /// The update and log rates in use.
    pub fn config(&self) -> VeConfig {
        self.config
    }

    /// The length of one integration step in seconds (`1 / update_hz`).
    pub fn update_step_s(&self) -> f64 {
        1.0 / f64::from(self.config.update_hz)
    }

    /// The current simulated time in seconds (always on the update grid).
    pub fn now_s(&self) -> f64 {
        self.time_of(self.step)
    }

    fn time_of(&self, step: u64) -> f64 {
        // Dividing the integer index (rather than summing 0.01s) keeps whole seconds exact.
        step as f64 / f64::from(self.config.update_hz)
    }

    fn log_every(&self) -> u64 {
        u64::from(self.config.update_hz / self.config.log_hz)
    }

    fn index_of(&self, name: &str) -> Result<usize, WorldError> {
        self.rovers
            .iter()
            .position(|r| r.name == name)
            .ok_or_else(|| WorldError::UnknownRover(name.to_string()))
    }

    /// Adds a rover at `pose` with both wheels at 0, at the current simulated time.
    ///
    /// Its pose is logged immediately if the current time is a logging instant.
    pub fn add_rover(&mut self, name: &str, pose: Pose) -> Result<(), WorldError> {
        if self.rovers.iter().any(|r| r.name == name) {
            return Err(WorldError::DuplicateRover(name.to_string()));
        }
        if !pose.is_finite() {
            return Err(WorldError::BadPose(name.to_string()));
        }
        // Re-normalise in case the caller built the Pose by hand with θ outside [0, 360).
        let pose = Pose::new(pose.x, pose.y, pose.theta_deg);
        self.rovers.push(RoverState {
            name: name.to_string(),
            pose,
            left: 0.0,
            right: 0.0,
        });
        if self.step % self.log_every() == 0 {
            self.log.push(PoseSample {
                t_s: self.now_s(),
                rover: name.to_string(),
                pose,
            });
        }
        Ok(())
    }

    /// Sets a rover's wheel commands, in force from the current simulated time on.
    ///
    /// Non-finite commands are rejected with [`WorldError::BadWheels`] and the rover keeps
    /// its previous wheels, so a corrupt *Wheels* message cannot make a rover vanish.
    pub fn set_wheels(&mut self, rover: &str, left: f64, right: f64) -> Result<(), WorldError> {
        let i = self.index_of(rover)?;
        if !left.is_finite() || !right.is_finite() {
            return Err(WorldError::BadWheels {
                rover: rover.to_string(),
                left,
                right,
            });
        }
        self.rovers[i].left = left;
        self.rovers[i].right = right;
        Ok(())
    }

    /// Moves every rover through each whole update step up to `now_s`, logging on the way.
    ///
    /// Returns the number of steps taken. A `now_s` at or before the current time takes no
    /// step (the environment never runs backwards); a NaN, infinite, negative or
    /// above-[`MAX_TIME_S`] time is refused with [`WorldError::BadTime`].
    pub fn advance(&mut self, now_s: f64) -> Result<u64, WorldError> {
        if !now_s.is_finite() || !(0.0..=MAX_TIME_S).contains(&now_s) {
            return Err(WorldError::BadTime(now_s));
        }
        let target = (now_s * f64::from(self.config.update_hz) + GRID_SNAP_STEPS).floor() as u64;
        if target <= self.step {
            return Ok(0);
        }
        let dt = self.update_step_s();
        let log_every = self.log_every();
        let taken = target - self.step;
        while self.step < target {
            for r in &mut self.rovers {
                r.pose = self.drive.step(r.pose, r.left, r.right, dt);
            }
            self.step += 1;
            if self.step % log_every == 0 {
                let t_s = self.time_of(self.step);
                self.log.extend(self.rovers.iter().map(|r| PoseSample {
                    t_s,
                    rover: r.name.clone(),
                    pose: r.pose,
                }));
            }
        }
        Ok(taken)
    }

    /// The current pose of a rover, if it exists.
    pub fn pose(&self, rover: &str) -> Option<Pose> {
        self.rovers.iter().find(|r| r.name == rover).map(|r| r.pose)
    }

    /// The current `(left, right)` wheel commands of a rover, if it exists.
    pub fn wheels(&self, rover: &str) -> Option<(f64, f64)> {
        self.rovers
            .iter()
            .find(|r| r.name == rover)
            .map(|r| (r.left, r.right))
    }

    /// Every rover's name and current pose, in the order they were added.
    pub fn poses(&self) -> impl Iterator<Item = (&str, Pose)> + '_ {
        self.rovers.iter().map(|r| (r.name.as_str(), r.pose))
    }

    /// Every rover's name and current `(x, y)`, in the order they were added.
    ///
    /// This is the feed for range-dependent links (e.g. a Bluetooth model that drops
    /// frames beyond some distance).
    pub fn positions(&self) -> impl Iterator<Item = (&str, f64, f64)> + '_ {
        self.rovers
            .iter()
            .map(|r| (r.name.as_str(), r.pose.x, r.pose.y))
    }

    /// The rover names in the order they were added.
    pub fn rover_names(&self) -> impl Iterator<Item = &str> + '_ {
        self.rovers.iter().map(|r| r.name.as_str())
    }

    /// Every pose sample logged so far, in time order (rovers in insertion order per instant).
    pub fn log(&self) -> &[PoseSample] {
        &self.log
    }

    /// Hands over the pose log, leaving the environment's log empty.
    pub fn take_log(&mut self) -> Vec<PoseSample> {
        std::mem::take(&mut self.log)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ve() -> VirtualEnvironment {
        let mut ve = VirtualEnvironment::new(DiffDrive::default());
        ve.add_rover("A", Pose::new(0.0, 0.0, 0.0)).unwrap();
        ve.add_rover("B", Pose::new(10.0, 10.0, 90.0)).unwrap();
        ve
    }

    #[test]
    fn advances_on_grid_and_logs_at_10hz() {
        let mut ve = ve();
        ve.set_wheels("A", 1.0, 1.0).unwrap();
        assert_eq!(ve.advance(1.0), Ok(100));
        assert_eq!(ve.now_s(), 1.0);
        let a = ve.pose("A").unwrap();
        assert!((a.x - 10.0).abs() < 1e-9 && a.y == 0.0 && a.theta_deg == 0.0);
        // B has wheels 0/0 and stays put.
        assert_eq!(ve.pose("B"), Some(Pose::new(10.0, 10.0, 90.0)));
        // t = 0 plus 10 samples, two rovers each.
        assert_eq!(ve.log().len(), 22);
        assert_eq!(ve.log()[0].t_s, 0.0);
        assert_eq!(ve.log()[21].t_s, 1.0);
        assert_eq!(ve.log()[21].rover, "B");
        let times: Vec<f64> = ve.log().iter().step_by(2).map(|s| s.t_s).collect();
        assert_eq!(times[3], 0.3);
        // Going back or standing still does nothing.
        assert_eq!(ve.advance(0.5), Ok(0));
        assert_eq!(ve.advance(1.0), Ok(0));
        assert_eq!(ve.advance(0.29 + 1.0), Ok(29));
    }

    #[test]
    fn slicing_time_does_not_change_the_result() {
        let mut one = ve();
        let mut many = ve();
        for v in [&mut one, &mut many] {
            v.set_wheels("A", -10.0, 10.0).unwrap();
            v.set_wheels("B", 0.7, 1.3).unwrap();
        }
        one.advance(7.3).unwrap();
        let mut t: f64 = 0.0;
        while t < 7.3 {
            t += 0.0137;
            many.advance(t.min(7.3)).unwrap();
        }
        assert_eq!(one.log(), many.log());
        assert_eq!(one.pose("B"), many.pose("B"));
    }

    #[test]
    fn wheels_take_effect_from_current_time() {
        let mut ve = ve();
        ve.set_wheels("A", 1.0, 1.0).unwrap();
        ve.advance(2.0).unwrap();
        ve.set_wheels("A", -10.0, 10.0).unwrap();
        ve.advance(3.0).unwrap();
        let a = ve.pose("A").unwrap();
        assert!((a.x - 20.0).abs() < 1e-9 && a.y.abs() < 1e-12);
        assert!((a.theta_deg - 1f64.to_degrees()).abs() < 1e-9);
    }

    #[test]
    fn bad_input_is_refused_without_changes() {
        let mut ve = ve();
        ve.set_wheels("A", 1.0, 1.0).unwrap();
        assert!(matches!(
            ve.set_wheels("A", f64::NAN, 1.0),
            Err(WorldError::BadWheels { .. })
        ));
        assert_eq!(ve.wheels("A"), Some((1.0, 1.0)));
        assert_eq!(
            ve.set_wheels("Z", 1.0, 1.0),
            Err(WorldError::UnknownRover("Z".into()))
        );
        assert_eq!(
            ve.add_rover("A", Pose::new(0.0, 0.0, 0.0)),
            Err(WorldError::DuplicateRover("A".into()))
        );
        assert_eq!(
            ve.add_rover(
                "C",
                Pose {
                    x: f64::NAN,
                    y: 0.0,
                    theta_deg: 0.0
                }
            ),
            Err(WorldError::BadPose("C".into()))
        );
        assert!(matches!(ve.advance(f64::NAN), Err(WorldError::BadTime(_))));
        assert!(matches!(ve.advance(-1.0), Err(WorldError::BadTime(_))));
        assert!(matches!(ve.advance(1e300), Err(WorldError::BadTime(_))));
        assert_eq!(ve.now_s(), 0.0);
        assert!(VirtualEnvironment::with_config(
            DiffDrive::default(),
            VeConfig {
                update_hz: 100,
                log_hz: 3
            }
        )
        .is_err());
        assert!(VirtualEnvironment::with_config(
            DiffDrive::default(),
            VeConfig {
                update_hz: 0,
                log_hz: 0
            }
        )
        .is_err());
    }

    #[test]
    fn positions_and_configurable_log_rate() {
        let mut ve = VirtualEnvironment::with_config(
            DiffDrive::default(),
            VeConfig {
                update_hz: 50,
                log_hz: 1,
            },
        )
        .unwrap();
        assert_eq!(ve.update_step_s(), 0.02);
        ve.add_rover("Alpha", Pose::new(1.0, 2.0, 0.0)).unwrap();
        ve.add_rover("Beta", Pose::new(3.0, 4.0, 0.0)).unwrap();
        let pos: Vec<(&str, f64, f64)> = ve.positions().collect();
        assert_eq!(pos, [("Alpha", 1.0, 2.0), ("Beta", 3.0, 4.0)]);
        assert_eq!(ve.rover_names().collect::<Vec<_>>(), ["Alpha", "Beta"]);
        ve.advance(3.5).unwrap();
        assert_eq!(ve.log().len(), 2 * 4);
        // A rover added mid-interval is not logged until the next logging instant.
        ve.add_rover("Late", Pose::new(0.0, 0.0, 0.0)).unwrap();
        assert_eq!(ve.log().len(), 8);
        ve.advance(4.0).unwrap();
        assert_eq!(ve.take_log().len(), 11);
        assert!(ve.log().is_empty());
    }
}
