//! Keys and security in the fleet file: `[security] keys = "DIR"`, systems' `public_key`,
//! `public_key_file` and `private_key_file`, a transport's `security`, every error about them
//! (pinned exactly), and the functions the command line's `--keys` and `--insecure` use.
//! Fixture key files are under `tests/keys/` (public keys are public; the one `.key` file is
//! not a key, the loader never reads private keys).

use std::path::{Path, PathBuf};

use hetcomm_config::*;
use hetcomm_core::SystemId;

mod common;
use common::{load, parse_str};

/// `AAECAwQFBgcICQoLDA0ODxAREhMUFRYXGBkaGxwdHh8=`, in `tests/keys/good/Alpha.pub`.
const ALPHA: [u8; 32] = {
    let mut k = [0; 32];
    let mut i = 0;
    while i < 32 {
        k[i] = i as u8;
        i += 1;
    }
    k
};
const ALPHA_B64: &str = "AAECAwQFBgcICQoLDA0ODxAREhMUFRYXGBkaGxwdHh8=";
/// Bytes 100..132, in `tests/keys/good/Bravo.pub`.
const BRAVO: [u8; 32] = {
    let mut k = [0; 32];
    let mut i = 0;
    while i < 32 {
        k[i] = 100 + i as u8;
        i += 1;
    }
    k
};

/// Parses `text` as `fleet.toml` in the `tests` directory (so key paths print short).
fn parse(text: &str) -> Result<Fleet, ConfigErrors> {
    parse_str(text, "fleet.toml", Some(Path::new("tests")))
}

fn error(text: &str) -> String {
    match parse(text) {
        Ok(_) => panic!("loaded, expected an error:\n{text}"),
        Err(e) => e.to_string(),
    }
}

