//! What the large-message tests of both ROS versions share (`crates/hetcomm-link-ros1/tests/
//! large_messages.rs`, `crates/hetcomm-link-ros2/tests/large_messages.rs`, with their
//! `tests/py/large_node.py`): the two payloads (`sensor_msgs/Image` 640×480 rgb8 and
//! `sensor_msgs/PointCloud2` of 100,000 points), the byte pattern every message carries so
//! that each byte is checked at the other end, and the figures of a run (rate and latency).
//! Included with `#[path]`; this crate's own tests do not use it (it needs the `hetcomm`
//! facade).
#![allow(dead_code)]

use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use hetcomm::{Message, Module, Outcome};
use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

/// Image width and height (pixels), and bytes a pixel (rgb8).
pub const WIDTH: u32 = 640;
/// Image height.
pub const HEIGHT: u32 = 480;
/// Points of the cloud.
pub const POINTS: u32 = 100_000;
/// Bytes of a point: x, y, z, intensity as float32.
pub const POINT_STEP: u32 = 16;
/// The publishing rate of the tests (Hz).
pub const RATE_HZ: f64 = 30.0;

/// The two large payloads.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    /// `sensor_msgs/Image`, 640×480 rgb8: 921,600 bytes of pixels.
    Image,
    /// `sensor_msgs/PointCloud2`, 100,000 points: 1,600,000 bytes.
    Cloud,
}

impl Kind {
    /// The `--type` of `large_node.py`.
    pub fn arg(self) -> &'static str {
        match self {
            Kind::Image => "image",
            Kind::Cloud => "cloud",
        }
    }

    /// Bytes of its `data`.
    pub fn size(self) -> usize {
        match self {
            Kind::Image => (WIDTH * HEIGHT * 3) as usize,
            Kind::Cloud => (POINTS * POINT_STEP) as usize,
        }
    }
}

/// Every message's data: message `k`'s is the bytes `(i + k) % 251` (as `large_node.py`
/// makes and checks them), a slice of one buffer made once (so that neither end spends its
/// time making or checking a pattern).
pub struct Pattern {
    kind: Kind,
    base: Vec<u8>,
}

impl Pattern {
    /// The pattern of `kind`'s messages.
    pub fn new(kind: Kind) -> Pattern {
        let base = (0..kind.size() + 251).map(|i| (i % 251) as u8).collect();
        Pattern { kind, base }
    }

    /// Message `k`'s data.
    pub fn of(&self, k: usize) -> &[u8] {
        &self.base[k % 251..k % 251 + self.kind.size()]
    }
}

/// `sensor_msgs/PointField` by field name.
#[derive(Serialize, Deserialize, Debug, Clone, PartialEq)]
pub struct PointField {
    pub name: String,
    pub offset: u32,
    pub datatype: u8,
    pub count: u32,
}

/// The cloud's fields: x, y, z, intensity, float32 (`PointField.FLOAT32` = 7).
pub fn point_fields() -> Vec<PointField> {
    ["x", "y", "z", "intensity"]
        .iter()
        .enumerate()
        .map(|(i, name)| PointField {
            name: name.to_string(),
            offset: 4 * i as u32,
            datatype: 7,
            count: 1,
        })
        .collect()
}

/// What a run measured at the reading end.
#[derive(Debug)]
pub struct Figures {
    /// Messages that arrived, and of those, how many had every byte right.
    pub arrived: usize,
    /// Arrived with every byte right.
    pub intact: usize,
    /// Messages per second between the first and last arrival.
    pub rate_hz: f64,
    /// Latency (send stamp to arrival), median and largest.
    pub latency_p50: Duration,
    /// Largest latency.
    pub latency_max: Duration,
}

