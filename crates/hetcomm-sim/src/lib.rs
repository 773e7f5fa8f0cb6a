//! # hetcomm-sim — the demonstration's virtual world and its reporting
//!
//! The pieces of the thesis's leader–follower demonstration (§5.1, Figs. 25–26,
//! Tables 9–15, Appendix A) that do not need the communication layer:
//!
//! * [`kinematics`] — a differential-drive model with exact arc integration, tuned so that
//!   trajectories look like the thesis's tables (10 units/s straight, ≈57°/s pivot).
//! * [`world`] — the [`VirtualEnvironment`]: rover poses by name, their latest wheel
//!   commands, a fixed 10 ms update grid, a 10 Hz pose log, and positions for
//!   range-dependent links.
//! * [`schedule`] — the leader's plan as data ([`Schedule::thesis`]: turn left at 2 s,
//!   straight at 5 s, turn left at 8 s, straight at 10 s, end at 13 s) and the
//!   [`Command`] codes with their wheel settings.
//! * [`scenario`] — the thesis's starting poses and a reference run that applies commands
//!   directly with fixed delays ([`Scenario::run_open_loop`]).
//! * [`report`] — Tables 9–15 as plain text, CSV files, and PNG plots of x, y, θ over time
//!   and of the trajectories ([`report::plot`]).
//!
//! What it does **not** do: send or receive anything. Wiring the leader, followers and
//! virtual environments to the communication runtime (Command and Wheels messages over
//! ROS-like and Bluetooth-like links) belongs to another crate; this one only offers the
//! deterministic parts it needs. Nothing here reads a clock, uses randomness, spawns a
//! thread, or panics on bad numbers: NaN or infinite inputs are refused with an error or
//! ignored, as each function documents.
//!
//! ```
//! use hetcomm_sim::{Scenario, report};
//! let run = Scenario::thesis().run_open_loop(&[("Charlie", 0.0), ("Tango", 0.5)]).unwrap();
//! let table = report::command_timing_matrix(&run.commands);
//! assert!(table.contains("Tango"));
//! assert!(report::pose_table(&run.samples, "Alpha").starts_with("Table 13: Alpha location data\n"));
//! ```

pub mod kinematics;
pub mod report;
pub mod scenario;
pub mod schedule;
pub mod world;

pub use kinematics::{DiffDrive, Pose};
pub use report::{CommandKind, CommandRecord};
pub use scenario::{OpenLoopRun, Scenario};
pub use schedule::{Command, Schedule};
pub use world::{PoseSample, VeConfig, VirtualEnvironment};
