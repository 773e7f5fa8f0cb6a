//! The measurement code every path shares: latency histograms and throughput counts.

use std::time::{Duration, Instant};

use hdrhistogram::Histogram;

/// Latency percentiles of one run, in microseconds.
#[derive(Clone, Debug, Default)]
pub struct Latency {
    /// Samples recorded.
    pub count: u64,
    /// Median.
    pub p50: f64,
    /// 90th percentile.
    pub p90: f64,
    /// 99th percentile.
    pub p99: f64,
    /// 99.9th percentile.
    pub p999: f64,
    /// Largest sample.
    pub max: f64,
    /// Samples lost (no answer within the timeout).
    pub lost: u64,
}

/// Records nanosecond samples and summarizes them.
pub struct Recorder {
    hist: Histogram<u64>,
    lost: u64,
}

impl Default for Recorder {
    fn default() -> Self {
        Self::new()
    }
}

impl Recorder {
    /// An empty recorder (1 ns to 100 s, 3 significant digits).
    pub fn new() -> Self {
        let hist = Histogram::new_with_bounds(1, 100_000_000_000, 3)
            .unwrap_or_else(|_| Histogram::new(3).unwrap_or_else(|_| unreachable_hist()));
        Recorder { hist, lost: 0 }
    }

    /// Adds one sample in nanoseconds (clamped into the histogram's range).
    pub fn record_ns(&mut self, ns: u64) {
        let v = ns.clamp(1, 100_000_000_000);
        let _ = self.hist.record(v);
    }

    /// Adds one sample.
    pub fn record(&mut self, d: Duration) {
        self.record_ns(d.as_nanos().min(u64::MAX as u128) as u64);
    }

    /// Counts a sample that never came back.
    pub fn lost(&mut self) {
        self.lost += 1;
    }

    /// The percentiles, in microseconds.
    pub fn summary(&self) -> Latency {
        let q = |x: f64| self.hist.value_at_quantile(x) as f64 / 1000.0;
        Latency {
            count: self.hist.len(),
            p50: q(0.5),
            p90: q(0.9),
            p99: q(0.99),
            p999: q(0.999),
            max: self.hist.max() as f64 / 1000.0,
            lost: self.lost,
        }
    }
}

fn unreachable_hist() -> Histogram<u64> {
    // `Histogram::new(3)` cannot fail for 3 significant digits; this keeps the code panic-free
    // in form as well: a histogram with 2 digits is the fallback of the fallback.
    Histogram::new(2).unwrap_or_else(|_| std::process::exit(3))
}

/// One-way throughput counted at the receiver.
#[derive(Clone, Debug, Default)]
pub struct Throughput {
    /// Messages the sender handed to its transport.
    pub sent: u64,
    /// Messages the receiver got.
    pub received: u64,
    /// Payload bytes the receiver got.
    pub bytes: u64,
    /// From the first to the last message at the receiver, seconds.
    pub seconds: f64,
    /// Acknowledged hetcomm paths: how the sender's accepted sends ended.
    pub outcomes: Option<Outcomes>,
    /// hetcomm paths: datagrams the receiving system's kernel dropped at its sockets (the
    /// links' `kernel_drops`; 0 on TCP).
    pub kernel_drops: Option<u64>,
}

/// How a sender's acknowledged sends ended, counted by its router over one run: delivered,
/// unconfirmed (no acknowledgement: may or may not have arrived) or failed (certainly not
/// delivered); `pending` had no outcome yet when the benchmark stopped waiting.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Outcomes {
    /// Ended delivered (in the receiving module's inbox).
    pub delivered: u64,
    /// Ended unconfirmed.
    pub unconfirmed: u64,
    /// Ended failed.
    pub failed: u64,
    /// No outcome yet.
    pub pending: u64,
}

impl Outcomes {
    /// `delivered/unconfirmed/failed`, and `+N pending` when some had none yet.
    pub fn cell(&self) -> String {
        let mut s = format!("{}/{}/{}", self.delivered, self.unconfirmed, self.failed);
        if self.pending > 0 {
            s.push_str(&format!(" +{} pending", self.pending));
        }
        s
    }
}

