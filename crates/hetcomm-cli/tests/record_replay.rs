//! `hetcomm demo --record` / `--replay`, `hetcomm replay`, `hetcomm record`, `hetcomm
//! monitor` (in a real terminal: tmux) and `hetcomm topology`, run as a user runs them.

mod support;

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

use hetcomm::sim::{SimFleet, SimOptions};
use hetcomm_record::format::Event;
use hetcomm_record::{RecordOptions, Recorder};
use support::*;

fn hetcomm(args: &[&str]) -> Finished {
    let mut cmd = Command::new(HETCOMM);
    cmd.args(args);
    run(&args.join(" "), cmd, Deadline::after(120))
}

fn ok(f: &Finished) {
    assert_eq!(f.status.code(), Some(0), "{f:?}");
}

fn read(path: &Path) -> String {
    std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

fn demo(dir: &Path, name: &str, extra: &[&str]) -> (Vec<String>, PathBuf) {
    let out = dir.join(name);
    let out_s = out.to_str().unwrap();
    let mut args = vec!["demo", "--out", out_s];
    args.extend_from_slice(extra);
    let f = hetcomm(&args);
    ok(&f);
    (f.stdout, out)
}

#[test]
fn replaying_the_demo_with_recorded_systems_replaced_reproduces_its_tables() {
    let dir = TempDir::new("rec-demo");
    let json = dir.path().join("run.mcap");
    let msgpack = dir.path().join("run-msgpack.mcap");
    let (tables, out) = demo(dir.path(), "orig", &["--record", json.to_str().unwrap()]);
    let (tables2, _) = demo(
        dir.path(),
        "orig2",
        &["--record", msgpack.to_str().unwrap(), "--msgpack"],
    );
    assert_eq!(tables, tables2, "recording changes nothing");
    assert!(tables.iter().any(|l| l.starts_with("Table 9")));
    for (file, replace) in [
        (&json, "Alpha"),
        (&json, "Charlie"),
        (&json, "Alpha,Charlie,Tango"),
        (&msgpack, "Alpha"),
    ] {
        let name = format!("replay-{replace}");
        let (replayed, out2) = demo(
            dir.path(),
            &name,
            &["--replay", file.to_str().unwrap(), "--replace", replace],
        );
        assert_eq!(
            replayed,
            tables,
            "replacing {replace} from {}",
            file.display()
        );
        for csv in ["commands.csv", "poses.csv"] {
            assert_eq!(read(&out.join(csv)), read(&out2.join(csv)), "{csv}");
        }
    }
}

#[test]
fn replaying_into_the_simulator_sends_every_recorded_send() {
    let dir = TempDir::new("rec-sim");
    let rec = dir.path().join("run.mcap");
    demo(dir.path(), "orig", &["--record", rec.to_str().unwrap()]);
    let (events, _) = hetcomm_record::read(&rec).unwrap();
    let sends = events
        .iter()
        .filter(|e| matches!(e, Event::Send(s) if s.attempt == 1))
        .count();
    let fleet = dir.write(
        "fleet.toml",
        hetcomm_examples::leader_follower::EMBEDDED_FLEET,
    );
    let f = hetcomm(&[
        "replay",
        rec.to_str().unwrap(),
        "--into",
        fleet.to_str().unwrap(),
        "--sim",
        "--speed",
        "4",
    ]);
    ok(&f);
    let text = f.stdout.join("\n");
    assert!(
        text.contains(&format!("replayed {sends} sends")),
        "{sends} sends: {text}"
    );
    assert!(
        text.contains(&format!("outcomes: {sends} delivered")),
        "{text}"
    );
}

#[test]
fn a_truncated_or_foreign_file_is_reported_with_what_was_readable() {
    let dir = TempDir::new("rec-cut");
    let rec = dir.path().join("run.mcap");
    demo(dir.path(), "orig", &["--record", rec.to_str().unwrap()]);
    let bytes = std::fs::read(&rec).unwrap();
    let fleet = dir.write(
        "fleet.toml",
        hetcomm_examples::leader_follower::EMBEDDED_FLEET,
    );
    let cut = dir.path().join("cut.mcap");
    std::fs::write(&cut, &bytes[..bytes.len() * 2 / 3]).unwrap();
    let f = hetcomm(&[
        "replay",
        cut.to_str().unwrap(),
        "--into",
        fleet.to_str().unwrap(),
        "--sim",
    ]);
    assert_eq!(f.status.code(), Some(1), "{f:?}");
    let text = f.stdout.join("\n");
    assert!(text.contains("cut short"), "{text}");
    let read_line = f.stdout.iter().find(|l| l.starts_with("read: ")).unwrap();
    let n: u64 = read_line["read: ".len()..]
        .split(' ')
        .next()
        .unwrap()
        .parse()
        .unwrap();
    assert!(n > 0, "{read_line}");
    assert!(!f.stderr.join("\n").contains("panicked"));

    let foreign = dir.write("notes.mcap", "not a recording");
    let f = hetcomm(&[
        "replay",
        foreign.to_str().unwrap(),
        "--into",
        fleet.to_str().unwrap(),
        "--sim",
    ]);
    assert_eq!(f.status.code(), Some(1));
    assert!(
        f.stderr.join("\n").contains("not an MCAP file"),
        "{:?}",
        f.stderr
    );
}

#[test]
fn topology_pictures_show_every_system_and_transport() {
    let dir = TempDir::new("rec-topo");
    let fleet = dir.write(
        "fleet.toml",
        hetcomm_examples::leader_follower::EMBEDDED_FLEET,
    );
    let svg = dir.path().join("fleet.svg");
    ok(&hetcomm(&[
        "topology",
        fleet.to_str().unwrap(),
        "-o",
        svg.to_str().unwrap(),
        "--show-x",
    ]));
    let text = read(&svg);
    assert!(text.starts_with("<svg xmlns=\"http://www.w3.org/2000/svg\""));
    assert!(text.trim_end().ends_with("</svg>"));
    for label in [
        ">Alpha<",
        ">Charlie<",
        ">Tango<",
        ">VirtualEnv<",
        ">VirtualEnv2<",
        ">VirtualEnv3<",
        ">wired<",
        ">radio<",
        ">X<",
    ] {
        assert!(text.contains(label), "{label} missing");
    }
    // Five pairs share a transport both ways (one two-headed arrow each); the other ten
    // unordered pairs are X.
    assert_eq!(text.matches("class=\"pair\"").count(), 15);
    assert_eq!(text.matches("marker-start").count(), 5);

    let png = dir.path().join("fleet.png");
    ok(&hetcomm(&[
        "topology",
        fleet.to_str().unwrap(),
        "-o",
        png.to_str().unwrap(),
    ]));
    let bytes = std::fs::read(&png).unwrap();
    assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n");
    let width = u32::from_be_bytes(bytes[16..20].try_into().unwrap());
    let height = u32::from_be_bytes(bytes[20..24].try_into().unwrap());
    assert_eq!((width, height), (900, 940));

    let bad = hetcomm(&["topology", fleet.to_str().unwrap(), "-o", "x.gif"]);
    assert_eq!(bad.status.code(), Some(1));
}

/// A UDP fleet A, B on loopback without security (this test is about monitoring).
fn udp_fleet(dir: &TempDir) -> PathBuf {
    let text = format!(
        r#"name = "monitored"
[systems]
A = 0
B = 1
[modules]
Plan = 0
Act = 1
[transports.net]
kind = "udp"
security = "none"
endpoints = {{ A = "127.0.0.1:{}", B = "127.0.0.1:{}" }}
[table]
columns = ["A", "B"]
A = ["X", "net"]
B = ["net", "X"]
"#,
        free_udp_port(),
        free_udp_port()
    );
    dir.write("fleet.toml", &text)
}

/// A recording of A sending to B every 20 ms for `seconds` (made in a simulation of the fleet:
/// milliseconds).
fn steady_recording(fleet: &Path, path: &Path, seconds: u64) {
    let fleet = hetcomm::load_fleet(fleet).unwrap();
    let sim = SimFleet::open(fleet, SimOptions::default()).unwrap();
    let a = sim.system("A").unwrap();
    let rec = Recorder::create(
        path,
        a.fleet(),
        RecordOptions {
            origin: sim.now(),
            ..RecordOptions::default()
        },
    )
    .unwrap();
    let h = rec.attach(&a);
    let plan = a.module("Plan").unwrap();
    let start = sim.now();
    for k in 0..seconds * 50 {
        sim.run_until(start + Duration::from_millis(20 * k));
        plan.send_raw(
            "B",
            "Act",
            hetcomm::MessageType(7),
            &hetcomm::payload::encode(&k).unwrap(),
            Default::default(),
        )
        .unwrap();
    }
    sim.run_idle(sim.now() + Duration::from_secs(5));
    drop(h);
    rec.finish().unwrap();
}

/// The number in the `msg/s` column of the A → B row of a monitor screen.
fn rate_on_screen(screen: &str) -> Option<f64> {
    screen.lines().find_map(|l| {
        let cells: Vec<&str> = l
            .split(|c: char| c.is_whitespace() || c == '│')
            .filter(|c| !c.is_empty())
            .collect();
        (cells.len() > 4 && cells[0] == "A" && cells[1] == "B" && cells[2] == "net")
            .then(|| cells[3].parse().ok())
            .flatten()
    })
}

#[test]
fn the_monitor_shows_live_rates_of_a_multi_process_udp_fleet_in_a_terminal_and_as_json() {
    if Command::new("tmux").arg("-V").output().is_err() {
        panic!("tmux is needed to capture the monitor from a real terminal: install it (scripts/test.sh does)");
    }
    let deadline = Deadline::after(90);
    let dir = TempDir::new("rec-monitor");
    let fleet = udp_fleet(&dir);
    let rec = dir.path().join("steady.mcap");
    steady_recording(&fleet, &rec, 12);
    let (tui_port, json_port) = (free_udp_port(), free_udp_port());
    let monitors = format!("127.0.0.1:{tui_port},127.0.0.1:{json_port}");

    // The terminal monitor, in a detached tmux session of its own server.
    let socket = format!("hetcomm-test-{}", std::process::id());
    let tmux = |args: &[&str]| {
        Command::new("tmux")
            .args(["-L", &socket])
            .args(args)
            .output()
            .expect("tmux runs")
    };
    let monitor_cmd = format!(
        "{HETCOMM} monitor {} --listen 127.0.0.1:{tui_port} --duration 40",
        fleet.display()
    );
    let started = tmux(&[
        "new-session",
        "-d",
        "-s",
        "mon",
        "-x",
        "160",
        "-y",
        "40",
        &monitor_cmd,
    ]);
    assert!(started.status.success(), "{started:?}");
    struct KillServer(String);
    impl Drop for KillServer {
        fn drop(&mut self) {
            let _ = Command::new("tmux")
                .args(["-L", &self.0, "kill-server"])
                .output();
        }
    }
    let _server = KillServer(socket.clone());

    let mut json_cmd = Command::new(HETCOMM);
    json_cmd.args([
        "monitor",
        fleet.to_str().unwrap(),
        "--json",
        "--duration",
        "9",
    ]);
    json_cmd.args(["--listen", &format!("127.0.0.1:{json_port}")]);
    let mut json_monitor = ChildGuard::spawn("monitor --json", json_cmd);

    // B listens in one process, A replays the steady recording in another; both publish.
    let mut b = Command::new(HETCOMM);
    b.args([
        "listen",
        fleet.to_str().unwrap(),
        "--as",
        "B",
        "--timeout",
        "30",
    ]);
    b.env("HETCOMM_MONITOR", &monitors);
    let mut b = ChildGuard::spawn("listen B", b);
    b.wait_stderr("listening as B", deadline);
    let mut a = Command::new(HETCOMM);
    a.args([
        "replay",
        rec.to_str().unwrap(),
        "--into",
        fleet.to_str().unwrap(),
    ]);
    a.env("HETCOMM_MONITOR", &monitors);
    let _a = ChildGuard::spawn("replay as A", a);

    // The terminal shows a non-zero rate for A → B within a few refreshes.
    let mut screen = String::new();
    let mut rate = None;
    while !deadline.passed() && !matches!(rate, Some(r) if r > 0.0) {
        std::thread::sleep(Duration::from_millis(500));
        let cap = tmux(&["capture-pane", "-p", "-t", "mon"]);
        screen = String::from_utf8_lossy(&cap.stdout).into_owned();
        rate = rate_on_screen(&screen);
    }
    let rate = rate.unwrap_or_else(|| panic!("no A → B row on screen:\n{screen}"));
    assert!(
        rate > 10.0 && rate < 100.0,
        "50 msg/s sent, {rate} shown:\n{screen}"
    );
    for heading in [
        "msg/s", "deliv", "unconf", "failed", "retx", "p50", "p99", "inboxes",
    ] {
        assert!(screen.contains(heading), "{heading} missing:\n{screen}");
    }

    // The JSON lines say the same to a script.
    json_monitor.wait_exit(deadline);
    let lines = json_monitor.stdout_lines();
    let best = lines
        .iter()
        .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
        .flat_map(|v| v["pairs"].as_array().cloned().unwrap_or_default())
        .filter(|p| p["source"] == "A" && p["destination"] == "B")
        .max_by(|x, y| x["sends"].as_u64().cmp(&y["sends"].as_u64()))
        .unwrap_or_else(|| panic!("no A → B pair in {lines:?}"));
    assert!(best["rate"].as_f64().unwrap() > 10.0, "{best}");
    assert!(best["delivered"].as_u64().unwrap() > 0, "{best}");
    assert!(best["received"].as_u64().unwrap() > 0, "{best}");
    assert_eq!(best["transport"], "net");
    assert!(best["latency_p50_us"].as_u64().is_some(), "{best}");
}

#[test]
fn record_captures_what_a_live_udp_fleet_sends_to_a_system_and_replay_sends_it_again() {
    let deadline = Deadline::after(60);
    let dir = TempDir::new("rec-live");
    let fleet = udp_fleet(&dir);
    let steady = dir.path().join("steady.mcap");
    steady_recording(&fleet, &steady, 2);
    let out = dir.path().join("live.mcap");

    // B is opened by `hetcomm record` (one process), A by `hetcomm replay` (another).
    let mut rec = Command::new(HETCOMM);
    rec.args(["record", fleet.to_str().unwrap(), "--as", "B", "-o"])
        .arg(&out)
        .args(["--duration", "15"]);
    let mut rec = ChildGuard::spawn("record B", rec);
    rec.wait_stderr("recording B into", deadline);
    let mut a = Command::new(HETCOMM);
    a.args([
        "replay",
        steady.to_str().unwrap(),
        "--into",
        fleet.to_str().unwrap(),
    ]);
    let replay = run("replay as A", a, deadline);
    assert_eq!(replay.status.code(), Some(0), "{replay:?}");
    let text = replay.stdout.join("\n");
    assert!(text.contains("replayed 100 sends"), "{text}");
    assert!(text.contains("outcomes: 100 delivered"), "{text}");
    assert_eq!(rec.wait_exit(deadline).code(), Some(0));
    assert!(
        rec.stderr_lines()
            .iter()
            .any(|l| l.contains("0 send attempts, 100 receipts, 0 outcomes")),
        "{:?}",
        rec.stderr_lines()
    );

    // Every message arrived once, in order, with its payload, over the UDP transport.
    let (events, report) = hetcomm_record::read(&out).unwrap();
    assert!(report.problem.is_none(), "{}", report.describe());
    let payloads: Vec<u64> = events
        .iter()
        .filter_map(|e| match e {
            Event::Receipt(r) => {
                assert_eq!(r.message.source.system, "A");
                assert_eq!(r.message.transport_name.as_deref(), Some("net"));
                assert_eq!(r.status, "delivered");
                hetcomm::payload::decode(&r.message.payload_bytes().unwrap()).ok()
            }
            _ => None,
        })
        .collect();
    assert_eq!(payloads, (0..100).collect::<Vec<u64>>());

    // That recording holds only what B received; replaying it sends those messages again
    // from A, to a B recording again (issue 41, item 3: it failed "no recorded send").
    let again = dir.path().join("again.mcap");
    let mut rec = Command::new(HETCOMM);
    rec.args(["record", fleet.to_str().unwrap(), "--as", "B", "-o"])
        .arg(&again)
        .args(["--duration", "15"]);
    let mut rec = ChildGuard::spawn("record B again", rec);
    rec.wait_stderr("recording B into", deadline);
    let mut a = Command::new(HETCOMM);
    a.args([
        "replay",
        out.to_str().unwrap(),
        "--into",
        fleet.to_str().unwrap(),
    ]);
    let replay = run("replay the receipts", a, deadline);
    assert_eq!(replay.status.code(), Some(0), "{replay:?}");
    assert!(
        replay.stderr.iter().any(|l| l.contains(
            "holds no sends, only what B received (100 messages): replaying those, sent again from A"
        )),
        "{replay:?}"
    );
    assert!(
        replay.stdout.join("\n").contains("outcomes: 100 delivered"),
        "{replay:?}"
    );
    assert_eq!(rec.wait_exit(deadline).code(), Some(0));
    let (events, _) = hetcomm_record::read(&again).unwrap();
    let received = events
        .iter()
        .filter(|e| matches!(e, Event::Receipt(r) if r.message.source.system == "A"))
        .count();
    assert_eq!(received, 100);

    // A recording with nothing to replay says what it holds and what to do.
    let empty = dir.path().join("empty.mcap");
    let mut rec = Command::new(HETCOMM);
    rec.args(["record", fleet.to_str().unwrap(), "--as", "B", "-o"])
        .arg(&empty)
        .args(["--duration", "1"]);
    assert_eq!(run("record nothing", rec, deadline).status.code(), Some(0));
    let mut a = Command::new(HETCOMM);
    a.args([
        "replay",
        empty.to_str().unwrap(),
        "--into",
        fleet.to_str().unwrap(),
    ]);
    let nothing = run("replay nothing", a, deadline);
    assert_eq!(nothing.status.code(), Some(1), "{nothing:?}");
    assert!(
        nothing.stderr.join("\n").contains(
            "nothing to replay: it holds 0 sends, 0 receipts and 0 outcomes; record a run with \
             `hetcomm demo --record FILE` (sends) or a live system with `hetcomm record FLEET \
             --as SYSTEM -o FILE` (receipts)"
        ),
        "{nothing:?}"
    );
}

#[test]
fn a_one_shot_send_reports_its_statistics_to_the_monitor_as_it_exits() {
    // `hetcomm send` lives for a fraction of the monitor's period: without a last report at
    // exit the monitor never heard of it (issue 41, item 5).
    let deadline = Deadline::after(30);
    let monitor = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    let sink = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    let dir = TempDir::new("send-monitor");
    let fleet = dir.write(
        "fleet.toml",
        &unsecured(&fleet_text(
            "udp",
            &[
                ("Alpha", 0, format!("127.0.0.1:{}", free_udp_port())),
                ("Bravo", 1, sink.local_addr().unwrap().to_string()),
            ],
        )),
    );
    let mut cmd = send_cmd(&fleet, "Alpha", "Bravo", r#"{"code": 1}"#);
    cmd.env("HETCOMM_MONITOR", monitor.local_addr().unwrap().to_string());
    let sent = run("send with a monitor", cmd, deadline);
    assert_eq!(sent.status.code(), Some(3), "nobody acknowledges: {sent:?}");
    monitor.set_nonblocking(true).unwrap();
    let mut buf = vec![0u8; 65_536];
    let mut reports = Vec::new();
    while let Ok((n, _)) = monitor.recv_from(&mut buf) {
        reports.push(serde_json::from_slice::<serde_json::Value>(&buf[..n]).unwrap());
    }
    let last = reports.last().expect("at least the report at exit");
    assert_eq!(last["system"], "Alpha", "{last}");
    let pair = &last["pairs"][0];
    assert_eq!(
        (&pair["destination"], &pair["sends"], &pair["unconfirmed"]),
        (
            &serde_json::json!("Bravo"),
            &serde_json::json!(1),
            &serde_json::json!(1)
        ),
        "{last}"
    );
}