const TAIL: &str = "
[transports.lan]
kind = \"udp\"
endpoints = { Alpha = \"127.0.0.1:0\", Bravo = \"127.0.0.1:0\" }

[table]
columns = [\"Alpha\", \"Bravo\"]
Alpha = [\"X\", \"lan\"]
Bravo = [\"lan\", \"X\"]
";

fn fleet_with(head: &str) -> String {
    format!("{head}{TAIL}")
}

#[test]
fn a_keys_directory_gives_public_keys_and_private_key_files() {
    let f = parse(&fleet_with(
        "[security]\nkeys = \"keys/good\"\n\n[systems]\nAlpha = 0\nBravo = 1\nCharlie = 2\n",
    ))
    .unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(f.keys_dir, Some(PathBuf::from("tests/keys/good")));
    let alpha = f.system_by_name("Alpha").unwrap();
    assert_eq!(alpha.public_key, Some(ALPHA));
    assert_eq!(
        alpha.private_key_file, None,
        "no Alpha.key in the directory"
    );
    let bravo = f.system_by_name("Bravo").unwrap();
    assert_eq!(bravo.public_key, Some(BRAVO));
    assert_eq!(
        bravo.private_key_file,
        Some(PathBuf::from("tests/keys/good/Bravo.key"))
    );
    let charlie = f.system_by_name("Charlie").unwrap();
    assert_eq!(
        (charlie.public_key, &charlie.private_key_file),
        (None, &None)
    );
    assert_eq!(f.transport("lan").unwrap().security, SecurityMode::Keys);
}

#[test]
fn a_systems_own_keys_override_the_directory() {
    let f = parse(&fleet_with(&format!(
        "[security]\nkeys = \"keys/good\"\n\n\
         [systems.Alpha]\nid = 0\npublic_key_file = \"keys/good/Bravo.pub\"\nprivate_key_file = \"/etc/hetcomm/alpha.key\"\n\n\
         [systems.Bravo]\nid = 1\npublic_key = \"{ALPHA_B64}\"\n"
    )))
    .unwrap_or_else(|e| panic!("{e}"));
    let alpha = f.system_by_name("Alpha").unwrap();
    assert_eq!(alpha.public_key, Some(BRAVO));
    assert_eq!(
        alpha.private_key_file,
        Some(PathBuf::from("/etc/hetcomm/alpha.key"))
    );
    let bravo = f.system_by_name("Bravo").unwrap();
    assert_eq!(bravo.public_key, Some(ALPHA));
    assert_eq!(
        bravo.private_key_file,
        Some(PathBuf::from("tests/keys/good/Bravo.key"))
    );
}

#[test]
fn keys_without_a_directory_and_relative_private_key_files() {
    let f = parse(&fleet_with(&format!(
        "[systems]\nAlpha = {{ id = 0, public_key = \" {ALPHA_B64} \", private_key_file = \"alpha.key\" }}\nBravo = 1\n"
    )))
    .unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(f.keys_dir, None);
    let alpha = f.system_by_name("Alpha").unwrap();
    assert_eq!(alpha.public_key, Some(ALPHA));
    assert_eq!(
        alpha.private_key_file,
        Some(PathBuf::from("tests/alpha.key"))
    );
    assert_eq!(f.system_by_name("Bravo").unwrap().public_key, None);
}

#[test]
fn a_missing_keys_directory_says_to_run_keygen() {
    assert_eq!(
        error(&fleet_with(
            "[security]\nkeys = \"no-keys\"\n\n[systems]\nAlpha = 0\nBravo = 1\n"
        )),
        "fleet.toml:2:8: the keys directory `tests/no-keys` does not exist\n  \
         help: run `hetcomm keygen --fleet fleet.toml --out tests/no-keys` to write every \
         system's keys there, or correct the path"
    );
    assert_eq!(
        error(&fleet_with(
            "[security]\nkeys = \"keys/good/Alpha.pub\"\n\n[systems]\nAlpha = 0\nBravo = 1\n"
        )),
        "fleet.toml:2:8: the keys directory `tests/keys/good/Alpha.pub` is not a directory\n  \
         help: run `hetcomm keygen --fleet fleet.toml --out tests/keys/good/Alpha.pub` to write \
         every system's keys there, or correct the path"
    );
}

#[test]
fn a_key_that_is_not_base64_is_located() {
    let bad = format!("{}!{}", &ALPHA_B64[..10], &ALPHA_B64[11..]);
    assert_eq!(
        error(&fleet_with(&format!(
            "[systems]\nAlpha = {{ id = 0, public_key = \"{bad}\" }}\nBravo = 1\n"
        ))),
        "fleet.toml:2:32: `systems.Alpha.public_key` is not base64: it contains `!` (U+0021) \
         at character 11; a key is 44 characters of base64 (32 bytes)\n  \
         help: copy the whole base64 line of the `.pub` file `hetcomm keygen` wrote for this \
         system, or name the file with `public_key_file`"
    );
}

#[test]
fn a_key_of_the_wrong_length_says_how_long_it_is() {
    let help = "\n  help: copy the whole base64 line of the `.pub` file `hetcomm keygen` wrote \
                for this system, or name the file with `public_key_file`";
    assert_eq!(
        error(&fleet_with(&format!(
            "[systems.Alpha]\nid = 0\npublic_key = \"{}\"\n[systems.Bravo]\nid = 1\n",
            &ALPHA_B64[..43]
        ))),
        format!(
            "fleet.toml:3:14: `systems.Alpha.public_key` is 43 characters long; a key is 44 \
             characters of base64 (32 bytes){help}"
        )
    );
    // Valid base64 of 36 bytes.
    assert_eq!(
        error(&fleet_with(
            "[systems.Alpha]\nid = 0\npublic_key = \"AAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAA\"\n[systems.Bravo]\nid = 1\n"
        )),
        format!(
            "fleet.toml:3:14: `systems.Alpha.public_key` decodes to 36 bytes, but a key has 32 \
             (44 characters of base64){help}"
        )
    );
    assert_eq!(
        error(&fleet_with(
            "[systems.Alpha]\nid = 0\npublic_key = 7\n[systems.Bravo]\nid = 1\n"
        )),
        "fleet.toml:3:14: `systems.Alpha.public_key` must be a string, found integer `7`\n  \
         help: write the key in quotes: the base64 line of the system's `.pub` file from \
         `hetcomm keygen`"
    );
}

#[test]
fn both_public_key_and_public_key_file_is_an_error() {
    assert_eq!(
        error(&fleet_with(&format!(
            "[systems.Alpha]\nid = 0\npublic_key = \"{ALPHA_B64}\"\npublic_key_file = \"keys/good/Alpha.pub\"\n[systems.Bravo]\nid = 1\n"
        ))),
        "fleet.toml:4:1: system `Alpha` has both `public_key` and `public_key_file`\n  \
         help: keep one of them: the key itself, or the file that holds it"
    );
}

#[test]
fn a_missing_public_key_file_is_named() {
    assert_eq!(
        error(&fleet_with(
            "[systems.Alpha]\nid = 0\npublic_key_file = \"keys/nowhere/Alpha.pub\"\n[systems.Bravo]\nid = 1\n"
        )),
        "fleet.toml:3:19: cannot read the public key of system `Alpha` from \
         `tests/keys/nowhere/Alpha.pub`: No such file or directory (os error 2)\n  \
         help: check the path (relative to the fleet file's directory); `hetcomm keygen` \
         writes `<System>.pub` files"
    );
}

#[test]
fn bad_key_files_are_reported_at_their_line() {
    let shape = "\n  help: a key file holds one line of base64 (44 characters), after optional \
                 `#` comment lines, as `hetcomm keygen` writes it";
    let text = fleet_with(
        "[security]\nkeys = \"keys/bad\"\n\n[systems]\nAlpha = 0\nBravo = 1\nEmpty = 2\nLong = 3\n",
    );
    assert_eq!(
        error(&text),
        [
            "tests/keys/bad/Alpha.pub:2:1: the public key file of system `Alpha` holds a key \
             that is not base64: it contains `!` (U+0021) at character 11; a key is 44 \
             characters of base64 (32 bytes)",
            shape,
            "\ntests/keys/bad/Bravo.pub:2:1: the public key file of system `Bravo` holds a \
             second line of text; one key was expected",
            shape,
            "\ntests/keys/bad/Empty.pub: the public key file of system `Empty` holds no key",
            shape,
            "\ntests/keys/bad/Long.pub:1:1: the public key file of system `Long` holds a key \
             that decodes to 36 bytes, but a key has 32 (44 characters of base64)",
            shape,
        ]
        .concat()
    );
}

#[test]
fn security_modes_and_a_misspelt_one() {
    let f = parse(
        "[systems]\nAlpha = 0\nBravo = 1\n\n\
         [transports.wired]\nkind = \"inproc\"\nsecurity = \"none\"\n\n\
         [transports.lan]\nkind = \"udp\"\nsecurity = \"keys\"\nendpoints = { Alpha = \"127.0.0.1:0\", Bravo = \"127.0.0.1:0\" }\n\n\
         [transports.open]\nkind = \"tcp\"\nsecurity = \"none\"\nendpoints = { Alpha = \"127.0.0.1:0\", Bravo = \"127.0.0.1:0\" }\n\n\
         [transports.radio]\nkind = \"emulated\"\nprofile = \"wifi\"\nsecurity = \"none\"\n\n\
         [transports.radio-lan]\nkind = \"emulated\"\nprofile = \"wifi\"\nover = \"lan\"\n\n\
         [table]\ncolumns = [\"Alpha\", \"Bravo\"]\nAlpha = [\"X\", \"lan\"]\nBravo = [\"open\", \"X\"]\n",
    )
    .unwrap_or_else(|e| panic!("{e}"));
    let mode = |n: &str| f.transport(n).unwrap().security;
    assert_eq!(mode("wired"), SecurityMode::None);
    assert_eq!(mode("lan"), SecurityMode::Keys);
    assert_eq!(mode("open"), SecurityMode::None);
    assert_eq!(mode("radio"), SecurityMode::None);
    assert_eq!(mode("radio-lan"), SecurityMode::Keys);
    let leaves = |n: &str| f.leaves_process(f.transport(n).unwrap());
    assert!(!leaves("wired") && !leaves("radio"));
    assert!(leaves("lan") && leaves("open") && leaves("radio-lan"));

    assert_eq!(
        error("[systems]\nAlpha = 0\n\n[transports.lan]\nkind = \"udp\"\nsecurity = \"nnone\"\nendpoints = { Alpha = \"127.0.0.1:0\" }\n"),
        "fleet.toml:6:12: unknown security mode `nnone`\n  \
         help: did you mean `none`? valid security modes: keys, none"
    );
    assert_eq!(
        error("[systems]\nAlpha = 0\n\n[transports.lan]\nkind = \"udp\"\nsecurity = false\nendpoints = { Alpha = \"127.0.0.1:0\" }\n"),
        "fleet.toml:6:12: `transports.lan.security` must be a string, found boolean `false`\n  \
         help: one of: keys, none"
    );
}

#[test]
fn unknown_keys_in_security_are_suggested() {
    assert_eq!(
        error(&fleet_with(
            "[security]\nkey = \"keys/good\"\n\n[systems]\nAlpha = 0\nBravo = 1\n"
        )),
        "fleet.toml:2:1: unknown key `key` in `security`\n  \
         help: did you mean `keys`?"
    );
    assert_eq!(
        error(&fleet_with(
            "[security]\nkeys = 1\n\n[systems]\nAlpha = 0\nBravo = 1\n"
        )),
        "fleet.toml:2:8: `security.keys` must be a string, found integer `1`\n  \
         help: write the directory `hetcomm keygen` wrote, in quotes, relative to the fleet \
         file, e.g. `keys = \"keys\"`"
    );
    assert_eq!(
        error(&fleet_with(
            "[systems.Alpha]\nid = 0\npublic_key_fle = \"a.pub\"\n[systems.Bravo]\nid = 1\n"
        )),
        "fleet.toml:3:1: unknown key `public_key_fle` in `systems.Alpha`\n  \
         help: did you mean `public_key_file`?"
    );
}

#[test]
fn load_skipping_keys_reads_no_key_file() {
    let dir = std::env::temp_dir().join(format!("hetcomm-skipkeys-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("fleet.toml");
    std::fs::write(
        &file,
        fleet_with(
            "[security]\nkeys = \"keys\"\n\n[systems.Alpha]\nid = 0\npublic_key_file = \"nowhere.pub\"\n[systems.Bravo]\nid = 1\n",
        ),
    )
    .unwrap();
    let e = load(&file).unwrap_err();
    assert_eq!(e.0.len(), 2, "{e}");
    let f = load_skipping_keys(&file, &Kinds::new()).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(f.keys_dir, Some(dir.join("keys")));
    assert!(f.systems.iter().all(|s| s.public_key.is_none()));
    // Inline keys are still checked.
    std::fs::write(
        &file,
        fleet_with("[systems]\nAlpha = { id = 0, public_key = \"abc\" }\nBravo = 1\n"),
    )
    .unwrap();
    assert!(load_skipping_keys(&file, &Kinds::new()).is_err());
    let _ = std::fs::remove_dir_all(&dir);
}

fn legacy_fleet() -> Fleet {
    // Table 1's systems are 0 to 4; the keys directory has Alpha and Bravo only by name, so
    // use a small fleet of our own with those names.
    parse_str(
        "[systems]\nAlpha = 0\nBravo = 1\n\n[transports.wired]\nkind = \"inproc\"\n\n\
         [transports.lan]\nkind = \"udp\"\nendpoints = { Alpha = \"127.0.0.1:0\", Bravo = \"127.0.0.1:0\" }\n\n\
         [table]\ncolumns = [\"Alpha\", \"Bravo\"]\nAlpha = [\"X\", \"lan\"]\nBravo = [\"wired\", \"X\"]\n",
        "plain.toml",
        None,
    )
    .unwrap_or_else(|e| panic!("{e}"))
}

#[test]
fn apply_keys_dir_fills_a_loaded_fleet() {
    let mut f = legacy_fleet();
    apply_keys_dir(&mut f, Path::new("tests/keys/good")).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(f.keys_dir, Some(PathBuf::from("tests/keys/good")));
    assert_eq!(f.system(SystemId(0)).unwrap().public_key, Some(ALPHA));
    assert_eq!(f.system(SystemId(1)).unwrap().public_key, Some(BRAVO));
    assert_eq!(
        f.system(SystemId(1)).unwrap().private_key_file,
        Some(PathBuf::from("tests/keys/good/Bravo.key"))
    );
}

#[test]
fn apply_keys_dir_errors_change_nothing() {
    let mut f = legacy_fleet();
    let before = f.clone();
    let e = apply_keys_dir(&mut f, Path::new("tests/keys/none")).unwrap_err();
    assert_eq!(
        e.to_string(),
        "tests/keys/none: the keys directory `tests/keys/none` does not exist\n  \
         help: run `hetcomm keygen --ids IDS --table TABLE --out tests/keys/none` to write \
         every system's keys there, or correct the path"
    );
    let e = apply_keys_dir(&mut f, Path::new("tests/keys/bad")).unwrap_err();
    assert_eq!(e.0.len(), 2, "{e}");
    assert!(
        e.0[0]
            .to_string()
            .starts_with("tests/keys/bad/Alpha.pub:2:1: "),
        "{e}"
    );
    assert!(
        e.0[1]
            .to_string()
            .starts_with("tests/keys/bad/Bravo.pub:2:1: "),
        "{e}"
    );
    assert_eq!(f, before);
}

#[test]
fn insecure_turns_every_transport_off() {
    let mut f = legacy_fleet();
    assert!(f
        .transports
        .iter()
        .all(|t| t.security == SecurityMode::Keys));
    insecure(&mut f);
    assert!(f
        .transports
        .iter()
        .all(|t| t.security == SecurityMode::None));
}

#[test]
fn security_lines_say_what_is_secured_and_which_keys_are_missing() {
    let mut f = legacy_fleet();
    assert_eq!(
        f.security_lines(),
        [
            "transport `wired` (inproc): in-process: frames never leave the process",
            "transport `lan` (udp): secured; 2 of the 2 systems it carries have no public key: \
             Alpha, Bravo",
        ]
    );
    f.systems[0].public_key = Some(ALPHA);
    assert_eq!(
        f.security_lines()[1],
        "transport `lan` (udp): secured; 1 of the 2 systems it carries have no public key: Bravo"
    );
    f.systems[1].public_key = Some(BRAVO);
    assert_eq!(
        f.security_lines()[1],
        "transport `lan` (udp): secured; all 2 systems it carries have a public key"
    );
    insecure(&mut f);
    assert_eq!(
        f.security_lines(),
        [
            "transport `wired` (inproc): in-process, not secured (security = \"none\")",
            "transport `lan` (udp): NOT SECURED (security = \"none\"): anyone who can reach it \
             can pose as any system",
        ]
    );
}

#[test]
fn load_with_keys_dir_replaces_the_files_directory() {
    let dir = std::env::temp_dir().join(format!("hetcomm-keysdir-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("fleet.toml");
    // The file's own directory does not exist on this machine; `public_key_file` is still read.
    std::fs::write(
        &file,
        fleet_with(&format!(
            "[security]\nkeys = \"keys\"\n\n[systems.Alpha]\nid = 0\npublic_key_file = \"{}\"\n[systems.Bravo]\nid = 1\n",
            std::fs::canonicalize("tests/keys/good/Bravo.pub").unwrap().display()
        )),
    )
    .unwrap();
    assert!(load(&file).is_err());
    let good = std::fs::canonicalize("tests/keys/good").unwrap();
    let f = load_with_keys_dir(&file, &Kinds::new(), &good).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(f.keys_dir.as_deref(), Some(good.as_path()));
    // DIR's Alpha.pub replaces the file's; Bravo's comes from DIR.
    assert_eq!(f.system_by_name("Alpha").unwrap().public_key, Some(ALPHA));
    assert_eq!(f.system_by_name("Bravo").unwrap().public_key, Some(BRAVO));
    let e = load_with_keys_dir(&file, &Kinds::new(), Path::new("tests/keys/none")).unwrap_err();
    assert!(
        e.to_string().starts_with(&format!(
            "tests/keys/none: the keys directory `tests/keys/none` does not exist\n  help: run `hetcomm keygen --fleet {} --out tests/keys/none`",
            file.display()
        )),
        "{e}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn legacy_sections_take_their_keys_from_the_security_section() {
    let dir = std::env::temp_dir().join(format!("hetcomm-legacykeys-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join("ids.txt"), "0 Alpha\n1 Bravo\n").unwrap();
    std::fs::write(dir.join("table.txt"), "  0 1\n0 X R\n1 R X\n").unwrap();
    let good = std::fs::canonicalize("tests/keys/good").unwrap();
    std::fs::write(
        dir.join("fleet.toml"),
        format!(
            "[legacy]\nids = \"ids.txt\"\ntable = \"table.txt\"\n\n[security]\nkeys = \"{}\"\n",
            good.display()
        ),
    )
    .unwrap();
    let f = load(&dir.join("fleet.toml")).unwrap_or_else(|e| panic!("{e}"));
    let _ = std::fs::remove_dir_all(&dir);
    assert_eq!(f.system(SystemId(0)).unwrap().public_key, Some(ALPHA));
    assert_eq!(f.system(SystemId(1)).unwrap().public_key, Some(BRAVO));
    assert_eq!(
        f.security_lines(),
        ["transport `R` (ros1): secured; all 2 systems it carries have a public key"]
    );
}

#[test]
fn in_process_security_is_read_and_checked() {
    let text = |v: &str| {
        format!(
            "[systems]\nA = 0\nB = 1\n[modules]\nM = 0\n[transports.t]\nkind = \"inproc\"\n[table]\ncolumns = [\"A\", \"B\"]\nA = [\"X\", \"t\"]\nB = [\"t\", \"X\"]\n[security]\nin_process = {v}\n"
        )
    };
    let fleet = parse_str(&text("true"), "f.toml", None).unwrap();
    assert!(fleet.secure_in_process);
    let fleet = parse_str(&text("false"), "f.toml", None).unwrap();
    assert!(!fleet.secure_in_process);
    let err = parse_str(&text("\"yes\""), "f.toml", None)
        .unwrap_err()
        .to_string();
    assert!(
        err.starts_with("f.toml:13:14:")
            && err.contains("security.in_process")
            && err.contains("true or false"),
        "{err}"
    );
}
