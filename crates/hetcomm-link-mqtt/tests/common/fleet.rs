//! Fleets of systems A and B on one `mqtt` transport, opened through the facade, and a plain
//! MQTT client for publishing what hetcomm would never publish.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use hetcomm::{Comm, MessageType, Module, Outcome, SendOptions};
use rumqttc::v5::mqttbytes::v5::{LastWill, Packet};
use rumqttc::v5::mqttbytes::QoS;
use rumqttc::v5::{Client, Event, MqttOptions};

/// A fleet of A and B on one mqtt transport `m` with `keys`. Unsecured: these tests look at the
/// transport (a malformed publish must reach its counters); the secured path runs in the
/// conformance suite.
pub fn fleet_text(keys: &str) -> String {
    format!(
        r#"[systems]
A = 0
B = 1
[modules]
M = 0
[transports.m]
kind = "mqtt"
{keys}
security = "none"
[table]
columns = ["A", "B"]
A = ["X", "m"]
B = ["m", "X"]
"#
    )
}

/// `broker = …` and a fleet level of its own.
pub fn keys(broker: &str, fleet: &str, more: &str) -> String {
    format!("broker = \"{broker}\"\nfleet = \"{fleet}\"\n{more}")
}

pub fn open(keys: &str, system: &str) -> Comm {
    let fleet = hetcomm::parse_fleet(&fleet_text(keys), "m.toml", None).expect("valid fleet");
    Comm::open_fleet(&fleet, system).unwrap_or_else(|e| panic!("open {system}: {e}"))
}

pub fn open_pair(keys: &str) -> (Comm, Comm) {
    (open(keys, "A"), open(keys, "B"))
}

/// Sends `[0x91, i]` (MessagePack `[i]`) from `from` to B's module M and waits for the outcome.
pub fn send(from: &Module, i: u8) -> Outcome {
    from.send_raw("B", "M", MessageType(7), &[0x91, i], SendOptions::default())
        .expect("send")
        .wait()
}

/// Waits up to `secs` for `what` to hold.
pub fn eventually(secs: u64, what: &str, mut check: impl FnMut() -> bool) {
    let deadline = Instant::now() + Duration::from_secs(secs);
    while !check() {
        assert!(Instant::now() < deadline, "not within {secs} s: {what}");
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// A plain MQTT 5 client of the broker at `host:port` (not a hetcomm system), with its event
/// loop on a thread of its own.
pub struct RawClient {
    pub client: Client,
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl RawClient {
    pub fn connect(address: &str, id: &str, will: Option<LastWill>) -> RawClient {
        let (host, port) = address.rsplit_once(':').expect("host:port");
        let mut o = MqttOptions::new(id, host, port.parse().expect("port"));
        o.set_max_packet_size(Some(32 << 20));
        if let Some(w) = will {
            o.set_last_will(w);
        }
        let (client, mut connection) = Client::new(o, 64);
        let (ready_tx, ready_rx) = std::sync::mpsc::channel();
        let stop = Arc::new(AtomicBool::new(false));
        let stopping = stop.clone();
        let thread = std::thread::spawn(move || {
            while !stopping.load(Ordering::SeqCst) {
                match connection.recv_timeout(Duration::from_millis(50)) {
                    Ok(Ok(Event::Incoming(Packet::ConnAck(_)))) => {
                        let _ = ready_tx.send(());
                    }
                    Ok(Ok(Event::Outgoing(rumqttc::Outgoing::Disconnect))) => break,
                    Ok(Err(_)) => std::thread::sleep(Duration::from_millis(50)),
                    _ => {}
                }
            }
            // Dropping the connection closes its socket: without a DISCONNECT first, the
            // broker publishes the last will.
        });
        ready_rx
            .recv_timeout(Duration::from_secs(5))
            .expect("the raw client connected");
        RawClient {
            client,
            stop,
            thread: Some(thread),
        }
    }

    pub fn publish(&self, topic: &str, payload: &[u8], retain: bool) {
        self.client
            .publish(topic, QoS::AtLeastOnce, retain, payload.to_vec())
            .expect("publish");
    }

    /// Subscribes to `filter` (what arrives is ignored); the broker has the subscription a
    /// round trip later.
    pub fn subscribe(&self, filter: &str) {
        self.client
            .subscribe(filter, QoS::AtLeastOnce)
            .expect("subscribe");
    }

    /// Leaves with a DISCONNECT (no last will), after what it published went out.
    pub fn disconnect(mut self) {
        let _ = self.client.disconnect();
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }

    /// Closes its socket without a DISCONNECT, as a crashed process would: the broker
    /// publishes its last will.
    pub fn vanish(mut self) {
        self.stop.store(true, Ordering::SeqCst);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

impl Drop for RawClient {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}
