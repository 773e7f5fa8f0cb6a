//! The fleet node example (`examples/fleet_node.rs`) reloads its fleet file on SIGHUP, as
//! `hetcomm listen` does: a reordered pair is applied live and printed (the difference, what
//! was applied); a file that changes an id is refused with the reason and changes nothing;
//! the node keeps running through both and quits when told. The example is built with the
//! crate's tests (`cargo test` builds examples; `scripts/zenoh-test.sh` runs them).

use std::io::{BufRead, BufReader, Write};
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::sync::mpsc::{self, Receiver};
use std::time::{Duration, Instant};

/// The example's binary, beside this test's (`target/debug/examples/fleet_node`).
fn node_binary() -> PathBuf {
    let exe = std::env::current_exe().expect("the test's path");
    let debug = exe
        .parent()
        .and_then(|deps| deps.parent())
        .expect("target/debug");
    let node = debug.join("examples").join("fleet_node");
    assert!(
        node.exists(),
        "{} is not built: run `cargo test` (which builds the examples) or `cargo build --example fleet_node`",
        node.display()
    );
    node
}

fn free_udp_port() -> u16 {
    std::net::UdpSocket::bind("127.0.0.1:0")
        .and_then(|s| s.local_addr())
        .expect("a free port")
        .port()
}

/// The fleet with A's id and the pair's cell as given.
fn fleet(ports: [u16; 4], a_id: u32, cell: &str) -> String {
    let [p1, p2, p3, p4] = ports;
    format!(
        "[systems]\nA = {a_id}\nB = 1\n[modules]\nM = 0\n\
         [transports.wifi]\nkind = \"udp\"\nsecurity = \"none\"\n\
         endpoints = {{ A = \"127.0.0.1:{p1}\", B = \"127.0.0.1:{p2}\" }}\n\
         [transports.radio]\nkind = \"udp\"\nsecurity = \"none\"\n\
         endpoints = {{ A = \"127.0.0.1:{p3}\", B = \"127.0.0.1:{p4}\" }}\n\
         [table]\ncolumns = [\"A\", \"B\"]\nA = [\"X\", \"{cell}\"]\nB = [\"{cell}\", \"X\"]\n"
    )
}

/// The node's stdout lines, read on a thread of their own.
fn lines_of(child: &mut Child) -> Receiver<String> {
    let out = child.stdout.take().expect("piped stdout");
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(out).lines().map_while(Result::ok) {
            if tx.send(line).is_err() {
                return;
            }
        }
    });
    rx
}

/// The next line holding `what`, within the deadline (the lines before it are passed over).
fn wait_for(rx: &Receiver<String>, what: &str, deadline: Instant) -> String {
    loop {
        let left = deadline.saturating_duration_since(Instant::now());
        match rx.recv_timeout(left) {
            Ok(line) if line.contains(what) => return line,
            Ok(_) => {}
            Err(e) => panic!("no line with {what:?} from the node: {e}"),
        }
    }
}

fn hangup(child: &Child) {
    let status = Command::new("kill")
        .args(["-HUP", &child.id().to_string()])
        .status()
        .expect("kill runs");
    assert!(status.success(), "kill -HUP {}", child.id());
}

#[test]
fn sighup_reloads_the_fleet_file_or_says_why_not() {
    let deadline = Instant::now() + Duration::from_secs(60);
    let dir = std::env::temp_dir().join(format!("fleet-node-reload-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("a temporary directory");
    let path = dir.join("fleet.toml");
    let ports = [
        free_udp_port(),
        free_udp_port(),
        free_udp_port(),
        free_udp_port(),
    ];
    std::fs::write(&path, fleet(ports, 0, "wifi,radio")).expect("write the fleet");
    let mut node = Command::new(node_binary())
        .arg(&path)
        .arg("A")
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .expect("the node starts");
    let rx = lines_of(&mut node);
    wait_for(&rx, "\"event\":\"ready\"", deadline);

    std::fs::write(&path, fleet(ports, 0, "radio,wifi")).expect("write the fleet");
    hangup(&node);
    let applied = wait_for(&rx, "\"event\":\"reload\"", deadline);
    assert!(applied.contains("\"ok\":true"), "{applied}");
    assert!(
        applied.contains("pair A -> B: wifi,radio -> radio,wifi"),
        "{applied}"
    );
    assert!(
        applied.contains("applied: traffic to B now takes radio,wifi"),
        "{applied}"
    );

    std::fs::write(&path, fleet(ports, 5, "wifi,radio")).expect("write the fleet");
    hangup(&node);
    let refused = wait_for(&rx, "\"event\":\"reload\"", deadline);
    assert!(refused.contains("\"ok\":false"), "{refused}");
    assert!(refused.contains("refused, nothing changed"), "{refused}");
    assert!(
        refused.contains("system `A` changes id (0 -> 5)"),
        "{refused}"
    );

    // Still running: it answers a command, then quits when told.
    let stdin = node.stdin.as_mut().expect("piped stdin");
    writeln!(stdin, "received").expect("a command");
    wait_for(&rx, "\"event\":\"received\"", deadline);
    writeln!(stdin, "quit").expect("quit");
    let status = node.wait().expect("the node ends");
    assert!(status.success(), "{status}");
    let _ = std::fs::remove_dir_all(&dir);
}
