//! External programs measured beside hetcomm: Zenoh (the peer binary built from
//! `benchmarks/zenoh-peer`), Cyclone DDS (`ddsperf` from Debian's `cyclonedds-tools`), and
//! hetcomm's C++ API (`examples/cpp/pingpong.cpp`, two C++ processes).

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Duration;

use crate::child::Peer;
use crate::raw::TempDir;
use crate::stats::{parse_sink_line, Latency, Recorder, Throughput};

/// Where the Zenoh peer is looked for without `--zenoh-bin`: the release build of
/// `benchmarks/zenoh-peer` (only with the `zenoh` feature).
pub fn default_zenoh_bin() -> Option<PathBuf> {
    if cfg!(feature = "zenoh") {
        let p = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../benchmarks/zenoh-peer/target/release/hetcomm-zenoh-peer");
        p.exists().then_some(p)
    } else {
        None
    }
}

fn free_tcp_port() -> Result<u16, String> {
    std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map(|a| a.port())
        .map_err(|e| e.to_string())
}

/// Ping/pong between two processes of a peer program (`benchmarks/zenoh-peer`,
/// `benchmarks/iceoryx2-peer`): `pong ARGS…` until it prints `ready`, then `ping ARGS… --size
/// --iters --warmup [PING_EXTRA…]`, which prints `rtt_ns` and then each round trip in
/// nanoseconds; this process builds the histogram.
pub fn peer_rtt(
    bin: &Path,
    pong_args: &[String],
    ping_args: &[String],
    (size, warmup, iters): (usize, u64, u64),
) -> Result<Latency, String> {
    let mut pong_cmd = vec!["pong".to_string()];
    pong_cmd.extend_from_slice(pong_args);
    let pong = Peer::spawn(Some(bin), &pong_cmd)?;
    pong.expect("ready", Duration::from_secs(20))?;
    let mut ping_cmd = vec!["ping".to_string()];
    ping_cmd.extend_from_slice(ping_args);
    ping_cmd.extend([
        "--size".into(),
        size.to_string(),
        "--iters".into(),
        iters.to_string(),
        "--warmup".into(),
        warmup.to_string(),
    ]);
    let ping = Peer::spawn(Some(bin), &ping_cmd)?;
    ping.expect("rtt_ns", Duration::from_secs(60))?;
    let mut rec = Recorder::new();
    for _ in 0..iters {
        let l = ping.line(Duration::from_secs(60))?;
        if let Ok(ns) = l.trim().parse::<u64>() {
            rec.record_ns(ns);
        }
    }
    ping.finish(Duration::from_secs(5));
    pong.finish(Duration::from_secs(5));
    Ok(rec.summary())
}

/// One-way between two processes of a peer program: `sink ARGS…` until it prints `ready`,
/// then `source ARGS… --size --millis`, which publishes for `duration` and prints `sent` and
/// its count; the sink's line is the figure (`what` names the peer in errors).
pub fn peer_oneway(
    bin: &Path,
    what: &str,
    sink_args: &[String],
    source_args: &[String],
    (size, duration): (usize, Duration),
) -> Result<Throughput, String> {
    let mut sink_cmd = vec!["sink".to_string()];
    sink_cmd.extend_from_slice(sink_args);
    let sink = Peer::spawn(Some(bin), &sink_cmd)?;
    sink.expect("ready", Duration::from_secs(20))?;
    let mut source_cmd = vec!["source".to_string()];
    source_cmd.extend_from_slice(source_args);
    source_cmd.extend([
        "--size".into(),
        size.to_string(),
        "--millis".into(),
        duration.as_millis().to_string(),
    ]);
    let source = Peer::spawn(Some(bin), &source_cmd)?;
    let sent = source
        .expect("sent", duration + Duration::from_secs(60))?
        .parse::<u64>()
        .unwrap_or(0);
    let line = sink.line(Duration::from_secs(30))?;
    source.finish(Duration::from_secs(5));
    sink.finish(Duration::from_secs(5));
    parse_sink_line(&line, sent).ok_or(format!("bad {what} sink line {line:?}"))
}

/// Zenoh ping/pong between two processes (the peer listens, the pinger connects).
pub fn zenoh_rtt(bin: &Path, size: usize, warmup: u64, iters: u64) -> Result<Latency, String> {
    let ep = format!("tcp/127.0.0.1:{}", free_tcp_port()?);
    let pong = ["--listen".to_string(), ep.clone()];
    peer_rtt(bin, &pong, &["--connect".into(), ep], (size, warmup, iters))
}

/// Zenoh one-way: a source process publishes for `duration`, a sink process counts.
pub fn zenoh_oneway(bin: &Path, size: usize, duration: Duration) -> Result<Throughput, String> {
    let ep = format!("tcp/127.0.0.1:{}", free_tcp_port()?);
    let sink = ["--listen".to_string(), ep.clone()];
    peer_oneway(
        bin,
        "zenoh",
        &sink,
        &["--connect".into(), ep],
        (size, duration),
    )
}

/// Whether `ddsperf` is on the PATH.
pub fn ddsperf_available() -> bool {
    Command::new("ddsperf")
        .arg("help")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok()
}

