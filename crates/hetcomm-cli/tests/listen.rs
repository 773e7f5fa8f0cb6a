//! What `hetcomm listen` shows while it runs and when it stops (drop counters, signals,
//! times, payloads that do not decode), and how `hetcomm send`, `listen` and `demo` answer a
//! misspelt name or a failure: by system names, once, with a hint where one helps.
//!
//! Ports are picked free on 127.0.0.1; every wait is bounded by the test's deadline; children
//! are killed on drop.

mod support;

use std::net::UdpSocket;
use std::process::Command;
use std::time::Duration;

use serde_json::Value;
use support::*;

/// The message the send tests use (type 7 to Act).
const HELLO: &str = r#"{"code":1,"text":"hello"}"#;

/// A two-system UDP fleet on loopback: (its dir, its path, Bravo's endpoint).
fn alpha_bravo() -> (TempDir, std::path::PathBuf, String) {
    let (dir, fleet, ports) = loopback_fleet("udp", &[("Alpha", 0), ("Bravo", 1)]);
    (dir, fleet, format!("127.0.0.1:{}", ports[1]))
}

/// [`alpha_bravo`] unsecured, for tests whose raw socket plays Alpha with hand-made frames
/// (on a secured fleet they are refused before the router sees them, see
/// `crates/hetcomm/tests/security_attacks.rs`).
fn alpha_bravo_unsecured() -> (TempDir, std::path::PathBuf, String) {
    let (dir, fleet, ports) = loopback_fleet_unsecured("udp", &[("Alpha", 0), ("Bravo", 1)]);
    (dir, fleet, format!("127.0.0.1:{}", ports[1]))
}

/// Seconds since the listener started, from a line's leading `+1.234 s` column.
fn seconds(line: &str) -> f64 {
    let (time, _) = line
        .split_once(" s  ")
        .unwrap_or_else(|| panic!("no `+S.mmm s` column in {line:?}"));
    time.strip_prefix('+')
        .and_then(|t| t.parse().ok())
        .unwrap_or_else(|| panic!("no `+S.mmm s` column in {line:?}"))
}

/// The status lines a listener printed (its stderr between the `listening as` line and the
/// summary).
fn status_lines(child: &ChildGuard) -> Vec<String> {
    child
        .stderr_lines()
        .into_iter()
        .filter(|l| l.starts_with('+'))
        .collect()
}

fn stopped_by_signal_prints_the_summary(sig: i32, name: &str) {
    let deadline = Deadline::after(30);
    let (_dir, fleet, _) = alpha_bravo();
    let mut bravo = listen(&fleet, "Bravo", &[], deadline);
    let sent = send(&fleet, "Alpha", "Bravo", HELLO, deadline);
    assert_eq!(sent.status.code(), Some(0), "{sent:?}");
    assert!(bravo.next_stdout(deadline).ends_with(HELLO));

    signal(&bravo, sig);
    let status = bravo.wait_exit(deadline);
    assert_eq!(status.code(), Some(0), "{status:?}");
    assert!(
        bravo.stderr_lines().contains(&format!("stopped by {name}")),
        "{:?}",
        bravo.stderr_lines()
    );
    assert_eq!(
        counters_line(&bravo),
        "received 1 message; router: 1 received, 0 duplicates, 0 too old, 0 malformed, 0 unknown origin, 0 misrouted, 0 unknown module; inboxes dropped 0; links dropped 0; security: rejected_auth 0, rejected_replay 0, rejected_table 0, rejected_unknown_sender 0, rejected_no_session 0, handshake_timeouts 0, handshakes 1"
    );
}

#[test]
fn ctrl_c_ends_listen_with_its_summary() {
    stopped_by_signal_prints_the_summary(libc::SIGINT, "SIGINT");
}

#[test]
fn sigterm_ends_listen_with_its_summary() {
    stopped_by_signal_prints_the_summary(libc::SIGTERM, "SIGTERM");
}

