//! Two systems in two network namespaces joined by a veth pair: `hetcomm listen` in one,
//! `hetcomm send` in the other, over UDP and TCP on a real (virtual) Ethernet link rather than
//! loopback (so UDP uses its default 1472-byte datagrams and fragments larger messages).
//!
//! Needs root and `ip` (iproute2), so it is `#[ignore]`d: a plain `cargo test` reports it as
//! not run. `scripts/test.sh` (CI, which runs as root after `scripts/install.sh` installed
//! iproute2) runs it with `cargo test -p hetcomm-cli --test netns -- --ignored`; run that way
//! on a machine without them, it fails and says why.
//! The namespaces are private to this test run (names include the pid), so their addresses
//! (10.77.0.0/24) and ports cannot collide with anything else; they are removed on drop, also
//! when the test fails.

mod support;

use std::process::{Command, Stdio};

use serde_json::{json, Value};
use support::*;

/// Runs `ip ARGS`, returning its stderr as the error.
fn ip(args: &[&str]) -> Result<(), String> {
    let out = Command::new("ip")
        .args(args)
        .stdin(Stdio::null())
        .output()
        .map_err(|e| format!("cannot run `ip`: {e}"))?;
    if out.status.success() {
        Ok(())
    } else {
        Err(format!(
            "`ip {}` failed: {}",
            args.join(" "),
            String::from_utf8_lossy(&out.stderr).trim()
        ))
    }
}

/// Two namespaces joined by a veth pair; everything is deleted on drop.
struct Netns {
    namespaces: Vec<String>,
    links: Vec<String>,
}

impl Netns {
    /// `ns[0]` gets 10.77.0.1/24, `ns[1]` gets 10.77.0.2/24.
    fn create(tag: &str) -> Result<Netns, String> {
        let pid = std::process::id();
        let mut n = Netns {
            namespaces: Vec::new(),
            links: Vec::new(),
        };
        for side in ["a", "b"] {
            let name = format!("hc{tag}{pid}{side}");
            ip(&["netns", "add", &name])?;
            n.namespaces.push(name);
        }
        // Interface names: at most 15 bytes.
        let (va, vb) = (format!("hv{pid}a"), format!("hv{pid}b"));
        ip(&["link", "add", &va, "type", "veth", "peer", "name", &vb])?;
        n.links = vec![va.clone(), vb.clone()];
        for (i, dev) in [&va, &vb].into_iter().enumerate() {
            let ns = n.namespaces[i].clone();
            ip(&["link", "set", dev, "netns", &ns])?;
            let addr = format!("10.77.0.{}/24", i + 1);
            ip(&["-n", &ns, "addr", "add", &addr, "dev", dev])?;
            ip(&["-n", &ns, "link", "set", dev, "up"])?;
            ip(&["-n", &ns, "link", "set", "lo", "up"])?;
        }
        Ok(n)
    }

    /// `ip netns exec NS PROGRAM ...`
    fn exec(&self, i: usize, program: &str) -> Command {
        let mut c = Command::new("ip");
        c.args(["netns", "exec", &self.namespaces[i], program]);
        c
    }
}

impl Drop for Netns {
    fn drop(&mut self) {
        // Deleting a namespace deletes the veth end inside it (and so the pair); the link
        // deletions only matter if setup failed before the ends were moved.
        for ns in &self.namespaces {
            let _ = ip(&["netns", "del", ns]);
        }
        for l in &self.links {
            let _ = ip(&["link", "del", l]);
        }
    }
}

/// Why this machine cannot run the test, if it cannot (the test then fails with it).
fn cannot_run() -> Option<String> {
    let uid = std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("Uid:"))
                .and_then(|l| l.split_whitespace().nth(2).map(str::to_string))
        });
    if uid.as_deref() != Some("0") {
        return Some(format!("not running as root (effective uid {uid:?})"));
    }
    match Command::new("ip").arg("-V").output() {
        Ok(o) if o.status.success() => None,
        _ => Some("`ip` (iproute2) is not installed".into()),
    }
}

