//! The command line's `--keys DIR` and `--insecure`, shared by every command that opens
//! systems (`listen`, `send`, `demo`, `experiment reliability`): both change the loaded fleet
//! before anything is opened.

use std::path::{Path, PathBuf};

use hetcomm::config::Fleet;

/// The warning `--insecure` prints on stderr, whatever else the command prints.
pub const INSECURE_WARNING: &str = "warning: --insecure: security is OFF on every transport: \
     traffic is unauthenticated and unencrypted, and anyone who can reach the fleet's \
     transports can pose as any system";

/// `--keys DIR` and `--insecure`.
#[derive(clap::Args, Clone, Debug, Default)]
pub struct SecurityArgs {
    /// Read the systems' keys from DIR instead of the fleet file's `[security] keys` directory
    /// (public keys from DIR/<System>.pub, this system's private key from DIR/<System>.key):
    /// for a fleet without `[security]` (e.g. one importing the thesis's legacy files) or whose
    /// keys are elsewhere on this machine. Write DIR with `hetcomm keygen`. Keys found there
    /// replace the fleet file's.
    #[arg(long, value_name = "DIR")]
    pub keys: Option<PathBuf>,
    /// Turn security off on every transport, as `security = "none"` would: frames are neither
    /// authenticated nor encrypted, so anyone who can reach the fleet's sockets can pose as
    /// any system. Prints a warning. For trying a fleet before its keys exist, never for
    /// robots on a shared network.
    #[arg(long, conflicts_with = "keys")]
    pub insecure: bool,
    /// Secure the links that stay in the process too (in-process and emulated ones), as
    /// `[security] in_process = true` would: every frame sealed, keys made for the run (or,
    /// in a simulation, from the seed). A simulation gives the same tables as without.
    #[arg(long, conflicts_with = "insecure")]
    pub secure: bool,
}

impl SecurityArgs {
    /// Loads the fleet file at `path` (its errors, each with file:line:column, are the whole
    /// message) and applies the flags. With `--keys DIR` the fleet file's own `[security] keys`
    /// directory is not read (it need not exist on this machine); with `--insecure` no key
    /// file is read, so a fleet whose keys do not exist yet still runs.
    pub fn load(&self, path: &Path) -> anyhow::Result<Fleet> {
        let kinds = hetcomm::registry().kinds();
        let loaded = match (&self.keys, self.insecure) {
            (_, true) => hetcomm::config::load_skipping_keys(path, kinds),
            (Some(dir), false) => hetcomm::config::load_with_keys_dir(path, kinds, dir),
            (None, false) => hetcomm::load_fleet(path),
        };
        let mut fleet = loaded.map_err(|errors| anyhow::anyhow!("{errors}"))?;
        self.apply(&mut fleet)?;
        Ok(fleet)
    }

    /// Applies the flags to a fleet loaded otherwise (the demo's embedded one, legacy files),
    /// printing the `--insecure` warning.
    pub fn apply(&self, fleet: &mut Fleet) -> anyhow::Result<()> {
        if let Some(dir) = &self.keys {
            hetcomm::config::apply_keys_dir(fleet, dir)
                .map_err(|errors| anyhow::anyhow!("--keys {}:\n{errors}", dir.display()))?;
        }
        if self.secure {
            fleet.secure_in_process = true;
        }
        if self.insecure {
            hetcomm::config::insecure(fleet);
            eprintln!("{INSECURE_WARNING}");
        }
        Ok(())
    }
}
