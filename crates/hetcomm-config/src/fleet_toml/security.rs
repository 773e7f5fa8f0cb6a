//! `[security]` (`keys = "DIR"`, the directory `hetcomm keygen` wrote) and each system's own
//! `public_key`, `public_key_file` and `private_key_file`. A transport's `security` is read
//! with its other common keys (`transports.rs`).

use super::*;
use crate::assemble::SysKeys;
use crate::keys;

impl P<'_> {
    /// `[security]`: resolves `keys`, checks the directory exists and fills in every system's
    /// keys from it where the system does not give its own. Returns the directory.
    pub(super) fn security(
        &mut self,
        item: &Item,
        top: &Loc,
        systems: &mut Systems,
    ) -> Option<PathBuf> {
        let loc = self.vloc(item, top);
        let t = self.table(item, "security", &loc)?;
        self.unknown_keys(t, &SECURITY_KEYS, Some("security"), &loc);
        let v = t.get("keys")?;
        let vl = self.vloc(v, &loc);
        let s = self.string(
            v,
            "security.keys",
            &vl,
            "write the directory `hetcomm keygen` wrote, in quotes, relative to the fleet file, \
             e.g. `keys = \"keys\"`",
        )?;
        let dir = self.resolve(s);
        if self.read_keys != KeyReading::All {
            return Some(dir);
        }
        let keygen = format!("hetcomm keygen --fleet {}", self.file);
        if !keys::check_dir(&dir, &vl, &keygen, &mut self.diag) {
            return Some(dir);
        }
        for spec in &mut systems.list {
            let own_public = spec.keys.public_given;
            let (public, private) = keys::from_dir(&dir, &spec.name, &mut self.diag);
            if !own_public {
                spec.keys.public_key = public;
            }
            if spec.keys.private_key_file.is_none() {
                spec.keys.private_key_file = private;
            }
        }
        Some(dir)
    }

    /// `[security] in_process = true`: secure in-process links too (unknown keys are reported
    /// by [`P::security`]).
    pub(super) fn security_in_process(&mut self, item: &Item, top: &Loc) -> Option<bool> {
        let loc = self.vloc(item, top);
        let v = item.as_table_like()?.get("in_process")?;
        let vl = self.vloc(v, &loc);
        self.boolean(
            v,
            "security.in_process",
            &vl,
            "write `in_process = true` to secure in-process and emulated links as well, or leave it out",
        )
    }

    /// A system's own keys in its long form `[systems.Name]`.
    pub(super) fn system_keys(
        &mut self,
        st: &dyn TableLike,
        path: &str,
        vl: &Loc,
        name: &str,
    ) -> SysKeys {
        let mut keys = SysKeys::default();
        let file_help = "write a path in quotes, relative to the fleet file";
        match (st.get("public_key"), st.get("public_key_file")) {
            (Some(_), Some(_)) => {
                let fl = self.kloc(st, "public_key_file", vl);
                self.diag.err_help(
                    &fl,
                    format!("system `{name}` has both `public_key` and `public_key_file`"),
                    "keep one of them: the key itself, or the file that holds it",
                );
                keys.public_given = true;
            }
            (Some(v), None) => {
                keys.public_given = true;
                let kl = self.vloc(v, vl);
                let p = format!("{path}.public_key");
                let help = "write the key in quotes: the base64 line of the system's `.pub` file \
                            from `hetcomm keygen`";
                if let Some(s) = self.string(v, &p, &kl, help) {
                    match keys::decode(s.trim()) {
                        Ok(k) => keys.public_key = Some(k),
                        Err(problem) => self.diag.err_help(
                            &kl,
                            format!("`{p}` {problem}"),
                            "copy the whole base64 line of the `.pub` file `hetcomm keygen` \
                             wrote for this system, or name the file with `public_key_file`",
                        ),
                    }
                }
            }
            (None, Some(v)) => {
                keys.public_given = true;
                let fl = self.vloc(v, vl);
                let p = format!("{path}.public_key_file");
                if let Some(s) = self.string(v, &p, &fl, file_help) {
                    if self.read_keys != KeyReading::Nothing {
                        let file = self.resolve(s);
                        keys.public_key =
                            keys::read_public(&file, name, Some(&fl), false, &mut self.diag);
                    }
                }
            }
            (None, None) => {}
        }
        if let Some(v) = st.get("private_key_file") {
            let fl = self.vloc(v, vl);
            let p = format!("{path}.private_key_file");
            // Not read here: a fleet file names every machine's key, each machine has its own.
            if let Some(s) = self.string(v, &p, &fl, file_help) {
                keys.private_key_file = Some(self.resolve(s));
            }
        }
        keys
    }
}
