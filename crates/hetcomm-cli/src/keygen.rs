//! `hetcomm keygen`: one key pair per system of a fleet, and what to put in the fleet file.

use std::path::{Component, Path, PathBuf};

use anyhow::Context;
use hetcomm::config::Fleet;
use hetcomm_security::Keypair;

/// Options of `hetcomm keygen`.
pub struct KeygenArgs<'a> {
    /// The fleet file, or None for the thesis's legacy files.
    pub fleet_file: Option<&'a Path>,
    /// The fleet (loaded without reading key files).
    pub fleet: &'a Fleet,
    /// Where the keys go.
    pub out: &'a Path,
    /// Replace existing key files.
    pub force: bool,
}

/// Writes `<out>/<System>.key` (mode 0600) and `<out>/<System>.pub` for every system, then
/// prints (stdout) what to put in the fleet file and where each private key goes.
pub fn keygen(args: KeygenArgs<'_>) -> anyhow::Result<()> {
    let KeygenArgs {
        fleet_file,
        fleet,
        out,
        force,
    } = args;
    anyhow::ensure!(!fleet.systems.is_empty(), "the fleet has no systems");
    if !force {
        let existing: Vec<String> = fleet
            .systems
            .iter()
            .flat_map(|s| [format!("{}.key", s.name), format!("{}.pub", s.name)])
            .map(|f| out.join(f))
            .filter(|p| p.exists())
            .map(|p| p.display().to_string())
            .collect();
        if !existing.is_empty() {
            anyhow::bail!(
                "refusing to overwrite existing keys: {}\n  help: pass --force to replace them \
                 (every machine then needs its new private key, and every copy of the fleet \
                 file the new public keys), or choose another --out",
                existing.join(", ")
            );
        }
    }
    if !out.exists() {
        std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
        // The directory holds private keys: only its owner may list it.
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            std::fs::set_permissions(out, std::fs::Permissions::from_mode(0o700))
                .with_context(|| format!("making {} private", out.display()))?;
        }
    } else if !out.is_dir() {
        anyhow::bail!("--out {}: not a directory", out.display());
    }
    let mut written = Vec::new();
    for s in &fleet.systems {
        let pair = Keypair::generate().map_err(|e| anyhow::anyhow!("{e}"))?;
        let (private, public) = pair
            .write(out, &s.name)
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        written.push((s, pair.public.to_string(), private, public));
    }
    println!(
        "wrote a key pair for each of the {} systems into {}:",
        written.len(),
        out.display()
    );
    for (s, _, private, public) in &written {
        println!(
            "  {}: {} (private, mode 0600), {}",
            s.name,
            private.display(),
            public.display()
        );
    }
    println!();
    match fleet_file {
        Some(file) => fleet_file_advice(file, fleet, out, &written),
        None => {
            let dir = out.display();
            println!(
                "The thesis's legacy files cannot name keys: give `--keys {dir}` to every command \
                 that opens systems (hetcomm listen, send, demo, experiment), e.g.\n  \
                 hetcomm listen FLEET --as SYSTEM --keys {dir}\nor move to a fleet file with \
                 `[legacy]` and `[security] keys = \"{dir}\"` (docs/config.md)."
            );
        }
    }
    println!();
    println!(
        "Private keys: copy each one only to the machine that runs its system, keep it mode \
         0600 there, and delete the copies elsewhere; every machine may have all the .pub files."
    );
    for (s, _, private, _) in &written {
        println!(
            "  {} -> the machine that runs {} (e.g. `hetcomm listen … --as {}`)",
            private.display(),
            s.name,
            s.name
        );
    }
    Ok(())
}

type Written<'f> = (
    &'f hetcomm::config::SystemDef,
    String,
    std::path::PathBuf,
    std::path::PathBuf,
);

