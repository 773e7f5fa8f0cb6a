//! One-shot `hetcomm send` processes through a `ros1_bridge` (issue 40), against a real ROS
//! master and `rostopic echo`: every send is a fresh process with a fresh ROS node, whose
//! publisher the already-running subscriber must connect to before the message goes, and the
//! process must not exit before the message was read.
//!
//! Compiled only with the `ros1` feature: `cargo test -p hetcomm-cli --features ros1 --test
//! ros1_bridge_send` (scripts/ros1-test.sh).
#![cfg(feature = "ros1")]

mod support;

#[path = "../../hetcomm-link-ros1/tests/common/mod.rs"]
mod ros;

use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use support::*;

/// How many fresh `hetcomm send` processes the test runs.
const SENDS: usize = 20;

/// Alpha and the ROS 1 robot Tango through a `ros1_bridge` publishing Twist on `topic`.
fn bridge_fleet(dir: &TempDir, master: &ros::Master, topic: &str, extra: &str) -> PathBuf {
    let link = format!("master_uri = \"{}\"", master.uri());
    twist_bridge_fleet(dir, "ros1_bridge", &link, topic, extra)
}

/// `rostopic echo -p TOPIC`, its lines on a channel; killed when dropped.
struct Echo {
    child: Child,
    lines: mpsc::Receiver<String>,
}

/// A rospy node subscribed to `topic` as geometry_msgs/Twist, printing each `linear.x`.
/// `rostopic echo` subscribes only to a topic whose type the master knows, which this
/// subscription tells it.
const TWIST_SUBSCRIBER: &str = r#"
import sys, rospy
from geometry_msgs.msg import Twist
rospy.init_node("hc_twist_subscriber", anonymous=True)
rospy.Subscriber(sys.argv[1], Twist, lambda m: print(int(m.linear.x), flush=True))
rospy.spin()
"#;

impl Echo {
    /// `rostopic echo -p TOPIC`.
    fn rostopic(master: &ros::Master, topic: &str) -> Echo {
        let mut cmd = Command::new("rostopic");
        cmd.args(["echo", "-p", topic]);
        Echo::spawn(master, cmd)
    }

    /// [`TWIST_SUBSCRIBER`] on `topic`.
    fn rospy(master: &ros::Master, topic: &str) -> Echo {
        let mut cmd = Command::new("/usr/bin/python3");
        cmd.args(["-c", TWIST_SUBSCRIBER, topic]);
        Echo::spawn(master, cmd)
    }

    fn spawn(master: &ros::Master, mut cmd: Command) -> Echo {
        let mut child = cmd
            .envs(master.env())
            .env("PYTHONUNBUFFERED", "1")
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .expect("a ROS subscriber");
        let (tx, lines) = mpsc::channel();
        let out = child.stdout.take().unwrap();
        std::thread::spawn(move || {
            for line in BufReader::new(out).lines().map_while(Result::ok) {
                if tx.send(line).is_err() {
                    break;
                }
            }
        });
        Echo { child, lines }
    }
}

impl Drop for Echo {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Waits until the master lists `n` subscribers of `topic` (`rostopic info`).
fn wait_subscribed(master: &ros::Master, topic: &str, n: usize) {
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        let out = Command::new("rostopic")
            .args(["info", topic])
            .envs(master.env())
            .stderr(Stdio::null())
            .output()
            .expect("rostopic info");
        let text = String::from_utf8_lossy(&out.stdout);
        if let Some((_, subs)) = text.split_once("Subscribers:") {
            if subs.matches(" * /").count() >= n {
                return;
            }
        }
        assert!(
            Instant::now() < deadline,
            "nobody subscribed to {topic}: {text}"
        );
        std::thread::sleep(Duration::from_millis(200));
    }
}

#[test]
fn twenty_one_shot_sends_reach_a_running_rostopic_echo() {
    let master = ros::Master::start();
    let deadline = Deadline::after(300);
    let dir = TempDir::new("ros1-bridge-send");
    let topic = format!("/hc_cli_{}/cmd_vel", std::process::id());
    let fleet = bridge_fleet(&dir, &master, &topic, "");
    let rospy = Echo::rospy(&master, &topic);
    wait_subscribed(&master, &topic, 1);
    let echo = Echo::rostopic(&master, &topic);
    wait_subscribed(&master, &topic, 2);
    for i in 0..SENDS {
        let sent = send_twist(&fleet, &twist(i), deadline);
        assert_eq!(
            sent.stdout,
            ["Tango: sent without confirmation (attempts: 1)"],
            "send {i}: {sent:?}"
        );
        assert_eq!(sent.status.code(), Some(0), "send {i}: {sent:?}");
    }
    // `-p`: a header line, then one line per message: time, linear.x, …
    let xs = echo.values(|line| {
        let x = line.split(',').nth(1).expect("a field.linear.x column");
        (!line.starts_with('%')).then(|| x.parse::<f64>().expect("a number") as usize)
    });
    assert_eq!(
        xs,
        (0..SENDS).collect::<Vec<_>>(),
        "what rostopic echo printed"
    );
    let xs = rospy.values(|line| Some(line.parse().expect("a number")));
    assert_eq!(
        xs,
        (0..SENDS).collect::<Vec<_>>(),
        "what the rospy node printed"
    );
}

impl Echo {
    /// The values of the first [`SENDS`] lines that `value` reads one from (waiting at most
    /// 10 s for them).
    fn values(&self, value: impl Fn(&str) -> Option<usize>) -> Vec<usize> {
        let mut values = Vec::new();
        let until = Instant::now() + Duration::from_secs(10);
        while values.len() < SENDS {
            let left = until.saturating_duration_since(Instant::now());
            let Ok(line) = self.lines.recv_timeout(left) else {
                break;
            };
            values.extend(value(&line));
        }
        values
    }
}

#[test]
fn a_send_nobody_subscribes_to_and_one_that_does_not_convert_fail_with_their_reason() {
    let master = ros::Master::start();
    let deadline = Deadline::after(120);
    let dir = TempDir::new("ros1-bridge-nobody");
    let topic = format!("/hc_cli_{}/nobody", std::process::id());
    let fleet = bridge_fleet(&dir, &master, &topic, "connect_timeout_ms = 150");
    let started = Instant::now();
    let sent = send_twist(&fleet, &twist(1), deadline);
    let took = started.elapsed();
    assert_eq!(
        sent.stdout,
        [format!(
            "Tango: failed: peer unreachable: no node subscribes to {topic} (waited 150 ms; \
             nothing was published) (attempts: 3)"
        )],
        "{sent:?}"
    );
    assert_eq!(sent.status.code(), Some(1), "{sent:?}");
    assert!(took >= Duration::from_millis(3 * 150), "took {took:?}");

    assert_a_non_twist_is_refused_at_once(&fleet, deadline);
}
