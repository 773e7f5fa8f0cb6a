//! Raw iceoryx2 between two processes, for `hetcomm-bench`'s `shm` rows: the bare payload as
//! a `[u8]` sample, no hetcomm frame, router or acknowledgement.
//!
//! ```text
//! hetcomm-iceoryx2-peer pong   --service NAME [--spin]
//! hetcomm-iceoryx2-peer ping   --service NAME --size N --iters N --warmup N [--spin]
//! hetcomm-iceoryx2-peer sink   --service NAME
//! hetcomm-iceoryx2-peer source --service NAME --size N --millis N
//! ```
//!
//! Without `--spin` a receiver sleeps on an iceoryx2 event (the sender notifies after each
//! sample), as the `shm` transport's receivers do; with it, it polls its subscriber in a busy
//! loop (iceoryx2's own benchmark's setting). `ping` prints `rtt_ns` followed by one round-trip
//! time per line (nanoseconds); `sink` prints `COUNT BYTES NANOS` once the source's stop
//! sample came; `source` prints `sent N`. Every peer prints `ready` once its ports are open.

use std::time::{Duration, Instant};

use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;

type Pub = Publisher<ipc::Service, [u8], ()>;
type Sub = Subscriber<ipc::Service, [u8], ()>;

struct Args {
    role: String,
    service: String,
    size: usize,
    iters: u64,
    warmup: u64,
    millis: u64,
    spin: bool,
}

fn args() -> Result<Args, String> {
    let mut it = std::env::args().skip(1);
    let role = it.next().ok_or("missing role (ping, pong, source, sink)")?;
    let mut a = Args {
        role,
        service: String::new(),
        size: 64,
        iters: 1000,
        warmup: 100,
        millis: 1000,
        spin: false,
    };
    while let Some(k) = it.next() {
        let mut v = || it.next().ok_or(format!("{k} needs a value"));
        match k.as_str() {
            "--service" => a.service = v()?,
            "--size" => a.size = v()?.parse().map_err(|e| format!("--size: {e}"))?,
            "--iters" => a.iters = v()?.parse().map_err(|e| format!("--iters: {e}"))?,
            "--warmup" => a.warmup = v()?.parse().map_err(|e| format!("--warmup: {e}"))?,
            "--millis" => a.millis = v()?.parse().map_err(|e| format!("--millis: {e}"))?,
            "--spin" => a.spin = true,
            other => return Err(format!("unknown argument {other}")),
        }
    }
    if a.service.is_empty() {
        return Err("--service is required".into());
    }
    Ok(a)
}

/// One direction: a publish-subscribe service and its wake-up event, both named `name`.
struct Channel {
    publisher: Option<Pub>,
    subscriber: Option<Sub>,
    notifier: Option<Notifier<ipc::Service>>,
    listener: Option<Listener<ipc::Service>>,
}

type Error = Box<dyn std::error::Error>;

fn channel(
    node: &Node<ipc::Service>,
    name: &str,
    send: bool,
    size: usize,
) -> Result<Channel, Error> {
    let sn = ServiceName::new(name)?;
    let service = node
        .service_builder(&sn)
        .publish_subscribe::<[u8]>()
        .enable_safe_overflow(false)
        .subscriber_max_buffer_size(16)
        .open_or_create()?;
    let event = node.service_builder(&sn).event().open_or_create()?;
    Ok(if send {
        Channel {
            publisher: Some(
                service
                    .publisher_builder()
                    .initial_max_slice_len(size)
                    .backpressure_strategy(BackpressureStrategy::RetryUntilDelivered)
                    .create()?,
            ),
            subscriber: None,
            notifier: Some(event.notifier_builder().create()?),
            listener: None,
        }
    } else {
        Channel {
            publisher: None,
            subscriber: Some(service.subscriber_builder().buffer_size(16).create()?),
            notifier: None,
            listener: Some(event.listener_builder().create()?),
        }
    })
}

impl Channel {
    fn send(&self, payload: &[u8], wake: bool) -> Result<(), Error> {
        let p = self.publisher.as_ref().expect("a sending channel");
        p.loan_slice_uninit(payload.len())?
            .write_from_slice(payload)
            .send()?;
        if wake {
            self.notifier
                .as_ref()
                .expect("a sending channel")
                .notify()?;
        }
        Ok(())
    }

