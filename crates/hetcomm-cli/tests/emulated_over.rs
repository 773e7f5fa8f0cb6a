//! An `emulated` transport over a real UDP or TCP transport, one system per process: `hetcomm
//! listen` in one process, `hetcomm send` from another. The emulation wraps the real link,
//! whose socket the runtime reads through the wrapper (issue 26: it used to read nothing).
//!
//! Ports are free ones on 127.0.0.1; every wait is bounded by the test's deadline; children
//! are killed on drop.

mod support;

use std::path::PathBuf;

use support::*;

/// The message every test sends (type 7 to Act).
const HELLO: &str = r#"{"code":1,"text":"hello"}"#;

/// A two-system fleet whose only route is `radio`: an emulated transport with `profile`
/// over `lan`, a `kind` (udp / tcp) transport on free loopback ports.
fn emulated_fleet(kind: &str, profile: &str) -> (TempDir, PathBuf) {
    let (a, b) = (free_port(kind), free_port(kind));
    let text = format!(
        r#"name = "emulated-over-{kind}"
[systems]
Alpha = 0
Bravo = 1

[modules]
Plan = 0
Act = 1

[transports.lan]
kind = "{kind}"
endpoints = {{ Alpha = "127.0.0.1:{a}", Bravo = "127.0.0.1:{b}" }}

[transports.radio]
kind = "emulated"
over = "lan"
profile = "{profile}"

[table]
columns = ["Alpha", "Bravo"]
Alpha = ["X", "radio"]
Bravo = ["radio", "X"]
"#
    );
    let dir = TempDir::new(&format!("emulated-over-{kind}"));
    let path = dir.write("fleet.toml", &text);
    (dir, path)
}

/// Over a lossless emulation (`wired`: a 0.1 ms delay, so frames go through the emulation's
/// delay thread), a message is delivered, the listener prints it once and labels the
/// transport as emulated over the real one's address. (The number of attempts is not
/// checked: on a loaded machine a hop through the delay thread and a TCP connect may outlast
/// the first retry timer.)
///
/// The listener runs for a fixed time rather than `--count 1`: on exit it waits for its
/// acknowledgements to be taken by its links, but a TCP link takes a frame into its queue
/// while it is still connecting, so an exiting listener could drop the acknowledgement.
fn delivered_across_processes(kind: &str) {
    let deadline = Deadline::after(30);
    let (_dir, fleet) = emulated_fleet(kind, "wired");
    let mut bravo = listen(&fleet, "Bravo", &["--timeout", "3"], deadline);
    let label = bravo
        .stderr_lines()
        .into_iter()
        .find(|l| l.starts_with("listening as Bravo "))
        .expect("the listening line");
    // Not `(in-process)`: the emulation runs over the real transport, which listens here.
    let prefix = format!(" on radio emulated over {kind}://127.0.0.1:");
    let port = label
        .split_once(&prefix)
        .map(|(_, rest)| rest.split(';').next().unwrap_or(rest));
    assert!(port.is_some_and(|p| p.parse::<u16>().is_ok()), "{label}");
    let sent = send(&fleet, "Alpha", "Bravo", HELLO, deadline);
    assert_eq!(sent.status.code(), Some(0), "{sent:?}");
    assert_eq!(sent.stdout.len(), 1, "{sent:?}");
    assert!(
        sent.stdout[0].starts_with("Bravo: delivered to the inbox (attempts: "),
        "{sent:?}"
    );
    let line = bravo.next_stdout(deadline);
    assert!(
        line.contains("Alpha.Plan -> Act  type=7 prio=100 "),
        "{line}"
    );
    assert!(line.ends_with(HELLO), "{line}");
    assert_eq!(bravo.wait_exit(deadline).code(), Some(0));
    let counters = counters_line(&bravo);
    assert!(
        counters.starts_with("received 1 message; router: 1 received, ")
            && counters.contains(" 0 malformed, 0 unknown origin, 0 misrouted")
            && counters.contains("; links dropped 0; security: rejected_auth 0, "),
        "{counters}"
    );
}

#[test]
fn emulated_over_udp_delivers_across_processes() {
    delivered_across_processes("udp");
}

#[test]
fn emulated_over_tcp_delivers_across_processes() {
    delivered_across_processes("tcp");
}

/// The fleet of the issue: `wifi` over UDP. Its delays have a long tail (a first
/// acknowledgement may come after the retry timer), so the outcome is checked, not the
/// number of attempts. The listener runs until it is stopped, so that an acknowledgement
/// still waiting in the emulation's delay queue is not discarded by its exit.
#[test]
fn wifi_emulated_over_udp_delivers_across_processes() {
    let deadline = Deadline::after(30);
    let (_dir, fleet) = emulated_fleet("udp", "wifi");
    let mut bravo = listen(&fleet, "Bravo", &["--timeout", "25"], deadline);
    let sent = send(&fleet, "Alpha", "Bravo", HELLO, deadline);
    assert_eq!(sent.status.code(), Some(0), "{sent:?}");
    assert!(
        sent.stdout[0].starts_with("Bravo: delivered to the inbox (attempts: "),
        "{sent:?}"
    );
    let line = bravo.next_stdout(deadline);
    assert!(line.ends_with(HELLO), "{line}");
    bravo.kill();
}
