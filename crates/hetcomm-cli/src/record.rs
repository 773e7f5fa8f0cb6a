//! `hetcomm record`, and recording / replaying / monitor statistics inside `hetcomm demo`
//! (the demo's [`RunHooks`]).

use parking_lot::Mutex;
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::{mpsc, Arc};
use std::time::{Duration, Instant};

use anyhow::Context;
use hetcomm::{Comm, LocalFleet, ObserverHandle, Time};
use hetcomm_examples::leader_follower::{Command, Hooks, RunHooks};
use hetcomm_record::format::Event;
use hetcomm_record::replay::Player;
use hetcomm_record::stats::Publisher;
use hetcomm_record::{Encoding, RecordOptions, Recorder, ReplayFilter, ReplayItem};
use hetcomm_sim::report::{CommandKind, CommandRecord};

use crate::foxglove::{FoxgloveArgs, Live, PoseRecorder};
use crate::listen::StopSignals;

/// `--record`, `--replay`, `--replace` and `--msgpack` of `hetcomm demo`.
#[derive(Clone, Debug, Default)]
pub struct DemoTools {
    /// Record to this file.
    pub record: Option<PathBuf>,
    /// Only these systems (empty: every system of the run).
    pub record_systems: Vec<String>,
    /// Raw MessagePack instead of JSON.
    pub msgpack: bool,
    /// A recording to replay.
    pub replay: Option<PathBuf>,
    /// The systems whose recorded sends replace their code.
    pub replace: Vec<String>,
    /// `--foxglove HOST:PORT`: the run served to Foxglove live (real time only).
    pub foxglove: FoxgloveArgs,
}

impl DemoTools {
    /// The demo's hooks, or None when no tool is asked for and no monitor is named.
    pub fn hooks(self) -> anyhow::Result<Option<Hooks>> {
        let monitor = std::env::var_os(hetcomm_record::stats::MONITOR_ENV).is_some();
        if self.record.is_none()
            && self.replay.is_none()
            && !monitor
            && self.foxglove.foxglove.is_none()
        {
            return Ok(None);
        }
        if self.replay.is_some() == self.replace.is_empty() {
            anyhow::bail!("--replay FILE and --replace SYSTEM[,…] go together");
        }
        let mut items: HashMap<String, Vec<ReplayItem>> = HashMap::new();
        let mut receipts = Vec::new();
        if let Some(path) = &self.replay {
            let filter = ReplayFilter {
                systems: self.replace.clone(),
                modules: Vec::new(),
                receipts: false,
            };
            let mut bad = 0u64;
            let report = hetcomm_record::reader::read_timed(path, |origin, e| {
                if let Event::Receipt(r) = &e {
                    if self.replace.contains(&r.message.destination.system) {
                        receipts.push((origin, r.clone()));
                    }
                }
                match ReplayItem::from_event(e, origin, &filter) {
                    Some(Ok(i)) => items.entry(i.source.system.clone()).or_default().push(i),
                    Some(Err(_)) => bad += 1,
                    None => {}
                }
            })?;
            eprintln!("replaying {}: {}", path.display(), report.describe());
            if bad > 0 {
                eprintln!("  {bad} recorded sends have a payload that cannot be rebuilt: skipped");
            }
            for name in &self.replace {
                if !items.contains_key(name) {
                    eprintln!("  {name} sent nothing in the recording");
                }
            }
        }
        // Started before the fleet opens, so a viewer can connect and see the run from its
        // first message.
        let live = self.foxglove.start("hetcomm demo")?;
        if let (Some(_), Some(note)) = (&self.record, PoseRecorder::NOTE) {
            eprintln!("note: {note}");
        }
        Ok(Some(Hooks(Arc::new(Mutex::new(DemoHooks {
            live,
            poses: PoseRecorder::new(),
            tools: self,
            items,
            next: HashMap::new(),
            receipts,
            recorder: None,
            handles: Vec::new(),
            player: None,
            publisher: None,
            start: Time(0),
            sent: Vec::new(),
        })))))
    }
}

