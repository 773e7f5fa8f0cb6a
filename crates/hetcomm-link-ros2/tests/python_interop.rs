//! A `ros2` link against a plain DDS program: Python `cyclonedds` (tests/py/frame_echo.py)
//! reads what system A's link writes on system B's topic as a typed
//! `std_msgs/msg/UInt8MultiArray` and writes each `data` back on A's topic, with a layout of
//! its own. Frames of 1 B to 64 KiB (DDS fragments the large ones) come back whole and in
//! order; on rustdds, and with the `cyclone` feature on Cyclone DDS.
//!
//! The Python interpreter with `cyclonedds` is `$HETCOMM_ROS2_PYTHON` (scripts/ros2-test.sh
//! sets it).

use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::time::Duration;

use hetcomm_core::SystemId;
use hetcomm_link::conformance::CollectSink;
use hetcomm_link_ros2::factory::open_link;
use hetcomm_link_ros2::{Backend, Ros2Settings};

/// The echo process, killed when dropped.
struct Echo(Child);

impl Drop for Echo {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn echo(domain: u16, namespace: &str) -> Echo {
    let python = std::env::var("HETCOMM_ROS2_PYTHON").expect(
        "set HETCOMM_ROS2_PYTHON to a Python with the `cyclonedds` package \
         (bash scripts/ros2-test.sh does)",
    );
    let script = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/py/frame_echo.py");
    let mut child = Command::new(python)
        .arg(script)
        .args(["--domain", &domain.to_string(), "--namespace", namespace])
        .args(["--seconds", "60"])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .expect("start frame_echo.py");
    let mut line = String::new();
    let stdout = child.stdout.take().expect("stdout");
    BufReader::new(stdout).read_line(&mut line).expect("read");
    assert_eq!(line.trim(), "ready", "frame_echo.py did not start");
    Echo(child)
}

fn frames_come_back_from_python(dds: Backend, domain_id: u16) {
    let namespace = format!("/py_{}_{domain_id}", std::process::id());
    let _echo = echo(domain_id, &namespace);
    let settings = Ros2Settings {
        domain_id,
        namespace,
        dds,
        // Python's participant may still be discovering ours.
        connect_timeout_ms: 20_000,
        ..Ros2Settings::default()
    };
    let names = vec![(SystemId(1), "A".into()), (SystemId(2), "B".into())];
    let sink = CollectSink::new();
    let a = open_link(SystemId(1), &names, &settings, sink.clone(), false).expect("open A");
    // Python's writer matches A's reader on its own schedule: probe until an echo comes
    // back, so that both directions are matched before the frames that are checked.
    let probe = b"probe".to_vec();
    let deadline = std::time::Instant::now() + Duration::from_secs(20);
    while sink.frames().is_empty() {
        assert!(std::time::Instant::now() < deadline, "no echo of the probe");
        a.send(SystemId(2), &probe).expect("send the probe");
        sink.wait_for(1, Duration::from_millis(200));
    }
    let frames: Vec<Vec<u8>> = [1usize, 3, 64, 1000, 65_536, 5]
        .iter()
        .enumerate()
        .map(|(i, &n)| (0..n).map(|j| (i * 31 + j + 1) as u8).collect())
        .collect();
    for f in &frames {
        a.send(SystemId(2), f).expect("send");
    }
    let echoed = || -> Vec<Vec<u8>> {
        let all = sink.frames().into_iter().map(|r| r.bytes);
        all.filter(|f| *f != probe).collect()
    };
    let deadline = std::time::Instant::now() + Duration::from_secs(20);
    while echoed().len() < frames.len() && std::time::Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(20));
    }
    assert_eq!(echoed(), frames);
    assert_eq!(a.stats().frames_dropped, 0);
}

#[test]
fn rustdds_frames_come_back_from_a_python_cyclonedds_program() {
    frames_come_back_from_python(Backend::RustDds, 69);
}

#[cfg(feature = "cyclone")]
#[test]
fn cyclone_frames_come_back_from_a_python_cyclonedds_program() {
    frames_come_back_from_python(Backend::Cyclone, 81);
}
