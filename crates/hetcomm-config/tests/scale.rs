//! Big fleets validate, and what they validate to is right. How fast, and in how much memory,
//! is measured by `hetcomm-bench --only config` (`benchmarks/run.sh`), not here.

use hetcomm_core::SystemId;

mod common;
use common::parse_str;

fn fleet(n: usize, table: bool) -> String {
    hetcomm_config::synthetic::scale_fleet_text(n, table)
}

fn check_full(n: usize) {
    let f = parse_str(&fleet(n, true), "big.toml", None).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(f.systems.len(), n);
    assert_eq!(f.table.len(), n * (n - 1));
    let lan = f.transports.iter().position(|t| t.name == "lan");
    let wifi = f.transports.iter().position(|t| t.name == "wifi");
    // Cell (i, j) is lan, wifi, L (= lan) or local by (i + j) mod 4.
    let (i, j) = (n as u16 - 1, 2);
    let want = match (usize::from(i) + usize::from(j)) % 4 {
        0 | 2 => lan,
        1 => wifi,
        _ => f.transports.iter().position(|t| t.name == "local"),
    };
    assert_eq!(f.table.get(&(SystemId(i), SystemId(j))).copied(), want);
    assert!(f.route(SystemId(5), SystemId(5)).is_none());
}

#[test]
fn a_thousand_systems_with_a_full_table_validate() {
    check_full(1000);
}

#[test]
fn ten_thousand_systems_validate() {
    let f = parse_str(&fleet(10_000, false), "big.toml", None).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(f.systems.len(), 10_000);
    assert_eq!(
        f.system_by_name("S9999").map(|s| s.id),
        Some(SystemId(9999))
    );
}

#[test]
fn a_big_table_with_one_mistake_reports_just_that_one() {
    let text = fleet(300, true).replacen(", \"wifi\"", ", \"wfii\"", 1);
    let e = parse_str(&text, "big.toml", None).unwrap_err();
    assert_eq!(e.0.len(), 1, "{e}");
    assert_eq!(e.0[0].message, "`wfii` names no transport or letter");
    assert_eq!(e.0[0].help.as_deref(), Some("did you mean `wifi`?"));
}

/// 100 million cells, 726 MB of text: about 12 s and 4 GB in a release build, far longer in a
/// debug one, so it runs on request: `cargo test --release -p hetcomm-config --test scale --
/// --ignored`. The benchmark measures it too.
#[test]
#[ignore = "100 M cells: run with --release -- --ignored"]
fn ten_thousand_systems_with_a_full_table_validate() {
    check_full(10_000);
}

#[test]
fn a_transport_renamed_but_not_in_the_table_gives_a_bounded_list() {
    // 90 000 cells name `wifi`, which no longer exists: ten are listed, the rest counted.
    let text = fleet(300, true).replace("[transports.wifi]", "[transports.wlan]");
    let e = parse_str(&text, "big.toml", None).unwrap_err();
    let unknown: Vec<_> =
        e.0.iter()
            .filter(|e| e.message.starts_with("`wifi` names no transport"))
            .collect();
    assert_eq!(unknown.len(), 11, "{e}");
    let cells = 300 * 300 / 4; // the cells with (i + j) % 4 == 1, none on the diagonal
    assert_eq!(
        unknown[10].message,
        format!(
            "`wifi` names no transport or letter: {} more cells from here on (the first 10 are \
             listed above)",
            cells - 10
        )
    );
}