impl Figures {
    /// From each arrival's (intact, latency, arrival time in seconds on any one clock).
    pub fn of(arrivals: &[(bool, Duration, f64)]) -> Figures {
        let mut latencies: Vec<Duration> = arrivals.iter().map(|a| a.1).collect();
        latencies.sort();
        let first = arrivals.iter().map(|a| a.2).fold(f64::INFINITY, f64::min);
        let last = arrivals
            .iter()
            .map(|a| a.2)
            .fold(f64::NEG_INFINITY, f64::max);
        let rate_hz = match arrivals.len() {
            0 | 1 => 0.0,
            n => (n - 1) as f64 / (last - first),
        };
        Figures {
            arrived: arrivals.len(),
            intact: arrivals.iter().filter(|a| a.0).count(),
            rate_hz,
            latency_p50: latencies
                .get(latencies.len() / 2)
                .copied()
                .unwrap_or_default(),
            latency_max: latencies.last().copied().unwrap_or_default(),
        }
    }

    /// Parses the reader's lines `K ok|bad LATENCY_MS ARRIVAL_S` (others are skipped).
    pub fn of_lines(lines: &[String]) -> Figures {
        let arrivals: Vec<(bool, Duration, f64)> = lines
            .iter()
            .filter_map(|line| {
                let parts: Vec<&str> = line.split_whitespace().collect();
                let [_, ok, latency, at] = parts[..] else {
                    return None;
                };
                let ms: f64 = latency.parse().ok()?;
                Some((
                    ok == "ok",
                    Duration::from_secs_f64(ms.max(0.0) / 1000.0),
                    at.parse().ok()?,
                ))
            })
            .collect();
        Figures::of(&arrivals)
    }

    /// One line: `WHAT: N arrived (N intact), R Hz, latency p50 X ms, max Y ms`.
    pub fn line(&self, what: &str) -> String {
        format!(
            "{what}: {} arrived ({} intact), {:.1} Hz, latency p50 {:.1} ms, max {:.1} ms",
            self.arrived,
            self.intact,
            self.rate_hz,
            self.latency_p50.as_secs_f64() * 1000.0,
            self.latency_max.as_secs_f64() * 1000.0
        )
    }
}

/// Messages a test sends each way: `HETCOMM_LARGE_COUNT` (the benchmark's longer runs), else
/// 60 (two seconds at 30 Hz).
pub fn count() -> usize {
    std::env::var("HETCOMM_LARGE_COUNT")
        .ok()
        .and_then(|n| n.parse().ok())
        .unwrap_or(60)
}

/// Seconds of the wall clock since the UNIX epoch (what the ROS stamps and the Python node's
/// arrival times are on).
pub fn wall_secs() -> f64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap_or_default()
        .as_secs_f64()
}

/// One stream at a time: the tests measure rates, which parallel streams would share.
pub static ONE_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// The foreign node (`large_node.py`), killed when dropped, and its stdout's lines.
pub struct Node {
    child: Child,
    lines: mpsc::Receiver<String>,
}

impl Drop for Node {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Node {
    /// Runs `cmd` with its stdout read line by line.
    pub fn start(mut cmd: Command) -> Node {
        let mut child = cmd
            .env("PYTHONUNBUFFERED", "1")
            .stdout(Stdio::piped())
            .spawn()
            .expect("start the large-message node");
        let out = BufReader::new(child.stdout.take().expect("stdout"));
        let (tx, lines) = mpsc::channel();
        std::thread::spawn(move || {
            for line in out.lines().map_while(Result::ok) {
                if tx.send(line).is_err() {
                    return;
                }
            }
        });
        Node { child, lines }
    }

