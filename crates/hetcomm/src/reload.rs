//! Reloading a changed fleet file into a running system ([`Comm::reload`], docs/failover.md):
//! the difference is worked out and printed by the caller; what can change live (the order
//! and the subset of each pair's transports among the ones this system opened for it) is
//! applied, and a file that asks for more (a changed id, a removed system this one talks to,
//! a transport this system has not opened for a pair) is refused as a whole, changing nothing.

use std::path::Path;
use std::sync::Arc;

use hetcomm_config::{ConfigErrors, Fleet};

use crate::Comm;

/// What a reload changed ([`Comm::reload`]).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Reload {
    /// The difference between the file in use and the new one, one line each (pairs changed,
    /// transports added or removed, systems added or removed); empty when nothing changed.
    pub changes: Vec<String>,
    /// The pairs of this system whose transports changed live: (destination, the transports
    /// in order).
    pub applied: Vec<(String, Vec<String>)>,
}

/// Why [`Comm::reload`] changed nothing.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ReloadError {
    /// The new file does not load (each problem with its file:line).
    #[error("{0}")]
    Config(#[from] ConfigErrors),
    /// The new file changes what a running system cannot change.
    #[error("refused, nothing changed: {}", reasons.join("; "))]
    Refused {
        /// Why, one reason per change that cannot be applied live.
        reasons: Vec<String>,
        /// The difference, as [`Reload::changes`].
        changes: Vec<String>,
    },
}

/// A pair's transports by name, in order (empty: X).
fn cell(f: &Fleet, from: &str, to: &str) -> Vec<String> {
    let (Some(a), Some(b)) = (f.system_by_name(from), f.system_by_name(to)) else {
        return Vec::new();
    };
    f.transports_for(a.id, b.id)
        .into_iter()
        .map(|i| f.transports[i].name.clone())
        .collect()
}

fn show(cell: &[String]) -> String {
    match cell.is_empty() {
        true => "X".into(),
        false => cell.join(","),
    }
}

/// The difference between two fleets, one line per change.
pub(crate) fn difference(old: &Fleet, new: &Fleet) -> Vec<String> {
    let mut out = Vec::new();
    for t in &new.transports {
        if !old.transports.iter().any(|o| o.name == t.name) {
            out.push(format!("transport `{}` added", t.name));
        }
    }
    for t in &old.transports {
        if !new.transports.iter().any(|n| n.name == t.name) {
            out.push(format!("transport `{}` removed", t.name));
        }
    }
    for s in &new.systems {
        match old.system_by_name(&s.name) {
            None => out.push(format!("system `{}` (id {}) added", s.name, s.id.0)),
            Some(o) if o.id != s.id => {
                out.push(format!("system `{}`: id {} -> {}", s.name, o.id.0, s.id.0))
            }
            Some(_) => {}
        }
    }
    for s in &old.systems {
        if new.system_by_name(&s.name).is_none() {
            out.push(format!("system `{}` removed", s.name));
        }
    }
    let mut names: Vec<&str> = old.systems.iter().map(|s| s.name.as_str()).collect();
    for s in &new.systems {
        if !names.contains(&s.name.as_str()) {
            names.push(&s.name);
        }
    }
    for a in &names {
        for b in &names {
            if a == b {
                continue;
            }
            let (x, y) = (cell(old, a, b), cell(new, a, b));
            if x != y {
                out.push(format!("pair {a} -> {b}: {} -> {}", show(&x), show(&y)));
            }
        }
    }
    out
}

impl Comm {
    /// Loads a changed fleet file into this running system: see [`Comm::reload_fleet`].
    pub fn reload(&self, path: impl AsRef<Path>) -> Result<Reload, ReloadError> {
        let fleet = crate::load_fleet(path.as_ref())?;
        self.reload_fleet(&fleet)
    }

