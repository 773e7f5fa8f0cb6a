//! `[[tap]]` tables in a fleet file: the scenario file's syntax, read by the same parser into
//! `Fleet::taps`; a tap on a path that does not exist is reported at `file:line:column` with
//! what to fix, on both of the loader's ways of reading `[table]` (the fast scan of a plain
//! table and the ordinary one).

use hetcomm_config::scenario::{TapKind, TapSpec};
use hetcomm_core::MessageType;

mod common;
use common::parse_str;

/// A fleet whose `[table]` the fast scanner reads (plain rows); Tango hosts only Plan.
const FLEET: &str = r#"[systems]
Alpha = 0
Charlie = 1
Tango = { id = 2, modules = ["Plan"] }

[modules]
Plan = 0
Act = 1

[transports.net]
kind = "inproc"

[table]
columns = ["Alpha", "Charlie", "Tango"]
Alpha   = ["X", "net", "X"]
Charlie = ["net", "X", "net"]
Tango   = ["X", "net", "X"]
"#;

/// The same fleet with an escape in a row, which the fast scanner leaves to the ordinary
/// reader (`\u0065` is `e`: the same table).
fn slow(fleet: &str) -> String {
    fleet.replace(
        "Alpha   = [\"X\", \"net\", \"X\"]",
        "Alpha   = [\"X\", \"n\\u0065t\", \"X\"]",
    )
}

/// `FLEET` followed by `taps`: the errors, one `line:column: message` string each.
fn errors(fleet: &str, taps: &str) -> Vec<String> {
    let text = format!("{fleet}\n{taps}");
    parse_str(&text, "fleet.toml", None)
        .unwrap_err()
        .0
        .iter()
        .map(|e| {
            assert_eq!(e.file, "fleet.toml");
            format!("{}:{}: {}", e.line, e.column, e.message)
        })
        .collect()
}

/// The line of the fleet file where `taps` starts (1-based).
fn first_tap_line(fleet: &str) -> usize {
    fleet.lines().count() + 2
}

#[test]
fn fleet_file_taps_parse_into_the_fleet() {
    let text = format!(
        "{FLEET}\n{}",
        r#"[[tap]]
to = "Tango"
from = "Charlie"
module = "Plan"
type = 7
action = "delay"
delay_ms = 250

[[tap]]
system = "Alpha"
topic = "pose"
action = "observe"

[[tap]]
to = "Charlie"
from = "Alpha"
module = "Act"
type = 0
action = "replace"
script = [{ at = 0.5, payload = { code = 1 } }]
"#
    );
    let fleet = parse_str(&text, "fleet.toml", None).unwrap();
    assert_eq!(fleet.taps.len(), 3);
    assert_eq!(
        fleet.taps[0].path,
        TapSpec::Messages {
            from: Some("Charlie".into()),
            to: "Tango".into(),
            module: Some("Plan".into()),
            message_type: Some(MessageType(7)),
        }
    );
    assert_eq!(fleet.taps[0].kind, TapKind::Delay(250.0));
    assert_eq!(fleet.taps[0].window, None);
    assert_eq!(fleet.taps[0].line, first_tap_line(FLEET));
    assert_eq!(
        fleet.taps[1].path,
        TapSpec::Topic {
            system: "Alpha".into(),
            topic: "pose".into()
        }
    );
    assert_eq!(fleet.taps[2].kind, TapKind::Replace);
    assert_eq!(fleet.taps[2].script.len(), 1);
    // A fleet without taps has none, and the same fleet read the ordinary way agrees.
    assert!(parse_str(FLEET, "fleet.toml", None)
        .unwrap()
        .taps
        .is_empty());
    let slow_text = format!("{}\n{}", slow(FLEET), &text[FLEET.len() + 1..]);
    assert_ne!(slow_text, text);
    let slow_fleet = parse_str(&slow_text, "fleet.toml", None).unwrap();
    assert_eq!(slow_fleet.taps, fleet.taps);
}

#[test]
fn each_path_that_does_not_exist_is_a_located_error() {
    let taps = r#"[[tap]]
to = "Tnago"
action = "drop"

[[tap]]
to = "Tango"
from = "Alfa"
action = "drop"

[[tap]]
to = "Tango"
module = "Plna"
action = "drop"

[[tap]]
to = "Tango"
module = "Act"
action = "drop"

[[tap]]
to = "Tango"
from = "Alpha"
action = "observe"

[[tap]]
to = "Tango"
type = -1
action = "observe"

[[tap]]
system = "Tango"
topic = "pose"
from = "Alpha"
action = "observe"

[[tap]]
to = "Tango"
action = "dorp"
"#;
    let l = first_tap_line(FLEET);
    let expected = [
        format!("{}:6: unknown system `Tnago` in [[tap]] at line {l}", l + 1),
        format!(
            "{}:8: unknown system `Alfa` in [[tap]] at line {}",
            l + 6,
            l + 4
        ),
        format!(
            "{}:10: unknown module `Plna` in [[tap]] at line {}",
            l + 11,
            l + 9
        ),
        format!(
            "{}:10: [[tap]] at line {} is on a path that does not exist: system `Tango` does not host module `Act`",
            l + 16,
            l + 14
        ),
        format!(
            "{}:8: [[tap]] at line {} is on a path that does not exist: the communication table has `X` from Alpha to Tango",
            l + 21,
            l + 19
        ),
        format!(
            "{}:8: `type` of [[tap]] at line {} must be a message type id (0 to 4294967295)",
            l + 26,
            l + 24
        ),
        format!(
            "{}:8: `from` does not apply to a topic tap ([[tap]] at line {})",
            l + 32,
            l + 29
        ),
        format!(
            "{}:10: unknown tap action `dorp` in [[tap]] at line {}",
            l + 37,
            l + 35
        ),
    ];
    assert_eq!(errors(FLEET, taps), expected);
    // The ordinary reader reports the same errors at the same places.
    assert_eq!(errors(&slow(FLEET), taps), expected);
    // Taps are checked against a valid fleet: with another error in the file, that one is
    // reported (and the taps once it is fixed).
    let broken = FLEET.replace("kind = \"inproc\"", "kind = \"inproc\"\nattempt = 3");
    let e = errors(&broken, taps);
    assert_eq!(e.len(), 1, "{e:?}");
    assert!(e[0].contains("attempt"), "{e:?}");
    // Every error says what to fix.
    let text = format!("{FLEET}\n{taps}");
    let e = parse_str(&text, "fleet.toml", None).unwrap_err();
    assert_eq!(e.0[0].help.as_deref(), Some("did you mean `Tango`?"));
    assert_eq!(e.0[3].help.as_deref(), Some("`Tango` hosts Plan"));
    assert_eq!(
        e.0[4].help.as_deref(),
        Some("tap a pair the table connects")
    );
    assert!(e.0.iter().all(|x| x.help.is_some()), "{e}");
}

#[test]
fn tap_tables_must_be_tables_with_known_keys() {
    let l = first_tap_line(FLEET);
    // (At the top: after `[table]` it would be a row of the table.)
    assert_eq!(
        errors(&format!("tap = 3\n{FLEET}"), ""),
        ["1:7: `tap` must be written as [[tap]] tables"]
    );
    assert_eq!(
        errors(FLEET, "[[tap]]\nto = \"Tango\"\nacton = \"drop\"\n"),
        [
            format!("{l}:1: [[tap]] at line {l} is missing `action`"),
            format!("{}:9: unknown key `acton` in [[tap]] at line {l}", l + 2),
        ]
    );
}
