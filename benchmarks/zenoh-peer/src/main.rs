//! `hetcomm-zenoh-peer`: the Zenoh side of `hetcomm-bench`.
//!
//! Peer-to-peer, no router: multicast scouting off, explicit `tcp/127.0.0.1:PORT` endpoints.
//! Roles (the benchmark starts two processes, one listening, one connecting):
//!
//! ```text
//! hetcomm-zenoh-peer pong   --listen  tcp/127.0.0.1:PORT
//! hetcomm-zenoh-peer ping   --connect tcp/127.0.0.1:PORT --size BYTES --iters N --warmup W
//! hetcomm-zenoh-peer sink   --listen  tcp/127.0.0.1:PORT
//! hetcomm-zenoh-peer source --connect tcp/127.0.0.1:PORT --size BYTES --millis MS
//! ```
//!
//! `ping` prints `rtt_ns` followed by one round-trip time per line (nanoseconds); `sink`
//! prints `count BYTES_TOTAL ELAPSED_NS` (first message to the stop marker). Statistics are
//! computed by `hetcomm-bench` with the same code as every other transport. Errors go to
//! stderr with exit status 2; nothing panics on bad arguments.

use std::io::Write;
use std::time::{Duration, Instant};

use zenoh::qos::CongestionControl;
use zenoh::Wait;

type Res<T> = Result<T, String>;

struct Args {
    role: String,
    listen: Option<String>,
    connect: Option<String>,
    size: usize,
    iters: u64,
    warmup: u64,
    millis: u64,
}

fn parse_args() -> Res<Args> {
    let mut it = std::env::args().skip(1);
    let role = it.next().ok_or("missing role (ping, pong, source, sink)")?;
    let mut a = Args {
        role,
        listen: None,
        connect: None,
        size: 64,
        iters: 1000,
        warmup: 100,
        millis: 1000,
    };
    while let Some(flag) = it.next() {
        let value = it.next().ok_or(format!("{flag} needs a value"))?;
        let num = || {
            value
                .parse::<u64>()
                .map_err(|e| format!("{flag} {value}: {e}"))
        };
        match flag.as_str() {
            "--listen" => a.listen = Some(value.clone()),
            "--connect" => a.connect = Some(value.clone()),
            "--size" => a.size = num()? as usize,
            "--iters" => a.iters = num()?,
            "--warmup" => a.warmup = num()?,
            "--millis" => a.millis = num()?,
            other => return Err(format!("unknown option {other}")),
        }
    }
    Ok(a)
}

fn session(a: &Args) -> Res<zenoh::Session> {
    let mut c = zenoh::Config::default();
    let set = |c: &mut zenoh::Config, k: &str, v: &str| {
        c.insert_json5(k, v).map_err(|e| format!("config {k}: {e}"))
    };
    set(&mut c, "mode", "\"peer\"")?;
    set(&mut c, "scouting/multicast/enabled", "false")?;
    set(&mut c, "scouting/gossip/enabled", "false")?;
    match &a.listen {
        Some(l) => set(&mut c, "listen/endpoints", &format!("[\"{l}\"]"))?,
        None => set(&mut c, "listen/endpoints", "[]")?,
    }
    if let Some(p) = &a.connect {
        set(&mut c, "connect/endpoints", &format!("[\"{p}\"]"))?;
    }
    zenoh::open(c).wait().map_err(|e| format!("open: {e}"))
}

