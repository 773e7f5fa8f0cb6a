//! Section `record`: what recording costs the leader–follower demo (wall time with and
//! without a [`Recorder`] on every system), and how fast a dense recording replays into the
//! simulator (recorded seconds per wall second, extrapolated to 1 GB).

use parking_lot::Mutex;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};

use hetcomm::sim::{SimFleet, SimOptions};
use hetcomm::{Comm, ObserverHandle, Time};
use hetcomm_examples::leader_follower::{self, DemoOptions, Hooks, RunHooks};
use hetcomm_record::{RecordOptions, Recorder, ReplayFilter};

use crate::report::Row;

struct RecordHooks {
    path: PathBuf,
    recorder: Option<Arc<Recorder>>,
    handles: Vec<ObserverHandle>,
}

impl RunHooks for RecordHooks {
    fn opened(&mut self, systems: &[Comm], start: Time) -> Result<(), Box<dyn std::error::Error>> {
        let fleet = systems.first().ok_or("no system")?.fleet();
        let r = Recorder::create(
            &self.path,
            fleet,
            RecordOptions {
                origin: start,
                ..RecordOptions::default()
            },
        )?;
        self.handles = systems.iter().map(|c| r.attach(c)).collect();
        self.recorder = Some(r);
        Ok(())
    }
    fn finish(
        &mut self,
    ) -> Result<Vec<hetcomm_sim::report::CommandRecord>, Box<dyn std::error::Error>> {
        self.handles.clear();
        if let Some(r) = self.recorder.take() {
            r.finish()?;
        }
        Ok(Vec::new())
    }
}

