//! Where a system's security layer gets its keys and its policy (see `hetcomm-security` and
//! `docs/security.md`).
//!
//! Every transport that leaves the process is secured unless its fleet-file section says
//! `security = "none"`. Keys come from one of three places:
//! - the fleet file (real fleets across processes and machines): every system's public key,
//!   and this process's private key from the system's `private_key_file`, the
//!   `HETCOMM_PRIVATE_KEY` environment variable (a file path), or [`OpenOptions::private_key`];
//! - generated on the fly for a fleet whose systems all run in this process and whose file
//!   names no keys ([`LocalFleet::open`](crate::LocalFleet::open), the demo): nobody outside
//!   the process has them, so nobody outside can join;
//! - derived from the seed in a simulation, so secured simulations repeat exactly.

use parking_lot::Mutex;
use std::collections::{HashMap, HashSet};
use std::path::PathBuf;
use std::sync::Arc;

use hetcomm_config::{Fleet, Protection, Reach, SecurityMode};
use hetcomm_core::SystemId;
use hetcomm_link::layer::LinkLayer;
use hetcomm_security::{Handshakes, Policy, SecurityLayer, SimSessions};

pub use hetcomm_security::{KeyError, Keypair, PrivateKey, PublicKey};

/// The environment variable naming this process's private key file.
pub const PRIVATE_KEY_ENV: &str = "HETCOMM_PRIVATE_KEY";

/// Where the systems opened together get their keys.
#[derive(Clone)]
pub(crate) enum KeySource {
    /// From the fleet file (and the private key from the places listed in the module docs).
    Fleet {
        /// A private key given through the API, for the system being opened.
        private_key: Option<PrivateKey>,
    },
    /// Generated in this process, for fleets that run wholly in it.
    Ephemeral(Arc<Mutex<HashMap<SystemId, Keypair>>>),
    /// Derived from a simulation's seed.
    Simulation(Arc<SimSessions>),
}

impl KeySource {
    /// Fresh keys for every system of a fleet that runs in this process, unless its file
    /// names keys (then those are used, as for any fleet).
    pub(crate) fn for_local_fleet(fleet: &Fleet) -> KeySource {
        if fleet.systems.iter().any(|s| s.public_key.is_some()) {
            KeySource::Fleet { private_key: None }
        } else {
            KeySource::Ephemeral(Default::default())
        }
    }

    /// Keys derived from `seed` for every system of `fleet`.
    pub(crate) fn for_simulation(fleet: &Fleet, seed: u64) -> KeySource {
        let keys = fleet
            .systems
            .iter()
            .map(|s| (s.id, Keypair::for_simulation(seed, s.id)))
            .collect();
        KeySource::Simulation(SimSessions::new(seed, keys))
    }
}

/// Whether transport `index` gets a security layer where it is opened: every kind that
/// leaves the process (the registry says which: [`Registry::leaves_process`]), unless it says
/// `security = "none"`; a kind whose factory declares its frames never leave the host
/// ([`Registry::host_local`], e.g. `shm`) only with `[security] in_process = true`, like
/// `inproc`. A transport layered over another (`emulated` with `over`, [`Registry::over`]) is
/// secured by that one's layer (below its own) in real time; a simulation opens the layered
/// transport itself, so there it takes the secured-ness of what it wraps.
///
/// [`Registry::leaves_process`]: hetcomm_link::registry::Registry::leaves_process
/// [`Registry::host_local`]: hetcomm_link::registry::Registry::host_local
/// [`Registry::over`]: hetcomm_link::registry::Registry::over
pub(crate) fn secured(fleet: &Fleet, index: usize, simulated: bool) -> bool {
    let t = &fleet.transports[index];
    if t.security == SecurityMode::None {
        return false;
    }
    let registry = crate::transports::registry();
    if fleet.secure_in_process {
        // Every link, in-process ones included; a transport layered over another is secured
        // by that one's layer in real time (see below).
        return simulated || !registry.is_layered(t);
    }
    if registry.is_layered(t) {
        return simulated
            && registry
                .over(fleet, t)
                .is_some_and(|i| secured(fleet, i, true));
    }
    registry.leaves_process(t.kind) && !registry.host_local(t.kind)
}

/// One line per transport of `fleet`, in file order, on what protects its frames when this
/// program opens it: sealed or not as [`secured`] decides for a real-time run (a transport
/// layered over another travels on that one's link, and its line says that one's
/// protection), where the frames can go (the registry's `leaves_process` and `host_local`),
/// and which systems whose frames its link carries (its pairs', and those of the transports
/// layered over it) lack a public key. What `hetcomm validate` prints; the
/// config crate's own `Fleet::security_lines` knows no kind registered by a link crate (it
/// would call `shm` secured).
pub fn security_lines(fleet: &Fleet) -> Vec<String> {
    let registry = crate::transports::registry();
    fleet.security_lines_with(|index| {
        // The transport whose link the frames travel on (the loader rejects loops; the bound
        // is for safety).
        let mut link = index;
        for _ in 0..fleet.transports.len() {
            match registry.over(fleet, &fleet.transports[link]) {
                Some(next) => link = next,
                None => break,
            }
        }
        let kind = fleet.transports[link].kind;
        let reach = if registry.host_local(kind) {
            Reach::Host
        } else if registry.leaves_process(kind) {
            Reach::Network
        } else {
            Reach::Process
        };
        let mut carries: Vec<usize> = carried(fleet, index)
            .into_iter()
            .filter(|&other| other != index)
            .collect();
        carries.sort_unstable();
        Protection {
            reach,
            sealed: secured(fleet, link, false),
            carries,
        }
    })
}