fn run(a: Args) -> Res<()> {
    let s = session(&a)?;
    let err = |what: &'static str| move |e: zenoh::Error| format!("{what}: {e}");
    match a.role.as_str() {
        "pong" => {
            let sub = s
                .declare_subscriber("hb/ping")
                .wait()
                .map_err(err("subscribe"))?;
            let publ = s
                .declare_publisher("hb/pong")
                .congestion_control(CongestionControl::Block)
                .express(true)
                .wait()
                .map_err(err("publisher"))?;
            println!("ready");
            let _ = std::io::stdout().flush();
            while let Ok(sample) = sub.recv() {
                let bytes = sample.payload().to_bytes().into_owned();
                if bytes.first() == Some(&0xff) && bytes.len() == 1 {
                    break; // stop marker
                }
                publ.put(bytes).wait().map_err(err("put"))?;
            }
        }
        "ping" => {
            let sub = s
                .declare_subscriber("hb/pong")
                .wait()
                .map_err(err("subscribe"))?;
            let publ = s
                .declare_publisher("hb/ping")
                .congestion_control(CongestionControl::Block)
                .express(true)
                .wait()
                .map_err(err("publisher"))?;
            let payload = vec![0u8; a.size.max(2)];
            // Until the first echo comes back the peers may not have matched yet.
            let deadline = Instant::now() + Duration::from_secs(20);
            loop {
                publ.put(payload.clone()).wait().map_err(err("put"))?;
                if let Ok(Some(_)) = sub.recv_timeout(Duration::from_millis(100)) {
                    break;
                }
                if Instant::now() > deadline {
                    return Err("no echo from the pong peer within 20 s".into());
                }
            }
            // Drain echoes of the probes.
            while let Ok(Some(_)) = sub.recv_timeout(Duration::from_millis(200)) {}
            let mut out = String::from("rtt_ns\n");
            for i in 0..a.warmup + a.iters {
                let t = Instant::now();
                publ.put(payload.clone()).wait().map_err(err("put"))?;
                match sub.recv_timeout(Duration::from_secs(5)) {
                    Ok(Some(_)) => {}
                    _ => return Err(format!("echo {i} lost")),
                }
                if i >= a.warmup {
                    out.push_str(&format!("{}\n", t.elapsed().as_nanos()));
                }
            }
            let _ = publ.put(vec![0xffu8]).wait();
            print!("{out}");
        }
        "sink" => {
            let sub = s
                .declare_subscriber("hb/data")
                .wait()
                .map_err(err("subscribe"))?;
            let hello = s
                .declare_subscriber("hb/hello")
                .wait()
                .map_err(err("subscribe"))?;
            let ready = s
                .declare_publisher("hb/ready")
                .congestion_control(CongestionControl::Block)
                .wait()
                .map_err(err("publisher"))?;
            println!("ready");
            let _ = std::io::stdout().flush();
            // Handshake: answer hellos until data starts.
            let (mut count, mut bytes, mut first) = (0u64, 0u64, None::<Instant>);
            loop {
                while let Ok(Some(_)) = hello.try_recv() {
                    ready.put(vec![1u8]).wait().map_err(err("put"))?;
                }
                match sub.recv_timeout(Duration::from_millis(20)) {
                    Ok(Some(sample)) => {
                        let len = sample.payload().len();
                        if len == 1 {
                            break; // stop marker
                        }
                        first.get_or_insert_with(Instant::now);
                        count += 1;
                        bytes += len as u64;
                    }
                    Ok(None) => {}
                    Err(e) => return Err(format!("recv: {e}")),
                }
            }
            let elapsed = first.map(|f| f.elapsed().as_nanos()).unwrap_or(0);
            println!("{count} {bytes} {elapsed}");
        }
        "source" => {
            let publ = s
                .declare_publisher("hb/data")
                .congestion_control(CongestionControl::Block)
                .wait()
                .map_err(err("publisher"))?;
            let hello = s
                .declare_publisher("hb/hello")
                .wait()
                .map_err(err("publisher"))?;
            let ready = s
                .declare_subscriber("hb/ready")
                .wait()
                .map_err(err("subscribe"))?;
            let deadline = Instant::now() + Duration::from_secs(20);
            loop {
                hello.put(vec![1u8]).wait().map_err(err("put"))?;
                if let Ok(Some(_)) = ready.recv_timeout(Duration::from_millis(100)) {
                    break;
                }
                if Instant::now() > deadline {
                    return Err("no answer from the sink within 20 s".into());
                }
            }
            let payload = vec![0u8; a.size.max(2)];
            let end = Instant::now() + Duration::from_millis(a.millis);
            let mut sent = 0u64;
            while Instant::now() < end {
                for _ in 0..64 {
                    publ.put(payload.clone()).wait().map_err(err("put"))?;
                    sent += 1;
                }
            }
            publ.put(vec![0xffu8]).wait().map_err(err("put"))?;
            // Let the stop marker leave before the session closes.
            std::thread::sleep(Duration::from_millis(300));
            println!("sent {sent}");
        }
        other => return Err(format!("unknown role {other}")),
    }
    let _ = s.close().wait();
    Ok(())
}

fn main() {
    match parse_args().and_then(run) {
        Ok(()) => {}
        Err(e) => {
            eprintln!("hetcomm-zenoh-peer: {e}");
            std::process::exit(2);
        }
    }
}
