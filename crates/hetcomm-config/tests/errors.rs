//! Error behaviour beyond the one-error case files: several errors at once, unreadable
//! files, and the exact Display shapes others rely on.

use std::path::Path;

use hetcomm_config::*;

mod common;
use common::{load, load_legacy, parse_str};

#[test]
fn all_errors_are_collected_and_sorted_by_position() {
    let text = "\
[systems]
Alpha = 0
Bravo = 0

[inbox]
capacity = 0

[transports.lan]
kind = \"udp\"
endpoints = { Alpha = \"nowhere\", Bravo = \"127.0.0.1:74000\" }
atempts = 2
";
    let e = parse_str(text, "multi.toml", None).unwrap_err();
    let lines: Vec<String> =
        e.0.iter()
            .map(|e| format!("{}:{}: {}", e.line, e.column, e.message))
            .collect();
    assert_eq!(
        lines,
        [
            "3:9: duplicate system id 0: `Alpha` and `Bravo` both use it",
            "6:12: `inbox.capacity` must be at least 1, found 0",
            "10:23: malformed endpoint `nowhere` for `Alpha`",
            "10:42: port 74000 of endpoint `127.0.0.1:74000` for `Bravo` is out of range",
            "11:1: unknown key `atempts` in `transports.lan`",
        ]
    );
    assert!(e.0.iter().all(|e| e.file == "multi.toml"));
}

#[test]
fn display_shapes() {
    let one = ConfigError {
        file: "f.toml".into(),
        line: 3,
        column: 7,
        message: "bad".into(),
        help: None,
    };
    assert_eq!(one.to_string(), "f.toml:3:7: bad");
    let two = ConfigError {
        help: Some("fix it".into()),
        ..one.clone()
    };
    assert_eq!(two.to_string(), "f.toml:3:7: bad\n  help: fix it");
    let all = ConfigErrors(vec![two, one]);
    assert_eq!(
        all.to_string(),
        "f.toml:3:7: bad\n  help: fix it\nf.toml:3:7: bad"
    );
    let _: &dyn std::error::Error = &all;
}

#[test]
fn missing_files_are_errors_not_panics() {
    let e = load(Path::new("tests/no-such-fleet.toml")).unwrap_err();
    assert_eq!(e.0.len(), 1);
    assert!(
        e.0[0].message.starts_with("cannot read the fleet file: "),
        "{e}"
    );
    // No position is made up for a file that could not be read.
    assert_eq!((e.0[0].line, e.0[0].column), (0, 0));
    assert!(
        e.to_string()
            .starts_with("tests/no-such-fleet.toml: cannot read the fleet file: "),
        "{e}"
    );

    let e = load_legacy(
        Path::new("tests/nope-ids.txt"),
        Path::new("tests/nope-table.txt"),
        None,
    )
    .unwrap_err();
    assert_eq!(e.0.len(), 2, "{e}");
    assert_eq!(e.0[0].file, "tests/nope-ids.txt");
    assert_eq!(e.0[1].file, "tests/nope-table.txt");
    assert!(e.0.iter().all(|e| (e.line, e.column) == (0, 0)), "{e}");
    assert!(
        e.to_string()
            .starts_with("tests/nope-ids.txt: cannot read `tests/nope-ids.txt`: "),
        "{e}"
    );

    let e = parse_str(
        "[legacy]\nids = \"missing.txt\"\n",
        "m.toml",
        Some(Path::new("tests")),
    )
    .unwrap_err();
    assert_eq!((e.0[0].line, e.0[0].column), (2, 7));
    assert!(
        e.0[0]
            .message
            .starts_with("cannot read `tests/missing.txt`: "),
        "{e}"
    );
}

#[test]
fn legacy_b_without_addresses_is_reported_at_the_cell() {
    let dir = Path::new("tests/fixtures");
    let e = load_legacy(
        &dir.join("table16-ids.txt"),
        &dir.join("table17-table.txt"),
        None,
    )
    .unwrap_err();
    assert_eq!(
        e.to_string(),
        "tests/fixtures/table17-table.txt:2:7: letter `B` means a Bluetooth transport, which needs \
         Bluetooth addresses, but none are given\n  help: give the Bluetooth addresses in a third \
         file (the Table 3 format): `hetcomm validate --ids … --table … --bluetooth bt.txt`"
    );
}

#[test]
fn garbage_never_panics() {
    // A spread of hostile inputs: each must come back as Ok or Err, never a panic.
    let inputs = [
        "",
        "\u{feff}",
        "[[systems]]\nA = 1",
        "systems = 5",
        "[systems]\n\"\" = 0",
        "[systems]\nA = -1",
        "[systems]\nA = 1.5",
        "[systems]\nA = { modules = 3 }",
        "[systems]\nA = 0\n[table]\nA = 1",
        "[systems]\nA = 0\n[table]\ncolumns = 3\nA = [\"X\"]",
        "[systems]\nA = 0\n[table]\ncolumns = [[]]\nA = [1]",
        "[systems]\nA = 0\n[transports]\nx = 1",
        "[systems]\nA = 0\n[transports.x]\nkind = 1",
        "[systems]\nA = 0\n[transports.X]\nkind = \"inproc\"",
        "[systems]\nA = 0\n[transports.\"\"]\nkind = \"inproc\"",
        "[systems]\nA = 0\n[transports.e]\nkind = \"emulated\"\nover = \"e\"",
        "[systems]\nA = 0\n[transports.a]\nkind = \"emulated\"\nover = \"b\"\n[transports.b]\nkind = \"emulated\"\nover = \"a\"",
        "[systems]\nA = 0\n[transports.e]\nkind = \"emulated\"\nloss_percent = 200\nlatency_ms = -1\njitter_ms = \"x\"",
        "[systems]\nA = 0\n[letters]\nRR = \"x\"\nX = 1",
        "[systems]\nA = 0\n[legacy]\nids = 5\ntable = \"/\"",
        "[systems]\nA = 0\n[transports.r]\nkind = \"ros1\"\nmaster_uri = \"localhost\"",
        "[systems]\nA = 0\n[transports.b]\nkind = \"bluetooth\"\naddresses = {}\naddresses_file = \"x\"",
        "[systems]\nA = 0\n[transports.z]\nkind = \"mqtt\"\n[transports.z.deep.er]\nx = [{a = 1}]",
        "[modules]\nA = 99999",
        "[inbox]\noverflow = 3\nblock_timeout_ms = -4",
        "[systems]\nA = 0\nB = 1\n[table]\ncolumns = [\"A\", \"A\", \"B\"]\nA = [\"X\", \"X\", \"X\"]\nA2 = [\"R\"]",
    ];
    for text in inputs {
        if let Ok(f) = parse_str(text, "g.toml", None) {
            assert!(!f.systems.is_empty(), "{text:?}");
        }
    }
}

#[test]
fn loops_of_emulated_transports_are_reported_once() {
    let text = "[systems]\nA = 0\n[transports.a]\nkind = \"emulated\"\nover = \"b\"\n\
                [transports.b]\nkind = \"emulated\"\nover = \"a\"\n";
    let e = parse_str(text, "loop.toml", None).unwrap_err();
    assert_eq!(e.0.len(), 1, "{e}");
    assert_eq!(
        e.0[0].message,
        "transports wrap each other in a loop: a → b → a"
    );
}
