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
    tag: String,
    namespaces: Vec<String>,
    links: Vec<String>,
}

impl Netns {
    /// `ns[0]` gets 10.77.0.1/24, `ns[1]` gets 10.77.0.2/24.
    fn create(tag: &str) -> Result<Netns, String> {
        Self::create_links(tag, 1)
    }

    /// Two namespaces joined by `links` veth pairs: on pair `k`, `ns[0]` gets 10.77.k.1/24
    /// and `ns[1]` 10.77.k.2/24; the ends are [`Netns::dev`].
    fn create_links(tag: &str, links: usize) -> Result<Netns, String> {
        let pid = std::process::id();
        let mut n = Netns {
            tag: tag.to_string(),
            namespaces: Vec::new(),
            links: Vec::new(),
        };
        for side in ["a", "b"] {
            let name = format!("hc{tag}{pid}{side}");
            ip(&["netns", "add", &name])?;
            n.namespaces.push(name);
        }
        for k in 0..links {
            // Interface names: at most 15 bytes.
            let (va, vb) = (n.dev(k, 0), n.dev(k, 1));
            ip(&["link", "add", &va, "type", "veth", "peer", "name", &vb])?;
            n.links.extend([va.clone(), vb.clone()]);
            for (i, dev) in [&va, &vb].into_iter().enumerate() {
                let ns = n.namespaces[i].clone();
                ip(&["link", "set", dev, "netns", &ns])?;
                let addr = format!("10.77.{k}.{}/24", i + 1);
                ip(&["-n", &ns, "addr", "add", &addr, "dev", dev])?;
                ip(&["-n", &ns, "link", "set", dev, "up"])?;
                ip(&["-n", &ns, "link", "set", "lo", "up"])?;
            }
        }
        Ok(n)
    }

    /// The end of veth pair `k` in namespace `side` (tests of one run running at once have
    /// their own tags, so their own names).
    fn dev(&self, k: usize, side: usize) -> String {
        let pid = std::process::id();
        let end = ["a", "b"][side];
        format!("h{}{pid}{k}{end}", self.tag)
    }

