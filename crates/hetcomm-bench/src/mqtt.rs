//! The `mqtt` transport (feature `mqtt`) beside a raw rumqttc client, through one mosquitto
//! this module starts on a free port of 127.0.0.1 (`set_tcp_nodelay true`, no persistence)
//! for the run and stops at its end ([`Broker`]).
//!
//! Both paths run their two ends in this process (the broker is its own process): systems A
//! and B opened on one unsecured `mqtt` transport at QoS 0 (`security = "none"`, since the raw
//! client seals nothing), B's module echoing on a thread of its own waiting in `recv` (or, in
//! [`UNACK_INLINE`], from an inline callback on its link's event-loop thread); and two
//! rumqttc v5 clients, B echoing from its event loop (what a plain rumqttc program does) or, in
//! [`RAW_THREAD`], from a thread of its own handed each publish (the structure of a module
//! waiting in `recv`), A's event loop handing each reply to the measuring thread. QoS 0 on both.

use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{mpsc, Arc, Mutex};
use std::time::{Duration, Instant};

use hetcomm::Comm;
use rumqttc::v5::mqttbytes::v5::Packet;
use rumqttc::v5::mqttbytes::QoS;
use rumqttc::v5::{Client, Event, MqttOptions};

use crate::child::DATA;
use crate::stats::{Latency, Recorder, Throughput};

/// Our rows: the `mqtt` transport unacknowledged and acknowledged.
pub const UNACK: &str = "hetcomm-mqtt-unack";
/// The acknowledged row (end-to-end acknowledgements through the broker).
pub const ACK: &str = "hetcomm-mqtt-ack";
/// Unacknowledged, B echoing from an inline callback on its link's event-loop thread
/// ([`hetcomm::Module::set_inline_callbacks`]): the raw client's structure.
pub const UNACK_INLINE: &str = "hetcomm-mqtt-unack-inline";
/// The raw rumqttc client's row.
pub const RAW: &str = "raw-mqtt-rumqttc";
/// The raw clients with B echoing from a thread of its own, handed each publish by its event
/// loop through a channel: the structure of [`UNACK`] (a module waiting in `recv`).
pub const RAW_THREAD: &str = "raw-mqtt-rumqttc-thread";
/// The round-trip rows.
pub const RTT_ROWS: [&str; 5] = [RAW, RAW_THREAD, UNACK, UNACK_INLINE, ACK];
/// The one-way rows: unacknowledged only, as the raw client's QoS 0 publishes are.
pub const ONEWAY_ROWS: [&str; 2] = [RAW, UNACK];
/// The sizes the rows run at.
pub const SIZES: [usize; 2] = [64, 64 * 1024];

/// A mosquitto of this run, killed when dropped.
pub struct Broker {
    child: Child,
    /// `127.0.0.1:PORT`.
    pub address: String,
    dir: std::path::PathBuf,
}

