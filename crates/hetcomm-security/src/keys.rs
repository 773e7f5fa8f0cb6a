//! System keys: one X25519 key pair per system. The public key goes in the fleet file (inline
//! or by file); the private key stays with the process that runs the system.
//!
//! Text form (what `hetcomm keygen` writes and the fleet file holds): standard base64 of the
//! 32 key bytes (44 characters). Key files hold that line, optionally after comment lines
//! starting with `#`. A private key file must not be readable by other users (mode 0600).

use std::fmt;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::str::FromStr;

use base64::engine::general_purpose::STANDARD;
use base64::Engine;
use hetcomm_core::SystemId;
use rand::{RngCore, SeedableRng};

/// Bytes in a key (X25519).
pub const KEY_LEN: usize = 32;

/// A system's public key: what its peers need to authenticate it.
#[derive(Clone, Copy, PartialEq, Eq, Hash)]
pub struct PublicKey(pub [u8; KEY_LEN]);

/// A system's private key. Its `Debug` form does not show the key.
#[derive(Clone, PartialEq, Eq)]
pub struct PrivateKey(pub [u8; KEY_LEN]);

/// A system's key pair.
#[derive(Clone, Debug)]
pub struct Keypair {
    /// The secret half.
    pub private: PrivateKey,
    /// The public half, derived from the private one.
    pub public: PublicKey,
}

/// Why a key could not be read.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum KeyError {
    /// The text is not base64 of 32 bytes.
    #[error("{what}: {problem}")]
    Malformed {
        /// What was being read (a file name, or "public key of Alpha").
        what: String,
        /// What is wrong with it.
        problem: String,
    },
    /// A key file could not be read.
    #[error("{}: cannot read: {source}", path.display())]
    Read {
        /// The file.
        path: PathBuf,
        /// The operating system's error.
        #[source]
        source: std::io::Error,
    },
    /// A private key file that other users can read.
    #[error("{}: private key is readable by other users (mode {mode:o}); run `chmod 600 {}`", path.display(), path.display())]
    TooOpen {
        /// The file.
        path: PathBuf,
        /// Its permission bits.
        mode: u32,
    },
    /// A key file could not be written.
    #[error("{}: cannot write: {source}", path.display())]
    Write {
        /// The file.
        path: PathBuf,
        /// The operating system's error.
        #[source]
        source: std::io::Error,
    },
    /// The cryptography library refused (should not happen with 32-byte keys).
    #[error("key operation failed: {0}")]
    Crypto(String),
}

impl PublicKey {
    /// Parses the base64 text form; `what` names the source in errors.
    pub fn parse(text: &str, what: &str) -> Result<PublicKey, KeyError> {
        decode_key(text, what).map(PublicKey)
    }

    /// Reads a public key file.
    pub fn load(path: &Path) -> Result<PublicKey, KeyError> {
        let text = read_key_text(path)?;
        PublicKey::parse(&text, &path.display().to_string())
    }
}

impl PrivateKey {
    /// Parses the base64 text form; `what` names the source in errors.
    pub fn parse(text: &str, what: &str) -> Result<PrivateKey, KeyError> {
        decode_key(text, what).map(PrivateKey)
    }

    /// Reads a private key file, refusing one that other users can read.
    pub fn load(path: &Path) -> Result<PrivateKey, KeyError> {
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            let meta = std::fs::metadata(path).map_err(|source| KeyError::Read {
                path: path.to_path_buf(),
                source,
            })?;
            let mode = meta.permissions().mode() & 0o777;
            if mode & 0o077 != 0 {
                return Err(KeyError::TooOpen {
                    path: path.to_path_buf(),
                    mode,
                });
            }
        }
        let text = read_key_text(path)?;
        PrivateKey::parse(&text, &path.display().to_string())
    }

    /// The public key that goes with this private key.
    pub fn public_key(&self) -> Result<PublicKey, KeyError> {
        let resolver = snow::resolvers::DefaultResolver;
        use snow::resolvers::CryptoResolver;
        let mut dh = resolver
            .resolve_dh(&snow::params::DHChoice::Curve25519)
            .ok_or_else(|| KeyError::Crypto("no X25519 implementation".into()))?;
        dh.set(&self.0);
        let mut public = [0; KEY_LEN];
        public.copy_from_slice(dh.pubkey());
        Ok(PublicKey(public))
    }
}

impl Keypair {
    /// A new random key pair (from the operating system's random source).
    pub fn generate() -> Result<Keypair, KeyError> {
        let mut private = [0; KEY_LEN];
        rand::rngs::OsRng.fill_bytes(&mut private);
        Keypair::from_private(PrivateKey(private))
    }

    /// The key pair of `private`.
    pub fn from_private(private: PrivateKey) -> Result<Keypair, KeyError> {
        let public = private.public_key()?;
        Ok(Keypair { private, public })
    }

    /// A key pair derived from a simulation's `seed` and the system: the same seed gives the
    /// same keys, so a simulated secured fleet is as repeatable as an unsecured one. Never
    /// use these outside a simulation: anyone who knows the seed knows the keys.
    pub fn for_simulation(seed: u64, system: SystemId) -> Keypair {
        let mut rng = rand_chacha::ChaCha20Rng::seed_from_u64(
            seed ^ 0x6865_7463_6f6d_6d00 ^ ((system.0 as u64) << 40),
        );
        let mut private = [0; KEY_LEN];
        rng.fill_bytes(&mut private);
        Keypair::from_private(PrivateKey(private)).expect("X25519 accepts any 32 bytes")
    }

