//! Interoperability with rospy both ways: `examples/ros1/hetcomm_rospy.py` (run with
//! /usr/bin/python3) builds an envelope by hand, publishes it on a hetcomm system's topic,
//! and gets a reply from a hetcomm module.

mod common;

use std::process::Command;
use std::time::Duration;

use common::Master;
use hetcomm::{Comm, Message, Outcome};
use serde::{Deserialize, Serialize};

#[derive(Serialize, Deserialize, Message, Debug)]
#[message(id = 7)]
struct Text {
    text: String,
}

#[test]
fn rospy_sends_and_gets_a_reply_from_a_hetcomm_module() {
    let master = Master::start();
    let dir = std::env::temp_dir().join(format!("hetcomm-rospy-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let fleet = dir.join("fleet.toml");
    std::fs::write(
        &fleet,
        format!(
            r#"
[systems]
Alpha = 1
Rospy = 2

[modules]
Plan = 1
Act = 2

[transports.ros]
kind = "ros1"
master_uri = "{}"
namespace = "interop"
delivery = "unacknowledged"
# The rospy node writes hetcomm's frames itself and cannot seal them (docs/ros1.md).
security = "none"

[table]
columns = ["Alpha", "Rospy"]
Alpha   = ["X",     "ros"]
Rospy   = ["ros",   "X"]
"#,
            master.uri()
        ),
    )
    .expect("writing fleet");
    let alpha = Comm::open(&fleet, "Alpha").expect("open Alpha over ros1");
    let act = alpha.module("Act").expect("module Act");

    // The hetcomm side: answer the first Text with an echo to the sender's Plan module.
    let replier = std::thread::spawn(move || {
        let got = act
            .recv_timeout::<Text>(Duration::from_secs(30))
            .expect("a Text from rospy");
        assert_eq!(got.envelope.source_system, "Rospy");
        let reply = Text {
            text: format!("echo: {}", got.message.text),
        };
        // Unacknowledged: rospy does not answer with ACK frames. One reply is enough: the
        // link waits until rospy's getBusInfo lists the connection from our publisher
        // before it publishes (the script only got this far because it publishes).
        let outcome = act.send("Rospy", "Plan", &reply).expect("reply").wait();
        (got.message.text, outcome)
    });

    let script = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../examples/ros1/hetcomm_rospy.py"
    );
    let out = Command::new("/usr/bin/python3")
        .arg(script)
        .args(["--namespace", "interop", "--to", "Alpha", "--to-id", "1"])
        .args([
            "--me",
            "Rospy",
            "--me-id",
            "2",
            "--text",
            "hello from rospy",
        ])
        .args(["--timeout", "25"])
        .envs(master.env())
        .output()
        .expect("running /usr/bin/python3 examples/ros1/hetcomm_rospy.py");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "rospy script failed: {}\nstdout: {stdout}\nstderr: {}",
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    let reply: serde_json::Value = serde_json::from_str(stdout.trim()).expect("JSON reply");
    assert_eq!(
        reply["payload"]["text"], "echo: hello from rospy",
        "{reply}"
    );
    assert_eq!(reply["source"][0], 1);
    assert_eq!(reply["destination"], serde_json::json!([2, 1]));
    assert_eq!(reply["message_type"], 7);
    let (text, outcome) = replier.join().expect("replier");
    assert_eq!(text, "hello from rospy");
    assert_eq!(outcome, Outcome::Sent { attempts: 1 }, "the one reply");
    let _ = std::fs::remove_dir_all(&dir);
}