impl Broker {
    /// Starts mosquitto (Debian's, from `bash scripts/install.sh apt`) on a free port.
    pub fn start() -> Result<Broker, String> {
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .and_then(|l| l.local_addr())
            .map(|a| a.port())
            .map_err(|e| format!("no free port: {e}"))?;
        let dir = std::env::temp_dir().join(format!("hetcomm-bench-mqtt-{}", std::process::id()));
        std::fs::create_dir_all(&dir).map_err(|e| e.to_string())?;
        let conf = dir.join("mosquitto.conf");
        std::fs::write(
            &conf,
            format!(
                "listener {port} 127.0.0.1\nallow_anonymous true\npersistence false\nset_tcp_nodelay true\n"
            ),
        )
        .map_err(|e| e.to_string())?;
        let bin = ["/usr/sbin/mosquitto", "/usr/bin/mosquitto"]
            .into_iter()
            .find(|p| std::path::Path::new(p).exists())
            .unwrap_or("mosquitto");
        let child = Command::new(bin)
            .arg("-c")
            .arg(&conf)
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .map_err(|e| format!("cannot start mosquitto ({e}): bash scripts/install.sh apt"))?;
        let mut b = Broker {
            child,
            address: format!("127.0.0.1:{port}"),
            dir,
        };
        let deadline = Instant::now() + Duration::from_secs(10);
        while std::net::TcpStream::connect(&b.address).is_err() {
            if let Ok(Some(status)) = b.child.try_wait() {
                return Err(format!("mosquitto exited: {status}"));
            }
            if Instant::now() > deadline {
                return Err("mosquitto did not listen within 10 s".into());
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        Ok(b)
    }
}

impl Drop for Broker {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

/// A fleet level no other run on this broker uses.
fn level() -> String {
    static N: AtomicU64 = AtomicU64::new(0);
    format!(
        "bench-{}-{}",
        std::process::id(),
        N.fetch_add(1, Ordering::Relaxed)
    )
}

fn fleet_text(broker: &str, acked: bool) -> String {
    format!(
        r#"[systems]
A = 0
B = 1
[modules]
M = 0
[inbox]
capacity = 65536
overflow = "block"
block_timeout_ms = 1000
[transports.m]
kind = "mqtt"
broker = "{broker}"
fleet = "{}"
qos = 0
delivery = "{}"
security = "none"
[table]
columns = ["A", "B"]
A = ["X", "m"]
B = ["m", "X"]
"#,
        level(),
        if acked {
            "acknowledged"
        } else {
            "unacknowledged"
        }
    )
}

/// Systems A and B on one `mqtt` transport through `broker`.
fn open_pair(broker: &str, acked: bool) -> Result<(Comm, Comm), String> {
    let text = fleet_text(broker, acked);
    let fleet = hetcomm::parse_fleet(&text, "bench-mqtt.toml", None).map_err(|e| e.to_string())?;
    let b = Comm::open_fleet(&fleet, "B").map_err(|e| e.to_string())?;
    let a = Comm::open_fleet(&fleet, "A").map_err(|e| e.to_string())?;
    Ok((a, b))
}

/// Ping-pong round trips over the `mqtt` transport, B echoing from an inline callback on
/// its link's thread ([`UNACK_INLINE`]).
pub fn rtt_inline(broker: &str, size: usize, warmup: u64, iters: u64) -> Result<Latency, String> {
    let (a, b) = open_pair(broker, false)?;
    let ma = a.module("M").map_err(|e| e.to_string())?;
    let mb = b.module("M").map_err(|e| e.to_string())?;
    let sender = b.module("M").map_err(|e| e.to_string())?;
    mb.set_inline_callbacks(true);
    mb.on_any(move |msg| {
        let _ = sender.send_raw("A", "M", DATA, &msg.payload, Default::default());
    });
    crate::hc::round_trips(&ma, size, warmup, iters)
}

/// Ping-pong round trips over the `mqtt` transport, B echoing on a thread waiting in `recv`.
pub fn rtt(
    broker: &str,
    acked: bool,
    size: usize,
    warmup: u64,
    iters: u64,
) -> Result<Latency, String> {
    let (a, b) = open_pair(broker, acked)?;
    let (ma, mb) = (
        a.module("M").map_err(|e| e.to_string())?,
        b.module("M").map_err(|e| e.to_string())?,
    );
    let stop = Arc::new(AtomicBool::new(false));
    let echo = {
        let stop = stop.clone();
        std::thread::spawn(move || {
            while !stop.load(Ordering::Relaxed) {
                if let Ok(m) = mb.recv_raw_timeout(Some(Duration::from_millis(20))) {
                    let _ = mb.send_raw("A", "M", DATA, &m.payload, Default::default());
                }
            }
        })
    };
    let r = crate::hc::round_trips(&ma, size, warmup, iters);
    stop.store(true, Ordering::Relaxed);
    let _ = echo.join();
    r
}

/// One-way over the `mqtt` transport, unacknowledged: A sends as fast as `send_raw` returns
/// for `duration`, B counts what arrives on a thread.
pub fn oneway(broker: &str, size: usize, duration: Duration) -> Result<Throughput, String> {
    let (a, b) = open_pair(broker, false)?;
    let (ma, mb) = (
        a.module("M").map_err(|e| e.to_string())?,
        b.module("M").map_err(|e| e.to_string())?,
    );
    let done = Arc::new(AtomicBool::new(false));
    let counter = {
        let done = done.clone();
        std::thread::spawn(move || {
            let mut batch = Vec::new();
            let mut count = Counted::default();
            loop {
                batch.clear();
                let _ = mb.recv_raw_many(&mut batch, 256, Some(Duration::from_millis(300)));
                if batch.is_empty() && done.load(Ordering::Relaxed) {
                    return count;
                }
                for m in &batch {
                    count.add(m.payload.len());
                }
            }
        })
    };
    let msg = vec![7u8; size];
    // B's presence first, and the first frame through.
    let sent_first = ma.send_raw("B", "M", DATA, &msg, Default::default());
    let mut sent = u64::from(sent_first.is_ok());
    let end = Instant::now() + duration;
    while Instant::now() < end {
        if ma
            .send_raw("B", "M", DATA, &msg, Default::default())
            .is_ok()
        {
            sent += 1;
        }
    }
    done.store(true, Ordering::Relaxed);
    let count = counter.join().map_err(|_| "counter panicked")?;
    Ok(count.throughput(sent))
}

/// What a receiver counted.
#[derive(Default)]
struct Counted {
    first: Option<Instant>,
    last: Option<Instant>,
    n: u64,
    bytes: u64,
}

impl Counted {
    fn add(&mut self, len: usize) {
        let now = Instant::now();
        self.first.get_or_insert(now);
        self.last = Some(now);
        self.n += 1;
        self.bytes += len as u64;
    }

    fn throughput(&self, sent: u64) -> Throughput {
        let seconds = match (self.first, self.last) {
            (Some(f), Some(l)) => (l - f).as_secs_f64(),
            _ => 0.0,
        };
        Throughput {
            sent,
            received: self.n,
            bytes: self.bytes,
            seconds,
            outcomes: None,
            kernel_drops: None,
        }
    }
}

/// A raw rumqttc v5 client connected to `broker` and subscribed to `subscribe`; `on_publish`
/// runs on its event-loop thread for each publish (with the client, to answer).
struct RawEnd {
    client: Client,
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl RawEnd {
    fn connect(
        broker: &str,
        id: &str,
        subscribe: &str,
        mut on_publish: impl FnMut(&Client, &[u8]) + Send + 'static,
    ) -> Result<RawEnd, String> {
        let (host, port) = broker.rsplit_once(':').ok_or("broker is not host:port")?;
        let mut o = MqttOptions::new(id, host, port.parse::<u16>().map_err(|e| e.to_string())?);
        o.set_max_packet_size(Some(16 << 20));
        // As the `mqtt` link does: no Nagle on the client's connection.
        let mut net = rumqttc::NetworkOptions::new();
        net.set_tcp_nodelay(true);
        o.set_network_options(net);
        let (client, mut connection) = Client::new(o, 1024);
        let (ready_tx, ready_rx) = mpsc::channel();
        let stop = Arc::new(AtomicBool::new(false));
        let topic = subscribe.to_string();
        let thread = {
            let (client, stop) = (client.clone(), stop.clone());
            std::thread::spawn(move || {
                while !stop.load(Ordering::Relaxed) {
                    match connection.recv_timeout(Duration::from_millis(100)) {
                        Ok(Ok(Event::Incoming(Packet::ConnAck(_)))) => {
                            let _ = client.try_subscribe(topic.clone(), QoS::AtMostOnce);
                        }
                        Ok(Ok(Event::Incoming(Packet::SubAck(_)))) => {
                            let _ = ready_tx.send(());
                        }
                        Ok(Ok(Event::Incoming(Packet::Publish(p)))) => {
                            on_publish(&client, &p.payload)
                        }
                        Ok(Err(_)) => std::thread::sleep(Duration::from_millis(20)),
                        _ => {}
                    }
                }
            })
        };
        ready_rx
            .recv_timeout(Duration::from_secs(10))
            .map_err(|_| format!("rumqttc client {id} did not connect to {broker}"))?;
        Ok(RawEnd {
            client,
            stop,
            thread: Some(thread),
        })
    }
}

impl Drop for RawEnd {
    fn drop(&mut self) {
        let _ = self.client.try_disconnect();
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// Ping-pong round trips between two raw rumqttc clients: B echoes from its event loop, or
/// (`threaded`) from a thread of its own that the event loop hands each publish.
pub fn raw_rtt(
    broker: &str,
    threaded: bool,
    size: usize,
    warmup: u64,
    iters: u64,
) -> Result<Latency, String> {
    let base = level();
    let (to_a, to_b) = (format!("{base}/a"), format!("{base}/b"));
    let echo_to = to_a.clone();
    let (hand, handed) = mpsc::channel::<Vec<u8>>();
    let b = RawEnd::connect(broker, &format!("{base}-b"), &to_b, move |c, payload| {
        if threaded {
            let _ = hand.send(payload.to_vec());
        } else {
            let _ = c.try_publish(echo_to.clone(), QoS::AtMostOnce, false, payload.to_vec());
        }
    })?;
    // The echo thread ends when B's event loop (and with it the channel's sender) is gone.
    let echo = threaded.then(|| {
        let (client, to) = (b.client.clone(), to_a.clone());
        std::thread::spawn(move || {
            for payload in handed {
                let _ = client.publish(to.clone(), QoS::AtMostOnce, false, payload);
            }
        })
    });
    let (tx, rx) = mpsc::channel::<()>();
    let tx = Mutex::new(tx);
    let a = RawEnd::connect(broker, &format!("{base}-a"), &to_a, move |_, _| {
        let _ = tx.lock().map(|t| t.send(()));
    })?;
    let msg = bytes_of(size);
    let mut rec = Recorder::new();
    for i in 0..warmup + iters {
        let t = Instant::now();
        a.client
            .publish(to_b.clone(), QoS::AtMostOnce, false, msg.clone())
            .map_err(|e| e.to_string())?;
        match rx.recv_timeout(Duration::from_secs(1)) {
            Ok(()) if i >= warmup => rec.record(t.elapsed()),
            Ok(()) => {}
            Err(_) => {
                rec.lost();
                if rec.summary().lost > crate::hc::MAX_LOST {
                    return Err(format!(
                        "more than {} round trips lost",
                        crate::hc::MAX_LOST
                    ));
                }
            }
        }
    }
    let summary = rec.summary();
    drop(b);
    if let Some(echo) = echo {
        let _ = echo.join();
    }
    Ok(summary)
}

/// One-way between two raw rumqttc clients: A publishes as fast as its client takes
/// publishes for `duration`, B counts on its event loop.
pub fn raw_oneway(broker: &str, size: usize, duration: Duration) -> Result<Throughput, String> {
    let base = level();
    let to_b = format!("{base}/b");
    let count = Arc::new(Mutex::new(Counted::default()));
    let _b = {
        let count = count.clone();
        RawEnd::connect(broker, &format!("{base}-b"), &to_b, move |_, payload| {
            if let Ok(mut c) = count.lock() {
                c.add(payload.len());
            }
        })?
    };
    let a = RawEnd::connect(
        broker,
        &format!("{base}-a"),
        &format!("{base}/a"),
        |_, _| {},
    )?;
    let msg = bytes_of(size);
    let mut sent = 0;
    let end = Instant::now() + duration;
    while Instant::now() < end {
        if a.client
            .publish(to_b.clone(), QoS::AtMostOnce, false, msg.clone())
            .is_ok()
        {
            sent += 1;
        }
    }
    // What is still on its way arrives within a moment.
    let mut last = 0;
    loop {
        std::thread::sleep(Duration::from_millis(300));
        let n = count.lock().map(|c| c.n).unwrap_or(0);
        if n == last {
            break;
        }
        last = n;
    }
    let t = count
        .lock()
        .map(|c| c.throughput(sent))
        .map_err(|e| e.to_string());
    drop(a);
    t
}

/// A payload rumqttc can share between publishes without copying.
fn bytes_of(size: usize) -> bytes::Bytes {
    bytes::Bytes::from(vec![7u8; size])
}
