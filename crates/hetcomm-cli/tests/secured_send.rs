//! `hetcomm send` on a secured fleet when no session with the receiver can be made: a wrong
//! key, a rogue receiver (its key is not the fleet's), a receiver whose table refuses the
//! pair, a receiver that is not running. The security layer sends no data frame before a
//! session exists, so nothing of the message left: the outcome is failed (exit 1), with a
//! reason that names the handshake, within the attempt budget, and a hint that does not claim
//! the receiver is down. The receiver counts what it refused by reason (`hetcomm listen`'s
//! summary). Also: `listen`'s summary names every counter, and key errors read once each.
//!
//! Real processes on 127.0.0.1; every wait is bounded by the test's deadline.

mod support;

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use support::*;

const HELLO: &str = r#"{"code":1,"text":"hello"}"#;

/// How the receiver's copy of the fleet differs from the sender's.
#[derive(Clone, Copy, Debug)]
enum Change {
    /// Bravo holds another public key for Alpha than Alpha's own.
    WrongKeyForSender,
    /// Bravo runs with a key pair the fleet does not know.
    RogueReceiver,
    /// Bravo's table says X both ways between Alpha and Bravo.
    RefusedPair,
}

/// The sender's fleet (Alpha, Bravo, Charlie on `kind`, every pair allowed, keys in `keys/`)
/// and the receiver's copy of it with `change` made: (both directories, Alpha's fleet file,
/// Bravo's fleet file).
fn two_views(kind: &str, change: Change) -> ((TempDir, TempDir), PathBuf, PathBuf) {
    let systems = [("Alpha", 0), ("Bravo", 1), ("Charlie", 2)];
    let (alpha_dir, alpha_fleet, _) = loopback_fleet(kind, &systems);
    let bravo_dir = TempDir::new("bravo-view");
    let mut text = std::fs::read_to_string(&alpha_fleet).unwrap();
    let keys = bravo_dir.path().join("keys");
    std::fs::create_dir_all(&keys).unwrap();
    for entry in std::fs::read_dir(alpha_dir.path().join("keys")).unwrap() {
        let entry = entry.unwrap();
        let to = keys.join(entry.file_name());
        std::fs::copy(entry.path(), &to).unwrap();
    }
    let regenerate = |name: &str| {
        hetcomm::security::Keypair::generate()
            .unwrap()
            .write(&keys, name)
            .unwrap();
    };
    match change {
        Change::WrongKeyForSender => regenerate("Alpha"),
        Change::RogueReceiver => regenerate("Bravo"),
        Change::RefusedPair => {
            for (from, to) in [
                (
                    "Alpha = [\"X\", \"net\", \"net\"]",
                    "Alpha = [\"X\", \"X\", \"net\"]",
                ),
                (
                    "Bravo = [\"net\", \"X\", \"net\"]",
                    "Bravo = [\"X\", \"X\", \"net\"]",
                ),
            ] {
                assert!(text.contains(from), "{text}");
                text = text.replace(from, to);
            }
        }
    }
    let bravo_fleet = bravo_dir.write_plain("fleet.toml", &text);
    ((alpha_dir, bravo_dir), alpha_fleet, bravo_fleet)
}

/// The value of counter `name` in a `listen` summary line's `security:` part.
fn security_counter(summary: &str, name: &str) -> u64 {
    let (_, security) = summary
        .split_once("; security: ")
        .unwrap_or_else(|| panic!("no security counters in {summary:?}"));
    security
        .split(", ")
        .find_map(|c| c.strip_prefix(&format!("{name} ")))
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no {name} in {summary:?}"))
}