    /// Lines until one equals `last` (included) or the node exits, at most `within`.
    pub fn lines_until(&self, last: &str, within: Duration) -> Vec<String> {
        let until = Instant::now() + within;
        let mut lines = Vec::new();
        while let Ok(line) = self
            .lines
            .recv_timeout(until.saturating_duration_since(Instant::now()))
        {
            let end = line == last;
            lines.push(line);
            if end {
                break;
            }
        }
        lines
    }
}

/// Sends `count` messages made by `make` to (Tango, Drive) at 30 Hz, each of which must end
/// Sent. The grid starts when the first send returns (it waits until the bridge matched the
/// reader, 250 ms or more): a grid started before it would make the next messages leave
/// back to back, megabytes at once, which is not a 30 Hz stream. On the grid from there, a
/// late message does not delay the rest.
pub fn send_at_30_hz<M: Message>(drive: &Module, count: usize, make: impl Fn(usize) -> M) {
    let mut start = Instant::now();
    for k in 0..count {
        let due = start + Duration::from_secs_f64(k as f64 / RATE_HZ);
        std::thread::sleep(due.saturating_duration_since(Instant::now()));
        let outcome = drive.send("Tango", "Drive", &make(k)).expect("send").wait();
        assert!(
            matches!(outcome, Outcome::Sent { .. }),
            "message {k}: {outcome:?}"
        );
        if k == 0 {
            start = Instant::now();
        }
    }
}

/// Checks what the reading node printed: every message arrived with every byte right, and the
/// stream kept up (see [`assert_rate`]). Prints the figures.
pub fn check_read(lines: &[String], count: usize, what: &str) {
    let figures = Figures::of_lines(lines);
    println!("{}", figures.line(what));
    assert_eq!(
        (figures.arrived, figures.intact),
        (count, count),
        "what the node read: {lines:?}"
    );
    assert_eq!(lines.last().map(String::as_str), Some("done"));
    assert_rate(&figures);
}

/// The stream kept up: at least a third of the 30 Hz sent. Whether 30 Hz itself is kept is a
/// speed figure, measured on a quiet machine by `benchmarks/ros-large.sh` beside the peers
/// alone, not asserted here (a CI machine running other work meanwhile would fail it, as the
/// peers alone do under load); a bridge that stalls (a sample resent whole, nothing arriving)
/// falls far below this floor.
pub fn assert_rate(figures: &Figures) {
    assert!(
        figures.rate_hz >= RATE_HZ / 3.0,
        "the stream did not keep up (less than a third of 30 Hz): {figures:?}"
    );
}

/// A ROS version's `std_msgs/Header` (ROS 1 has `seq` and `time`, ROS 2
/// `builtin_interfaces/Time`), which is all the two versions' messages differ in.
pub trait Stamp: Serialize + DeserializeOwned + Send + std::fmt::Debug + 'static {
    /// The header of message `k`: its frame id is `k`, its stamp the wall clock now.
    fn for_message(k: usize) -> Self;
    /// The frame id.
    fn frame_id(&self) -> &str;
    /// The stamp, in seconds since the Unix epoch.
    fn secs(&self) -> f64;
}

/// `sensor_msgs/Image` by field name; the pixels as bytes (one copy each way).
#[derive(Serialize, Deserialize, Message, Debug)]
#[message(id = 60)]
#[serde(bound = "H: Stamp")]
pub struct Image<H: Stamp> {
    pub header: H,
    pub height: u32,
    pub width: u32,
    pub encoding: String,
    pub is_bigendian: u8,
    pub step: u32,
    #[serde(with = "serde_bytes")]
    pub data: Vec<u8>,
}

/// `sensor_msgs/PointCloud2` by field name.
#[derive(Serialize, Deserialize, Message, Debug)]
#[message(id = 61)]
#[serde(bound = "H: Stamp")]
pub struct PointCloud2<H: Stamp> {
    pub header: H,
    pub height: u32,
    pub width: u32,
    pub fields: Vec<PointField>,
    pub is_bigendian: bool,
    pub point_step: u32,
    pub row_step: u32,
    #[serde(with = "serde_bytes")]
    pub data: Vec<u8>,
    pub is_dense: bool,
}

