//! The thesis's §5.1 fleet (the leader–follower demonstration, Tables 6–8) with its `R` and
//! `B` transports emulated as the reliability experiment emulates them (`R` = profile `wired`,
//! `B` = profile `bluetooth-classic`), and the delays the thesis publishes for it.
//!
//! The thesis times only the Command messages of the demonstration (Table 12, to the second):
//! Alpha sent four commands; Charlie received each in the second it was sent and forwarded it
//! to Tango, who received them 2, 0, 0 and 2 s after Alpha sent them. It gives no delay for
//! the Wheels messages to the virtual environments, no round trip and no distribution.

use std::path::Path;

use hetcomm::config::Fleet;

use crate::reliability::{load_fleet, write_fleet_files, ExperimentError};

/// The §5.1 fleet's files, embedded: (file name, contents).
pub const FLEET_FILES: [(&str, &str); 4] = [
    (
        "fleet.toml",
        include_str!("../../data/thesis-5.1/fleet.toml"),
    ),
    (
        "table6-ids.txt",
        include_str!("../../data/thesis-5.1/table6-ids.txt"),
    ),
    (
        "table7-table.txt",
        include_str!("../../data/thesis-5.1/table7-table.txt"),
    ),
    (
        "table8-bluetooth.txt",
        include_str!("../../data/thesis-5.1/table8-bluetooth.txt"),
    ),
];

/// Writes the §5.1 fleet's files into `dir` (created if missing) and returns the path of its
/// `fleet.toml`.
pub fn write_fleet(dir: &Path) -> Result<std::path::PathBuf, ExperimentError> {
    write_fleet_files(dir, &FLEET_FILES)
}

/// Loads the §5.1 fleet written by [`write_fleet`] into `dir`.
pub fn fleet(dir: &Path) -> Result<Fleet, ExperimentError> {
    load_fleet(&write_fleet(dir)?)
}

/// What the thesis publishes about the delay from `from` to `to` in its §5.1 fleet.
pub fn published(from: &str, to: &str) -> String {
    match (from, to) {
        ("Alpha", "Charlie") => "Table 12: all 4 Command messages received in the second they \
                                 were sent (one-way < 1 s at 1 s resolution); no round trip"
            .into(),
        ("Charlie", "Tango") => "Table 12: Tango received the 4 commands 2, 0, 0 and 2 s after \
                                 Alpha sent them, Charlie forwarding each in the second it got \
                                 it (one-way 0–2 s at 1 s resolution, forwarding included); no \
                                 round trip"
            .into(),
        _ => "none: the thesis times only the Command messages Alpha → Charlie → Tango".into(),
    }
}