/// The transports whose traffic a link of transport `index` carries: itself, and every
/// transport layered over it (in real time their frames travel on its link).
fn carried(fleet: &Fleet, index: usize) -> HashSet<usize> {
    let registry = crate::transports::registry();
    let mut set = HashSet::from([index]);
    loop {
        let before = set.len();
        for (i, t) in fleet.transports.iter().enumerate() {
            if registry.over(fleet, t).is_some_and(|o| set.contains(&o)) {
                set.insert(i);
            }
        }
        if set.len() == before {
            return set;
        }
    }
}

/// Why a secured transport cannot open.
#[derive(Debug, thiserror::Error)]
#[error("{problem}\n  to fix: {fix}")]
pub struct SecurityError {
    problem: String,
    fix: String,
}

fn keys_fix(fleet: &Fleet, transport: &str) -> String {
    let file = fleet
        .source
        .as_ref()
        .map(|p| p.display().to_string())
        .unwrap_or_else(|| "FLEET".into());
    format!(
        "run `hetcomm keygen --fleet {file} --out keys` and add the `[security]` section it prints to the fleet file (or pass `--keys keys` to hetcomm commands); or, to run without authentication, set `security = \"none\"` in [transports.{transport}] (anyone who can reach it can then pose as any system)"
    )
}

/// The security layer for system `local`'s link of transport `index`.
pub(crate) fn layer(
    fleet: &Fleet,
    index: usize,
    local: SystemId,
    keys: &KeySource,
) -> Result<Arc<dyn LinkLayer>, SecurityError> {
    let t = &fleet.transports[index];
    let carried = carried(fleet, index);
    // Every transport a cell lists carries its pair (first choice or fallback); a transport
    // the cell does not list is refused its frames (`rejected_table`).
    let data_from: HashSet<SystemId> = fleet
        .table_entries()
        .filter(|(s, d, i)| *d == local && *s != local && carried.contains(i))
        .map(|(s, _, _)| s)
        .collect();
    let acks_from: HashSet<SystemId> = fleet
        .table_entries()
        .filter(|(s, d, i)| *s == local && *d != local && carried.contains(i))
        .map(|(_, d, _)| d)
        .collect();
    let talks_to: HashSet<SystemId> = data_from.union(&acks_from).copied().collect();
    // The layer knows every member's key, not only those the table connects to this system:
    // a member the table keeps away is then told from a stranger (`rejected_table`, not
    // `rejected_unknown_sender`), and refused before any handshake work.
    let members = || fleet.systems.iter().map(|s| s.id).filter(|&p| p != local);
    let name = |id: SystemId| {
        fleet
            .system(id)
            .map(|s| s.name.clone())
            .unwrap_or_else(|| id.to_string())
    };
    let (keypair, peers, handshakes) = match keys {
        KeySource::Simulation(sim) => {
            let keypair = sim.keypair(local).cloned().ok_or_else(|| SecurityError {
                problem: format!("no simulated key for system {}", name(local)),
                fix: "report this as a bug".into(),
            })?;
            let peers = members()
                .filter_map(|p| sim.keypair(p).map(|k| (p, k.public)))
                .collect();
            (keypair, peers, Handshakes::InMemory(sim.clone()))
        }
        KeySource::Ephemeral(store) => {
            let mut store = store.lock();
            // Every system of the fleet gets its key now: they all run in this process.
            for s in &fleet.systems {
                if let std::collections::hash_map::Entry::Vacant(slot) = store.entry(s.id) {
                    slot.insert(Keypair::generate().map_err(|e| SecurityError {
                        problem: format!("cannot generate a key: {e}"),
                        fix: "check the operating system's random source".into(),
                    })?);
                }
            }
            let keypair = store[&local].clone();
            let peers = members().map(|p| (p, store[&p].public)).collect();
            (keypair, peers, Handshakes::OverTheLink)
        }
        KeySource::Fleet { private_key } => {
            let missing: Vec<String> = talks_to
                .iter()
                .chain(std::iter::once(&local))
                .filter(|&&p| fleet.system(p).is_none_or(|s| s.public_key.is_none()))
                .map(|&p| name(p))
                .collect();
            if !missing.is_empty() {
                let mut missing = missing;
                missing.sort();
                return Err(SecurityError {
                    problem: format!(
                        "transport `{}` is secured (the default for a transport that leaves the process) but the fleet file has no public key for {}",
                        t.name,
                        missing.join(", ")
                    ),
                    fix: keys_fix(fleet, &t.name),
                });
            }
            let private = private_key_for(fleet, local, private_key.as_ref(), &t.name)?;
            let keypair = Keypair::from_private(private).map_err(|e| SecurityError {
                problem: e.to_string(),
                fix: "give the private key `hetcomm keygen` wrote for this system".into(),
            })?;
            let declared = fleet
                .system(local)
                .and_then(|s| s.public_key)
                .map(PublicKey);
            if declared != Some(keypair.public) {
                return Err(SecurityError {
                    problem: format!(
                        "the private key given for system {} does not belong to it: its public key is {}, the fleet file says {}",
                        name(local),
                        keypair.public,
                        declared.map(|k| k.to_string()).unwrap_or_default()
                    ),
                    fix: format!(
                        "give {}'s own private key (the `{}.key` that `hetcomm keygen` wrote with the public keys in the fleet file)",
                        name(local),
                        name(local)
                    ),
                });
            }
            let peers = members()
                .filter_map(|p| {
                    fleet
                        .system(p)
                        .and_then(|s| s.public_key)
                        .map(|k| (p, PublicKey(k)))
                })
                .collect();
            (keypair, peers, Handshakes::OverTheLink)
        }
    };
    let policy = Policy {
        local,
        keypair,
        peers,
        data_from,
        acks_from,
    };
    Ok(Arc::new(SecurityLayer::new(&t.name, policy, handshakes)))
}