impl Throughput {
    /// Messages per second at the receiver.
    pub fn msgs_per_s(&self) -> f64 {
        if self.seconds > 0.0 {
            self.received as f64 / self.seconds
        } else {
            0.0
        }
    }

    /// Payload bytes per second at the receiver.
    pub fn bytes_per_s(&self) -> f64 {
        if self.seconds > 0.0 {
            self.bytes as f64 / self.seconds
        } else {
            0.0
        }
    }

    /// Share of sent messages that never arrived, percent (0 when unknown).
    pub fn lost_percent(&self) -> f64 {
        if self.sent > 0 && self.sent >= self.received {
            100.0 * (self.sent - self.received) as f64 / self.sent as f64
        } else {
            0.0
        }
    }
}

/// Counts messages at a receiver: first-to-last arrival time, messages, bytes.
#[derive(Default)]
pub struct SinkCounter {
    first: Option<Instant>,
    last: Option<Instant>,
    /// Messages counted.
    pub count: u64,
    /// Bytes counted.
    pub bytes: u64,
}

impl SinkCounter {
    /// Counts one message of `len` bytes arriving now.
    pub fn add(&mut self, len: usize) {
        let now = Instant::now();
        self.first.get_or_insert(now);
        self.last = Some(now);
        self.count += 1;
        self.bytes += len as u64;
    }

    /// Counts `n` messages of `len` bytes in all, taken together now (a batch): one clock
    /// reading for all of them. Nothing if `n` is 0.
    pub fn add_many(&mut self, n: u64, len: usize) {
        if n == 0 {
            return;
        }
        let now = Instant::now();
        self.first.get_or_insert(now);
        self.last = Some(now);
        self.count += n;
        self.bytes += len as u64;
    }

    /// Nanoseconds from the first to the last message.
    pub fn elapsed_ns(&self) -> u128 {
        match (self.first, self.last) {
            (Some(a), Some(b)) => b.duration_since(a).as_nanos(),
            _ => 0,
        }
    }

    /// The line a sink prints: `result COUNT BYTES ELAPSED_NS` (hetcomm sinks add
    /// `kernel_drops=N`).
    pub fn line(&self) -> String {
        format!("result {} {} {}", self.count, self.bytes, self.elapsed_ns())
    }
}

/// Parses a `COUNT BYTES ELAPSED_NS` triple (optionally after a `result` word), and a
/// `kernel_drops=N` after it if there is one.
pub fn parse_sink_line(line: &str, sent: u64) -> Option<Throughput> {
    let mut it = line.split_whitespace().filter(|w| *w != "result");
    let count = it.next()?.parse::<u64>().ok()?;
    let bytes = it.next()?.parse::<u64>().ok()?;
    let ns = it.next()?.parse::<u128>().ok()?;
    let kernel_drops = it
        .find_map(|w| w.strip_prefix("kernel_drops="))
        .and_then(|n| n.parse().ok());
    Some(Throughput {
        sent,
        received: count,
        bytes,
        seconds: ns as f64 / 1e9,
        outcomes: None,
        kernel_drops,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentiles_and_parse() {
        let mut r = Recorder::new();
        for i in 1..=1000u64 {
            r.record_ns(i * 1000);
        }
        let s = r.summary();
        assert_eq!(s.count, 1000);
        assert!((s.p50 - 500.0).abs() < 2.0, "{}", s.p50);
        let t = parse_sink_line("result 10 640 1000000000", 20).unwrap();
        assert_eq!(t.msgs_per_s(), 10.0);
        assert_eq!(t.lost_percent(), 50.0);
        assert!(parse_sink_line("garbage", 0).is_none());
        assert_eq!(t.kernel_drops, None);
        let t = parse_sink_line("result 10 640 1000000000 kernel_drops=7", 20).unwrap();
        assert_eq!((t.received, t.kernel_drops), (10, Some(7)));
        let o = Outcomes {
            delivered: 9,
            unconfirmed: 1,
            failed: 0,
            pending: 0,
        };
        assert_eq!(o.cell(), "9/1/0");
        assert_eq!(Outcomes { pending: 2, ..o }.cell(), "9/1/0 +2 pending");
    }
}