    /// Writes `<dir>/<name>.key` (mode 0600) and `<dir>/<name>.pub`; returns their paths.
    pub fn write(&self, dir: &Path, name: &str) -> Result<(PathBuf, PathBuf), KeyError> {
        let private_path = dir.join(format!("{name}.key"));
        let public_path = dir.join(format!("{name}.pub"));
        let private_text = format!(
            "# hetcomm private key of system {name} (X25519). Keep it secret: only the process that runs {name} needs it.\n{}\n",
            STANDARD.encode(self.private.0)
        );
        write_file(&private_path, &private_text, true)?;
        let public_text = format!(
            "# hetcomm public key of system {name} (X25519): every system of the fleet may know it.\n{}\n",
            self.public
        );
        write_file(&public_path, &public_text, false)?;
        Ok((private_path, public_path))
    }
}

fn write_file(path: &Path, text: &str, secret: bool) -> Result<(), KeyError> {
    let err = |source| KeyError::Write {
        path: path.to_path_buf(),
        source,
    };
    let mut options = std::fs::OpenOptions::new();
    options.write(true).create(true).truncate(true);
    #[cfg(unix)]
    if secret {
        use std::os::unix::fs::OpenOptionsExt;
        options.mode(0o600);
    }
    let mut file = options.open(path).map_err(err)?;
    #[cfg(unix)]
    if secret {
        // An existing file keeps its mode on open: make sure it is private.
        use std::os::unix::fs::PermissionsExt;
        file.set_permissions(std::fs::Permissions::from_mode(0o600))
            .map_err(err)?;
    }
    let _ = secret;
    file.write_all(text.as_bytes()).map_err(err)
}

fn read_key_text(path: &Path) -> Result<String, KeyError> {
    std::fs::read_to_string(path).map_err(|source| KeyError::Read {
        path: path.to_path_buf(),
        source,
    })
}

fn decode_key(text: &str, what: &str) -> Result<[u8; KEY_LEN], KeyError> {
    let malformed = |problem: String| KeyError::Malformed {
        what: what.to_string(),
        problem,
    };
    let lines: Vec<&str> = text
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty() && !l.starts_with('#'))
        .collect();
    let line = match lines.as_slice() {
        [one] => *one,
        [] => {
            return Err(malformed(
                "no key found (expected one line of base64, as `hetcomm keygen` writes)".into(),
            ))
        }
        _ => {
            return Err(malformed(format!(
                "{} lines of text where one key was expected",
                lines.len()
            )))
        }
    };
    let bytes = STANDARD.decode(line).map_err(|e| {
        malformed(format!(
            "not a key: {e} (expected 44 characters of base64, as `hetcomm keygen` writes)"
        ))
    })?;
    bytes.as_slice().try_into().map_err(|_| {
        malformed(format!(
            "a key has {KEY_LEN} bytes, this one has {} (expected 44 characters of base64)",
            bytes.len()
        ))
    })
}

impl fmt::Display for PublicKey {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&STANDARD.encode(self.0))
    }
}

impl fmt::Debug for PublicKey {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "PublicKey({self})")
    }
}

impl FromStr for PublicKey {
    type Err = KeyError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        PublicKey::parse(s, "public key")
    }
}

impl fmt::Debug for PrivateKey {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("PrivateKey(…)")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn written_keys_read_back_and_the_private_file_is_private() {
        let dir = std::env::temp_dir().join(format!("hc-keys-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let pair = Keypair::generate().unwrap();
        let (private, public) = pair.write(&dir, "Alpha").unwrap();
        assert_eq!(PublicKey::load(&public).unwrap(), pair.public);
        assert_eq!(PrivateKey::load(&private).unwrap(), pair.private);
        use std::os::unix::fs::PermissionsExt;
        let mode = std::fs::metadata(&private).unwrap().permissions().mode() & 0o777;
        assert_eq!(mode, 0o600);
        std::fs::set_permissions(&private, std::fs::Permissions::from_mode(0o644)).unwrap();
        let err = PrivateKey::load(&private).unwrap_err().to_string();
        assert!(
            err.contains("readable by other users") && err.contains("chmod 600"),
            "{err}"
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn malformed_keys_say_what_is_wrong() {
        let e = PublicKey::parse("abc", "keys/A.pub")
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("keys/A.pub: not a key"), "{e}");
        let e = PublicKey::parse(&STANDARD.encode([1u8; 16]), "k")
            .unwrap_err()
            .to_string();
        assert!(e.contains("this one has 16"), "{e}");
        let e = PublicKey::parse("# only a comment\n", "k")
            .unwrap_err()
            .to_string();
        assert!(e.contains("no key found"), "{e}");
    }

    #[test]
    fn simulation_keys_follow_the_seed() {
        let a = Keypair::for_simulation(7, SystemId(1));
        assert_eq!(a.public, Keypair::for_simulation(7, SystemId(1)).public);
        assert_ne!(a.public, Keypair::for_simulation(8, SystemId(1)).public);
        assert_ne!(a.public, Keypair::for_simulation(7, SystemId(2)).public);
        assert_eq!(a.private.public_key().unwrap(), a.public);
    }
}
