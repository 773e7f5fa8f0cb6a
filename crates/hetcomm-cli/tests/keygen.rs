//! `hetcomm keygen`: the key files it writes (private ones mode 0600, public ones readable by
//! hetcomm-security), its refusal to overwrite, and the fleet-file snippets it prints, which
//! must load to the keys it wrote.

mod support;

use std::path::{Path, PathBuf};
use std::process::Command;

use hetcomm_security::{Keypair, PrivateKey, PublicKey};
use support::{TempDir, HETCOMM};

fn hetcomm(args: &[&str]) -> (i32, String, String) {
    let out = Command::new(HETCOMM)
        .args(args)
        .output()
        .expect("run hetcomm");
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

const SYSTEMS: &str = "[systems]\nAlpha = 0\nBravo = { id = 1, modules = [\"Plan\"] }\n";
const REST: &str = "
[transports.lan]
kind = \"udp\"
endpoints = { Alpha = \"127.0.0.1:0\", Bravo = \"127.0.0.1:0\" }

[table]
columns = [\"Alpha\", \"Bravo\"]
Alpha = [\"X\", \"lan\"]
Bravo = [\"lan\", \"X\"]
";

/// Runs keygen for a fleet at `dir/conf/fleet.toml` into `dir/keys`; returns (fleet, keys,
/// stdout).
fn keygen_fleet(dir: &TempDir) -> (PathBuf, PathBuf, String) {
    std::fs::create_dir_all(dir.path().join("conf")).unwrap();
    let fleet = dir.write_plain("conf/fleet.toml", &format!("{SYSTEMS}{REST}"));
    let keys = dir.path().join("keys");
    let (code, out, err) = hetcomm(&[
        "keygen",
        "--fleet",
        fleet.to_str().unwrap(),
        "--out",
        keys.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{err}");
    assert!(err.is_empty(), "{err}");
    (fleet, keys, out)
}

/// The lines of `out` from the one equal to `first` up to the next blank line.
fn snippet(out: &str, first: &str) -> String {
    let lines: Vec<&str> = out
        .lines()
        .skip_while(|l| *l != first)
        .take_while(|l| !l.is_empty())
        .collect();
    assert!(!lines.is_empty(), "no `{first}` in:\n{out}");
    lines.join("\n") + "\n"
}

#[cfg(unix)]
fn mode(p: &Path) -> u32 {
    use std::os::unix::fs::PermissionsExt;
    std::fs::metadata(p).unwrap().permissions().mode() & 0o777
}

#[test]
fn writes_a_key_pair_per_system() {
    let dir = TempDir::new("keygen-files");
    let (_, keys, out) = keygen_fleet(&dir);
    for name in ["Alpha", "Bravo"] {
        let private_path = keys.join(format!("{name}.key"));
        let public_path = keys.join(format!("{name}.pub"));
        #[cfg(unix)]
        assert_eq!(mode(&private_path), 0o600, "{}", private_path.display());
        let private = PrivateKey::load(&private_path).unwrap_or_else(|e| panic!("{e}"));
        let public = PublicKey::load(&public_path).unwrap_or_else(|e| panic!("{e}"));
        let pair = Keypair::from_private(private).unwrap();
        assert_eq!(
            pair.public, public,
            "{name}'s .pub is the public half of its .key"
        );
        assert!(
            out.contains(&format!(
                "  {} -> the machine that runs {name}",
                private_path.display()
            )),
            "{out}"
        );
    }
    #[cfg(unix)]
    assert_eq!(mode(&keys), 0o700, "a new keys directory is private");
    let a = PublicKey::load(&keys.join("Alpha.pub")).unwrap();
    let b = PublicKey::load(&keys.join("Bravo.pub")).unwrap();
    assert_ne!(a, b);
}

#[test]
fn the_security_snippet_is_relative_to_the_fleet_file_and_loads() {
    let dir = TempDir::new("keygen-dir");
    let (fleet, keys, out) = keygen_fleet(&dir);
    let section = snippet(&out, "[security]");
    assert_eq!(section, "[security]\nkeys = \"../keys\"\n");
    let secured = dir.write_plain("conf/fleet.toml", &format!("{section}\n{SYSTEMS}{REST}"));
    assert_eq!(secured, fleet);
    let f = hetcomm::load_fleet(&fleet).unwrap_or_else(|e| panic!("{e}"));
    for s in &f.systems {
        let public = PublicKey::load(&keys.join(format!("{}.pub", s.name))).unwrap();
        assert_eq!(s.public_key, Some(public.0), "{}", s.name);
        let private = s.private_key_file.as_deref().expect("private key file");
        assert_eq!(
            std::fs::canonicalize(private).unwrap(),
            std::fs::canonicalize(keys.join(format!("{}.key", s.name))).unwrap()
        );
    }
    // And `validate` agrees.
    let (code, out, err) = hetcomm(&["validate", fleet.to_str().unwrap()]);
    assert_eq!(code, 0, "{err}");
    assert!(
        out.contains("transport `lan` (udp): secured; all 2 systems it carries have a public key"),
        "{out}"
    );
    // Run again, keygen sees the fleet already reads this directory.
    let (code, _, err) = hetcomm(&[
        "keygen",
        "--fleet",
        fleet.to_str().unwrap(),
        "--out",
        keys.to_str().unwrap(),
        "--force",
    ]);
    assert_eq!(code, 0, "{err}");
}

#[test]
fn the_inline_snippet_loads_to_the_same_keys() {
    let dir = TempDir::new("keygen-inline");
    let (fleet, keys, out) = keygen_fleet(&dir);
    let systems = snippet(&out, "[systems]");
    assert!(systems.contains("Bravo = { id = 1, modules = [\"Plan\"], public_key = \""));
    assert!(systems.contains("private_key_file = \"../keys/Alpha.key\" }"));
    dir.write_plain("conf/fleet.toml", &format!("{systems}{REST}"));
    let f = hetcomm::load_fleet(&fleet).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(f.keys_dir, None);
    for s in &f.systems {
        let public = PublicKey::load(&keys.join(format!("{}.pub", s.name))).unwrap();
        assert_eq!(s.public_key, Some(public.0), "{}", s.name);
        let private = PrivateKey::load(s.private_key_file.as_deref().unwrap()).unwrap();
        assert_eq!(Keypair::from_private(private).unwrap().public, public);
    }
    let bravo = f.system_by_name("Bravo").unwrap();
    assert_eq!(bravo.modules.as_ref().map(Vec::len), Some(1));
}

#[test]
fn refuses_to_overwrite_without_force() {
    let dir = TempDir::new("keygen-force");
    let (fleet, keys, _) = keygen_fleet(&dir);
    let before = std::fs::read_to_string(keys.join("Alpha.key")).unwrap();
    let args = [
        "keygen",
        "--fleet",
        fleet.to_str().unwrap(),
        "--out",
        keys.to_str().unwrap(),
    ];
    let (code, out, err) = hetcomm(&args);
    assert_eq!(code, 1, "{out}");
    let alpha_key = keys.join("Alpha.key");
    assert!(
        err.starts_with(&format!(
            "error: refusing to overwrite existing keys: {}, ",
            alpha_key.display()
        )),
        "{err}"
    );
    assert!(err.contains("pass --force to replace them"), "{err}");
    assert_eq!(std::fs::read_to_string(&alpha_key).unwrap(), before);
    let (code, _, err) = hetcomm(&[&args[..], &["--force"]].concat());
    assert_eq!(code, 0, "{err}");
    assert_ne!(std::fs::read_to_string(&alpha_key).unwrap(), before);
    #[cfg(unix)]
    assert_eq!(mode(&alpha_key), 0o600);
}

#[test]
fn a_fleet_with_errors_is_reported_not_keyed() {
    let dir = TempDir::new("keygen-bad");
    let fleet = dir.write_plain("fleet.toml", "[systems]\nAlpha = \"one\"\n");
    let keys = dir.path().join("keys");
    let (code, _, err) = hetcomm(&[
        "keygen",
        "--fleet",
        fleet.to_str().unwrap(),
        "--out",
        keys.to_str().unwrap(),
    ]);
    assert_eq!(code, 2);
    assert!(
        err.contains("fleet.toml:2:9: `systems.Alpha` must be an id"),
        "{err}"
    );
    assert!(!keys.exists());
}

#[test]
fn legacy_files_get_keys_and_run_with_keys_dir() {
    let dir = TempDir::new("keygen-legacy");
    let ids = dir.write_plain("ids.txt", "0 Alpha\n1 Bravo\n");
    let table = dir.write_plain("table.txt", "  0 1\n0 X R\n1 R X\n");
    let keys = dir.path().join("keys");
    let (ids, table, keys) = (
        ids.to_str().unwrap(),
        table.to_str().unwrap(),
        keys.to_str().unwrap(),
    );
    let (code, out, err) = hetcomm(&["keygen", "--ids", ids, "--table", table, "--out", keys]);
    assert_eq!(code, 0, "{err}");
    assert!(
        out.contains(&format!("give `--keys {keys}` to every command")),
        "{out}"
    );
    let (code, out, err) = hetcomm(&["validate", "--ids", ids, "--table", table, "--keys", keys]);
    assert_eq!(code, 0, "{err}");
    assert!(
        out.contains("transport `R` (ros1): secured; all 2 systems it carries have a public key"),
        "{out}"
    );
}

#[test]
fn insecure_warns_on_stderr() {
    // `send` with --insecure: the warning comes before anything is opened (the destination
    // does not exist, so the command then fails on the name).
    let dir = TempDir::new("keygen-insecure");
    let fleet = dir.write_plain(
        "fleet.toml",
        &format!("[security]\nkeys = \"keys\"\n{SYSTEMS}{REST}"),
    );
    let (code, _, err) = hetcomm(&[
        "send",
        fleet.to_str().unwrap(),
        "--as",
        "Alpha",
        "--to",
        "Nobody",
        "--module",
        "Plan",
        "--type",
        "1",
        "--json",
        "1",
        "--insecure",
    ]);
    assert_eq!(code, 1);
    let mut lines = err.lines();
    assert_eq!(
        lines.next(),
        Some(
            "warning: --insecure: security is OFF on every transport: traffic is \
             unauthenticated and unencrypted, and anyone who can reach the fleet's transports \
             can pose as any system"
        ),
        "{err}"
    );
    assert!(
        lines.next().unwrap_or("").contains("has no such system"),
        "{err}"
    );
    // Without --insecure the missing keys directory stops it first.
    let (code, _, err) = hetcomm(&[
        "send",
        fleet.to_str().unwrap(),
        "--as",
        "Alpha",
        "--to",
        "Nobody",
        "--module",
        "Plan",
        "--type",
        "1",
        "--json",
        "1",
    ]);
    assert_eq!(code, 1);
    assert!(err.contains("the keys directory"), "{err}");
    // --keys DIR replaces the file's directory, which need not exist on this machine.
    let elsewhere = TempDir::new("keygen-elsewhere");
    let (_, keys, _) = keygen_fleet(&elsewhere);
    assert!(!dir.path().join("keys").exists());
    let (code, _, err) = hetcomm(&[
        "send",
        fleet.to_str().unwrap(),
        "--as",
        "Alpha",
        "--to",
        "Nobody",
        "--module",
        "Plan",
        "--type",
        "1",
        "--json",
        "1",
        "--keys",
        keys.to_str().unwrap(),
    ]);
    assert_eq!(code, 1);
    assert!(err.contains("has no such system"), "{err}");
    assert!(!err.contains("warning"), "{err}");
    // --keys and --insecure exclude each other.
    let (code, _, err) = hetcomm(&[
        "listen",
        fleet.to_str().unwrap(),
        "--as",
        "Alpha",
        "--keys",
        "k",
        "--insecure",
    ]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("cannot be used with"), "{err}");
}
