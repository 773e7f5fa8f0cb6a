//! A foreign system in Python (the `iceoryx2` package; tests/python/shm_system.py, written
//! from docs/shm.md and docs/wire-format.md) exchanges frames with a hetcomm system on an
//! unsecured `shm` transport: it checks A's frames and answers each with a frame of its own,
//! which A's module receives.
//!
//! The interpreter is `HETCOMM_SHM_PYTHON` (scripts/shm-test.sh points it at the venv that
//! scripts/install.sh makes), else `target/py-venv/bin/python`; a test that cannot find the
//! package fails, it does not pass without running.

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::time::Duration;

use hetcomm::{Comm, MessageType, Outcome, SendOptions};

fn python() -> String {
    std::env::var("HETCOMM_SHM_PYTHON").unwrap_or_else(|_| {
        concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../target/py-venv/bin/python"
        )
        .to_string()
    })
}

#[test]
fn a_python_iceoryx2_system_exchanges_frames_with_hetcomm() {
    const N: u8 = 3;
    let name = format!("py-{}", std::process::id());
    let text = format!(
        r#"name = "{name}"
[systems]
A = 0
B = 1
[modules]
M = 0
[transports.s]
kind = "shm"
delivery = "unacknowledged"
security = "none"
[table]
columns = ["A", "B"]
A = ["X", "s"]
B = ["s", "X"]
"#
    );
    let fleet = hetcomm::parse_fleet(&text, "py.toml", None).unwrap();
    let a = Comm::open_fleet(&fleet, "A").expect("open A");
    let script = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/python/shm_system.py");
    let mut child = Command::new(python())
        .args([script, &format!("hetcomm/{name}"), "1", "0", &N.to_string()])
        .stdout(Stdio::piped())
        .spawn()
        .unwrap_or_else(|e| panic!("start {} (iceoryx2's Python package): {e}", python()));
    let mut out = BufReader::new(child.stdout.take().unwrap());
    let mut line = String::new();
    out.read_line(&mut line).unwrap();
    assert_eq!(
        line.trim(),
        "ready",
        "the Python system did not open its ports"
    );
    let m = a.module("M").unwrap();
    for i in 0..N {
        let outcome = m
            .send_raw("B", "M", MessageType(7), &[0x91, i], SendOptions::default())
            .expect("send")
            .wait();
        assert!(matches!(outcome, Outcome::Sent { .. }), "{outcome:?}");
        let reply = m
            .recv_raw_timeout(Some(Duration::from_secs(20)))
            .expect("the Python system's answer");
        assert_eq!(reply.envelope.source_system, "B");
        assert_eq!(reply.payload, vec![0x91, i]);
    }
    line.clear();
    out.read_line(&mut line).unwrap();
    assert_eq!(line.trim(), format!("answered {N}"));
    assert!(child.wait().unwrap().success());
}
