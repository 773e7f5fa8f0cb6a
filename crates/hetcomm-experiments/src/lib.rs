//! # hetcomm-experiments — the thesis's experiments, re-run in virtual time
//!
//! [`reliability`] reproduces the reliability analysis of the 2019 thesis (§5.2, Tables 16–20,
//! Fig. 29): three systems, Bravo, Charlie and Delta, each sending one broadcast and five
//! point-to-point messages to random destinations per trial, over the two transports of the
//! thesis's Table 17 (`R` and `B`), for 20 trials. It runs the same experiment in two modes side
//! by side:
//!
//! - **thesis**: unacknowledged delivery; the transport reports a failed transmission and the
//!   router retries up to the transport's attempt budget (3). This is what the thesis measured.
//! - **acknowledged**: losses are silent (as on a real radio); the receiving router
//!   acknowledges and the sender retransmits on an RTT-derived timeout.
//!
//! [`sweep`] repeats both modes over a range of loss rates (independent and bursty) and plots
//! the delivery ratio and the delay ([`plot`]). [`report`] formats a run as text, CSV or JSON.
//!
//! [`latency`] is the delay analysis the thesis leaves for future work (§6.1): one-way and
//! round-trip delay per ordered pair and transport of any fleet, under a given load and
//! message size, in virtual time for emulated links and in real time for real ones.
//!
//! ```no_run
//! use hetcomm_experiments::reliability::{self, ReliabilityConfig};
//!
//! let fleet = reliability::default_fleet().unwrap();
//! let report = reliability::run(&fleet, &ReliabilityConfig::default()).unwrap();
//! for mode in &report.modes {
//!     println!("{}: {} of {} received", mode.mode, mode.received, mode.messages);
//! }
//! ```

#![warn(missing_docs)]

pub mod latency;
pub mod plot;
pub mod reliability;
pub mod report;
pub mod sweep;

pub use reliability::{
    ExperimentError, LossModel, Mode, ModeReport, ReliabilityConfig, ReliabilityReport,
};
pub use sweep::{SweepConfig, SweepPoint, SweepReport};