    /// Applies a changed fleet to this running system, or refuses it as a whole.
    ///
    /// Applied live: a pair of this system whose transports are reordered or narrowed among
    /// the ones its cell listed when the system opened (the links it opened for the pair,
    /// and the ones the peer's security layer accepts its frames on), as
    /// [`Comm::set_transports`] would; changes that do not concern this system's pairs (other
    /// systems' pairs) are listed and need nothing here. Refused, with the reason: a changed
    /// id of a system or a module (ids are on the wire), this system removed, a removed
    /// system this one has traffic to, a new system this one would send to, and a pair of
    /// this system that would need a transport it has not opened for the pair (or none at
    /// all). Later reloads are compared with the last one applied.
    pub fn reload_fleet(&self, new: &Fleet) -> Result<Reload, ReloadError> {
        let mut loaded = self.handle.loaded.lock();
        let old: Arc<Fleet> = loaded.clone();
        let opened = &self.handle.fleet;
        let me = self.name();
        let changes = difference(&old, new);
        let mut reasons = Vec::new();
        for s in &old.systems {
            match new.system_by_name(&s.name) {
                Some(n) if n.id != s.id => reasons.push(format!(
                    "system `{}` changes id ({} -> {}): ids are on the wire, restart every system to change them",
                    s.name, s.id.0, n.id.0
                )),
                Some(_) => {}
                None if s.name == me => reasons.push(format!(
                    "system `{me}` (this one) is not in the new file"
                )),
                None if !cell(&old, me, &s.name).is_empty() || !cell(&old, &s.name, me).is_empty() => {
                    reasons.push(format!(
                        "system `{}` is removed but open to this one (its pair with `{me}` is in use): restart to remove it",
                        s.name
                    ))
                }
                None => {}
            }
        }
        for m in &old.modules {
            match new.modules.iter().find(|n| n.name == m.name) {
                Some(n) if n.id != m.id => reasons.push(format!(
                    "module `{}` changes id ({} -> {}): ids are on the wire",
                    m.name, m.id.0, n.id.0
                )),
                _ => {}
            }
        }
        let mut apply = Vec::new();
        for s in &new.systems {
            if s.name == me {
                continue;
            }
            let (before, after) = (cell(&old, me, &s.name), cell(new, me, &s.name));
            if before == after {
                continue;
            }
            if old.system_by_name(&s.name).is_none() {
                if !after.is_empty() {
                    reasons.push(format!(
                        "system `{}` is new and `{me}` would send to it: a running system has no route to a new system, restart to add it",
                        s.name
                    ));
                }
                continue;
            }
            let usable = cell(opened, me, &s.name);
            if after.is_empty() {
                reasons.push(format!(
                    "pair {me} -> {}: the new file stops its traffic (X), which a running system cannot do: restart, or keep one transport",
                    s.name
                ));
                continue;
            }
            let missing: Vec<&String> = after.iter().filter(|t| !usable.contains(t)).collect();
            if !missing.is_empty() {
                reasons.push(format!(
                    "pair {me} -> {}: {} not open for this pair here (it opened {}): a new link needs a restart",
                    s.name,
                    missing
                        .iter()
                        .map(|t| format!("`{t}`"))
                        .collect::<Vec<_>>()
                        .join(", "),
                    show(&usable)
                ));
                continue;
            }
            apply.push((s.name.clone(), after));
        }
        if !reasons.is_empty() {
            return Err(ReloadError::Refused { reasons, changes });
        }
        for (to, transports) in &apply {
            let names: Vec<&str> = transports.iter().map(String::as_str).collect();
            // Checked above against the same cells `set_transports` checks.
            if let Err(e) = self.set_transports(to, &names) {
                debug_assert!(false, "a checked reload was refused: {e}");
            }
        }
        *loaded = Arc::new(new.clone());
        Ok(Reload {
            changes,
            applied: apply,
        })
    }
}

/// What a reload of the fleet file did, as lines for a person (what `hetcomm listen` prints
/// on SIGHUP, and the fleet node examples): the difference, then what was applied, or why
/// nothing was.
pub fn describe_reload(file: &Path, result: &Result<Reload, ReloadError>) -> Vec<String> {
    let file = file.display();
    match result {
        Ok(r) if r.changes.is_empty() => vec![format!("reload {file}: no change")],
        Ok(r) => {
            let mut out = vec![format!("reload {file}: {} change(s)", r.changes.len())];
            out.extend(r.changes.iter().map(|c| format!("  {c}")));
            match r.applied.is_empty() {
                true => out.push("  applied: nothing this system does changes".into()),
                false => out.extend(r.applied.iter().map(|(to, t)| {
                    format!("  applied: traffic to {to} now takes {}", t.join(","))
                })),
            }
            out
        }
        Err(ReloadError::Refused { reasons, changes }) => {
            let mut out = vec![format!("reload {file} refused, nothing changed:")];
            out.extend(reasons.iter().map(|r| format!("  refused: {r}")));
            out.extend(changes.iter().map(|c| format!("  in the file: {c}")));
            out
        }
        Err(e) => vec![format!("reload {file} refused, nothing changed: {e}")],
    }
}