/// One demo run as `hetcomm demo` does it (the run, then its tables, CSV files and plots
/// into `out`), with or without recording into `record`: (whole wall time, the run's own).
fn demo_wall(record: Option<&Path>, out: &Path) -> Result<(f64, f64), String> {
    let hooks = record.map(|p| {
        Hooks(Arc::new(Mutex::new(RecordHooks {
            path: p.to_path_buf(),
            recorder: None,
            handles: Vec::new(),
        })))
    });
    let t = Instant::now();
    let report = leader_follower::run(&DemoOptions {
        hooks,
        ..DemoOptions::default()
    })
    .map_err(|e| e.to_string())?;
    let run = t.elapsed().as_secs_f64();
    leader_follower::write_outputs(&report, out).map_err(|e| e.to_string())?;
    Ok((t.elapsed().as_secs_f64(), run))
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Demo wall time without and with recording, interleaved, medians of `rounds`.
pub fn demo_overhead(dir: &Path, rounds: usize) -> Row {
    let path = dir.join("demo.mcap");
    let out = dir.join("demo-out");
    let run = || -> Result<[f64; 5], String> {
        let (mut plain, mut rec, mut plain_run, mut rec_run) =
            (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        for _ in 0..rounds {
            let (w, r) = demo_wall(None, &out)?;
            plain.push(w);
            plain_run.push(r);
            let (w, r) = demo_wall(Some(&path), &out)?;
            rec.push(w);
            rec_run.push(r);
        }
        let bytes = std::fs::metadata(&path).map_err(|e| e.to_string())?.len();
        Ok([
            median(plain),
            median(rec),
            median(plain_run),
            median(rec_run),
            bytes as f64,
        ])
    };
    let mut r = row("demo recording overhead");
    match run() {
        Ok([plain, rec, plain_run, rec_run, bytes]) => {
            r.metrics = vec![
                ("plain_s", plain),
                ("recorded_s", rec),
                ("overhead_pct", (rec / plain - 1.0) * 100.0),
                ("run_only_plain_s", plain_run),
                ("run_only_recorded_s", rec_run),
                ("file_bytes", bytes),
            ];
            r.note = format!(
                "`hetcomm demo` in virtual time (run, tables, CSV, plots), median of {rounds} interleaved runs each; the simulation alone: {:.1} ms → {:.1} ms",
                plain_run * 1e3,
                rec_run * 1e3
            );
        }
        Err(e) => r.error = Some(e),
    }
    r
}

const DENSE_FLEET: &str = r#"
name = "dense"
[systems]
A = 0
B = 1
[modules]
Plan = 0
Act = 1
[transports.net]
kind = "inproc"
[table]
columns = ["A", "B"]
A = ["X", "net"]
B = ["net", "X"]
"#;

/// A dense recording: A sends B a ~1 KiB message every millisecond of virtual time for
/// `seconds`, sends, receipts and outcomes recorded.
fn dense_recording(path: &Path, seconds: u64) -> Result<(), String> {
    let fleet =
        hetcomm::config::parse_str(DENSE_FLEET, "dense.toml", None).map_err(|e| e.to_string())?;
    let sim = SimFleet::open(fleet, SimOptions::default()).map_err(|e| e.to_string())?;
    let a = sim.system("A").map_err(|e| e.to_string())?;
    let b = sim.system("B").map_err(|e| e.to_string())?;
    let rec = Recorder::create(
        path,
        a.fleet(),
        RecordOptions {
            origin: sim.now(),
            ..RecordOptions::default()
        },
    )
    .map_err(|e| e.to_string())?;
    let handles = [rec.attach(&a), rec.attach(&b)];
    let plan = a.module("Plan").map_err(|e| e.to_string())?;
    let act = b.module("Act").map_err(|e| e.to_string())?;
    let payload: Vec<u32> = (0..200).map(|i| i * 7919).collect();
    let bytes = hetcomm::payload::encode(&payload).map_err(|e| e.to_string())?;
    let start = sim.now();
    for k in 0..seconds * 1000 {
        sim.run_until(start + Duration::from_millis(k));
        plan.send_raw(
            "B",
            "Act",
            hetcomm::MessageType(9),
            &bytes,
            Default::default(),
        )
        .map_err(|e| e.to_string())?;
        while act.try_recv_raw().is_some() {}
    }
    sim.run_idle(sim.now() + Duration::from_secs(5));
    drop(handles);
    rec.finish().map_err(|e| e.to_string())?;
    Ok(())
}

/// Replay speed of a dense recording of `seconds` into the simulator.
pub fn replay_speed(dir: &Path, seconds: u64) -> Row {
    let path = dir.join("dense.mcap");
    let mut r = row("dense recording replayed into the simulator");
    let run = || -> Result<Row, String> {
        dense_recording(&path, seconds)?;
        let bytes = std::fs::metadata(&path).map_err(|e| e.to_string())?.len() as f64;
        let fleet = hetcomm::config::parse_str(DENSE_FLEET, "dense.toml", None)
            .map_err(|e| e.to_string())?;
        let sim = SimFleet::open(fleet, SimOptions::default()).map_err(|e| e.to_string())?;
        let act = sim
            .system("B")
            .and_then(|b| b.module("Act"))
            .map_err(|e| e.to_string())?;
        act.on_any(|_| {});
        let report = hetcomm_record::replay::replay_sim(&path, &sim, &ReplayFilter::default(), 1.0)
            .map_err(|e| e.to_string())?;
        if report.stats.delivered != seconds * 1000 {
            return Err(format!("replay delivered {:?}", report.stats));
        }
        let wall = report.wall.as_secs_f64();
        let speed = report.recorded_s / wall;
        let mut out = row("dense recording replayed into the simulator");
        out.metrics = vec![
            ("file_bytes", bytes),
            ("recorded_s", report.recorded_s),
            ("sends", report.stats.sent as f64),
            ("wall_s", wall),
            ("speed_x", speed),
            // Replay streams the file: time grows with its size, the speed stays.
            ("wall_s_per_gb", wall * 1e9 / bytes),
        ];
        out.note = "1 KiB messages at 1 kHz (sends, receipts, outcomes recorded, JSON)".into();
        Ok(out)
    };
    match run() {
        Ok(row) => r = row,
        Err(e) => r.error = Some(e),
    }
    let _ = std::fs::remove_file(&path);
    r
}

fn row(path: &str) -> Row {
    Row {
        section: "record",
        path: path.to_string(),
        size: 0,
        metrics: Vec::new(),
        note: String::new(),
        error: None,
    }
}

/// A report table: title, column headings, rows.
type Table = (String, Vec<&'static str>, Vec<Vec<String>>);

/// The section's table for the report.
pub fn tables(rows: &[Row]) -> Vec<Table> {
    let f = |v: Option<f64>, d: usize| v.map_or("-".into(), |v| format!("{v:.d$}"));
    let body: Vec<Vec<String>> = rows
        .iter()
        .filter(|r| r.section == "record")
        .map(|r| {
            if let Some(e) = &r.error {
                return vec![r.path.clone(), format!("failed: {e}")];
            }
            if r.get("overhead_pct").is_some() {
                vec![
                    r.path.clone(),
                    format!(
                        "{} s → {} s",
                        f(r.get("plain_s"), 3),
                        f(r.get("recorded_s"), 3)
                    ),
                    format!("{} %", f(r.get("overhead_pct"), 1)),
                    f(r.get("file_bytes").map(|b| b / 1e6), 2),
                    r.note.clone(),
                ]
            } else {
                vec![
                    r.path.clone(),
                    format!(
                        "{} recorded s in {} s",
                        f(r.get("recorded_s"), 1),
                        f(r.get("wall_s"), 2)
                    ),
                    format!(
                        "{}× real time ({} s per GB)",
                        f(r.get("speed_x"), 1),
                        f(r.get("wall_s_per_gb"), 1)
                    ),
                    f(r.get("file_bytes").map(|b| b / 1e6), 1),
                    r.note.clone(),
                ]
            }
        })
        .collect();
    vec![(
        "Record and replay (hetcomm-record)".into(),
        vec!["what", "wall time", "figure", "file MB", "how"],
        body,
    )]
}
