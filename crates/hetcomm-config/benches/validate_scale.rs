//! How long validating a big fleet file takes, and how much memory it needs at its peak.
//!
//! ```text
//! cargo bench -p hetcomm-config --bench validate_scale            # 3 000 and 10 000 systems
//! cargo bench -p hetcomm-config --bench validate_scale -- 3000    # one size
//! ```
//!
//! For each size it writes a generated fleet file (every system has a UDP endpoint; every
//! off-diagonal cell of the communication table carries traffic, over a transport name, a
//! letter or an emulated transport, so N systems make N² cells), then runs
//! `hetcomm_config::load` and `Fleet::summary` (what `hetcomm validate` does) in a child
//! process of its own, so that the child's peak resident set size (`getrusage`,
//! `ru_maxrss`) is the validation's alone. It prints one line per size:
//! `config validation at N systems: T s, peak RSS M MB (C cells, F MB file)`.

use std::io::Write;
use std::path::Path;
use std::process::Command;
use std::time::Instant;

/// Set in the child to the fleet file it validates.
const CHILD_ENV: &str = "HETCOMM_VALIDATE_SCALE_CHILD";

/// A fleet of `n` systems whose table is full.
fn fleet_text(n: usize) -> String {
    let mut t = String::with_capacity(n * n * 7 + n * 64);
    t.push_str("name = \"scale\"\n\n[systems]\n");
    for i in 0..n {
        t.push_str(&format!("S{i} = {i}\n"));
    }
    t.push_str("\n[transports.lan]\nkind = \"udp\"\n\n[transports.lan.endpoints]\n");
    for i in 0..n {
        t.push_str(&format!("S{i} = \"10.{}.{}.1:7400\"\n", i / 250, i % 250));
    }
    t.push_str("\n[transports.wifi]\nkind = \"emulated\"\nprofile = \"wifi\"\nover = \"lan\"\n");
    t.push_str("\n[transports.local]\nkind = \"inproc\"\n\n[letters]\nL = \"lan\"\n\n[table]\n");
    t.push_str("columns = [");
    for i in 0..n {
        t.push_str(&format!("{}\"S{i}\"", if i == 0 { "" } else { ", " }));
    }
    t.push_str("]\n");
    const CELLS: [&str; 4] = ["lan", "wifi", "L", "local"];
    for i in 0..n {
        t.push_str(&format!("S{i} = ["));
        for j in 0..n {
            let cell = if i == j { "X" } else { CELLS[(i + j) % 4] };
            t.push_str(if j == 0 { "\"" } else { ", \"" });
            t.push_str(cell);
            t.push('"');
        }
        t.push_str("]\n");
    }
    t
}

/// Peak resident set size of this process, bytes.
fn peak_rss_bytes() -> u64 {
    // SAFETY: a zeroed rusage is a valid out-parameter for getrusage.
    let mut ru: libc::rusage = unsafe { std::mem::zeroed() };
    // SAFETY: `ru` is a valid, writable rusage.
    if unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut ru) } != 0 {
        return 0;
    }
    u64::try_from(ru.ru_maxrss).unwrap_or(0) * 1024 // kilobytes on Linux
}

/// The child: validate one file, print `seconds peak_rss_bytes summary`.
fn child(path: &Path) -> ! {
    let start = Instant::now();
    let result = hetcomm_config::load(path);
    let summary = match &result {
        Ok(fleet) => fleet.summary(),
        Err(e) => {
            eprintln!("{e}");
            std::process::exit(2);
        }
    };
    let secs = start.elapsed().as_secs_f64();
    println!("{secs:.3} {} {summary}", peak_rss_bytes());
    std::process::exit(0);
}

fn main() {
    if let Some(path) = std::env::var_os(CHILD_ENV) {
        child(Path::new(&path));
    }
    let mut sizes: Vec<usize> = std::env::args()
        .skip(1)
        .filter(|a| !a.starts_with('-'))
        .filter_map(|a| a.parse().ok())
        .collect();
    if sizes.is_empty() {
        sizes = vec![3000, 10_000];
    }
    let exe = std::env::current_exe().expect("own path");
    for n in sizes {
        let path = std::env::temp_dir().join(format!(
            "hetcomm-validate-scale-{}-{n}.toml",
            std::process::id()
        ));
        let text = fleet_text(n);
        std::fs::File::create(&path)
            .and_then(|mut f| f.write_all(text.as_bytes()))
            .expect("write the fleet file");
        let file_mb = text.len() as f64 / 1e6;
        drop(text);
        let out = Command::new(&exe)
            .env(CHILD_ENV, &path)
            .output()
            .expect("run the child");
        let _ = std::fs::remove_file(&path);
        let stdout = String::from_utf8_lossy(&out.stdout);
        let mut parts = stdout.trim().splitn(3, ' ');
        match (out.status.success(), parts.next(), parts.next()) {
            (true, Some(secs), Some(rss)) => {
                let rss_mb = rss.parse::<f64>().unwrap_or(0.0) / 1e6;
                println!(
                    "config validation at {n} systems: {secs} s, peak RSS {rss_mb:.0} MB \
                     ({} cells, {file_mb:.0} MB file; {})",
                    n * n,
                    parts.next().unwrap_or("")
                );
            }
            _ => {
                println!(
                    "config validation at {n} systems: failed ({}): {}",
                    out.status,
                    String::from_utf8_lossy(&out.stderr)
                        .lines()
                        .next()
                        .unwrap_or("")
                );
            }
        }
    }
}
