//! [`SettingsReader`]: a registered kind's view of its transport table, reporting through the
//! walker's own helpers (`values.rs`) so its errors are located and worded like the built-in
//! kinds' errors.

use super::*;
use hetcomm_core::SystemId;

/// One transport's table, as a registered kind's [`crate::kinds::KindSpec::parse`] reads it.
/// Every read reports a problem at the `file:line:column` of the value (or of the transport's
/// table for a missing key) into the loader's list of errors, and returns None for it; a
/// key that is absent returns None without an error.
pub struct SettingsReader<'r, 'f> {
    p: &'r mut P<'f>,
    t: &'r dyn TableLike,
    path: String,
    tloc: Loc,
    name: &'r str,
    kind: TransportKind,
    systems: &'r Systems,
    /// What [`SettingsReader::layered_over`] read, for the loader.
    over: Option<(String, Loc)>,
}

impl<'r, 'f> SettingsReader<'r, 'f> {
    pub(super) fn new(
        p: &'r mut P<'f>,
        t: &'r dyn TableLike,
        (path, tloc): (String, Loc),
        (name, kind): (&'r str, TransportKind),
        systems: &'r Systems,
    ) -> Self {
        SettingsReader {
            p,
            t,
            path,
            tloc,
            name,
            kind,
            systems,
            over: None,
        }
    }

    /// The transport named by [`SettingsReader::layered_over`], with its location.
    pub(super) fn take_over(&mut self) -> Option<(String, Loc)> {
        self.over.take()
    }

    /// The transport's name.
    pub fn transport(&self) -> &str {
        self.name
    }

    /// The transport's kind.
    pub fn kind(&self) -> TransportKind {
        self.kind
    }

    /// The path `written` in the fleet file names: relative to the fleet file's directory,
    /// when it has one.
    pub fn path(&self, written: &str) -> std::path::PathBuf {
        match self.p.base_dir {
            Some(d) => d.join(written),
            None => std::path::PathBuf::from(written),
        }
    }

    /// Whether the table has `key`.
    pub fn has(&self, key: &str) -> bool {
        self.t.get(key).is_some()
    }

    fn item(&self, key: &str) -> Option<(&'r Item, Loc, String)> {
        let v = self.t.get(key)?;
        Some((
            v,
            self.p.vloc(v, &self.tloc),
            format!("{}.{key}", self.path),
        ))
    }

    /// A string; `help` says what to write instead of something else.
    pub fn string(&mut self, key: &str, help: &str) -> Option<String> {
        let (v, vl, path) = self.item(key)?;
        self.p.string(v, &path, &vl, help).map(str::to_string)
    }

    /// A number, written as an integer or a float (`5` or `5.0`); `help` says what to write
    /// instead of something else.
    pub fn number(&mut self, key: &str, help: &str) -> Option<f64> {
        let (v, vl, path) = self.item(key)?;
        match v.as_value() {
            Some(Value::Integer(i)) => Some(*i.value() as f64),
            Some(Value::Float(f)) => Some(*f.value()),
            _ => {
                self.p.wrong_type(&vl, &path, "a number", v, help);
                None
            }
        }
    }

    /// `key`'s dotted path as errors name it, e.g. `transports.radio.loss_percent`.
    pub fn key_path(&self, key: &str) -> String {
        format!("{}.{key}", self.path)
    }

    /// `key`'s value as the file writes it, for an error that quotes it.
    pub fn written(&self, key: &str) -> Option<String> {
        let (v, _, _) = self.item(key)?;
        Some(self.p.raw(v))
    }

    /// The name of the transport this one is layered over (`over = "lan"`): its frames travel
    /// on that transport's link. The loader checks that it names another transport, rejects
    /// loops, follows it for the table's address check and for
    /// [`Fleet::leaves_process`](crate::Fleet::leaves_process), whatever the kind, and keeps
    /// it as [`TransportDef::over`](crate::TransportDef::over).
    pub fn layered_over(&mut self, key: &str, help: &str) -> Option<String> {
        let (v, vl, path) = self.item(key)?;
        let name = crate::names::nfc(self.p.string(v, &path, &vl, help)?).into_owned();
        self.over = Some((name.clone(), vl));
        Some(name)
    }

    /// An integer from `min` to `max`.
    pub fn int_in(&mut self, key: &str, min: i64, max: i64, help: &str) -> Option<i64> {
        let (v, vl, path) = self.item(key)?;
        self.p.int_in(v, &path, &vl, min, max, help)
    }

    /// An array of strings (`["a", "b"]`, possibly empty); `help` says what to write instead
    /// of something else.
    pub fn strings(&mut self, key: &str, help: &str) -> Option<Vec<String>> {
        let (v, vl, path) = self.item(key)?;
        let strings = v.as_array().and_then(|a| {
            a.iter()
                .map(|e| e.as_str().map(str::to_string))
                .collect::<Option<Vec<String>>>()
        });
        if strings.is_none() {
            self.p
                .wrong_type(&vl, &path, "an array of strings", v, help);
        }
        strings
    }

    /// `true` or `false`.
    pub fn boolean(&mut self, key: &str, help: &str) -> Option<bool> {
        let (v, vl, path) = self.item(key)?;
        self.p.boolean(v, &path, &vl, help)
    }

    /// One of `options` (its index), reporting anything else with a "did you mean";
    /// `what` names one and several of them, e.g. `("mode", "modes")`.
    pub fn choice(&mut self, key: &str, what: (&str, &str), options: &[&str]) -> Option<usize> {
        let (v, vl, path) = self.item(key)?;
        self.p.choice(v, &path, &vl, what, options)
    }

    /// `key = { "name" = "text", … }` (or a `[transports.x.key]` section): each entry's name
    /// and string value, in file order. Entries that are not strings are reported (and left
    /// out); a `key` that is not a table is reported and gives None.
    pub fn string_table(&mut self, key: &str, help: &str) -> Option<Vec<(String, String)>> {
        let (v, vl, path) = self.item(key)?;
        let t = self.p.table(v, &path, &vl)?;
        let mut out = Vec::new();
        for (name, item) in t.iter() {
            let il = self.p.vloc(item, &vl);
            if let Some(text) = self.p.string(item, &format!("{path}.{name}"), &il, help) {
                out.push((name.to_string(), text.to_string()));
            }
        }
        Some(out)
    }

    /// Reports a problem of entry `entry` of the table `key` (see
    /// [`string_table`](Self::string_table)) at that entry's value.
    pub fn error_entry(
        &mut self,
        key: &str,
        entry: &str,
        message: impl Into<String>,
        help: impl Into<String>,
    ) {
        let loc = match self.item(key) {
            Some((v, vl, _)) => match v.as_table_like().and_then(|t| t.get(entry)) {
                Some(item) => self.p.vloc(item, &vl),
                None => vl,
            },
            None => self.tloc.clone(),
        };
        self.p.diag.err_help(&loc, message, help);
    }

    /// `key = { System = "host:port", … }`, checked as `udp` and `tcp` endpoints are: known
    /// systems, well-formed `host:port`, and no two systems of this kind on one address and
    /// port (port 0 excepted).
    pub fn endpoints(&mut self, key: &str) -> Option<BTreeMap<SystemId, String>> {
        let v = self.t.get(key)?;
        let path = format!("{}.{key}", self.path);
        Some(
            self.p
                .endpoints(v, &path, &self.tloc, (self.name, self.kind), self.systems),
        )
    }

    /// `key = { System = "XX:XX:XX:XX:XX:XX", … }`: each system's Bluetooth device address,
    /// checked as the thesis's address files are: known systems, well-formed addresses, one
    /// per system, none used twice.
    pub fn bluetooth_addresses(&mut self, key: &str) -> Option<BTreeMap<SystemId, BdAddr>> {
        let v = self.t.get(key)?;
        let path = format!("{}.{key}", self.path);
        Some(self.p.addresses(v, &path, &self.tloc, self.systems))
    }

    /// `key = "bt.txt"`: a file of Bluetooth device addresses in the thesis's Table 3 format
    /// (`<id> <address>` per line), relative to the fleet file, checked as
    /// [`bluetooth_addresses`](Self::bluetooth_addresses) are; with the file's name as errors
    /// give it. None when the key is absent or not a string; a file that cannot be read is
    /// reported and gives no addresses.
    pub fn bluetooth_address_file(
        &mut self,
        key: &str,
    ) -> Option<(BTreeMap<SystemId, BdAddr>, String)> {
        let (v, vl, path) = self.item(key)?;
        let help = "write a path in quotes, relative to the fleet file";
        let written = self.p.string(v, &path, &vl, help)?;
        let file = self.path(written);
        let lp = LegacyPath {
            display: Rc::from(file.display().to_string()),
            path: file,
            loc: vl,
        };
        let addresses = match self.p.read_legacy(&lp) {
            Some(text) => {
                let lines = legacy::parse_bluetooth(&lp.display, &text, &mut self.p.diag);
                assemble::bt_addresses(lines, self.systems, &lp.display, &mut self.p.diag)
            }
            None => BTreeMap::new(),
        };
        Some((addresses, lp.display.to_string()))
    }

    /// Reports a required key that is absent, at the transport's table, as the built-in kinds
    /// do: "transport `x` (kind k) is missing required setting `key`".
    pub fn missing(&mut self, key: &str, help: &str) {
        self.p.diag.err_help(
            &self.tloc,
            format!(
                "transport `{}` (kind {}) is missing required setting `{key}`",
                self.name, self.kind
            ),
            help,
        );
    }

    /// Reports a problem of the kind's own (a value out of its domain, two keys that do not
    /// fit together) at `key`'s value, or at the transport's table when `key` is absent.
    pub fn error(&mut self, key: &str, message: impl Into<String>, help: impl Into<String>) {
        let loc = match self.item(key) {
            Some((_, vl, _)) => vl,
            None => self.tloc.clone(),
        };
        self.p.diag.err_help(&loc, message, help);
    }
}