#[test]
fn drops_show_on_a_status_line_while_listening() {
    let deadline = Deadline::after(40);
    let (_dir, fleet, bravo_ep) = alpha_bravo_unsecured();
    let mut bravo = listen(&fleet, "Bravo", &[], deadline);
    let raw = UdpSocket::bind("127.0.0.1:0").unwrap();

    for _ in 0..3 {
        raw.send_to(b"not a frame at all", &bravo_ep).unwrap();
    }
    // Within about a second, while the listener still runs.
    let first = bravo.wait_stderr("3 malformed", deadline.within(Duration::from_secs(10)));
    assert!(
        message_text(&first).starts_with("0 messages so far, 3 malformed"),
        "{first}"
    );

    // From a system the fleet does not have, then for a module it does not have.
    raw.send_to(&raw_data_frame(999, 1, 1, 1, &[0xc0]), &bravo_ep)
        .unwrap();
    raw.send_to(&raw_data_frame(0, 1, 9, 1, &[0xc0]), &bravo_ep)
        .unwrap();
    let second = bravo.wait_stderr("1 unknown module", deadline);
    assert_eq!(
        message_text(&second),
        "0 messages so far, 3 malformed, 1 unknown origin, 1 unknown module"
    );
    // At most one status line a second.
    let lines = status_lines(&bravo);
    for pair in lines.windows(2) {
        assert!(
            seconds(&pair[1]) - seconds(&pair[0]) >= 0.99,
            "status lines less than a second apart: {lines:?}"
        );
    }

    // Nothing changes now: no status line, however long it runs. (Waiting is the point here:
    // absence can only be seen by letting time pass.)
    std::thread::sleep(Duration::from_millis(2500));
    signal(&bravo, libc::SIGINT);
    assert_eq!(bravo.wait_exit(deadline).code(), Some(0));
    let lines = status_lines(&bravo);
    assert_eq!(lines.last(), Some(&second), "{lines:?}");
    for pair in lines.windows(2) {
        assert_ne!(
            message_text(&pair[0]),
            message_text(&pair[1]),
            "a status line repeated unchanged counters: {lines:?}"
        );
    }
    assert_eq!(
        counters_line(&bravo),
        "received 0 messages; router: 0 received, 0 duplicates, 0 too old, 3 malformed, 1 unknown origin, 0 misrouted, 1 unknown module; inboxes dropped 0; links dropped 0"
    );
}

#[test]
fn verbose_prints_each_drop_as_it_is_counted() {
    let deadline = Deadline::after(30);
    let (_dir, fleet, bravo_ep) = alpha_bravo_unsecured();
    let mut bravo = listen(&fleet, "Bravo", &["--verbose"], deadline);
    let raw = UdpSocket::bind("127.0.0.1:0").unwrap();

    raw.send_to(b"garbage", &bravo_ep).unwrap();
    let line = bravo.wait_stderr("malformed", deadline);
    assert_eq!(message_text(&line), "+1 malformed (1 in all)");
    // Addressed to system 5, which Bravo is not.
    raw.send_to(&raw_data_frame(0, 5, 1, 1, &[0xc0]), &bravo_ep)
        .unwrap();
    let line = bravo.wait_stderr("misrouted", deadline);
    assert_eq!(message_text(&line), "+1 misrouted (1 in all)");
    raw.send_to(b"garbage", &bravo_ep).unwrap();
    let line = bravo.wait_stderr("malformed", deadline);
    assert_eq!(message_text(&line), "+1 malformed (2 in all)");

    signal(&bravo, libc::SIGTERM);
    assert_eq!(bravo.wait_exit(deadline).code(), Some(0));
    assert!(counters_line(&bravo).contains(" 2 malformed, 0 unknown origin, 1 misrouted,"));
}