    /// The next sample's length and first byte: polling with `spin`, else sleeping on the
    /// event between looks.
    fn recv(&self, spin: bool) -> Result<(usize, u8), Error> {
        let s = self.subscriber.as_ref().expect("a receiving channel");
        loop {
            if let Some(sample) = s.receive()? {
                let p = sample.payload();
                return Ok((p.len(), p.first().copied().unwrap_or(0)));
            }
            if spin {
                std::hint::spin_loop();
            } else {
                let l = self.listener.as_ref().expect("a receiving channel");
                l.timed_wait(|_| {}, Duration::from_millis(100))?;
            }
        }
    }
}

/// The first byte of the source's last sample: the sink stops there.
const STOP: u8 = 0xff;

fn run(a: Args) -> Result<(), Error> {
    // iceoryx2 warns that no config file was loaded (its defaults are what we want).
    set_log_level(LogLevel::Error);
    let node = NodeBuilder::new()
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<ipc::Service>()?;
    let ping_name = format!("{}/ping", a.service);
    let pong_name = format!("{}/pong", a.service);
    match a.role.as_str() {
        "pong" => {
            let rx = channel(&node, &ping_name, false, a.size)?;
            let tx = channel(&node, &pong_name, true, 1 << 20)?;
            println!("ready");
            let mut buf = Vec::new();
            loop {
                let s = rx.subscriber.as_ref().unwrap();
                match s.receive()? {
                    Some(sample) => {
                        buf.clear();
                        buf.extend_from_slice(sample.payload());
                        drop(sample);
                        tx.send(&buf, !a.spin)?;
                    }
                    None if a.spin => std::hint::spin_loop(),
                    None => {
                        rx.listener
                            .as_ref()
                            .unwrap()
                            .timed_wait(|_| {}, Duration::from_millis(100))?;
                    }
                }
            }
        }
        "ping" => {
            let tx = channel(&node, &ping_name, true, a.size)?;
            let rx = channel(&node, &pong_name, false, a.size)?;
            let msg = vec![7u8; a.size];
            // The pong printed `ready` before this process started: its subscriber is there,
            // and this process's reply subscriber exists before the first ping goes.
            println!("rtt_ns");
            for i in 0..a.warmup + a.iters {
                let t = Instant::now();
                tx.send(&msg, !a.spin)?;
                rx.recv(a.spin)?;
                if i >= a.warmup {
                    println!("{}", t.elapsed().as_nanos());
                }
            }
            Ok(())
        }
        "sink" => {
            let rx = channel(&node, &ping_name, false, a.size)?;
            println!("ready");
            let (mut count, mut bytes, mut first) = (0u64, 0u64, None);
            loop {
                let (len, head) = rx.recv(false)?;
                if len == 1 && head == STOP {
                    break;
                }
                first.get_or_insert_with(Instant::now);
                count += 1;
                bytes += len as u64;
            }
            let ns = first.map_or(0, |t| t.elapsed().as_nanos());
            println!("{count} {bytes} {ns}");
            Ok(())
        }
        "source" => {
            let tx = channel(&node, &ping_name, true, a.size)?;
            std::thread::sleep(Duration::from_millis(100));
            let msg = vec![7u8; a.size];
            let end = Instant::now() + Duration::from_millis(a.millis);
            let mut sent = 0u64;
            while Instant::now() < end {
                tx.send(&msg, true)?;
                sent += 1;
            }
            tx.send(&[STOP], true)?;
            println!("sent {sent}");
            Ok(())
        }
        other => Err(format!("unknown role {other}").into()),
    }
}

fn main() {
    let a = match args() {
        Ok(a) => a,
        Err(e) => {
            eprintln!("hetcomm-iceoryx2-peer: {e}");
            std::process::exit(2);
        }
    };
    if let Err(e) = run(a) {
        eprintln!("hetcomm-iceoryx2-peer: {e}");
        std::process::exit(1);
    }
}
