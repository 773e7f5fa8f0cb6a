//! Test support: a real ROS master (`rosmaster --core`) on a free port, killed on drop.
#![allow(dead_code)]

use std::io::{Read, Write};
use std::net::{TcpListener, TcpStream};
use std::process::{Child, Command, Stdio};
use std::sync::Once;
use std::time::{Duration, Instant};

/// How long a master may take to answer after it was started.
const READY: Duration = Duration::from_secs(15);

/// Points ROS at the loopback interface before anything reads the environment.
pub fn ros_env() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        if std::env::var_os("ROS_HOSTNAME").is_none() && std::env::var_os("ROS_IP").is_none() {
            std::env::set_var("ROS_HOSTNAME", "127.0.0.1");
        }
    });
}

/// Fails the test with instructions when `rosmaster` is not installed. There is no way to
/// pass without it: to leave these tests out, leave them out of the run (`cargo test
/// --workspace --exclude hetcomm-link-ros1`), which then reports them as not run.
pub fn require_ros() {
    ros_env();
    let found = Command::new("rosmaster")
        .arg("--help")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok();
    assert!(
        found,
        "`rosmaster` is not installed: run `bash scripts/ros1-test.sh` (it installs ros-core, \
         python3-rospy, python3-rostopic and ros-std-msgs, then runs these tests)"
    );
}

/// A free TCP port on the loopback interface.
pub fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map(|a| a.port())
        .expect("binding port 0")
}

/// A running `rosmaster --core -p PORT`.
pub struct Master {
    pub port: u16,
    child: Option<Child>,
    log_dir: std::path::PathBuf,
}

impl Master {
    /// Starts a master on a free port and waits until it answers (the test fails if ROS is
    /// not installed).
    pub fn start() -> Master {
        require_ros();
        let port = free_port();
        let log_dir =
            std::env::temp_dir().join(format!("hetcomm-ros1-test-{}-{port}", std::process::id()));
        let mut master = Master {
            port,
            child: None,
            log_dir,
        };
        master.spawn();
        master
    }

    /// `http://127.0.0.1:PORT`.
    pub fn uri(&self) -> String {
        format!("http://127.0.0.1:{}", self.port)
    }

    fn spawn(&mut self) {
        let child = Command::new("rosmaster")
            .args(["--core", "-p", &self.port.to_string()])
            .env("ROS_HOSTNAME", "127.0.0.1")
            .env("ROS_MASTER_URI", self.uri())
            .env("ROS_LOG_DIR", &self.log_dir)
            .env("ROS_HOME", &self.log_dir)
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("starting rosmaster");
        self.child = Some(child);
        let deadline = Instant::now() + READY;
        while !self.answers() {
            if let Some(Ok(Some(status))) = self.child.as_mut().map(|c| c.try_wait()) {
                panic!("rosmaster exited with {status} before answering");
            }
            assert!(
                Instant::now() < deadline,
                "rosmaster on port {} did not answer within {READY:?}",
                self.port
            );
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// Whether the master answers an XML-RPC `getPid`.
    pub fn answers(&self) -> bool {
        let body = "<?xml version=\"1.0\"?><methodCall><methodName>getPid</methodName><params>\
                    <param><value><string>/hetcomm_test</string></value></param></params></methodCall>";
        let request = format!(
            "POST / HTTP/1.0\r\nHost: 127.0.0.1\r\nContent-Type: text/xml\r\nContent-Length: {}\r\n\r\n{body}",
            body.len()
        );
        let Ok(mut s) = TcpStream::connect(("127.0.0.1", self.port)) else {
            return false;
        };
        let _ = s.set_read_timeout(Some(Duration::from_secs(2)));
        if s.write_all(request.as_bytes()).is_err() {
            return false;
        }
        let mut response = String::new();
        let _ = s.read_to_string(&mut response);
        response.contains("200 OK") && response.contains("<int>")
    }

    /// The TCP port on which `node`'s publisher of `topic` takes subscribers (the master's
    /// `lookupNode`, then the node's `requestTopic`).
    pub fn tcpros_port(&self, node: &str, topic: &str) -> u16 {
        let caller = "<param><value><string>/hetcomm_test</string></value></param>";
        let answer = xmlrpc(
            &format!("127.0.0.1:{}", self.port),
            "lookupNode",
            &format!("{caller}<param><value><string>{node}</string></value></param>"),
        );
        let start = answer.find("http://").expect("lookupNode answer") + "http://".len();
        let end = start + answer[start..].find(['/', '<']).expect("node URI");
        let protocols = "<param><value><array><data><value><array><data>\
                         <value><string>TCPROS</string></value></data></array></value>\
                         </data></array></value></param>";
        let answer = xmlrpc(
            &answer[start..end],
            "requestTopic",
            &format!("{caller}<param><value><string>{topic}</string></value></param>{protocols}"),
        );
        // [1, "", ["TCPROS", host, port]]: the port is the last integer.
        let last = answer
            .rsplit(['<', '>'])
            .find_map(|t| t.parse::<u16>().ok().filter(|&p| p > 1));
        last.unwrap_or_else(|| panic!("no TCPROS port in {answer}"))
    }

    /// Kills the master (as a crash would: nothing is unregistered).
    pub fn kill(&mut self) {
        if let Some(mut c) = self.child.take() {
            let _ = c.kill();
            let _ = c.wait();
        }
    }

    /// Starts the master again on the same port, empty (as a restarted master is).
    pub fn restart(&mut self) {
        self.kill();
        self.spawn();
    }

    /// Environment for ROS command-line tools talking to this master.
    pub fn env(&self) -> Vec<(&'static str, String)> {
        vec![
            ("ROS_MASTER_URI", self.uri()),
            ("ROS_HOSTNAME", "127.0.0.1".to_string()),
            ("ROS_LOG_DIR", self.log_dir.display().to_string()),
            ("ROS_HOME", self.log_dir.display().to_string()),
        ]
    }
}

/// Calls `method` with `params` (XML) on the XML-RPC server at `addr` (`host:port`); the
/// answer's text.
fn xmlrpc(addr: &str, method: &str, params: &str) -> String {
    let body = format!(
        "<?xml version=\"1.0\"?><methodCall><methodName>{method}</methodName>\
         <params>{params}</params></methodCall>"
    );
    let request = format!(
        "POST / HTTP/1.0\r\nHost: {addr}\r\nContent-Type: text/xml\r\nContent-Length: {}\r\n\r\n{body}",
        body.len()
    );
    let mut s = TcpStream::connect(addr).expect("connecting to an XML-RPC server");
    s.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
    s.write_all(request.as_bytes()).unwrap();
    let mut answer = String::new();
    let _ = s.read_to_string(&mut answer);
    answer
}

impl Drop for Master {
    fn drop(&mut self) {
        self.kill();
        if std::thread::panicking() {
            // Kept for the post-mortem: the master's log names every registration and update.
            eprintln!("rosmaster log kept in {}", self.log_dir.display());
        } else {
            let _ = std::fs::remove_dir_all(&self.log_dir);
        }
    }
}
