//! rustdds alone, without hetcomm: a 64 B ping-pong between two processes over the same DDS
//! set-up as the `ros2` transport (participant, QoS, `std_msgs/UInt8MultiArray` topics, one
//! reader polled through `mio`). It is the floor under the `ros2` transport's round trip:
//! what `hetcomm-bench`'s `hetcomm-ros2-unack` row costs beyond it is hetcomm's (framing,
//! router, module wake-up); what it costs beyond raw UDP is rustdds's (docs/ros2.md, "Speed").
//!
//! ```sh
//! cargo run --release --manifest-path crates/hetcomm-link-ros2/Cargo.toml --example dds_pingpong -- \
//!     [--iters 20000] [--size 64] [--spin] [--best-effort]
//! ```
//!
//! With `--spin`, both ends poll their reader without sleeping (as `Module::set_wait_spin`
//! does): the round trip then has no wake-up of the application's threads, only rustdds's.
//! With `--best-effort`, both topics are best effort instead of reliable (no heartbeats nor
//! acknowledgements on the wire). Prints the round trip's p50 / p90 / p99 (µs) and the median time `DataWriter::write` takes
//! on the caller's thread.

use std::io::Write;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use hetcomm_link_ros2::link::{participant, qos};
use hetcomm_link_ros2::msg::FrameMessage;
use hetcomm_link_ros2::{names, Reliability, Ros2Settings};
use rustdds::mio1::{Events, Interest, Poll, Token};
use rustdds::no_key::{DataReaderCdr, DataWriterCdr};
use rustdds::{DataWriterStatus, StatusEvented, TopicKind};

type Res<T> = Result<T, Box<dyn std::error::Error>>;

struct End {
    _dp: rustdds::DomainParticipant,
    writer: DataWriterCdr<FrameMessage>,
    reader: DataReaderCdr<FrameMessage>,
    poll: Poll,
    events: Events,
    spin: bool,
}

fn open(domain: u16, mine: &str, theirs: &str, spin: bool, best_effort: bool) -> Res<End> {
    let settings = Ros2Settings {
        domain_id: domain,
        reliability: match best_effort {
            true => Reliability::BestEffort,
            false => Reliability::Reliable,
        },
        ..Ros2Settings::default()
    };
    let dp = participant(&settings)?;
    let q = qos(&settings);
    let ty = names::dds_type(hetcomm_link_ros2::msg::FRAME_TYPE);
    let topic = |n: &str| dp.create_topic(names::dds_topic(n), ty.clone(), &q, TopicKind::NoKey);
    let reader = dp
        .create_subscriber(&q)?
        .create_datareader_no_key_cdr::<FrameMessage>(&topic(mine)?, Some(q.clone()))?;
    let writer = dp
        .create_publisher(&q)?
        .create_datawriter_no_key_cdr::<FrameMessage>(&topic(theirs)?, Some(q.clone()))?;
    let mut end = End {
        _dp: dp,
        writer,
        reader,
        poll: Poll::new()?,
        events: Events::with_capacity(8),
        spin,
    };
    end.poll
        .registry()
        .register(&mut end.reader, Token(0), Interest::READABLE)?;
    // Wait for the other end's reader.
    let deadline = Instant::now() + Duration::from_secs(20);
    let mut matched = 0;
    while matched == 0 {
        while let Some(s) = end.writer.try_recv_status() {
            if let DataWriterStatus::PublicationMatched { current, .. } = s {
                matched = current.count();
            }
        }
        if Instant::now() > deadline {
            return Err("the other end's reader did not match in 20 s".into());
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    Ok(end)
}

impl End {
    /// The next sample's data.
    fn recv(&mut self) -> Res<Vec<u8>> {
        loop {
            if let Some(s) = self.reader.take_next_sample()? {
                return Ok(s.into_value().data);
            }
            let timeout = if self.spin {
                Duration::ZERO
            } else {
                Duration::from_millis(100)
            };
            self.poll.poll(&mut self.events, Some(timeout))?;
        }
    }

    fn send(&self, data: Vec<u8>) -> Res<()> {
        self.writer.write(
            FrameMessage {
                data,
                ..FrameMessage::default()
            },
            None,
        )?;
        Ok(())
    }
}

/// The wall clock in ns: one clock for both processes of this host (the round trip's few
/// seconds leave no room for it to be adjusted noticeably).
fn now_ns() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as u64)
}

