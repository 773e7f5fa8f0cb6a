//! The `shm` transport (feature `shm`, docs/shm.md): round trips and one-way runs between two
//! processes over iceoryx2 shared memory, unacknowledged and unsecured, beside raw iceoryx2
//! (`benchmarks/iceoryx2-peer`, the bare payload as a sample) measured in the same run, with
//! sleeping receivers (woken through iceoryx2 events) and spinning ones.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use hetcomm::Comm;

use crate::child::{Peer, DATA, STOP};
use crate::ext::{peer_oneway, peer_rtt};
use crate::raw::TempDir;
use crate::report::{find, Row, Target};
use crate::stats::{parse_sink_line, Latency, Throughput};
use crate::{Options, Run};

/// Our rows: sleeping and spinning receivers.
pub const PATH: &str = "hetcomm-shm-unack";
/// Our row with spinning receivers (`Module::set_wait_spin`).
pub const SPIN_PATH: &str = "hetcomm-shm-unack-spin";
/// Raw iceoryx2, receivers sleeping on an event.
pub const RAW: &str = "iceoryx2-raw";
/// Raw iceoryx2, receivers polling (iceoryx2's own benchmark's setting).
pub const RAW_SPIN: &str = "iceoryx2-raw-spin";

/// Where the raw peer is looked for: the release build of `benchmarks/iceoryx2-peer`.
pub fn raw_bin() -> Option<PathBuf> {
    let p = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../benchmarks/iceoryx2-peer/target/release/hetcomm-iceoryx2-peer");
    p.exists().then_some(p)
}

/// Systems A and B on one unacknowledged, unsecured `shm` transport with a fleet name of
/// their own (concurrent runs never meet), frames up to 2 MiB.
fn fleet_text() -> String {
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.subsec_nanos())
        .unwrap_or(0);
    format!(
        r#"name = "bench-{}-{nanos}"
[systems]
A = 0
B = 1
[modules]
M = 0
[inbox]
capacity = 65536
overflow = "block"
block_timeout_ms = 1000
[transports.t]
kind = "shm"
delivery = "unacknowledged"
security = "none"
max_frame = 2200000
queue_depth = 64
[table]
columns = ["A", "B"]
A = ["X", "t"]
B = ["t", "X"]
"#,
        std::process::id()
    )
}

/// Writes the fleet, starts B as a peer process in `role` and opens A.
fn open(role: &str) -> Result<(TempDir, Peer, Comm), String> {
    let dir = TempDir::new()?;
    let path = dir.0.join("fleet.toml");
    std::fs::write(&path, fleet_text()).map_err(|e| format!("{}: {e}", path.display()))?;
    let peer = Peer::spawn(None, &[format!("hc-{role}"), path.display().to_string()])?;
    peer.expect("ready", Duration::from_secs(20))?;
    let comm = Comm::open(&path, "A").map_err(|e| e.to_string())?;
    Ok((dir, peer, comm))
}

/// Ping-pong round trips through a peer process that echoes; with `spin`, both ends' waiting
/// modules spin [`crate::hc::WAIT_SPIN`] before they sleep.
pub fn rtt(size: usize, warmup: u64, iters: u64, spin: bool) -> Result<Latency, String> {
    let (_dir, peer, comm) = open(if spin { "echo-spin" } else { "echo" })?;
    let m = comm.module("M").map_err(|e| e.to_string())?;
    if spin {
        m.set_wait_spin(crate::hc::WAIT_SPIN);
    }
    let result = crate::hc::round_trips(&m, size, warmup, iters);
    drop(m);
    drop(comm);
    peer.finish(Duration::from_secs(3));
    result
}

