//! Scenario files: a schedule, in scenario time (seconds from the start of a run), of network
//! faults, message injections and taps for a fleet. Checked against the fleet at load time:
//! every problem is reported at `file:line:column`, all of them in one pass.
//!
//! ```toml
//! seed = 7                       # optional: the faults' random loss and jitter
//!
//! [[partition]]                  # nothing passes between the two sides
//! between = ["Charlie", "Tango"] # two systems, or two groups: [["A", "B"], ["C"]]
//! start = 4.0
//! end = 7.0
//!
//! [[silence]]                    # a system neither sends nor receives
//! system = "Tango"
//! start = 9.0
//! end = 10.0
//!
//! [[link]]                       # loss, latency and jitter on a pair
//! between = ["Alpha", "Charlie"] # both directions (or from = "Alpha", to = "Charlie")
//! loss = 0.2
//! latency_ms = 30.0
//! jitter_ms = 10.0
//! start = 1.0
//! end = 3.0
//!
//! [[inject]]                     # a real send from a module, at a time
//! at = 5.0
//! from = "Alpha.Plan"
//! to = "Charlie.Plan"
//! type = 0
//! payload = { code = 2 }         # MessagePack-encoded, fields by name
//!
//! [[tap]]                        # on messages into a system, or on a topic of one
//! to = "Tango"                   # or: system = "Tango", topic = "pose"
//! from = "Charlie"               # optional narrowing: from, module, type
//! module = "Plan"
//! action = "delay"               # observe | drop | delay | duplicate | replace
//! delay_ms = 500.0               # delay; duplicate takes copies = N
//! start = 2.0                    # optional window (default: the whole run)
//! end = 6.0
//! script = [{ at = 3.0, payload = { code = 1 } }]  # replace: what arrives instead
//! ```

mod parse;

use std::path::Path;

use hetcomm_core::MessageType;

use crate::error::ConfigErrors;
use crate::Fleet;

pub(crate) use parse::parse_fleet_taps;
pub use parse::parse_scenario;

/// A window of scenario time, in seconds.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Window {
    /// When it starts (≥ 0).
    pub start_s: f64,
    /// When it ends (> start).
    pub end_s: f64,
}

impl Window {
    /// Whether two windows share an instant.
    pub fn overlaps(&self, o: &Window) -> bool {
        self.start_s < o.end_s && o.start_s < self.end_s
    }
}

/// What a fault does to the frames of its pairs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum FaultEffect {
    /// Nothing passes.
    Cut,
    /// Loss, added latency and jitter.
    Degrade {
        /// Probability that a frame is lost, 0 to 1.
        loss: f64,
        /// Added one-way latency, milliseconds.
        latency_ms: f64,
        /// Added uniform jitter, 0 to this many milliseconds.
        jitter_ms: f64,
    },
}

/// One scheduled fault: frames between the listed directed pairs of systems (by name).
#[derive(Clone, Debug, PartialEq)]
pub struct Fault {
    /// `partition`, `silence` or `link`: the table it came from.
    pub kind: &'static str,
    /// Directed pairs (source, destination) it acts on.
    pub pairs: Vec<(String, String)>,
    /// When.
    pub window: Window,
    /// What.
    pub effect: FaultEffect,
    /// Where it is written.
    pub line: usize,
}

/// A message sent by a module at a time.
#[derive(Clone, Debug, PartialEq)]
pub struct Injection {
    /// When, seconds.
    pub at_s: f64,
    /// Sending system and module.
    pub from: (String, String),
    /// Destination system and module.
    pub to: (String, String),
    /// The message type.
    pub message_type: MessageType,
    /// The payload, MessagePack-encoded as a send would encode it.
    pub payload: Vec<u8>,
    /// Where it is written.
    pub line: usize,
}

/// Where a scenario tap sits.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum TapSpec {
    /// A topic of a system.
    Topic {
        /// The system.
        system: String,
        /// The topic.
        topic: String,
    },
    /// Messages arriving at a system.
    Messages {
        /// Only from this system.
        from: Option<String>,
        /// The destination system.
        to: String,
        /// Only for this module.
        module: Option<String>,
        /// Only of this type.
        message_type: Option<MessageType>,
    },
}