#[test]
fn json_tells_an_undecodable_payload_from_nil() {
    let deadline = Deadline::after(30);
    let (_dir, fleet, bravo_ep) = alpha_bravo_unsecured();
    let mut bravo = listen(&fleet, "Bravo", &["--count", "4", "--json"], deadline);
    let raw = UdpSocket::bind("127.0.0.1:0").unwrap();
    // A string of 5 bytes cut after 1; 0xc1, the one byte MessagePack never uses; 0xc0, nil;
    // 0x01 0x02, a value and a byte too many.
    let payloads: [&[u8]; 4] = [&[0xa5, b'h'], &[0xc1], &[0xc0], &[0x01, 0x02]];
    for (seq, payload) in (1..).zip(payloads) {
        raw.send_to(&raw_data_frame(0, 1, 1, seq, payload), &bravo_ep)
            .unwrap();
    }
    assert_eq!(bravo.wait_exit(deadline).code(), Some(0));
    let got: Vec<Value> = bravo
        .stdout_lines()
        .iter()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(got.len(), 4, "{got:?}");

    for (undecodable, hex, why) in [
        (
            &got[0],
            "a568",
            "not MessagePack: the value is cut short after 2 bytes",
        ),
        (
            &got[1],
            "c1",
            "not MessagePack: 0xc1 is no MessagePack value",
        ),
    ] {
        let undecodable = undecodable.as_object().unwrap();
        assert!(!undecodable.contains_key("payload"), "{undecodable:?}");
        assert_eq!(undecodable["payload_hex"], hex);
        assert_eq!(undecodable["payload_error"], why);
    }

    let nil = got[2].as_object().unwrap();
    assert_eq!(nil.get("payload"), Some(&Value::Null), "{nil:?}");
    assert_eq!(nil["payload_hex"], "c0");
    assert!(!nil.contains_key("payload_error"), "{nil:?}");

    let trailing = got[3].as_object().unwrap();
    assert!(!trailing.contains_key("payload"), "{trailing:?}");
    assert_eq!(trailing["payload_hex"], "0102");
    assert_eq!(
        trailing["payload_error"],
        "1 byte after the first MessagePack value"
    );
    // Every field of a line, as README.md lists them; the id is unique per message (issue
    // 41, item 11: two messages of one sender's two incarnations had the same id).
    let keys: Vec<&str> = got[0]
        .as_object()
        .unwrap()
        .keys()
        .map(String::as_str)
        .collect();
    assert_eq!(
        keys,
        [
            "broadcast",
            "from_module",
            "from_system",
            "id",
            "payload_error",
            "payload_hex",
            "priority",
            "received_us",
            "size",
            "timestamp_us",
            "to_module",
            "type"
        ]
    );
    assert_eq!(
        got[0]["id"],
        serde_json::json!({"origin": 0, "incarnation": 0x5eed, "seq": 1, "broadcast_space": false})
    );
}

#[test]
fn text_lines_show_seconds_since_the_start_or_raw_microseconds() {
    let deadline = Deadline::after(30);
    let (_dir, fleet, _) = loopback_fleet("udp", &[("Alpha", 0), ("Bravo", 1), ("Charlie", 2)]);
    let mut bravo = listen(&fleet, "Bravo", &["--count", "1"], deadline);
    let mut charlie = listen(
        &fleet,
        "Charlie",
        &["--count", "1", "--raw-times"],
        deadline,
    );
    let sent = send(&fleet, "Alpha", "All", HELLO, deadline);
    assert_eq!(sent.status.code(), Some(0), "{sent:?}");

    let line = bravo.next_stdout(deadline);
    let at = seconds(&line);
    assert!((0.0..60.0).contains(&at), "{line}");
    let rest = message_text(&line);
    assert!(
        rest.starts_with("Alpha.Plan -> Act  type=7 prio=100 sent=+"),
        "{line}"
    );
    assert!(rest.ends_with(HELLO), "{line}");

    let line = charlie.next_stdout(deadline);
    let (time, rest) = line.split_once("  ").unwrap();
    let us: u64 = time
        .strip_suffix("us")
        .and_then(|t| t.parse().ok())
        .unwrap_or_else(|| panic!("no raw time column in {line:?}"));
    let now_us = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_micros() as u64;
    assert!(now_us.abs_diff(us) < 60_000_000, "{line}");
    assert!(
        rest.starts_with("Alpha.Plan -> Act  type=7 prio=100 ts="),
        "{line}"
    );
    for child in [&mut bravo, &mut charlie] {
        assert_eq!(child.wait_exit(deadline).code(), Some(0));
    }
}

/// `hetcomm ARGS...` run to completion.
fn hetcomm(args: &[&str], deadline: Deadline) -> Finished {
    let mut cmd = Command::new(HETCOMM);
    cmd.args(args);
    run(&args.join(" "), cmd, deadline)
}