struct DemoHooks {
    tools: DemoTools,
    /// The live Foxglove view (`--foxglove`).
    live: Option<Live>,
    /// The rovers' poses into the recording, for Foxglove's 3D panel.
    poses: PoseRecorder,
    /// Per replaced system, its recorded sends in time order, and the next one due.
    items: HashMap<String, Vec<ReplayItem>>,
    next: HashMap<String, usize>,
    /// Receipts of replaced systems: (origin, receipt).
    receipts: Vec<(u64, hetcomm_record::format::ReceiptEvent)>,
    recorder: Option<Arc<Recorder>>,
    handles: Vec<ObserverHandle>,
    player: Option<Player>,
    publisher: Option<Publisher>,
    start: Time,
    /// Commands the replayed leader sent (Table 9).
    sent: Vec<CommandRecord>,
}

impl RunHooks for DemoHooks {
    fn replaced(&self) -> Vec<String> {
        self.tools.replace.clone()
    }

    fn opened(&mut self, systems: &[Comm], start: Time) -> Result<(), Box<dyn std::error::Error>> {
        self.start = start;
        if let Some(path) = &self.tools.record {
            let fleet = systems.first().ok_or("no system is open")?.fleet();
            let recorder = Recorder::create(
                path,
                fleet,
                RecordOptions {
                    encoding: if self.tools.msgpack {
                        Encoding::MsgPack
                    } else {
                        Encoding::Json
                    },
                    origin: start,
                    ..RecordOptions::default()
                },
            )?;
            for c in systems {
                let wanted = &self.tools.record_systems;
                if wanted.is_empty() || wanted.iter().any(|w| w == c.name()) {
                    self.handles.push(recorder.attach(c));
                }
            }
            self.recorder = Some(recorder);
        }
        if !self.tools.replace.is_empty() {
            self.player = Some(Player::new(systems));
        }
        self.publisher = Publisher::from_env(systems)?;
        if let Some(live) = &self.live {
            live.watch(systems)?;
        }
        Ok(())
    }

    fn poses(
        &mut self,
        t_s: f64,
        poses: &[(String, hetcomm_sim::Pose)],
    ) -> Result<(), Box<dyn std::error::Error>> {
        if let Some(live) = &self.live {
            live.poses(poses);
        }
        if let Some(r) = &self.recorder {
            // On the recording's clock, as its events: the run's origin plus scenario time.
            let time = self.start + Duration::from_secs_f64(t_s);
            self.poses.write(r, poses, time);
        }
        Ok(())
    }

    fn step(&mut self, system: &str, t_s: f64) -> Result<(), Box<dyn std::error::Error>> {
        let due = Duration::from_secs_f64(t_s).as_micros() as u64;
        let (Some(items), Some(player)) = (self.items.get(system), self.player.as_mut()) else {
            return Ok(());
        };
        let next = self.next.entry(system.to_string()).or_default();
        while let Some(item) = items.get(*next).filter(|i| i.offset_us <= due) {
            player.send(item);
            // What the leader's own code logs for Table 9 (followers log what they receive,
            // not what they forward).
            let leader = hetcomm_sim::Scenario::thesis().leader() == Some(system);
            if leader && item.destination.module == "Plan" && item.message_type == 0 {
                if let Ok(c) = hetcomm::payload::decode::<Command>(&item.payload) {
                    self.sent.push(CommandRecord::new(
                        system,
                        t_s,
                        c.code.into(),
                        CommandKind::Sent,
                    ));
                }
            }
            *next += 1;
        }
        Ok(())
    }