/// One-way: A sends as fast as `send_raw` returns for `duration`; the peer counts.
pub fn oneway(size: usize, duration: Duration) -> Result<Throughput, String> {
    let (_dir, mut peer, comm) = open("sink")?;
    let m = comm.module("M").map_err(|e| e.to_string())?;
    let msg = vec![7u8; size];
    let mut sent = 0;
    let end = Instant::now() + duration;
    while Instant::now() < end {
        for _ in 0..16 {
            if m.send_raw("B", "M", DATA, &msg, Default::default()).is_ok() {
                sent += 1;
            }
        }
    }
    for _ in 0..3 {
        let _ = m.send_raw("B", "M", STOP, &[0], Default::default());
        std::thread::sleep(Duration::from_millis(5));
    }
    peer.close_input();
    let line = peer.expect("result", Duration::from_secs(40))?;
    drop(m);
    drop(comm);
    peer.finish(Duration::from_secs(3));
    parse_sink_line(&line, sent).ok_or(format!("bad sink line {line:?}"))
}

fn service() -> String {
    format!(
        "hetcomm-bench/raw-{}-{}",
        std::process::id(),
        Instant::now().elapsed().as_nanos()
    )
}

/// Raw iceoryx2 ping/pong between two processes of `bin` (both spinning with `spin`).
pub fn raw_rtt(
    bin: &Path,
    size: usize,
    warmup: u64,
    iters: u64,
    spin: bool,
) -> Result<Latency, String> {
    let mut args = vec!["--service".to_string(), service()];
    if spin {
        args.push("--spin".into());
    }
    peer_rtt(bin, &args, &args, (size, warmup, iters))
}

/// Raw iceoryx2 one-way: a source process publishes for `duration`, a sink process counts.
pub fn raw_oneway(bin: &Path, size: usize, duration: Duration) -> Result<Throughput, String> {
    let args = ["--service".to_string(), service()];
    peer_oneway(bin, "iceoryx2", &args, &args, (size, duration))
}

/// The round-trip paths at `size`, run interleaved with the raw socket rows: ours sleeping and
/// spinning, raw iceoryx2 sleeping and spinning (when its peer is built). Spinning rows at
/// 64 B only.
pub(crate) fn rtt_paths(
    o: &Options,
    size: usize,
    warmup: u64,
    iters: u64,
) -> Vec<(String, Run<Latency>)> {
    let mut paths: Vec<(String, Run<Latency>)> = Vec::new();
    let spins: &[bool] = if size == 64 { &[false, true] } else { &[false] };
    for &spin in spins {
        let name = if spin { SPIN_PATH } else { PATH };
        paths.push((
            name.into(),
            Box::new(move || rtt(size, warmup, iters, spin)),
        ));
        if let Some(bin) = raw_bin() {
            let name = if spin { RAW_SPIN } else { RAW };
            paths.push((
                name.into(),
                Box::new(move || raw_rtt(&bin, size, warmup, iters, spin)),
            ));
        }
    }
    paths.retain(|(name, _)| o.path_wanted(name));
    paths
}

/// The one-way paths at `size`: ours and raw iceoryx2's.
pub(crate) fn oneway_paths(
    o: &Options,
    size: usize,
    duration: Duration,
) -> Vec<(String, Run<Throughput>)> {
    let mut paths: Vec<(String, Run<Throughput>)> =
        vec![(PATH.into(), Box::new(move || oneway(size, duration)))];
    if let Some(bin) = raw_bin() {
        paths.push((
            RAW.into(),
            Box::new(move || raw_oneway(&bin, size, duration)),
        ));
    }
    paths.retain(|(name, _)| o.path_wanted(name));
    paths
}

const WHY: &str = "the `shm` transport carries our frame (48-byte header, router, inbox) as one iceoryx2 sample, one copy into the loaned sample, read in place; a send notifies the receiver's iceoryx2 event (a Unix datagram) so that a sleeping receiver wakes, unless the receiver's flag in shared memory says it spins; a spinning receiver looks at its queue without a system call but yields the CPU after every look (a `sched_yield`), so that a peer sharing its CPU still runs. Raw iceoryx2 (benchmarks/iceoryx2-peer) sends the bare payload; its spinning rows poll the subscriber without any system call. Measured on a shared 2-vCPU VM: a spinning receiver competes with its peer for the CPUs, so spinning rows there are worse than on a machine with cores to spare.";

