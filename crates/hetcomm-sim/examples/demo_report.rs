//! Writes the open-loop demonstration's tables, CSV files and plots into a directory.
//!
//! `cargo run -p hetcomm-sim --example demo_report -- OUT_DIR` (default `target/demo-report`).
//! This is the open-loop reference run (no communication). The README's images,
//! `docs/img/demo-*.png`, come from `hetcomm demo` instead: `bash scripts/readme-images.sh`.

use hetcomm_sim::report::{self, plot};
use hetcomm_sim::scenario::{CHARLIE, TANGO};
use hetcomm_sim::Scenario;
use std::path::PathBuf;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let dir = std::env::args_os()
        .nth(1)
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("target/demo-report"));
    // Charlie hears the leader at once; Tango, at the end of the Bluetooth hop, 0.5 s later.
    let run = Scenario::thesis().run_open_loop(&[(CHARLIE, 0.0), (TANGO, 0.5)])?;
    let mut written = report::write_tables(&dir, &run.commands, &run.samples)?;
    written.extend(plot::write_all(&dir, &run.samples, &run.commands, &[])?);
    for p in written {
        println!("{}", p.display());
    }
    Ok(())
}