    /// Moves the calling thread into namespace `i` (the sockets it and the threads it starts
    /// make from then on are there).
    fn enter(&self, i: usize) -> Result<(), String> {
        let path = format!("/run/netns/{}", self.namespaces[i]);
        let f = std::fs::File::open(&path).map_err(|e| format!("{path}: {e}"))?;
        use std::os::fd::AsRawFd;
        // SAFETY: a valid namespace file descriptor; changes only this thread's namespace.
        match unsafe { libc::setns(f.as_raw_fd(), libc::CLONE_NEWNET) } {
            0 => Ok(()),
            _ => Err(format!("setns {path}: {}", std::io::Error::last_os_error())),
        }
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

/// A pair with two transports over two veth links (UDP on the first, TCP on the second), A in
/// one namespace and B in the other, each opened by a thread moved into its namespace. A
/// streams acknowledged sends; the first link is taken down on B's side (`ip link set … down`)
/// mid-stream and brought back up: traffic moves to TCP and returns to UDP, and every send is
/// accounted for (each delivered, each in B's inbox once, each outcome naming its transport).
#[test]
#[ignore = "needs root and iproute2 (network namespaces); scripts/test.sh runs it with --ignored"]
fn a_veth_link_down_moves_a_pair_to_its_second_link_and_back() {
    use std::collections::BTreeSet;
    use std::time::{Duration, Instant};
    if let Some(why) = cannot_run() {
        panic!("this test needs network namespaces: {why} (run it as root with iproute2)");
    }
    let net = std::sync::Arc::new(
        Netns::create_links("f", 2)
            .unwrap_or_else(|why| panic!("cannot create network namespaces: {why}")),
    );
    let text = r#"
[systems]
A = 0
B = 1
[modules]
M = 0
[transports.wifi]
kind = "udp"
security = "none"
endpoints = { A = "10.77.0.2:47500", B = "10.77.0.1:47500" }
[transports.wired]
kind = "tcp"
security = "none"
endpoints = { A = "10.77.1.2:47501", B = "10.77.1.1:47501" }
[table]
columns = ["A", "B"]
A = ["X", "wifi,wired"]
B = ["wifi,wired", "X"]
"#;
    let fleet =
        hetcomm::parse_fleet(text, "two-links.toml", None).unwrap_or_else(|e| panic!("{e}"));
    let n: u32 = 1_000;
    let (ready_tx, ready_rx) = std::sync::mpsc::channel();
    let receiver = {
        let (net, fleet) = (net.clone(), fleet.clone());
        std::thread::spawn(move || {
            net.enter(0).unwrap();
            let b = hetcomm::Comm::open_fleet(&fleet, "B").unwrap();
            let m = b.module("M").unwrap();
            ready_tx.send(()).unwrap();
            let mut got = Vec::new();
            while let Ok(msg) = m.recv_raw_timeout(Some(Duration::from_secs(5))) {
                got.push(u32::from_le_bytes(msg.payload[..4].try_into().unwrap()));
            }
            got
        })
    };
    ready_rx
        .recv_timeout(Duration::from_secs(10))
        .expect("B opened");
    let sender = {
        let (net, fleet) = (net.clone(), fleet.clone());
        std::thread::spawn(move || {
            net.enter(1).unwrap();
            let a = hetcomm::Comm::open_fleet(&fleet, "A").unwrap();
            let m = a.module("M").unwrap();
            let started = Instant::now();
            let mut outcomes = Vec::new();
            let mut tickets = Vec::new();
            let mut switches = Vec::new();
            for i in 0..n {
                let due = Duration::from_millis(5 * u64::from(i));
                if let Some(w) = due.checked_sub(started.elapsed()) {
                    std::thread::sleep(w);
                }
                let t = m
                    .send_raw(
                        "B",
                        "M",
                        hetcomm::MessageType(1),
                        &i.to_le_bytes(),
                        Default::default(),
                    )
                    .unwrap_or_else(|e| panic!("send {i}: {e}"));
                tickets.push((started.elapsed(), t));
                switches.extend(a.path_changes().into_iter().map(|s| (started.elapsed(), s)));
            }
            for (at, t) in &tickets {
                let o = t.wait_timeout(Duration::from_secs(20)).expect("an outcome");
                outcomes.push((*at, o, t.transport().map(str::to_string)));
            }
            switches.extend(a.path_changes().into_iter().map(|s| (started.elapsed(), s)));
            (outcomes, switches, a.stats().router)
        })
    };
    // The first link goes down on B's side 1.5 s into the stream, back up at 3 s.
    std::thread::sleep(Duration::from_millis(1_500));
    let dev = net.dev(0, 0);
    ip(&["-n", &net.namespaces[0], "link", "set", &dev, "down"]).unwrap();
    std::thread::sleep(Duration::from_millis(1_500));
    ip(&["-n", &net.namespaces[0], "link", "set", &dev, "up"]).unwrap();
    let (outcomes, switches, stats) = sender.join().unwrap();
    let got = receiver.join().unwrap();
    let distinct: BTreeSet<u32> = got.iter().copied().collect();
    assert_eq!(got.len(), distinct.len(), "a message reached B twice");
    assert_eq!(
        distinct,
        (0..n).collect::<BTreeSet<_>>(),
        "B misses messages"
    );
    let mut on = std::collections::BTreeMap::<String, u32>::new();
    for (i, (at, o, transport)) in outcomes.iter().enumerate() {
        assert!(
            matches!(o, hetcomm::Outcome::Delivered { .. }),
            "send {i} at {at:?}: {o}"
        );
        *on.entry(transport.clone().expect("names its transport"))
            .or_default() += 1;
    }
    assert_eq!(
        (stats.sends, stats.delivered),
        (u64::from(n), u64::from(n)),
        "{stats:?}"
    );
    let moved = |from: &str, to: &str| switches.iter().any(|(_, s)| s.from == from && s.now == to);
    assert!(moved("wifi", "wired"), "{switches:?}");
    assert!(moved("wired", "wifi"), "{switches:?}");
    let last = switches.last().map(|(_, s)| s.now.as_str());
    assert_eq!(
        last,
        Some("wifi"),
        "back on the first link at the end: {switches:?}"
    );
    assert!(on.get("wired").copied().unwrap_or(0) > 100, "{on:?}");
    assert!(on.get("wifi").copied().unwrap_or(0) > 400, "{on:?}");
    eprintln!("outcomes by transport {on:?}; switches {switches:?}");
}