fn g(rows: &[Row], section: &str, path: &str, size: usize, k: &str) -> Option<f64> {
    find(rows, section, path, size).and_then(|r| r.get(k))
}

fn target(
    name: &'static str,
    ours: Option<f64>,
    theirs: Option<f64>,
    bound: f64,
    what: &str,
) -> Target {
    match (ours, theirs) {
        (Some(o), Some(t)) if t > 0.0 => {
            let x = o / t;
            Target {
                name,
                status: if x <= bound { "met" } else { "missed" },
                figure: format!("{what}: {o:.2} vs {t:.2} = {x:.2}× (bound {bound}×)"),
                why: WHY,
            }
        }
        _ => Target {
            name,
            status: "not measured",
            figure: "-".into(),
            why: "a run failed, a row was not selected (--paths), or benchmarks/iceoryx2-peer is not built",
        },
    }
}

/// Issue 38's speed targets, each against a baseline of the same run.
pub fn targets(rows: &[Row]) -> Vec<Target> {
    const MIB: usize = 1024 * 1024;
    let p50 = |path: &str, size: usize| g(rows, "rtt", path, size, "p50_us");
    let mut t = vec![
        target(
            "shm 64 B round trip p50, spinning receivers: ≤ 2 µs",
            p50(SPIN_PATH, 64),
            Some(2.0),
            1.0,
            "p50 µs vs the 2 µs bound",
        ),
        target(
            "shm 64 B round trip p50, sleeping receivers: ≤ raw Unix socket's",
            p50(PATH, 64),
            p50("raw-unix", 64),
            1.0,
            "p50 µs, ours vs raw-unix",
        ),
        target(
            "shm 64 B round trip p50: ≤ 3× raw iceoryx2's (spinning)",
            p50(SPIN_PATH, 64),
            p50(RAW_SPIN, 64),
            3.0,
            "p50 µs, ours vs raw iceoryx2, both spinning",
        ),
        target(
            "shm 64 B round trip p50: ≤ 3× raw iceoryx2's (sleeping)",
            p50(PATH, 64),
            p50(RAW, 64),
            3.0,
            "p50 µs, ours vs raw iceoryx2, both sleeping",
        ),
        target(
            "shm 1 MiB round trip p50: ≤ 0.2× raw UDP's",
            p50(PATH, MIB),
            p50("raw-udp", MIB),
            0.2,
            "p50 µs, ours vs raw-udp",
        ),
        target(
            "shm 1 MiB round trip p50: ≤ 1.5× raw iceoryx2's",
            p50(PATH, MIB),
            p50(RAW, MIB),
            1.5,
            "p50 µs, ours vs raw iceoryx2",
        ),
    ];
    // One-way beside raw iceoryx2: the issue sets no bound, so the figure is shown, not judged.
    for (name, size, key) in [
        (
            "shm one-way 64 B beside raw iceoryx2 (msg/s)",
            64,
            "msgs_per_s",
        ),
        (
            "shm one-way 64 KiB beside raw iceoryx2 (B/s)",
            64 * 1024,
            "bytes_per_s",
        ),
    ] {
        let (ours, raw) = (
            g(rows, "oneway", PATH, size, key),
            g(rows, "oneway", RAW, size, key),
        );
        t.push(match (ours, raw) {
            (Some(o), Some(r)) if r > 0.0 => Target {
                name,
                status: "shown",
                figure: format!("{o:.3e} vs {r:.3e} = {:.2}× raw iceoryx2", o / r),
                why: WHY,
            },
            _ => Target {
                name,
                status: "not measured",
                figure: "-".into(),
                why: "a run failed, a row was not selected (--paths), or benchmarks/iceoryx2-peer is not built",
            },
        });
    }
    t
}