/// The one error line of a run that failed with exit code `code`.
fn error_line(f: &Finished, code: i32) -> String {
    assert_eq!(f.status.code(), Some(code), "{f:?}");
    let errors: Vec<&String> = f
        .stderr
        .iter()
        .filter(|l| l.starts_with("error: "))
        .collect();
    assert_eq!(errors.len(), 1, "{f:?}");
    errors[0].clone()
}

#[test]
fn misspelt_names_get_did_you_mean_and_the_list_once() {
    let deadline = Deadline::after(30);
    let (_dir, fleet, _) = alpha_bravo();
    let path = fleet.to_str().unwrap();
    let send_args = |from: &'static str, to: &'static str, module: &'static str| {
        vec![
            "send", path, "--as", from, "--to", to, "--module", module, "--type", "7", "--json",
            "1",
        ]
    };
    let cases: Vec<(Vec<&str>, String)> = vec![
        (
            send_args("Alpah", "Bravo", "Act"),
            format!("error: `--as Alpah`: {path} has no such system; did you mean `Alpha`? (systems: Alpha, Bravo)"),
        ),
        (
            send_args("Alpha", "Bravoo", "Act"),
            format!("error: `--to Bravoo`: {path} has no such system; did you mean `Bravo`? (destinations: Bravo, All)"),
        ),
        (
            send_args("Alpha", "all", "Act"),
            format!("error: `--to all`: {path} has no such system; did you mean `All`? (destinations: Bravo, All)"),
        ),
        (
            send_args("Alpha", "Zulu", "Act"),
            format!("error: `--to Zulu`: {path} has no such system; destinations: Bravo, All"),
        ),
        (
            send_args("Alpha", "Bravo", "Actt"),
            format!("error: `--module Actt`: {path} has no such module; did you mean `Act`? (modules: Plan, Act)"),
        ),
        (
            vec!["listen", path, "--as", "bravo", "--timeout", "5"],
            format!("error: `--as bravo`: {path} has no such system; did you mean `Bravo`? (systems: Alpha, Bravo)"),
        ),
        (
            vec!["listen", path, "--as", "Bravo", "--module", "Pln", "--timeout", "5"],
            format!("error: `--module Pln`: {path} has no such module; did you mean `Plan`? (modules: Plan, Act)"),
        ),
    ];
    for (args, expected) in cases {
        let f = hetcomm(&args, deadline);
        assert_eq!(error_line(&f, 1), expected, "{args:?}");
    }
}

#[test]
fn demo_letters_suggest_the_nearest_value() {
    let deadline = Deadline::after(30);
    for (flag, typo, nearest, values) in [
        (
            "--r",
            "wfi",
            "wifi",
            "inproc, wired, wifi, bluetooth-classic, ros1, zenoh, mqtt",
        ),
        (
            "--b",
            "bluetoth",
            "bluetooth",
            "inproc, wired, wifi, bluetooth-classic, bluetooth, zenoh, mqtt",
        ),
    ] {
        let f = hetcomm(&["demo", flag, typo], deadline);
        assert_eq!(f.status.code(), Some(2), "{f:?}");
        let err = f.stderr.join("\n");
        assert!(
            err.contains(&format!("a similar value exists: '{nearest}'")),
            "{err}"
        );
        assert!(
            err.contains(&format!("[possible values: {values}]")),
            "{err}"
        );
    }
}

#[test]
fn unreachable_names_the_system_not_its_id() {
    let deadline = Deadline::after(30);
    let dir = TempDir::new("inproc");
    let fleet = dir.write(
        "fleet.toml",
        "[systems]\nAlpha = 0\nBravo = 1\n\n[modules]\nPlan = 0\nAct = 1\n\n\
         [transports.local]\nkind = \"inproc\"\n\n\
         [table]\ncolumns = [\"Alpha\", \"Bravo\"]\nAlpha = [\"X\", \"local\"]\nBravo = [\"local\", \"X\"]\n",
    );
    // Bravo is not in this process: the in-process transport cannot reach it.
    let sent = send(&fleet, "Alpha", "Bravo", HELLO, deadline);
    assert_eq!(sent.status.code(), Some(1), "{sent:?}");
    assert_eq!(sent.stdout.len(), 1, "{sent:?}");
    let line = &sent.stdout[0];
    assert!(
        line.starts_with("Bravo: failed: peer unreachable: ") && line.ends_with("(attempts: 3)"),
        "{line}"
    );
    assert!(!line.contains("peer 1"), "an id instead of a name: {line}");
    assert_eq!(line.matches("unreachable").count(), 1, "{line}");
    assert_eq!(line.matches("Bravo").count(), 1, "{line}");
    assert_eq!(
        sent.stderr,
        [format!(
            "hint: `Alpha` reaches `Bravo` over an in-process transport, which reaches only systems opened by the same process: give the pair a udp or tcp transport in {} to reach another process",
            fleet.display()
        )],
        "{sent:?}"
    );
}