    fn finish(&mut self) -> Result<Vec<CommandRecord>, Box<dyn std::error::Error>> {
        self.handles.clear();
        self.publisher = None;
        if let Some(live) = &self.live {
            live.finish();
        }
        if let Some(r) = self.recorder.take() {
            let s = r.finish()?;
            eprintln!(
                "recorded {}: {} send attempts, {} receipts, {} outcomes{}",
                r.path().display(),
                s.sends,
                s.receipts,
                s.outcomes,
                match s.others {
                    0 => String::new(),
                    n => format!(", {n} pose messages for Foxglove"),
                }
            );
        }
        if let Some(p) = self.player.take() {
            let s = p.finish();
            eprintln!(
                "replayed {} sends ({} delivered, {} sent, {} unconfirmed, {} failed, {} refused, {} pending)",
                s.sent, s.delivered, s.sent_unconfirmable, s.unconfirmed, s.failed, s.refused, s.pending
            );
            if let Some(why) = s.first_refusal {
                eprintln!("  first refusal: {why}");
            }
        }
        // The leader's commands as its code would have logged them; a replaced follower's
        // received commands as it received them in the recording.
        let mut out = std::mem::take(&mut self.sent);
        for (origin, r) in &self.receipts {
            if r.message.destination.module == "Plan" && r.message.message_type == 0 {
                if let Some(c) = r
                    .message
                    .payload_bytes()
                    .ok()
                    .and_then(|b| hetcomm::payload::decode::<Command>(&b).ok())
                {
                    let t = Duration::from_micros(r.time_us.saturating_sub(*origin)).as_secs_f64();
                    out.push(CommandRecord::new(
                        &r.message.destination.system,
                        t,
                        c.code.into(),
                        CommandKind::Received,
                    ));
                }
            }
        }
        Ok(out)
    }
}

/// Flags of `hetcomm record`.
pub struct RecordArgs<'a> {
    /// The fleet file.
    pub fleet: &'a Path,
    /// Systems to open and record.
    pub systems: Vec<String>,
    /// Output file.
    pub out: &'a Path,
    /// Stop after this long.
    pub duration: Option<Duration>,
    /// Raw MessagePack instead of JSON.
    pub msgpack: bool,
}

/// Opens `systems` of a live fleet in this process, records everything they receive (their
/// modules' inboxes are drained, so recording never fills them) until `--duration` or
/// Ctrl-C / SIGTERM, and writes the MCAP file.
pub fn record(args: RecordArgs<'_>) -> anyhow::Result<()> {
    let signals = StopSignals::block()?;
    let fleet = hetcomm::load_fleet(args.fleet)?;
    let names: Vec<&str> = args.systems.iter().map(String::as_str).collect();
    let local = LocalFleet::open_systems(fleet.clone(), &names)?;
    let recorder = Recorder::create(
        args.out,
        &fleet,
        RecordOptions {
            encoding: if args.msgpack {
                Encoding::MsgPack
            } else {
                Encoding::Json
            },
            ..RecordOptions::default()
        },
    )?;
    let mut handles = Vec::new();
    for comm in local.systems() {
        handles.push(recorder.attach(comm));
        for m in &fleet.modules {
            if let Ok(module) = comm.module(&m.name) {
                module.on_any(|_| {});
            }
        }
    }
    let _publisher = Publisher::from_env(local.systems()).map_err(anyhow::Error::msg)?;
    let (tx, rx) = mpsc::channel();
    signals.watch(move |_| {
        let _ = tx.send(());
    })?;
    eprintln!(
        "recording {} into {} ({})",
        args.systems.join(", "),
        args.out.display(),
        match args.duration {
            Some(d) => format!("for {:.1} s", d.as_secs_f64()),
            None => "until Ctrl-C".to_string(),
        }
    );
    let started = Instant::now();
    match args.duration {
        Some(d) => {
            let _ = rx.recv_timeout(d);
        }
        None => {
            let _ = rx.recv();
        }
    }
    drop(handles);
    let s = recorder
        .finish()
        .with_context(|| format!("finishing {}", args.out.display()))?;
    eprintln!(
        "recorded {:.1} s into {}: {} send attempts, {} receipts, {} outcomes",
        started.elapsed().as_secs_f64(),
        args.out.display(),
        s.sends,
        s.receipts,
        s.outcomes
    );
    Ok(())
}