/// What to write in the fleet file: the `[security]` section, or the keys inline.
fn fleet_file_advice(file: &Path, fleet: &Fleet, out: &Path, written: &[Written<'_>]) {
    let base = file.parent().unwrap_or(Path::new(""));
    let rel = relative_to(out, base);
    let already = fleet
        .keys_dir
        .as_deref()
        .is_some_and(|d| same_place(d, out));
    if already {
        println!(
            "{} already reads its keys from this directory (`[security] keys = \"{}\"`): \
             nothing to change in it.",
            file.display(),
            rel.display()
        );
        return;
    }
    println!(
        "In {}, either read every key from the directory (paths are relative to the fleet \
         file):\n",
        file.display()
    );
    println!("[security]\nkeys = \"{}\"\n", toml_path(&rel));
    println!(
        "or give each system its keys in [systems] (replacing its line there; each machine \
         reads only its own private key file):\n"
    );
    println!("[systems]");
    for (s, public, private, _) in written {
        let modules = match &s.modules {
            Some(ids) => {
                let names: Vec<String> = ids
                    .iter()
                    .filter_map(|&id| fleet.module(id))
                    .map(|m| format!("{:?}", m.name))
                    .collect();
                format!(", modules = [{}]", names.join(", "))
            }
            None => String::new(),
        };
        let private = relative_to(private, base);
        println!(
            "{} = {{ id = {}{modules}, public_key = \"{public}\", private_key_file = \"{}\" }}",
            toml_key(&s.name),
            s.id.0,
            toml_path(&private)
        );
    }
}

/// Whether two paths name the same directory (both may be relative).
fn same_place(a: &Path, b: &Path) -> bool {
    match (std::fs::canonicalize(a), std::fs::canonicalize(b)) {
        (Ok(a), Ok(b)) => a == b,
        _ => a == b,
    }
}

/// `path` relative to the directory `base` (`..` where needed), or `path` made absolute when
/// that cannot be worked out.
fn relative_to(path: &Path, base: &Path) -> PathBuf {
    let absolute = |p: &Path| {
        let p = if p.as_os_str().is_empty() {
            Path::new(".")
        } else {
            p
        };
        std::fs::canonicalize(p).ok()
    };
    let Some(target) = absolute(path) else {
        return path.to_path_buf();
    };
    let Some(base) = absolute(base) else {
        return target;
    };
    let t: Vec<Component> = target.components().collect();
    let b: Vec<Component> = base.components().collect();
    let common = t.iter().zip(&b).take_while(|(x, y)| x == y).count();
    let mut rel = PathBuf::new();
    for _ in common..b.len() {
        rel.push("..");
    }
    for c in &t[common..] {
        rel.push(c);
    }
    if rel.as_os_str().is_empty() {
        rel.push(".");
    }
    rel
}

/// A path in a TOML basic string.
fn toml_path(p: &Path) -> String {
    let s = p.display().to_string();
    s.replace('\\', "\\\\").replace('"', "\\\"")
}

/// A system name as a TOML key: bare when it can be.
fn toml_key(name: &str) -> String {
    if !name.is_empty()
        && name
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || b == b'_' || b == b'-')
    {
        name.to_string()
    } else {
        format!("{name:?}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn relative_paths() {
        let dir = std::env::temp_dir().join(format!("hetcomm-rel-{}", std::process::id()));
        std::fs::create_dir_all(dir.join("a/b")).unwrap();
        std::fs::create_dir_all(dir.join("c")).unwrap();
        assert_eq!(relative_to(&dir.join("a/b"), &dir), PathBuf::from("a/b"));
        assert_eq!(
            relative_to(&dir.join("c"), &dir.join("a/b")),
            PathBuf::from("../../c")
        );
        assert_eq!(relative_to(&dir, &dir), PathBuf::from("."));
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn toml_keys_are_quoted_when_needed() {
        assert_eq!(toml_key("Alpha"), "Alpha");
        assert_eq!(toml_key("Café"), "\"Café\"");
    }
}
