//! Systems' keys in a fleet. To this crate a key is 32 bytes in a text form (standard base64,
//! 44 characters, as `hetcomm keygen` writes and `hetcomm-security` reads); there is no
//! cryptography here. This module reads public key files, applies a keys directory to a fleet
//! already loaded ([`apply_keys_dir`], the command line's `--keys DIR`), turns security off
//! ([`insecure`], the command line's `--insecure`) and says what `hetcomm validate` prints about
//! each transport's security ([`Fleet::security_lines`]).

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::rc::Rc;

use base64::engine::general_purpose::STANDARD;
use base64::Engine;
use hetcomm_core::SystemId;

use crate::error::{ConfigErrors, Diag, Loc};
use crate::model::*;

/// Bytes in a key (X25519).
pub const KEY_LEN: usize = 32;

/// What a key file must look like, for help texts.
const FILE_SHAPE: &str = "a key file holds one line of base64 (44 characters), after optional \
                          `#` comment lines, as `hetcomm keygen` writes it";

/// Decodes a key's text form; the error completes "the key …".
pub(crate) fn decode(text: &str) -> Result<[u8; KEY_LEN], String> {
    let shape = "a key is 44 characters of base64 (32 bytes)";
    if let Some((i, c)) = text
        .chars()
        .enumerate()
        .find(|&(_, c)| !(c.is_ascii_alphanumeric() || matches!(c, '+' | '/' | '=')))
    {
        return Err(format!(
            "is not base64: it contains {} at character {}; {shape}",
            crate::names::describe(c),
            i + 1
        ));
    }
    match STANDARD.decode(text) {
        Ok(bytes) => <[u8; KEY_LEN]>::try_from(bytes.as_slice()).map_err(|_| {
            format!(
                "decodes to {} bytes, but a key has {KEY_LEN} (44 characters of base64)",
                bytes.len()
            )
        }),
        Err(_) if text.chars().count() != 44 => Err(format!(
            "is {} characters long; {shape}",
            text.chars().count()
        )),
        Err(e) => Err(format!(
            "is not valid base64 ({}); {shape}",
            e.to_string().trim_end_matches('.')
        )),
    }
}

/// The key in a key file's text, or the 1-based line of the problem (0: the whole file) and
/// what is wrong ("… the key …" completes it).
fn parse_file(text: &str) -> Result<[u8; KEY_LEN], (usize, String)> {
    let mut lines = text
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim()))
        .filter(|(_, l)| !l.is_empty() && !l.starts_with('#'));
    let Some((line, key)) = lines.next() else {
        return Err((0, "holds no key".to_string()));
    };
    if let Some((second, _)) = lines.next() {
        return Err((
            second,
            "holds a second line of text; one key was expected".to_string(),
        ));
    }
    decode(key).map_err(|problem| (line, format!("holds a key that {problem}")))
}

/// Reads the public key of `system` from `path`. A missing file is None without an error when
/// `missing_ok`; otherwise an unreadable file is reported at `named_at` (where the fleet file
/// names it) or at the file itself, and a malformed key at its line in the file.
pub(crate) fn read_public(
    path: &Path,
    system: &str,
    named_at: Option<&Loc>,
    missing_ok: bool,
    diag: &mut Diag,
) -> Option<[u8; KEY_LEN]> {
    let display: Rc<str> = Rc::from(path.display().to_string());
    let text = match std::fs::read_to_string(path) {
        Ok(t) => t,
        Err(e) if missing_ok && e.kind() == std::io::ErrorKind::NotFound => return None,
        Err(e) => {
            let loc = named_at.cloned().unwrap_or_else(|| Loc::whole(&display));
            diag.err_help(
                &loc,
                format!("cannot read the public key of system `{system}` from `{display}`: {e}"),
                "check the path (relative to the fleet file's directory); `hetcomm keygen` \
                 writes `<System>.pub` files",
            );
            return None;
        }
    };
    match parse_file(&text) {
        Ok(key) => Some(key),
        Err((line, problem)) => {
            let loc = Loc {
                file: display.clone(),
                line,
                column: usize::from(line > 0),
            };
            diag.err_help(
                &loc,
                format!("the public key file of system `{system}` {problem}"),
                FILE_SHAPE,
            );
            None
        }
    }
}

