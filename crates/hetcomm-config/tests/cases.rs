//! Every file under `tests/cases/invalid/` must fail with exactly the text its `# expect:`
//! lines give (one line per output line, help lines included); every file under
//! `tests/cases/valid/` must load. Paths are relative because cargo runs tests from the
//! crate directory, which keeps the pinned messages short and machine-independent.

use std::path::{Path, PathBuf};

mod common;
use common::load;

fn toml_files(dir: &str) -> Vec<PathBuf> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap_or_else(|e| panic!("cannot list {dir}: {e}"))
        .map(|e| e.expect("directory entry").path())
        .filter(|p| p.extension().is_some_and(|x| x == "toml"))
        .map(|p| Path::new(dir).join(p.file_name().expect("file name")))
        .collect();
    files.sort();
    files
}

fn expected(path: &Path) -> String {
    let text = std::fs::read_to_string(path).expect("readable case");
    text.lines()
        .filter_map(|l| l.strip_prefix("# expect: "))
        .collect::<Vec<_>>()
        .join("\n")
}

#[test]
fn invalid_cases_fail_with_their_pinned_messages() {
    let files = toml_files("tests/cases/invalid");
    assert!(files.len() >= 25, "only {} invalid cases", files.len());
    let mut failures = Vec::new();
    for f in &files {
        let want = expected(f);
        assert!(!want.is_empty(), "{} has no `# expect:` line", f.display());
        match load(f) {
            Ok(_) => failures.push(format!("{}: loaded, expected an error", f.display())),
            Err(e) => {
                let got = e.to_string();
                if got != want {
                    failures.push(format!(
                        "{}:\n--- want\n{want}\n--- got\n{got}",
                        f.display()
                    ));
                }
            }
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n\n"));
}

#[test]
fn valid_cases_load() {
    let files = toml_files("tests/cases/valid");
    assert!(files.len() >= 3, "only {} valid cases", files.len());
    for f in &files {
        if let Err(e) = load(f) {
            panic!("{} should load:\n{e}", f.display());
        }
    }
}
