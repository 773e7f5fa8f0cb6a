//! # hetcomm-config — the framework manager's files
//!
//! Loads a TOML fleet file (and the thesis's legacy id / communication-table / Bluetooth
//! address files) into one validated [`Fleet`]: the systems and their ids, the modules and
//! their inbox policies, the named transport instances, and the communication table saying
//! which transport carries each (source, destination) pair.
//!
//! The thesis (§3.5) warned that "the system will not attempt to identify erroneous
//! configuration files". This crate does the opposite: every problem it finds is reported with
//! `file:line:column` of the offending token, the offending value and, where it can tell, what
//! would fix it — and it keeps going, so one run lists every problem ([`ConfigErrors`]).
//!
//! What it does not do: it opens nothing (no sockets, no ROS master, no Bluetooth adapter), and
//! it does not know which transport kinds are compiled into a program — that is decided when
//! the fleet is opened by the `hetcomm` facade. A kind beyond the built-in ones brings its
//! keys and their parser in a [`KindSpec`] from its own crate; [`load_with`] and
//! [`parse_str_with`] take a table of them ([`kinds`]). It does not watch files for changes, and it
//! does not write fleet files (except for printing [`EXAMPLE_FLEET`]).
//!
//! The file format, every key, the legacy formats and the list of errors are documented in
//! `docs/config.md`.
//!
//! ```
//! use hetcomm_config::{parse_str, TransportKind};
//! use hetcomm_core::SystemId;
//!
//! let fleet = parse_str(
//!     r#"
//!     [systems]
//!     Alpha = 0
//!     Charlie = 1
//!
//!     [transports.wired]
//!     kind = "inproc"
//!
//!     [table]
//!     columns = ["Alpha", "Charlie"]
//!     Alpha   = ["X", "wired"]
//!     Charlie = ["wired", "X"]
//!     "#,
//!     "fleet.toml",
//!     None,
//! )
//! .expect("a valid fleet");
//! assert_eq!(fleet.systems.len(), 2);
//! assert_eq!(fleet.modules.len(), 4); // Sense, Plan, Act, World by default
//! let route = fleet.route(SystemId(0), SystemId(1)).expect("Alpha talks to Charlie");
//! assert_eq!(route.kind, TransportKind::Inproc);
//! assert_eq!(route.tag, b'w');
//!
//! let errors = parse_str("[systems]\nAlpha = \"one\"\n", "bad.toml", None).unwrap_err();
//! assert_eq!(
//!     errors.to_string(),
//!     "bad.toml:2:9: `systems.Alpha` must be an id or a table `{ id = …, modules = […] }`, \
//!      found string `\"one\"`\n  help: write `Name = 0` or `Name = { id = 0, modules = [\"Plan\"] }`"
//! );
//! ```

mod assemble;
mod error;
mod fleet_toml;
mod keys;
pub mod kinds;
mod legacy;
pub mod model;
mod names;
pub mod scenario;
pub mod suggest;
pub mod synthetic;
mod table;

use std::path::Path;
use std::rc::Rc;

pub use error::{ConfigError, ConfigErrors};
pub use keys::{apply_keys_dir, insecure, Protection, Reach, KEY_LEN};
pub use kinds::{Addresses, KindSpec, Kinds, LegacyFiles, SettingsReader};
pub use model::*;

use crate::assemble::{LegacyBt, ModSpec, Parts, SysSpec, Systems, DEFAULT_MODULES};
use crate::error::{Diag, Loc};
use crate::fleet_toml::KeyReading;

/// The commented example fleet file; `hetcomm generate-config` prints it, and it is a good
/// starting point for a new fleet.
pub const EXAMPLE_FLEET: &str = include_str!("../fleet.example.toml");

/// Reads and validates the fleet file at `path`. Paths under `[legacy]` (and a Bluetooth
/// transport's `addresses_file`) are resolved relative to the file's directory, and errors
/// name the file as `path` was given.
pub fn load(path: &Path) -> Result<Fleet, ConfigErrors> {
    load_with(path, &Kinds::new())
}

/// [`load`], knowing the kinds in `kinds` besides the built-in ones (see [`kinds`]).
pub fn load_with(path: &Path, kinds: &Kinds) -> Result<Fleet, ConfigErrors> {
    load_reading(path, kinds, KeyReading::All)
}

/// [`load_with`] without reading any key file: `[security] keys` may name a directory that
/// does not exist yet and `public_key_file`s are not read (inline `public_key`s are still
/// checked), so systems have only their inline public keys and `private_key_file`s as given.
/// For `hetcomm keygen`, which is run to create those files.
pub fn load_skipping_keys(path: &Path, kinds: &Kinds) -> Result<Fleet, ConfigErrors> {
    load_reading(path, kinds, KeyReading::Nothing)
}

/// [`load_with`], with the systems' keys read from `dir` instead of the file's
/// `[security] keys` directory (which need not exist on this machine): the command line's
/// `--keys DIR`. Systems' own `public_key` / `public_key_file` are still read; then
/// [`apply_keys_dir`] reads `dir`, whose keys replace them.
pub fn load_with_keys_dir(path: &Path, kinds: &Kinds, dir: &Path) -> Result<Fleet, ConfigErrors> {
    let mut fleet = load_reading(path, kinds, KeyReading::NotDir)?;
    apply_keys_dir(&mut fleet, dir)?;
    Ok(fleet)
}