/// This process's private key for `local`: from the API, the environment, or the fleet file.
fn private_key_for(
    fleet: &Fleet,
    local: SystemId,
    given: Option<&PrivateKey>,
    transport: &str,
) -> Result<PrivateKey, SecurityError> {
    if let Some(key) = given {
        return Ok(key.clone());
    }
    let system = fleet.system(local);
    let name = system.map(|s| s.name.as_str()).unwrap_or("?");
    let load = |path: PathBuf, from: String| {
        PrivateKey::load(&path).map_err(|e| {
            let fix = match &e {
                // The error already says which chmod to run.
                KeyError::TooOpen { .. } => {
                    "make it readable by its owner only, as `hetcomm keygen` wrote it".to_string()
                }
                _ => format!("point it at the `{name}.key` file `hetcomm keygen` wrote for {name}"),
            };
            SecurityError {
                problem: format!("cannot read the private key of {name} ({from}): {e}"),
                fix,
            }
        })
    };
    if let Some(path) = std::env::var_os(PRIVATE_KEY_ENV) {
        return load(PathBuf::from(path), format!("from {PRIVATE_KEY_ENV}"));
    }
    // Where a key from the keys directory would be: the fleet file's `[security] keys`, or
    // `--keys` (either sets `keys_dir`).
    let in_dir = fleet
        .keys_dir
        .as_ref()
        .map(|d| d.join(format!("{name}.key")));
    match system.and_then(|s| s.private_key_file.clone()) {
        Some(path) if in_dir.as_ref() == Some(&path) => {
            load(path, "found in the fleet's keys directory".into())
        }
        Some(path) => load(
            path,
            format!("the fleet file's `private_key_file` for {name}"),
        ),
        None => {
            let looked = match &in_dir {
                Some(p) => format!("there is no {}, ", p.display()),
                None => "the fleet names no keys directory, ".into(),
            };
            Err(SecurityError {
                problem: format!(
                    "transport `{transport}` is secured but this process has no private key for system {name}: {looked}no `private_key_file` for {name}, and {PRIVATE_KEY_ENV} is not set"
                ),
                fix: format!(
                    "put {name}'s `.key` file there (`hetcomm keygen` writes `{name}.key`), set `private_key_file` for {name}, set {PRIVATE_KEY_ENV}=<path>, or pass the key through the API (OpenOptions::private_key)"
                ),
            })
        }
    }
}

/// Options for opening one system ([`Comm::open_with`](crate::Comm::open_with)).
#[derive(Clone, Debug, Default)]
pub struct OpenOptions {
    pub(crate) private_key: Option<PrivateKey>,
    pub(crate) shapes: hetcomm_link::shape::MessageShapes,
}

impl OpenOptions {
    /// Default options: keys from the fleet file and the environment.
    pub fn new() -> Self {
        Self::default()
    }

    /// This system's private key, read from a `.key` file (`hetcomm keygen` writes them),
    /// instead of the fleet file's `private_key_file` or the environment.
    pub fn private_key_file(
        mut self,
        path: impl AsRef<std::path::Path>,
    ) -> Result<Self, hetcomm_security::KeyError> {
        self.private_key = Some(PrivateKey::load(path.as_ref())?);
        Ok(self)
    }

    /// This system's private key, given directly.
    pub fn private_key(mut self, key: PrivateKey) -> Self {
        self.private_key = Some(key);
        self
    }

    /// Declares message type `M` (its id, name and fields, read off its `Deserialize`), so a
    /// transport that converts payloads checks its mappings of `M` when it opens: a ROS
    /// bridge refuses to open if `M` does not convert to the ROS type a mapping names, with
    /// both types and the field in the error. Types not declared are checked per message.
    pub fn message<M: hetcomm_core::Message>(mut self) -> Self {
        self.shapes
            .insert(M::TYPE.0, M::NAME, crate::shape::trace::<M>());
        self
    }
}
