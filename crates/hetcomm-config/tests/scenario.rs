//! Scenario files: a valid file parses into its schedule; every kind of mistake is reported at
//! `file:line:column` with what is wrong, all of them in one pass.

use hetcomm_config::scenario::{parse_scenario, FaultEffect, TapKind, TapSpec};
use hetcomm_config::Fleet;

mod common;
use common::parse_str;

fn fleet() -> Fleet {
    parse_str(
        r#"
[systems]
Alpha = 0
Charlie = 1
Tango = 2
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
"#,
        "fleet.toml",
        None,
    )
    .unwrap()
}

/// The errors of `text`, one `line:column: message` string each.
fn errors(text: &str) -> Vec<String> {
    parse_scenario(text, "s.toml", &fleet())
        .unwrap_err()
        .0
        .iter()
        .map(|e| {
            assert_eq!(e.file, "s.toml");
            format!("{}:{}: {}", e.line, e.column, e.message)
        })
        .collect()
}

#[test]
fn a_valid_scenario_parses_into_its_schedule() {
    let sc = parse_scenario(
        r#"
seed = 9
[[partition]]
between = ["Charlie", "Tango"]
start = 5.0
end = 8
[[link]]
from = "Alpha"
to = "Charlie"
loss = 0.1
latency_ms = 20
start = 0
end = 3
[[inject]]
at = 5
from = "Alpha.Plan"
to = "Charlie.Plan"
type = 0
payload = { code = 2 }
[[tap]]
to = "Tango"
from = "Charlie"
module = "Plan"
type = 0
action = "replace"
start = 5.0
end = 8.0
script = [{ at = 6.0, payload = { code = 1 } }]
[[tap]]
system = "Tango"
topic = "pose"
action = "delay"
delay_ms = 100
"#,
        "s.toml",
        &fleet(),
    )
    .unwrap();
    assert_eq!(sc.seed, Some(9));
    assert_eq!(sc.faults.len(), 2);
    assert_eq!(sc.faults[0].effect, FaultEffect::Cut);
    assert_eq!(
        sc.faults[0].pairs,
        [
            ("Charlie".into(), "Tango".into()),
            ("Tango".into(), "Charlie".into())
        ]
    );
    assert_eq!(sc.faults[1].pairs, [("Alpha".into(), "Charlie".into())]);
    assert_eq!(
        sc.injections[0].payload,
        [0x81, 0xa4, b'c', b'o', b'd', b'e', 2]
    );
    assert_eq!(sc.taps[0].kind, TapKind::Replace);
    assert_eq!(sc.taps[0].script.len(), 1);
    assert!(matches!(sc.taps[1].path, TapSpec::Topic { .. }));
    assert_eq!(sc.taps[1].kind, TapKind::Delay(100.0));
    assert_eq!(sc.end_s(), 8.0);
    assert_eq!(sc.summary_lines().len(), 5);
}

#[test]
fn unknown_systems_and_modules_are_located_with_a_suggestion() {
    let text = "[[silence]]\nsystem = \"Tnago\"\nstart = 1.0\nend = 2.0\n\n[[inject]]\nat = 1\nfrom = \"Alpha.Plna\"\nto = \"Charlie.Plan\"\ntype = 0\npayload = 1\n";
    assert_eq!(
        errors(text),
        [
            "2:10: unknown system `Tnago` in [[silence]] at line 1",
            "8:8: unknown module `Plna` in [[inject]] at line 6",
        ]
    );
    let e = parse_scenario(text, "s.toml", &fleet()).unwrap_err();
    assert_eq!(e.0[0].help.as_deref(), Some("did you mean `Tango`?"));
}

#[test]
fn times_in_the_past_and_backwards_windows_are_refused() {
    assert_eq!(
        errors("[[partition]]\nbetween = [\"Alpha\", \"Charlie\"]\nstart = -1.0\nend = 2.0\n\n[[silence]]\nsystem = \"Tango\"\nstart = 3.0\nend = 2.0\n\n[[inject]]\nat = -0.5\nfrom = \"Alpha.Plan\"\nto = \"Charlie.Plan\"\ntype = 0\npayload = 1\n"),
        [
            "3:9: `start` of [[partition]] at line 1 is -1 s: scenario time starts at 0, so a time must be 0 or later",
            "9:7: [[silence]] at line 6 ends at 2 s, not after its start at 3 s",
            "12:6: `at` of [[inject]] at line 11 is -0.5 s: scenario time starts at 0, so a time must be 0 or later",
        ]
    );
}

#[test]
fn overlapping_contradictory_schedules_are_refused() {
    let text = r#"[[link]]
between = ["Alpha", "Charlie"]
loss = 0.5
start = 0.0
end = 5.0

[[link]]
from = "Charlie"
to = "Alpha"
latency_ms = 100
start = 4.0
end = 6.0

[[tap]]
to = "Tango"
action = "replace"
start = 0.0
end = 5.0

[[tap]]
to = "Tango"
module = "Plan"
action = "replace"
start = 3.0
end = 9.0
"#;
    assert_eq!(
        errors(text),
        [
            "7:1: [[link]] at line 7 changes Charlie→Alpha while [[link]] at line 1 already does: the two contradict",
            "20:1: [[tap]] at line 20 replaces the source of a path that [[tap]] at line 14 already replaces at the same time: the two contradict",
        ]
    );
    // Back to back is not an overlap.
    assert!(parse_scenario(
        "[[link]]\nbetween = [\"Alpha\", \"Charlie\"]\nloss = 0.5\nstart = 0\nend = 5\n[[link]]\nbetween = [\"Alpha\", \"Charlie\"]\nloss = 0.1\nstart = 5\nend = 6\n",
        "s.toml",
        &fleet()
    )
    .is_ok());
}

#[test]
fn taps_on_paths_that_do_not_exist_are_refused() {
    assert_eq!(
        errors("[[tap]]\nto = \"Tango\"\nfrom = \"Alpha\"\naction = \"drop\"\n\n[[tap]]\nto = \"Tango\"\nmodule = \"World\"\naction = \"dorp\"\n\n[[inject]]\nat = 1\nfrom = \"Alpha.Plan\"\nto = \"Tango.Plan\"\ntype = 0\npayload = 1\n"),
        [
            "3:8: [[tap]] at line 1 is on a path that does not exist: the communication table has `X` from Alpha to Tango",
            "8:10: unknown module `World` in [[tap]] at line 6",
            "9:10: unknown tap action `dorp` in [[tap]] at line 6",
            "14:6: [[inject]] at line 11: the communication table has `X` from Alpha to Tango, so this message cannot be sent",
        ]
    );
}

#[test]
fn unknown_keys_and_bad_toml_are_located() {
    assert_eq!(
        errors("[[partition]]\nbetween = [\"Alpha\", \"Charlie\"]\nstart = 1\nende = 2\n"),
        [
            "1:1: [[partition]] at line 1 is missing `end`",
            "4:8: unknown key `ende` in [[partition]] at line 1",
        ]
    );
    assert_eq!(
        errors("[[partition]\n"),
        ["1:12: not valid TOML: invalid table header"]
    );
    assert_eq!(
        errors("[[cut]]\nbetween = 1\n"),
        ["1:1: unknown key `cut` in a scenario file"]
    );
}