/// Reads and parses the fleet file at `path`, reading key files as `keys` says.
fn load_reading(path: &Path, kinds: &Kinds, keys: KeyReading) -> Result<Fleet, ConfigErrors> {
    let origin = path.display().to_string();
    let text = match std::fs::read_to_string(path) {
        Ok(t) => t,
        Err(e) => return Err(unreadable(&origin, &e)),
    };
    let base = path.parent().unwrap_or(Path::new(""));
    fleet_toml::parse(
        &text,
        &origin,
        Some(base),
        Some(path.to_path_buf()),
        kinds,
        keys,
    )
}

/// Validates fleet-file text. `origin` is the file name used in error locations; relative
/// paths under `[legacy]` are resolved against `base_dir`, or the current directory if None.
/// The result's `source` is None.
pub fn parse_str(text: &str, origin: &str, base_dir: Option<&Path>) -> Result<Fleet, ConfigErrors> {
    parse_str_with(text, origin, base_dir, &Kinds::new())
}

/// [`parse_str`], knowing the kinds in `kinds` besides the built-in ones (see [`kinds`]).
pub fn parse_str_with(
    text: &str,
    origin: &str,
    base_dir: Option<&Path>,
    kinds: &Kinds,
) -> Result<Fleet, ConfigErrors> {
    fleet_toml::parse(text, origin, base_dir, None, kinds, KeyReading::All)
}

/// Loads the thesis's files alone: the id file (Tables 1, 6, 16), the communication table
/// (Tables 2, 7, 17) and optionally the Bluetooth address file (Tables 3, 8, 18). Letters keep
/// their thesis meanings: `R` is ROS 1 (with the `ros1` kind's crate among `kinds`: master
/// from `ROS_MASTER_URI`, else `http://localhost:11311`) and `B` is Bluetooth with the given
/// addresses; modules are the defaults (Sense = 0, Plan = 1, Act = 2, World = 3) with default
/// inboxes.
pub fn load_legacy(
    ids: &Path,
    table: &Path,
    bluetooth: Option<&Path>,
) -> Result<Fleet, ConfigErrors> {
    load_legacy_with(ids, table, bluetooth, &Kinds::new())
}

/// [`load_legacy`], knowing the kinds in `kinds` besides the built-in ones.
pub fn load_legacy_with(
    ids: &Path,
    table: &Path,
    bluetooth: Option<&Path>,
    kinds: &Kinds,
) -> Result<Fleet, ConfigErrors> {
    let mut diag = Diag::default();
    let ids_name: Rc<str> = Rc::from(ids.display().to_string());
    let table_name: Rc<str> = Rc::from(table.display().to_string());

    let read = |p: &Path, name: &Rc<str>, diag: &mut Diag| match std::fs::read_to_string(p) {
        Ok(t) => Some(t),
        Err(e) => {
            diag.err_help(
                &Loc::whole(name),
                format!("cannot read `{name}`: {e}"),
                "check the path",
            );
            None
        }
    };

    let specs = read(ids, &ids_name, &mut diag)
        .map(|text| {
            legacy::parse_ids(&ids_name, &text, &mut diag)
                .into_iter()
                .map(|l| SysSpec {
                    id: l.id,
                    id_loc: l.id_loc,
                    name: l.name,
                    name_loc: l.name_loc,
                    modules: None,
                    keys: Default::default(),
                })
                .collect()
        })
        .unwrap_or_default();
    let systems = Systems::new(specs, &mut diag);
    let raw_table = read(table, &table_name, &mut diag)
        .and_then(|text| legacy::parse_table(&table_name, &text, &mut diag));
    let legacy_bt = bluetooth.and_then(|p| {
        let name: Rc<str> = Rc::from(p.display().to_string());
        let text = read(p, &name, &mut diag)?;
        let lines = legacy::parse_bluetooth(&name, &text, &mut diag);
        Some(LegacyBt {
            addresses: assemble::bt_addresses(lines, &systems, &name, &mut diag),
            file: name,
        })
    });
    let modules = assemble::modules(
        DEFAULT_MODULES
            .iter()
            .map(|&(n, id)| ModSpec {
                id,
                id_loc: Loc::start(&ids_name),
                name: n.to_string(),
                inbox: InboxConfig::default(),
            })
            .collect(),
        &mut diag,
    );
    assemble::finish(
        Parts {
            name: None,
            source: None,
            systems,
            modules,
            transports: Vec::new(),
            letters: Vec::new(),
            table: raw_table,
            legacy_bt,
            keys_dir: None,
            secure_in_process: false,
            fallback: Loc::start(&table_name),
            b_help: "give the Bluetooth addresses in a third file (the Table 3 format): \
                     `hetcomm validate --ids … --table … --bluetooth bt.txt`",
        },
        kinds,
        diag,
    )
}

/// The error for a fleet file that cannot be read at all.
fn unreadable(origin: &str, e: &std::io::Error) -> ConfigErrors {
    ConfigErrors(vec![ConfigError {
        file: origin.to_string(),
        line: 0,
        column: 0,
        message: format!("cannot read the fleet file: {e}"),
        help: Some("check the path and the file's permissions".to_string()),
    }])
}