/// Sends Alpha → Bravo and checks it ended failed for want of a session, quickly, with a
/// hint that names both possibilities: the finished command.
fn send_fails_for_want_of_a_session(fleet: &Path, deadline: Deadline) -> Finished {
    let started = Instant::now();
    let sent = send(fleet, "Alpha", "Bravo", HELLO, deadline);
    let took = started.elapsed();
    assert_eq!(sent.status.code(), Some(1), "failed: {sent:?}");
    assert_eq!(sent.stdout.len(), 1, "{sent:?}");
    let line = &sent.stdout[0];
    assert!(
        line.starts_with("Bravo: failed: no secure session with Bravo: handshake unanswered for ")
            && line.ends_with("; the frame was not sent (attempts: 3)"),
        "{line}"
    );
    // Three attempts a round-trip timeout apart (100 + 200 ms), not a 5 s queue: within the
    // budget, with room for a loaded machine.
    assert!(took < Duration::from_secs(4), "took {took:?}: {sent:?}");
    assert_eq!(sent.stderr.len(), 1, "{sent:?}");
    let hint = &sent.stderr[0];
    assert!(
        hint.starts_with("hint: `Bravo` did not answer the security handshake"),
        "{hint}"
    );
    assert!(
        hint.contains("it refuses `Alpha`'s key or this pair"),
        "{hint}"
    );
    assert!(!hint.contains("is `Bravo` running"), "{hint}");
    sent
}

/// Bravo listens with its changed copy; Alpha's send fails; Bravo's summary counts why.
fn refused(kind: &str, change: Change) -> String {
    let deadline = Deadline::after(40);
    let (_dirs, alpha_fleet, bravo_fleet) = two_views(kind, change);
    let mut bravo = listen(&bravo_fleet, "Bravo", &[], deadline);
    send_fails_for_want_of_a_session(&alpha_fleet, deadline);
    signal(&bravo, libc::SIGTERM);
    let status = bravo.wait_exit(deadline);
    assert_eq!(status.code(), Some(0), "{status:?}");
    assert!(
        bravo.stdout_lines().is_empty(),
        "{:?}",
        bravo.stdout_lines()
    );
    let summary = counters_line(&bravo);
    assert_eq!(security_counter(&summary, "handshakes"), 0, "{summary}");
    summary
}

#[test]
fn udp_wrong_key_fails_naming_the_handshake() {
    let summary = refused("udp", Change::WrongKeyForSender);
    assert!(
        security_counter(&summary, "rejected_auth") >= 1,
        "{summary}"
    );
}

#[test]
fn tcp_wrong_key_fails_naming_the_handshake() {
    let summary = refused("tcp", Change::WrongKeyForSender);
    assert!(
        security_counter(&summary, "rejected_auth") >= 1,
        "{summary}"
    );
}

#[test]
fn udp_rogue_receiver_fails_naming_the_handshake() {
    let summary = refused("udp", Change::RogueReceiver);
    assert!(
        security_counter(&summary, "rejected_auth") >= 1,
        "{summary}"
    );
}

#[test]
fn udp_refused_pair_fails_and_counts_as_the_tables() {
    let summary = refused("udp", Change::RefusedPair);
    // Alpha is a member with a valid key: the table refused it, it is no stranger.
    assert!(
        security_counter(&summary, "rejected_table") >= 1,
        "{summary}"
    );
    assert_eq!(
        security_counter(&summary, "rejected_unknown_sender"),
        0,
        "{summary}"
    );
    assert_eq!(security_counter(&summary, "rejected_auth"), 0, "{summary}");
}

#[test]
fn tcp_refused_pair_fails_and_counts_as_the_tables() {
    let summary = refused("tcp", Change::RefusedPair);
    assert!(
        security_counter(&summary, "rejected_table") >= 1,
        "{summary}"
    );
    assert_eq!(
        security_counter(&summary, "rejected_unknown_sender"),
        0,
        "{summary}"
    );
}

/// Nobody on Bravo's port: only handshakes left (the layer sends no data frame before a
/// session exists), so the message certainly did not arrive.
fn receiver_not_running(kind: &str) {
    let deadline = Deadline::after(30);
    let (_dir, fleet, _) = loopback_fleet(kind, &[("Alpha", 0), ("Bravo", 1)]);
    send_fails_for_want_of_a_session(&fleet, deadline);
}

