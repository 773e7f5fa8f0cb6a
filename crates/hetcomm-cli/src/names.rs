//! The fleet file as the commands see it: the system and module names given on the command
//! line are checked before anything is opened (a typo gets "did you mean" and the list to
//! choose from, said once), and opening a system says what to check when it fails.

use std::path::Path;

use hetcomm::config::suggest::closest;
use hetcomm::config::Fleet;
use hetcomm::{Comm, OpenError};

use crate::security::SecurityArgs;

/// Opens `system` of `fleet` (loaded from `path`); an endpoint already taken gets a hint.
pub fn open_system(path: &Path, fleet: &Fleet, system: &str) -> anyhow::Result<Comm> {
    Comm::open_fleet(fleet, system).map_err(|e| match &e {
        OpenError::Transport { reason, .. } if reason.contains("in use") => anyhow::anyhow!(
            "{e}; is another program running as `{system}` (e.g. `hetcomm listen {} --as {system}`)?",
            path.display()
        ),
        _ => e.into(),
    })
}

/// Loads the fleet file (its errors, each with file:line:column, are the whole message) and
/// applies `--keys` / `--insecure`.
pub fn load_fleet(path: &Path, security: &SecurityArgs) -> anyhow::Result<Fleet> {
    security.load(path)
}

/// Fails unless `name` is a system of `fleet`. `flag` is the option that gave it (`--as`);
/// `extra` are words the option also takes (`All` for `--to`).
pub fn check_system(
    fleet: &Fleet,
    path: &Path,
    flag: &str,
    name: &str,
    extra: &[&str],
) -> anyhow::Result<()> {
    let mut known: Vec<&str> = fleet.systems.iter().map(|s| s.name.as_str()).collect();
    if known.contains(&name) || extra.contains(&name) {
        return Ok(());
    }
    known.extend_from_slice(extra);
    anyhow::bail!(
        "`{flag} {name}`: {} has no such system; {}",
        path.display(),
        help(name, &known, "systems")
    )
}

/// Fails unless `name` is a system `sender` may name as a destination (`--to`): another
/// system of `fleet`, or `All`. The suggestion never names the sender itself.
pub fn check_destination(
    fleet: &Fleet,
    path: &Path,
    name: &str,
    sender: &str,
) -> anyhow::Result<()> {
    let mut known: Vec<&str> = fleet.systems.iter().map(|s| s.name.as_str()).collect();
    if known.contains(&name) || name == "All" {
        return Ok(());
    }
    known.retain(|s| *s != sender);
    known.push("All");
    anyhow::bail!(
        "`--to {name}`: {} has no such system; {}",
        path.display(),
        help(name, &known, "destinations")
    )
}

/// Fails unless `name` is a module of `fleet` (see [`check_system`]).
pub fn check_module(fleet: &Fleet, path: &Path, flag: &str, name: &str) -> anyhow::Result<()> {
    let known: Vec<&str> = fleet.modules.iter().map(|m| m.name.as_str()).collect();
    if known.contains(&name) {
        return Ok(());
    }
    anyhow::bail!(
        "`{flag} {name}`: {} has no such module; {}",
        path.display(),
        help(name, &known, "modules")
    )
}

/// "did you mean `X`? (systems: A, B, C)", or just the list when nothing is close.
fn help(word: &str, candidates: &[&str], list_name: &str) -> String {
    let list = format!("{list_name}: {}", candidates.join(", "));
    match closest(word, candidates) {
        Some(c) => format!("did you mean `{c}`? ({list})"),
        None => list,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn suggests_the_nearest_name_or_lists_them() {
        let names = ["Alpha", "Bravo", "Charlie", "All"];
        assert_eq!(closest("Bravoo", &names), Some("Bravo"));
        assert_eq!(closest("all", &names), Some("All"));
        assert_eq!(closest("Zulu", &names), None);
        assert_eq!(
            help("Zulu", &names, "systems"),
            "systems: Alpha, Bravo, Charlie, All"
        );
        assert_eq!(
            help("Alpah", &names, "systems"),
            "did you mean `Alpha`? (systems: Alpha, Bravo, Charlie, All)"
        );
    }

    #[test]
    fn a_destination_suggestion_never_names_the_sender() {
        let fleet = hetcomm::config::parse_str(
            "[systems]\nRover1 = 0\nRover2 = 1\nBase = 2\n[modules]\nPlan = 0\n\
             [transports.R]\nkind = \"inproc\"\n[table]\ncolumns = [\"Rover1\", \"Rover2\", \"Base\"]\n\
             Rover1 = [\"X\", \"R\", \"R\"]\nRover2 = [\"R\", \"X\", \"R\"]\nBase = [\"R\", \"R\", \"X\"]\n",
            "f.toml",
            None,
        )
        .unwrap();
        let e = check_destination(&fleet, Path::new("f.toml"), "Rover3", "Rover2").unwrap_err();
        assert_eq!(
            e.to_string(),
            "`--to Rover3`: f.toml has no such system; did you mean `Rover1`? \
             (destinations: Rover1, Base, All)"
        );
        assert!(check_destination(&fleet, Path::new("f.toml"), "All", "Rover2").is_ok());
    }
}