#[test]
fn no_acknowledgement_hints_at_a_listener() {
    let deadline = Deadline::after(30);
    // Bravo's endpoint is a socket that never answers. Unsecured, so the message's frames do
    // leave (a secured sender sends nothing but handshakes to it, and fails: see
    // `secured_send.rs`).
    let sink = UdpSocket::bind("127.0.0.1:0").unwrap();
    let bravo_ep = sink.local_addr().unwrap().to_string();
    let alpha_ep = format!("127.0.0.1:{}", free_udp_port());
    let dir = TempDir::new("hint");
    let fleet = dir.write(
        "fleet.toml",
        &unsecured(&fleet_text(
            "udp",
            &[("Alpha", 0, alpha_ep), ("Bravo", 1, bravo_ep)],
        )),
    );
    let sent = send(&fleet, "Alpha", "Bravo", HELLO, deadline);
    assert_eq!(sent.status.code(), Some(3), "unconfirmed: {sent:?}");
    assert_eq!(
        sent.stderr,
        [format!(
            "hint: nothing acknowledged it: is `Bravo` running, e.g. `hetcomm listen {} --as Bravo`?",
            fleet.display()
        )],
        "{sent:?}"
    );
}

#[test]
fn a_kind_built_out_names_the_command_that_builds_it_in() {
    let deadline = Deadline::after(30);
    let dir = TempDir::new("ros1");
    let fleet = dir.write(
        "fleet.toml",
        "[systems]\nAlpha = 0\nBravo = 1\n\n[modules]\nPlan = 0\n\n\
         [transports.ros]\nkind = \"ros1\"\n\n\
         [table]\ncolumns = [\"Alpha\", \"Bravo\"]\nAlpha = [\"X\", \"ros\"]\nBravo = [\"ros\", \"X\"]\n",
    );
    let f = hetcomm(
        &[
            "listen",
            fleet.to_str().unwrap(),
            "--as",
            "Bravo",
            "--timeout",
            "5",
        ],
        deadline,
    );
    let line = error_line(&f, 1);
    if line.contains("is unreachable") {
        // This binary has the kind built in: `cargo test --workspace` unifies features, and
        // hetcomm-link-ros1's tests turn hetcomm's `ros1` on. Then it says what it needs.
        assert!(line.contains("is `roscore`"), "{line}");
        return;
    }
    assert!(
        line.contains(
            "rebuild this command with `cargo build --release -p hetcomm-cli --features ros1`"
        ),
        "{line}"
    );
    assert_eq!(line.matches("--features").count(), 1, "{line}");

    // The demonstration with R = ROS 1 says the same.
    let out = dir.path().join("demo");
    let f = hetcomm(
        &["demo", "--r", "ros1", "--out", out.to_str().unwrap()],
        deadline,
    );
    let line = error_line(&f, 1);
    assert!(
        line.contains(
            "rebuild this command with `cargo build --release -p hetcomm-cli --features ros1`"
        ),
        "{line}"
    );
}

#[test]
fn an_endpoint_in_use_asks_whether_the_system_already_runs() {
    let deadline = Deadline::after(30);
    let (_dir, fleet, _) = alpha_bravo();
    let _bravo = listen(&fleet, "Bravo", &[], deadline);
    let path = fleet.to_str().unwrap();
    let f = hetcomm(
        &["listen", path, "--as", "Bravo", "--timeout", "5"],
        deadline,
    );
    let line = error_line(&f, 1);
    assert!(line.contains("in use"), "{line}");
    assert!(
        line.ends_with(&format!(
            "; is another program running as `Bravo` (e.g. `hetcomm listen {path} --as Bravo`)?"
        )),
        "{line}"
    );
}