#[test]
fn udp_receiver_not_running_fails_since_no_data_frame_left() {
    receiver_not_running("udp");
}

#[test]
fn tcp_receiver_not_running_fails_since_no_data_frame_left() {
    receiver_not_running("tcp");
}

/// The summary names every counter, the security layer's included, and what was refused in
/// the last moment before the end shows in it and on a last status line.
#[test]
fn listen_summary_has_every_counter_and_the_last_moment() {
    let deadline = Deadline::after(30);
    let (_dir, fleet, ports) = loopback_fleet("udp", &[("Alpha", 0), ("Bravo", 1)]);
    let mut bravo = listen(&fleet, "Bravo", &[], deadline);
    let sent = send(&fleet, "Alpha", "Bravo", HELLO, deadline);
    assert_eq!(sent.status.code(), Some(0), "{sent:?}");
    assert!(bravo.next_stdout(deadline).ends_with(HELLO));
    // Unsecured frames on a secured link, just before the end: well within the second
    // between two status lines.
    let raw = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    for seq in 1..=5 {
        let frame = raw_data_frame(0, 1, 1, 100 + seq, &[0xc0]);
        raw.send_to(&frame, ("127.0.0.1", ports[1])).unwrap();
    }
    std::thread::sleep(Duration::from_millis(200));
    signal(&bravo, libc::SIGTERM);
    assert_eq!(bravo.wait_exit(deadline).code(), Some(0));
    let summary = counters_line(&bravo);
    assert!(
        summary.ends_with(
            "; security: rejected_auth 5, rejected_replay 0, rejected_table 0, rejected_unknown_sender 0, rejected_no_session 0, handshake_timeouts 0, handshakes 1"
        ),
        "{summary}"
    );
    let last_status = bravo
        .stderr_lines()
        .into_iter()
        .rfind(|l| l.starts_with('+'))
        .unwrap_or_else(|| panic!("no status line: {:?}", bravo.stderr_lines()));
    assert!(
        last_status.ends_with("1 message so far, 5 rejected_auth, 1 handshakes"),
        "{last_status}"
    );
}

/// `hetcomm send` as Alpha, expected to fail to open: its stderr.
fn open_error(fleet: &Path, deadline: Deadline) -> Vec<String> {
    let sent = run(
        "send with a bad key",
        send_cmd(fleet, "Alpha", "Bravo", HELLO),
        deadline,
    );
    assert_eq!(sent.status.code(), Some(1), "{sent:?}");
    assert!(sent.stdout.is_empty(), "{sent:?}");
    sent.stderr
}

#[test]
fn key_errors_say_each_thing_once_and_where() {
    use std::os::unix::fs::PermissionsExt;
    let deadline = Deadline::after(30);
    let (dir, fleet, _) = loopback_fleet("udp", &[("Alpha", 0), ("Bravo", 1)]);
    let key = dir.path().join("keys").join("Alpha.key");

    std::fs::set_permissions(&key, std::fs::Permissions::from_mode(0o644)).unwrap();
    let err = open_error(&fleet, deadline).join("\n");
    assert_eq!(err.matches("readable by other users").count(), 1, "{err}");
    assert_eq!(err.matches("to fix:").count(), 1, "{err}");
    assert!(
        err.contains("found in the fleet's keys directory"),
        "names where the key came from: {err}"
    );
    // The fleet file has no `private_key_file`: the error must not send the reader to one.
    assert!(!err.contains("private_key_file"), "{err}");
    assert!(
        err.contains(&format!("chmod 600 {}", key.display())),
        "{err}"
    );
    assert_eq!(err.matches("chmod 600").count(), 1, "{err}");

    std::fs::remove_file(&key).unwrap();
    let err = open_error(&fleet, deadline).join("\n");
    assert_eq!(
        err.matches("no private key for system Alpha").count(),
        1,
        "{err}"
    );
    assert_eq!(err.matches("to fix:").count(), 1, "{err}");
    assert!(
        err.contains(&format!("there is no {}", key.display())),
        "names the path it looked in: {err}"
    );
}