/// Checks that the keys directory exists, reporting at `loc` with how to create it.
pub(crate) fn check_dir(dir: &Path, loc: &Loc, keygen: &str, diag: &mut Diag) -> bool {
    let problem = match std::fs::metadata(dir) {
        Ok(m) if m.is_dir() => return true,
        Ok(_) => "is not a directory".to_string(),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => "does not exist".to_string(),
        Err(e) => format!("cannot be read: {e}"),
    };
    diag.err_help(
        loc,
        format!("the keys directory `{}` {problem}", dir.display()),
        format!(
            "run `{keygen} --out {}` to write every system's keys there, or correct the path",
            dir.display()
        ),
    );
    false
}

/// The keys `dir` holds for `system`: `<dir>/<system>.pub` (when present) and the path of
/// `<dir>/<system>.key` (when present; read when the system is opened).
pub(crate) fn from_dir(
    dir: &Path,
    system: &str,
    diag: &mut Diag,
) -> (Option<[u8; KEY_LEN]>, Option<PathBuf>) {
    let public = read_public(&dir.join(format!("{system}.pub")), system, None, true, diag);
    let private = dir.join(format!("{system}.key"));
    (public, private.exists().then_some(private))
}

/// The keygen command line that would write keys for `fleet`, for help texts.
fn keygen_for(fleet: &Fleet) -> String {
    match &fleet.source {
        Some(path) => format!("hetcomm keygen --fleet {}", path.display()),
        None => "hetcomm keygen --ids IDS --table TABLE".to_string(),
    }
}

/// Reads systems' keys from `dir` into a fleet already loaded, as `[security] keys = "DIR"`
/// would have: each system's public key from `<dir>/<Name>.pub` where that file exists, and
/// `<dir>/<Name>.key` as its private key file where that file exists; `keys_dir` becomes
/// `dir`. Keys found in `dir` replace the fleet's (the caller — the command line's
/// `--keys DIR` — is the more specific); systems without files there keep theirs.
///
/// Errors (nothing is changed then): `dir` is missing or not a directory, or a `.pub` file in
/// it cannot be read or holds no valid key; each names the file and says what to fix.
pub fn apply_keys_dir(fleet: &mut Fleet, dir: &Path) -> Result<(), ConfigErrors> {
    let mut diag = Diag::default();
    let here: Rc<str> = Rc::from(dir.display().to_string());
    if !check_dir(dir, &Loc::whole(&here), &keygen_for(fleet), &mut diag) {
        return Err(diag.into_sorted());
    }
    let found: Vec<_> = fleet
        .systems
        .iter()
        .map(|s| from_dir(dir, &s.name, &mut diag))
        .collect();
    if !diag.errors.is_empty() {
        return Err(diag.into_sorted());
    }
    for (s, (public, private)) in fleet.systems.iter_mut().zip(found) {
        if public.is_some() {
            s.public_key = public;
        }
        if private.is_some() {
            s.private_key_file = private;
        }
    }
    fleet.keys_dir = Some(dir.to_path_buf());
    Ok(())
}

/// Turns security off on every transport (`security = "none"` everywhere): what the command
/// line's `--insecure` does. Anyone who can reach the fleet's transports can then pose as any
/// system; a program doing this should say so loudly.
pub fn insecure(fleet: &mut Fleet) {
    for t in &mut fleet.transports {
        t.security = SecurityMode::None;
    }
}

impl Fleet {
    /// Whether frames on `t` leave the process: for a transport layered `over` another, that
    /// one's answer; else whether its own link does (false for `inproc` and for an `emulated`
    /// transport's private hub: [`TransportDef::in_process`]).
    pub fn leaves_process(&self, t: &TransportDef) -> bool {
        let mut cur = t;
        // A chain of layers is at most as long as the list (the loader rejects loops).
        for _ in 0..=self.transports.len() {
            match cur.over.as_deref().and_then(|o| self.transport(o)) {
                Some(inner) => cur = inner,
                None => return !cur.in_process,
            }
        }
        true
    }