#[test]
fn a_closed_output_ends_listen_with_its_summary() {
    let deadline = Deadline::after(40);
    let (_dir, fleet, _) = alpha_bravo();
    // `hetcomm listen … | head -1`, the listener's exit code kept by pipefail.
    let mut cmd = Command::new("bash");
    cmd.arg("-c").arg(format!(
        "set -o pipefail; '{HETCOMM}' listen '{}' --as Bravo --timeout 30 | head -1",
        fleet.display()
    ));
    let mut pipeline = ChildGuard::spawn("listen | head -1", cmd);
    pipeline.wait_stderr("listening as Bravo ", deadline);
    // The first line ends `head`; a later one finds the pipe closed (how many later depends
    // on when `head` is gone).
    for n in 0..10 {
        let sent = send(&fleet, "Alpha", "Bravo", &format!("{n}"), deadline);
        if sent.status.code() != Some(0)
            || pipeline
                .stderr_lines()
                .iter()
                .any(|l| l.starts_with("stopped: "))
        {
            break;
        }
    }
    assert_eq!(pipeline.wait_exit(deadline).code(), Some(0));
    assert_eq!(pipeline.stdout_lines().len(), 1);
    assert!(
        pipeline
            .stderr_lines()
            .contains(&"stopped: standard output was closed".to_string()),
        "{:?}",
        pipeline.stderr_lines()
    );
    assert!(counters_line(&pipeline).contains("; router: "));
}

/// SIGHUP reloads the fleet file: a reordered pair is applied live (the difference, what was
/// applied and the path switch are printed); a file that changes an id is refused with the
/// reason and changes nothing; the listener keeps running through both.
#[test]
fn sighup_reloads_the_fleet_file_or_says_why_not() {
    let deadline = Deadline::after(40);
    let dir = TempDir::new("reload");
    let (p1, p2, p3, p4) = (
        free_udp_port(),
        free_udp_port(),
        free_udp_port(),
        free_udp_port(),
    );
    let text = |bravo: u16, cell: &str| {
        format!(
            "[systems]\nAlpha = 0\nBravo = {bravo}\n[modules]\nPlan = 0\nAct = 1\n\
             [transports.wifi]\nkind = \"udp\"\nsecurity = \"none\"\n\
             endpoints = {{ Alpha = \"127.0.0.1:{p1}\", Bravo = \"127.0.0.1:{p2}\" }}\n\
             [transports.radio]\nkind = \"udp\"\nsecurity = \"none\"\n\
             endpoints = {{ Alpha = \"127.0.0.1:{p3}\", Bravo = \"127.0.0.1:{p4}\" }}\n\
             [table]\ncolumns = [\"Alpha\", \"Bravo\"]\n\
             Alpha = [\"X\", \"{cell}\"]\nBravo = [\"{cell}\", \"X\"]\n"
        )
    };
    let fleet = dir.write("fleet.toml", &text(1, "wifi,radio"));
    let mut bravo = listen(&fleet, "Bravo", &[], deadline);
    dir.write("fleet.toml", &text(1, "radio,wifi"));
    signal(&bravo, libc::SIGHUP);
    bravo.wait_stderr("reload", deadline);
    bravo.wait_stderr("applied: traffic to Alpha now takes radio,wifi", deadline);
    bravo.wait_stderr(
        "traffic to Alpha moved from transport wifi to radio",
        deadline,
    );
    dir.write("fleet.toml", &text(5, "wifi,radio"));
    signal(&bravo, libc::SIGHUP);
    bravo.wait_stderr("refused, nothing changed", deadline);
    bravo.wait_stderr("system `Bravo` changes id (1 -> 5)", deadline);
    signal(&bravo, libc::SIGINT);
    assert_eq!(bravo.wait_exit(deadline).code(), Some(0));
    let err = bravo.stderr_lines();
    assert!(
        err.iter()
            .any(|l| l.contains("pair Bravo -> Alpha: wifi,radio -> radio,wifi")),
        "{err:?}"
    );
    let moved = err
        .iter()
        .filter(|l| l.contains("moved from transport"))
        .count();
    assert_eq!(moved, 1, "the refused reload moved nothing: {err:?}");
}