fn cyclone_config(dir: &TempDir) -> Result<String, String> {
    let path = dir.0.join("cyclonedds.xml");
    std::fs::write(
        &path,
        r#"<CycloneDDS><Domain id="any"><General><Interfaces><NetworkInterface name="lo"/></Interfaces><AllowMulticast>false</AllowMulticast></General><Discovery><ParticipantIndex>auto</ParticipantIndex><Peers><Peer address="127.0.0.1"/></Peers></Discovery></Domain></CycloneDDS>"#,
    )
    .map_err(|e| e.to_string())?;
    Ok(format!("file://{}", path.display()))
}

fn run_pair(
    uri: &str,
    server: &[&str],
    client: &[&str],
    seconds: f64,
) -> Result<(String, String), String> {
    let dur = format!("{seconds}");
    let mut s = Command::new("ddsperf")
        .env("CYCLONEDDS_URI", uri)
        .args(["-D", &format!("{}", seconds + 1.5)])
        .args(server)
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .map_err(|e| format!("ddsperf: {e}"))?;
    std::thread::sleep(Duration::from_millis(300));
    let c = Command::new("ddsperf")
        .env("CYCLONEDDS_URI", uri)
        .args(["-D", &dur])
        .args(client)
        .stderr(Stdio::null())
        .output()
        .map_err(|e| format!("ddsperf: {e}"))?;
    let _ = s.kill();
    let out = s.wait_with_output().map_err(|e| e.to_string())?;
    Ok((
        String::from_utf8_lossy(&c.stdout).into_owned(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
    ))
}

fn field(line: &str, key: &str) -> Option<f64> {
    let mut it = line.split_whitespace();
    while let Some(w) = it.next() {
        if w == key {
            return it.next()?.trim_end_matches("us").parse().ok();
        }
    }
    None
}

/// Cyclone DDS round trip: `ddsperf ping` against `ddsperf pong` (reliable, unicast peer on
/// 127.0.0.1). ddsperf prints one-way latency (half the round trip) per second: the last
/// full second's percentiles, doubled. No p99.9 is printed (reported as 0).
pub fn ddsperf_rtt(size: usize, seconds: f64) -> Result<Latency, String> {
    let dir = TempDir::new()?;
    let uri = cyclone_config(&dir)?;
    let sz = size.to_string();
    let (ping, _) = run_pair(&uri, &["pong"], &["ping", "size", &sz], seconds)?;
    let line = ping
        .lines()
        .rev()
        .find(|l| l.contains(" 50% ") && l.contains(" cnt "))
        .ok_or("ddsperf printed no latency line")?;
    let g = |k| field(line, k).map(|v| v * 2.0).unwrap_or(0.0);
    Ok(Latency {
        count: field(line, "cnt").unwrap_or(0.0) as u64,
        p50: g("50%"),
        p90: g("90%"),
        p99: g("99%"),
        p999: 0.0,
        max: g("max"),
        lost: 0,
    })
}

/// Cyclone DDS one-way: `ddsperf pub size S` (as fast as possible) into `ddsperf sub`; the
/// median of the subscriber's per-second rates.
pub fn ddsperf_oneway(size: usize, seconds: f64) -> Result<Throughput, String> {
    let dir = TempDir::new()?;
    let uri = cyclone_config(&dir)?;
    let sz = size.to_string();
    let (_, sub) = run_pair(&uri, &["sub"], &["pub", "size", &sz], seconds)?;
    let mut rates: Vec<f64> = sub
        .lines()
        .filter(|l| l.contains(" rate ") && l.contains("kS/s"))
        .filter_map(|l| field(l, "rate"))
        .filter(|r| *r > 0.0)
        .collect();
    if rates.is_empty() {
        return Err("ddsperf sub printed no rate".into());
    }
    rates.sort_by(|a, b| a.total_cmp(b));
    let ks = rates[rates.len() / 2];
    let msgs = ks * 1000.0;
    Ok(Throughput {
        sent: 0,
        received: msgs as u64,
        bytes: (msgs * size as f64) as u64,
        seconds: 1.0,
        ..Throughput::default()
    })
}

/// Round trips between two C++ processes (`examples/cpp/pingpong.cpp` built against
/// libhetcomm_c): the same fleet (systems A and B over acknowledged `udp`), payload and
/// counts as the Rust `hetcomm-udp-ack` row; the pinging process reports each round trip.
pub fn cpp_rtt(bin: &Path, size: usize, warmup: u64, iters: u64) -> Result<Latency, String> {
    let dir = TempDir::new()?;
    let path = dir.0.join("fleet.toml");
    let ports = crate::hc::free_port_pair(crate::hc::Kind::Udp)?;
    let text = crate::hc::fleet_text(crate::hc::Kind::Udp, true, Some(ports));
    std::fs::write(&path, text).map_err(|e| format!("{}: {e}", path.display()))?;
    let fleet = path.display().to_string();
    let echo = Peer::spawn(Some(bin), &["echo".into(), fleet.clone()])?;
    echo.expect("ready", Duration::from_secs(20))?;
    let ping = Peer::spawn(
        Some(bin),
        &[
            "ping".into(),
            fleet,
            "--size".into(),
            size.to_string(),
            "--warmup".into(),
            warmup.to_string(),
            "--iters".into(),
            iters.to_string(),
        ],
    )?;
    ping.expect("rtt_ns", Duration::from_secs(120))?;
    let mut rec = Recorder::new();
    for _ in 0..iters {
        let l = ping.line(Duration::from_secs(30))?;
        if let Ok(ns) = l.trim().parse::<u64>() {
            rec.record_ns(ns);
        }
    }
    ping.finish(Duration::from_secs(5));
    echo.finish(Duration::from_secs(5));
    Ok(rec.summary())
}