fn stamp(data: &mut [u8], at: usize) {
    data[at..at + 8].copy_from_slice(&now_ns().to_le_bytes());
}

fn read_stamp(data: &[u8], at: usize) -> u64 {
    data.get(at..at + 8)
        .and_then(|b| b.try_into().ok())
        .map_or(0, u64::from_le_bytes)
}

fn arg(name: &str) -> Option<String> {
    let args: Vec<String> = std::env::args().collect();
    args.iter()
        .position(|a| a == name)
        .and_then(|i| args.get(i + 1).cloned())
}

fn main() -> Res<()> {
    let spin = std::env::args().any(|a| a == "--spin");
    let best_effort = std::env::args().any(|a| a == "--best-effort");
    let iters: usize = arg("--iters").map_or(Ok(20_000), |v| v.parse())?;
    let size: usize = arg("--size").map_or(Ok(64), |v| v.parse())?;
    let domain = 150 + (std::process::id() % 80) as u16;
    if let Some(domain) = arg("--echo") {
        let mut end = open(domain.parse()?, "/pp/echo", "/pp/ping", spin, best_effort)?;
        println!("ready");
        std::io::stdout().flush()?;
        loop {
            let mut data = end.recv()?;
            if data.is_empty() {
                return Ok(());
            }
            // When the sample was taken, then when the reply is written.
            stamp(&mut data, 8);
            stamp(&mut data, 16);
            end.send(data)?;
        }
    }
    let mut cmd = Command::new(std::env::current_exe()?);
    cmd.args(["--echo", &domain.to_string()]);
    if spin {
        cmd.arg("--spin");
    }
    if best_effort {
        cmd.arg("--best-effort");
    }
    // Both ends wait for the other's reader to match.
    let mut child = cmd.stdout(Stdio::null()).spawn()?;
    let mut end = open(domain, "/pp/ping", "/pp/echo", spin, best_effort)?;
    let warmup = iters / 10;
    let mut rtts = Vec::with_capacity(iters);
    let mut writes = Vec::with_capacity(iters);
    let (mut there, mut turn, mut back) = (Vec::new(), Vec::new(), Vec::new());
    for i in 0..warmup + iters {
        let t0 = Instant::now();
        let mut data = vec![7u8; size.max(24)];
        stamp(&mut data, 0);
        end.send(data)?;
        let t1 = Instant::now();
        let reply = end.recv()?;
        let got = now_ns();
        if i >= warmup {
            rtts.push(t0.elapsed());
            writes.push(t1 - t0);
            let [sent, taken, replied] = [0, 8, 16].map(|at| read_stamp(&reply, at));
            there.push(Duration::from_nanos(taken.saturating_sub(sent)));
            turn.push(Duration::from_nanos(replied.saturating_sub(taken)));
            back.push(Duration::from_nanos(got.saturating_sub(replied)));
        }
    }
    end.send(Vec::new())?;
    let _ = child.wait();
    for v in [&mut rtts, &mut writes, &mut there, &mut turn, &mut back] {
        v.sort();
    }
    let pct = |v: &[Duration], p: f64| v[((v.len() - 1) as f64 * p) as usize].as_secs_f64() * 1e6;
    println!(
        "rustdds ping-pong {size} B{}{}: p50 {:.1} µs, p90 {:.1} µs, p99 {:.1} µs; write() on the caller's thread p50 {:.1} µs",
        if spin { " (spinning readers)" } else { "" },
        if best_effort { " best effort" } else { " reliable" },
        pct(&rtts, 0.5),
        pct(&rtts, 0.9),
        pct(&rtts, 0.99),
        pct(&writes, 0.5)
    );
    println!(
        "  one way, p50: there (write → taken by the echo) {:.1} µs, echo's turnaround {:.1} µs, back {:.1} µs",
        pct(&there, 0.5),
        pct(&turn, 0.5),
        pct(&back, 0.5)
    );
    Ok(())
}