/// Sends `count` messages of `kind` (message `k` carrying `pattern.of(k)`) at 30 Hz.
pub fn send_kind<H: Stamp>(drive: &Module, kind: Kind, count: usize) {
    let pattern = Pattern::new(kind);
    match kind {
        Kind::Image => send_at_30_hz(drive, count, |k| Image {
            header: H::for_message(k),
            height: HEIGHT,
            width: WIDTH,
            encoding: "rgb8".into(),
            is_bigendian: 0,
            step: WIDTH * 3,
            data: pattern.of(k).to_vec(),
        }),
        Kind::Cloud => send_at_30_hz(drive, count, |k| PointCloud2 {
            header: H::for_message(k),
            height: 1,
            width: POINTS,
            fields: point_fields(),
            is_bigendian: false,
            point_step: POINT_STEP,
            row_step: POINT_STEP * POINTS,
            data: pattern.of(k).to_vec(),
            is_dense: true,
        }),
    }
}

/// Receives `count` messages of `kind` from `peer` in `world`, which must come in order;
/// each as (every field and byte as sent, latency from its stamp, arrival in s).
pub fn receive_in_order<H: Stamp>(
    world: &Module,
    kind: Kind,
    count: usize,
    peer: &str,
) -> Vec<(bool, Duration, f64)> {
    let pattern = Pattern::new(kind);
    let mut arrivals = Vec::new();
    for _ in 0..count {
        let within = Duration::from_secs(30);
        let (header, intact, at) = match kind {
            Kind::Image => {
                let got = world
                    .recv_timeout::<Image<H>>(within)
                    .unwrap_or_else(|e| panic!("an Image from {peer}: {e:?}"));
                let m = got.message;
                let k: usize = m.header.frame_id().parse().expect("K");
                let intact = m.data == pattern.of(k)
                    && (m.width, m.height, m.step, m.encoding.as_str())
                        == (WIDTH, HEIGHT, WIDTH * 3, "rgb8");
                (m.header, intact, got.envelope.received_at)
            }
            Kind::Cloud => {
                let got = world
                    .recv_timeout::<PointCloud2<H>>(within)
                    .unwrap_or_else(|e| panic!("a PointCloud2 from {peer}: {e:?}"));
                let m = got.message;
                let k: usize = m.header.frame_id().parse().expect("K");
                let intact = m.data == pattern.of(k)
                    && m.fields == point_fields()
                    && (m.width, m.point_step, m.is_dense) == (POINTS, POINT_STEP, true);
                (m.header, intact, got.envelope.received_at)
            }
        };
        let k: usize = header.frame_id().parse().expect("K");
        assert_eq!(k, arrivals.len(), "messages arrive in order, none lost");
        let at = at.as_micros() as f64 / 1e6;
        let latency = Duration::from_secs_f64((at - header.secs()).max(0.0));
        arrivals.push((intact, latency, at));
    }
    arrivals
}

/// `large_node.py`'s arguments: `verb` (`read` or `publish`) `count` messages of `kind` on
/// `topic`.
pub fn node_args(verb: &str, topic: &str, kind: Kind, count: usize) -> Vec<String> {
    let args = [verb, "--topic", topic, "--type", kind.arg(), "--count"];
    let mut args: Vec<String> = args.iter().map(|a| a.to_string()).collect();
    args.push(count.to_string());
    args
}

/// Checks a stream `system` received from `node`: every byte of every message, the node said
/// it sent them all, the stream kept up, and the system dropped nothing. Prints the figures
/// as `what`.
pub fn check_received(
    arrivals: &[(bool, Duration, f64)],
    count: usize,
    what: &str,
    node: &Node,
    system: &hetcomm::Comm,
) {
    let stats = system.stats();
    let dropped: u64 = stats.links.iter().map(|(_, l)| l.frames_dropped).sum();
    let figures = Figures::of(arrivals);
    println!("{}", figures.line(what));
    assert_eq!(figures.intact, count, "every byte of every message");
    let sent = node.lines_until("", Duration::from_secs(10));
    let prefix = format!("sent {count} ");
    assert!(
        sent.first().is_some_and(|l| l.starts_with(&prefix)),
        "{sent:?}"
    );
    assert_rate(&figures);
    assert_eq!(dropped, 0, "frames dropped by the system: {stats:?}");
}
