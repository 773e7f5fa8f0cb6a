//! Config validation at scale: how long `hetcomm validate`'s work (load the fleet file, then
//! summarise it) takes on a fleet of N systems whose communication table is full (N² cells),
//! and the peak memory it needs.
//!
//! The fleet file is generated and written to a temporary file by this process; a child
//! process (this binary, `__validate FILE`) validates it and reports its wall time and its own
//! peak resident set size (`VmHWM` in `/proc/self/status`), so the figure is the validation's
//! alone, not this process's. Not `getrusage`'s `ru_maxrss`: Linux folds the high-water mark of
//! the address space a process had before `exec` into it — for a child spawned with vfork that
//! is the parent's, so inside the full benchmark run (parent at ~1.2 GB after the throughput
//! rows) it reported 1 242 MB for a validation that peaks at ~355 MB.
//! `cargo run --release -p hetcomm-bench -- --only config` runs this alone.

use std::io::Write;
use std::process::Command;
use std::time::Instant;

/// What one fleet size gave.
#[derive(Clone, Debug)]
pub struct ValidateResult {
    /// Systems in the fleet.
    pub systems: usize,
    /// Table cells (systems²).
    pub cells: usize,
    /// Size of the fleet file, bytes.
    pub file_bytes: usize,
    /// Wall time of load + summary in the child, seconds.
    pub seconds: f64,
    /// Peak resident set size of the child, bytes.
    pub peak_rss_bytes: f64,
}

/// A fleet of `n` systems whose every off-diagonal cell carries traffic (the generator the
/// config crate's scale tests use too).
pub fn full_fleet_text(n: usize) -> String {
    hetcomm::config::synthetic::scale_fleet_text(n, true)
}

/// Peak resident set size of this process's own address space since `exec`, bytes (0 if
/// `/proc/self/status` cannot be read).
fn peak_rss_bytes() -> u64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|status| {
            let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
            let kib = line.split_whitespace().nth(1)?.parse::<u64>().ok()?;
            Some(kib * 1024)
        })
        .unwrap_or(0)
}

/// The child (`__validate FILE`): validates the file and prints `seconds peak_rss_bytes`.
pub fn child(args: &[String]) -> Result<(), String> {
    let path = args.first().ok_or("__validate needs a file")?;
    let start = Instant::now();
    let fleet = hetcomm::config::load(std::path::Path::new(path)).map_err(|e| e.to_string())?;
    let summary = fleet.summary();
    let seconds = start.elapsed().as_secs_f64();
    println!("{seconds:.4} {} {summary}", peak_rss_bytes());
    Ok(())
}

/// Generates a fleet of `n` systems and validates it in a child process.
pub fn measure(n: usize) -> Result<ValidateResult, String> {
    let text = full_fleet_text(n);
    let path = std::env::temp_dir().join(format!(
        "hetcomm-bench-validate-{}-{n}.toml",
        std::process::id()
    ));
    std::fs::File::create(&path)
        .and_then(|mut f| f.write_all(text.as_bytes()))
        .map_err(|e| format!("writing {}: {e}", path.display()))?;
    let file_bytes = text.len();
    drop(text);
    let exe = std::env::current_exe().map_err(|e| e.to_string())?;
    let out = Command::new(exe).arg("__validate").arg(&path).output();
    let _ = std::fs::remove_file(&path);
    let out = out.map_err(|e| format!("running the child: {e}"))?;
    if !out.status.success() {
        let err = String::from_utf8_lossy(&out.stderr);
        return Err(format!(
            "the child failed ({}): {}",
            out.status,
            err.lines().next().unwrap_or("")
        ));
    }
    let stdout = String::from_utf8_lossy(&out.stdout);
    let mut parts = stdout.split_whitespace();
    let mut next = |what: &str| {
        parts
            .next()
            .and_then(|s| s.parse::<f64>().ok())
            .ok_or(format!("the child printed no {what}: {stdout}"))
    };
    Ok(ValidateResult {
        systems: n,
        cells: n * n,
        file_bytes,
        seconds: next("time")?,
        peak_rss_bytes: next("peak RSS")?,
    })
}