/// What a scenario tap does.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum TapKind {
    /// Counts (in the harness statistics) and changes nothing.
    Observe,
    /// Discards.
    Drop,
    /// Delivers later, by this many milliseconds.
    Delay(f64),
    /// Delivers this many extra copies.
    Duplicate(u32),
    /// Discards the real messages; the script supplies others.
    Replace,
}

/// One scheduled tap.
#[derive(Clone, Debug, PartialEq)]
pub struct ScenarioTap {
    /// Where.
    pub path: TapSpec,
    /// What.
    pub kind: TapKind,
    /// When (None: the whole run).
    pub window: Option<Window>,
    /// For a replacement: (time, MessagePack payload) injected on the path.
    pub script: Vec<(f64, Vec<u8>)>,
    /// For a scripted message path: the type of the scripted messages.
    pub script_type: Option<MessageType>,
    /// Where it is written.
    pub line: usize,
}

/// A checked scenario file.
#[derive(Clone, Debug, PartialEq, Default)]
pub struct Scenario {
    /// The file, as named by the user.
    pub origin: String,
    /// Seed of the faults' randomness (None: the run's own seed).
    pub seed: Option<u64>,
    /// Network faults.
    pub faults: Vec<Fault>,
    /// Injections, in time order.
    pub injections: Vec<Injection>,
    /// Taps.
    pub taps: Vec<ScenarioTap>,
}

impl Scenario {
    /// The last instant the scenario schedules something, seconds.
    pub fn end_s(&self) -> f64 {
        let f = self.faults.iter().map(|f| f.window.end_s);
        let i = self.injections.iter().map(|i| i.at_s);
        let t = self.taps.iter().filter_map(|t| t.window.map(|w| w.end_s));
        f.chain(i).chain(t).fold(0.0, f64::max)
    }

    /// One line per scheduled item, in time order, for a run's report.
    pub fn summary_lines(&self) -> Vec<String> {
        let mut lines: Vec<(f64, String)> = Vec::new();
        for f in &self.faults {
            let what = match f.effect {
                FaultEffect::Cut => "cut".to_string(),
                FaultEffect::Degrade {
                    loss,
                    latency_ms,
                    jitter_ms,
                } => format!("loss {loss}, +{latency_ms} ms ± {jitter_ms} ms"),
            };
            let mut pairs: Vec<String> = f.pairs.iter().map(|(a, b)| format!("{a}→{b}")).collect();
            if pairs.len() > 4 {
                let n = pairs.len();
                pairs.truncate(4);
                pairs.push(format!("… ({n} pairs)"));
            }
            lines.push((
                f.window.start_s,
                format!(
                    "{:6.2}–{:6.2} s  {} ({what}): {}",
                    f.window.start_s,
                    f.window.end_s,
                    f.kind,
                    pairs.join(", ")
                ),
            ));
        }
        for i in &self.injections {
            lines.push((
                i.at_s,
                format!(
                    "{:6.2} s          inject type {} {}.{} → {}.{}",
                    i.at_s, i.message_type.0, i.from.0, i.from.1, i.to.0, i.to.1
                ),
            ));
        }
        for t in &self.taps {
            let (a, b) = t
                .window
                .map_or((0.0, f64::INFINITY), |w| (w.start_s, w.end_s));
            lines.push((
                a,
                format!("{a:6.2}–{b:6.2} s  tap {:?} on {:?}", t.kind, t.path),
            ));
        }
        lines.sort_by(|a, b| a.0.total_cmp(&b.0));
        lines.into_iter().map(|(_, l)| l).collect()
    }
}

/// Loads and checks a scenario file against `fleet`.
pub fn load_scenario(path: &Path, fleet: &Fleet) -> Result<Scenario, ConfigErrors> {
    let origin = path.display().to_string();
    let text = match std::fs::read_to_string(path) {
        Ok(t) => t,
        Err(e) => {
            return Err(ConfigErrors(vec![crate::ConfigError {
                file: origin,
                line: 0,
                column: 0,
                message: format!("cannot read the scenario file: {e}"),
                help: None,
            }]))
        }
    };
    parse_scenario(&text, &origin, fleet)
}