    /// One line per transport, in file order, on its security: whether it is secured and
    /// whether every system it carries (sends or receives on it, by the table) has a public
    /// key; judged by this crate alone ([`Fleet::leaves_process`], which knows no kind
    /// registered by a link crate). A program that opens links says it as its registry
    /// decides (`hetcomm::security_lines`, what `hetcomm validate` prints), through
    /// [`Fleet::security_lines_with`].
    pub fn security_lines(&self) -> Vec<String> {
        self.security_lines_with(|i| {
            let t = &self.transports[i];
            match self.leaves_process(t) {
                true => Protection {
                    reach: Reach::Network,
                    sealed: t.security == SecurityMode::Keys,
                    carries: Vec::new(),
                },
                false => Protection {
                    reach: Reach::Process,
                    sealed: false,
                    carries: Vec::new(),
                },
            }
        })
    }

    /// [`Fleet::security_lines`], with what protects each transport (by index) as `of` says.
    pub fn security_lines_with(&self, of: impl Fn(usize) -> Protection) -> Vec<String> {
        let mut by_table: Vec<BTreeSet<SystemId>> = vec![BTreeSet::new(); self.transports.len()];
        for (src, dst, i) in self.table_entries() {
            if let Some(set) = by_table.get_mut(i) {
                set.insert(src);
                set.insert(dst);
            }
        }
        self.transports
            .iter()
            .enumerate()
            .map(|(i, t)| {
                let head = format!("transport `{}` ({})", t.name, t.kind);
                let Protection {
                    reach,
                    sealed,
                    carries,
                } = of(i);
                // The systems whose frames this transport's link carries: its own pairs', and
                // those of the transports whose frames travel on it.
                let systems: BTreeSet<SystemId> = std::iter::once(i)
                    .chain(carries)
                    .filter_map(|j| by_table.get(j))
                    .flatten()
                    .copied()
                    .collect();
                let state = match (sealed, t.security, reach) {
                    (true, _, _) => "secured",
                    (false, SecurityMode::None, Reach::Network) => {
                        return format!(
                            "{head}: NOT SECURED (security = \"none\"): anyone who can reach \
                             it can pose as any system"
                        )
                    }
                    (false, SecurityMode::None, Reach::Process) => {
                        return format!("{head}: in-process, not secured (security = \"none\")")
                    }
                    (false, SecurityMode::None, Reach::Host) => {
                        return format!("{head}: on this host, not secured (security = \"none\")")
                    }
                    (false, SecurityMode::Keys, Reach::Process) => {
                        return format!("{head}: in-process: frames never leave the process")
                    }
                    (false, SecurityMode::Keys, Reach::Host) => {
                        return format!(
                            "{head}: host-local, not sealed: frames never leave this host and \
                             the operating system's permissions guard them (`[security] \
                             in_process = true` seals them)"
                        )
                    }
                    (false, SecurityMode::Keys, Reach::Network) => {
                        // Only a transport layered over one that says `security = "none"`.
                        return format!(
                            "{head}: NOT SECURED: its frames travel on a transport with \
                             `security = \"none\"`"
                        )
                    }
                };
                if systems.is_empty() {
                    return format!("{head}: {state}; carries no traffic");
                }
                let missing: Vec<&str> = systems
                    .iter()
                    .filter_map(|&id| self.system(id))
                    .filter(|s| s.public_key.is_none())
                    .map(|s| s.name.as_str())
                    .collect();
                match missing.len() {
                    0 => format!(
                        "{head}: {state}; all {} systems it carries have a public key",
                        systems.len()
                    ),
                    n => {
                        let mut names = missing.iter().take(8).copied().collect::<Vec<_>>().join(", ");
                        if n > 8 {
                            names.push_str(", …");
                        }
                        format!(
                            "{head}: {state}; {n} of the {} systems it carries have no public key: {names}",
                            systems.len()
                        )
                    }
                }
            })
            .collect()
    }
}

/// Where a transport's frames can go, for [`Fleet::security_lines_with`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Reach {
    /// They stay in the process (`inproc`, a private `emulated` link).
    Process,
    /// They stay on this host (shared memory).
    Host,
    /// They cross a network.
    Network,
}

/// What protects a transport's frames, for [`Fleet::security_lines_with`].
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Protection {
    /// Where its frames can go.
    pub reach: Reach,
    /// Whether a security layer seals them (its own, or that of the transport it is layered
    /// over).
    pub sealed: bool,
    /// The other transports (by index) whose frames travel on this one's link, so that the
    /// systems of their pairs need keys here too (an `emulated` transport over this one).
    pub carries: Vec<usize>,
}
