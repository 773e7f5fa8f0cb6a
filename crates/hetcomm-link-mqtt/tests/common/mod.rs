//! Shared by the tests: a real mosquitto broker, and `mqtt` links for systems 1, 2 and a few
//! more through it.
//!
//! `scripts/mqtt-test.sh` starts one mosquitto for the whole group and names its listeners in
//! the environment (`HETCOMM_MQTT_BROKER`: anonymous; `HETCOMM_MQTT_AUTH_BROKER`: username
//! `robot`, password `s3cret`; `HETCOMM_MQTT_TLS_BROKER`: TLS with client certificates, the
//! files in `HETCOMM_MQTT_TLS_DIR`). Without them, a test binary starts its own mosquitto (it
//! must be installed: `bash scripts/install.sh apt`).

#![allow(dead_code)]

pub mod fleet;

use std::collections::HashMap;
use std::io::Write;
use std::net::TcpStream;
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::{Arc, OnceLock};
use std::time::{Duration, Instant};

use hetcomm_core::SystemId;
use hetcomm_link::conformance::Harness;
use hetcomm_link::{FrameSink, Link};
pub use hetcomm_link_mqtt::Qos;
use hetcomm_link_mqtt::{MqttLink, MqttLinkConfig, MqttSettings};

/// A free TCP port on 127.0.0.1 (bound, read, released).
pub fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map(|a| a.port())
        .expect("bind 127.0.0.1:0")
}

/// A fleet topic level no other test of this process uses.
pub fn unique_fleet() -> String {
    static N: AtomicU32 = AtomicU32::new(0);
    format!(
        "t{}-{}",
        std::process::id(),
        N.fetch_add(1, Ordering::Relaxed)
    )
}

/// A mosquitto process of this test, killed when dropped.
pub struct Mosquitto {
    child: Child,
    /// Its plain listener, `127.0.0.1:PORT`.
    pub address: String,
    pub port: u16,
    dir: PathBuf,
    extra: String,
}

impl Mosquitto {
    /// Starts mosquitto on a free port with `extra` lines of configuration.
    pub fn start(extra: &str) -> Mosquitto {
        let port = free_port();
        let dir = std::env::temp_dir().join(format!("hetcomm-mqtt-{}-{port}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("broker dir");
        let mut m = Mosquitto {
            child: Self::spawn(&dir, port, extra),
            address: format!("127.0.0.1:{port}"),
            port,
            dir,
            extra: extra.to_string(),
        };
        m.wait_listening();
        m
    }

    fn spawn(dir: &std::path::Path, port: u16, extra: &str) -> Child {
        let conf = dir.join("mosquitto.conf");
        let mut f = std::fs::File::create(&conf).expect("broker conf");
        writeln!(
            f,
            "listener {port} 127.0.0.1\nallow_anonymous true\npersistence false\nset_tcp_nodelay true\n{extra}"
        )
        .expect("write conf");
        Command::new(mosquitto_binary())
            .arg("-c")
            .arg(&conf)
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("start mosquitto (install it: bash scripts/install.sh apt)")
    }

    fn wait_listening(&mut self) {
        let deadline = Instant::now() + Duration::from_secs(10);
        while TcpStream::connect(&self.address).is_err() {
            if let Ok(Some(status)) = self.child.try_wait() {
                panic!("mosquitto exited: {status}");
            }
            assert!(Instant::now() < deadline, "mosquitto did not listen");
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// Kills the broker (SIGKILL: no goodbye to anyone) and waits for it to go.
    pub fn kill(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }

    /// Freezes the broker (SIGSTOP): its connections stay open, nothing answers.
    pub fn pause(&self) {
        assert!(self.signal("-STOP"), "kill -STOP mosquitto");
    }

    /// Lets a frozen broker go on (SIGCONT).
    pub fn resume(&self) {
        assert!(self.signal("-CONT"), "kill -CONT mosquitto");
    }

    /// Sends the signal `which` to the broker; whether it was there to get it.
    fn signal(&self, which: &str) -> bool {
        Command::new("kill")
            .arg(which)
            .arg(self.child.id().to_string())
            .stderr(Stdio::null())
            .status()
            .is_ok_and(|s| s.success())
    }

    /// Starts it again on the same port, with the same configuration.
    pub fn restart(&mut self) {
        self.child = Self::spawn(&self.dir, self.port, &self.extra);
        self.wait_listening();
    }
}

impl Drop for Mosquitto {
    fn drop(&mut self) {
        // A broker a failed test left frozen: let it go on, so it dies as a running one does.
        let _ = self.signal("-CONT");
        self.kill();
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

fn mosquitto_binary() -> String {
    for p in ["/usr/sbin/mosquitto", "/usr/bin/mosquitto"] {
        if std::path::Path::new(p).exists() {
            return p.into();
        }
    }
    "mosquitto".into()
}

/// The group's anonymous broker: the script's, or one this test binary starts.
pub fn broker() -> String {
    if let Ok(b) = std::env::var("HETCOMM_MQTT_BROKER") {
        return b;
    }
    static OWN: OnceLock<Mosquitto> = OnceLock::new();
    OWN.get_or_init(|| Mosquitto::start("")).address.clone()
}

/// Names for systems 1 to 8.
pub fn systems() -> HashMap<SystemId, String> {
    (1..=8).map(|i| (SystemId(i), format!("S{i}"))).collect()
}

/// Opens `mqtt` links through one broker, under one fleet level.
pub struct MqttHarness {
    pub settings: MqttSettings,
    pub fleet: String,
}

impl MqttHarness {
    /// Links through the group's broker with QoS `qos`.
    pub fn new(qos: Qos) -> MqttHarness {
        let mut settings = MqttSettings::with_broker(&broker()).expect("broker address");
        settings.qos = qos;
        MqttHarness {
            settings,
            fleet: unique_fleet(),
        }
    }

    /// Opens system `system`'s link.
    pub fn open_link(&mut self, system: SystemId, sink: Arc<dyn FrameSink>) -> MqttLink {
        MqttLink::open(
            MqttLinkConfig {
                local: system,
                systems: systems(),
                fleet: self.fleet.clone(),
                settings: self.settings.clone(),
            },
            sink,
        )
        .unwrap_or_else(|e| panic!("open {system}: {e}"))
    }
}

impl Harness for MqttHarness {
    fn open(&mut self, system: SystemId, sink: Arc<dyn FrameSink>) -> Box<dyn Link> {
        Box::new(self.open_link(system, sink))
    }
}