/// Fleet: Bravo at 10.77.0.1 (namespace 0, listens), Alpha at 10.77.0.2 (namespace 1,
/// sends). Fixed ports are fine here: the namespaces are new and private to this run.
fn fleet(dir: &TempDir, kind: &str) -> std::path::PathBuf {
    dir.write(
        &format!("{kind}.toml"),
        &fleet_text(
            kind,
            &[
                ("Alpha", 0, "10.77.0.2:47400".into()),
                ("Bravo", 1, "10.77.0.1:47401".into()),
            ],
        ),
    )
}

fn listen_in(net: &Netns, fleet: &std::path::Path, count: &str, deadline: Deadline) -> ChildGuard {
    let mut cmd = net.exec(0, HETCOMM);
    cmd.arg("listen").arg(fleet).args([
        "--as",
        "Bravo",
        "--json",
        "--count",
        count,
        "--timeout",
        "30",
    ]);
    let mut child = ChildGuard::spawn("listen as Bravo (netns)", cmd);
    child.wait_stderr("listening as Bravo ", deadline);
    child
}

fn send_in(net: &Netns, fleet: &std::path::Path, json: &str, deadline: Deadline) -> Finished {
    let mut cmd = net.exec(1, HETCOMM);
    cmd.arg("send").arg(fleet).args([
        "--as",
        "Alpha",
        "--to",
        "Bravo",
        "--module",
        "Act",
        "--type",
        "7",
        "--json",
        json,
        "--timeout",
        "20",
    ]);
    run("send as Alpha (netns)", cmd, deadline)
}

fn assert_delivered(sent: &Finished) {
    assert_eq!(sent.stdout.len(), 1, "{sent:?}");
    assert!(
        sent.stdout[0].starts_with("Bravo: delivered to the inbox (attempts: "),
        "{sent:?}"
    );
    assert_eq!(sent.status.code(), Some(0), "{sent:?}");
}

#[test]
#[ignore = "needs root and iproute2 (network namespaces); scripts/test.sh runs it with --ignored"]
fn udp_and_tcp_between_two_network_namespaces() {
    if let Some(why) = cannot_run() {
        panic!("this test needs network namespaces: {why} (run it as root with iproute2)");
    }
    let deadline = Deadline::after(50);
    let net =
        Netns::create("n").unwrap_or_else(|why| panic!("cannot create network namespaces: {why}"));
    let dir = TempDir::new("netns");

    // UDP: a small message, then one of 60 KB that travels as ~42 datagrams of 1472 bytes.
    let udp = fleet(&dir, "udp");
    let mut bravo = listen_in(&net, &udp, "2", deadline);
    assert!(
        bravo.stderr_lines()[0].contains("udp://10.77.0.1:47401"),
        "{:?}",
        bravo.stderr_lines()
    );
    assert_delivered(&send_in(&net, &udp, r#"{"code":1}"#, deadline));
    let big = "x".repeat(60_000);
    assert_delivered(&send_in(
        &net,
        &udp,
        &json!({ "big": big }).to_string(),
        deadline,
    ));
    assert_eq!(bravo.wait_exit(deadline).code(), Some(0));
    let got: Vec<Value> = bravo
        .stdout_lines()
        .iter()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(got.len(), 2, "{got:?}");
    assert_eq!(got[0]["payload"], json!({"code": 1}));
    assert_eq!(got[0]["from_system"], "Alpha");
    assert_eq!(got[1]["payload"]["big"], json!(big));
    assert!(got[1]["size"].as_u64().unwrap() > 60_000);

    // TCP.
    let tcp = fleet(&dir, "tcp");
    let mut bravo = listen_in(&net, &tcp, "1", deadline);
    assert!(
        bravo.stderr_lines()[0].contains("tcp://10.77.0.1:47401"),
        "{:?}",
        bravo.stderr_lines()
    );
    assert_delivered(&send_in(&net, &tcp, r#"{"code":2}"#, deadline));
    assert_eq!(bravo.wait_exit(deadline).code(), Some(0));
    let got: Value = serde_json::from_str(&bravo.stdout_lines()[0]).unwrap();
    assert_eq!(got["payload"], json!({"code": 2}));

    eprintln!(
        "network namespaces {:?}: udp and tcp delivered",
        net.namespaces
    );
}
